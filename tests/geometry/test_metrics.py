import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsem import metrics as m, quadrics as q


def _monte_carlo_iou(Ra, ca, ha, Rb, cb, hb, n=400_000, seed=0):
    rng = np.random.default_rng(seed)
    lo = np.minimum(ca - np.linalg.norm(ha), cb - np.linalg.norm(hb))
    hi = np.maximum(ca + np.linalg.norm(ha), cb + np.linalg.norm(hb))
    P = rng.uniform(lo, hi, size=(n, 3))
    ina = np.all(np.abs((P - ca) @ Ra) <= ha, axis=1)
    inb = np.all(np.abs((P - cb) @ Rb) <= hb, axis=1)
    union = (ina | inb).sum()
    return (ina & inb).sum() / union if union else 0.0


@pytest.mark.slow
def test_iou_exact_cases():
    I = np.eye(3)
    one = np.ones(3)
    assert np.isclose(m.iou_3d_boxes(I, np.zeros(3), one, I, np.zeros(3), one), 1.0)
    assert np.isclose(m.iou_3d_boxes(I, np.zeros(3), one, I, [1.0, 0, 0], one), 1 / 3)
    assert np.isclose(m.iou_3d_boxes(I, np.zeros(3), one, I, [1.0, 1.0, 0], one), 1 / 7)
    assert m.iou_3d_boxes(I, np.zeros(3), one, I, [2.0, 0, 0], one) == 0.0  # touching faces
    assert m.iou_3d_boxes(I, np.zeros(3), one, I, [5.0, 0, 0], one) == 0.0
    # Nested: a small box inside a big one.
    assert np.isclose(m.iou_3d_boxes(I, np.zeros(3), one, I, [0.1, 0, 0], 0.5 * one), 1 / 8)
    # A box rotated by 90 deg about z with swapped extents is the same box.
    Rz = np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]])
    assert np.isclose(m.iou_3d_boxes(I, np.zeros(3), [1.0, 2, 3], Rz, np.zeros(3), [2.0, 1, 3]), 1.0)


@pytest.mark.slow
def test_iou_against_monte_carlo_and_symmetric():
    rng = np.random.default_rng(0)
    Ra = np.asarray(q.random_rotation(jax.random.PRNGKey(0), (8,)))
    Rb = np.asarray(q.random_rotation(jax.random.PRNGKey(1), (8,)))
    ca = rng.normal(scale=0.3, size=(8, 3))
    cb = rng.normal(scale=0.3, size=(8, 3))
    ha = rng.uniform(0.2, 1.0, size=(8, 3))
    hb = rng.uniform(0.2, 1.0, size=(8, 3))
    iou = np.asarray(jax.jit(m.iou_3d_boxes)(Ra, ca, ha, Rb, cb, hb))
    iou_ba = np.asarray(m.iou_3d_boxes(Rb, cb, hb, Ra, ca, ha))
    np.testing.assert_allclose(iou, iou_ba, atol=1e-9)
    for k in range(8):
        ref = _monte_carlo_iou(Ra[k], ca[k], ha[k], Rb[k], cb[k], hb[k], seed=k)
        assert abs(iou[k] - ref) < 0.01, (k, iou[k], ref)
    assert np.all((iou >= 0) & (iou <= 1)) and iou.max() > 0.1


def test_ellipsoid_metric_symmetries():
    R = np.asarray(q.random_rotation(jax.random.PRNGKey(2)))
    c = np.array([1.0, 2.0, 3.0])
    r = np.array([0.5, 1.0, 2.0])
    # Permuting axes together with radii, and flipping axis signs, is the same ellipsoid.
    P = np.array([[0.0, 1, 0], [0, 0, 1], [1, 0, 0]])
    e = m.ellipsoid_errors(R @ P, c, P.T @ r, R, c, r)
    assert float(e["orientation"]) < 1e-5 and float(e["shape"]) < 1e-12
    e = m.ellipsoid_errors(R @ np.diag([-1.0, -1, 1]), c, -r, R, c, r)
    assert float(e["orientation"]) < 1e-5 and float(e["shape"]) < 1e-12
    # A 10 degree rotation about the middle axis reads as 10 degrees.
    a = np.radians(10.0)
    Ry = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    e = m.ellipsoid_errors(R @ Ry, c + [0.3, 0.4, 0], r + [0.1, 0, 0], R, c, r)
    np.testing.assert_allclose(float(e["orientation"]), 10.0, atol=1e-6)
    np.testing.assert_allclose(float(e["position"]), 0.5, atol=1e-12)
    np.testing.assert_allclose(float(e["shape"]), 0.1, atol=1e-12)
    # Two equal radii: rotation about the distinct axis is invisible; tilting it is not.
    rs = np.array([1.0, 1.0, 2.0])
    Rz = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    assert float(m.ellipsoid_errors(R @ Rz, c, rs, R, c, rs)["orientation"]) < 1e-5
    np.testing.assert_allclose(float(m.ellipsoid_errors(R @ Ry, c, rs, R, c, rs)["orientation"]), 10.0, atol=1e-6)
    # Sphere: orientation error is zero whatever the rotation.
    assert float(m.ellipsoid_errors(R, c, np.ones(3), np.eye(3), c, np.ones(3))["orientation"]) == 0.0


@pytest.mark.slow
def test_ellipsoid_metric_batched_with_finite_gradients():
    R = q.random_rotation(jax.random.PRNGKey(3), (4, 5))
    c = jnp.zeros((4, 5, 3))
    r = jnp.ones((4, 5, 3)) * jnp.array([1.0, 2.0, 3.0])
    e = jax.jit(m.ellipsoid_errors)(R, c, r, jnp.eye(3), c, r)
    assert e["orientation"].shape == (4, 5)
    g = jax.grad(lambda c: sum(jnp.sum(v) for v in m.ellipsoid_errors(R, c, r, R, c * 0, r).values()))(c)
    assert np.all(np.isfinite(g))


def test_adi_against_brute_force():
    rng = np.random.default_rng(5)
    a = rng.normal(size=(3, 40, 3))
    b = rng.normal(size=(3, 55, 3))
    ref = np.array([np.mean([np.min(np.linalg.norm(b[k] - p, axis=1)) for p in a[k]]) for k in range(3)])
    np.testing.assert_allclose(m.adi(a, b), ref, rtol=1e-10)
    assert float(m.adi(a[0], a[0])) == 0.0
    mask = np.zeros((3, 40), bool)
    mask[:, :10] = True
    ref_masked = np.array([np.mean([np.min(np.linalg.norm(b[k] - p, axis=1)) for p in a[k, :10]]) for k in range(3)])
    np.testing.assert_allclose(m.adi(a, b, true_mask=mask), ref_masked, rtol=1e-10)
    np.testing.assert_allclose(m.add(a, a + [0.0, 0.0, 0.5]), 0.5)


def test_auc_rectangle_rule():
    assert float(m.auc_pass_rate(jnp.zeros(10))) == pytest.approx(10.0)
    assert float(m.auc_pass_rate(jnp.full(10, 0.2))) == 0.0
    # Uniform errors over [0, 0.1]: the pass rate rises linearly, area 5.
    e = jnp.linspace(0, 0.1, 100001)
    assert float(m.auc_pass_rate(e)) == pytest.approx(5.0, abs=0.01)
    # NaN and inf count as failures.
    assert float(m.auc_pass_rate(jnp.array([0.0, jnp.nan, jnp.inf, 1.0]))) == pytest.approx(2.5)


def test_cost_statistics():
    mean, sem = m.mean_sem([1.0, 2.0, 3.0])
    assert mean == 2.0 and sem == pytest.approx(np.std([1, 2, 3], ddof=1) / np.sqrt(3))
    assert m.zero_intercept_slope([1.0, 2.0], [2.0, 4.0]) == pytest.approx(2.0)
    with pytest.raises(ValueError, match="x, y"):
        m.zero_intercept_slope([1.0], [1.0, 2.0])


def test_non_finite_ground_truth_is_refused_and_failed_predictions_stay_nan():
    eye, c, r = np.eye(3), np.zeros(3), np.array([0.3, 0.2, 0.1])
    with pytest.raises(ValueError, match="true_center: must be finite"):
        m.ellipsoid_errors(eye, c, r, eye, np.array([np.nan, 0, 0]), r)
    with pytest.raises(ValueError, match="half_extents_b: must be finite"):
        m.iou_3d_boxes(eye, c, r, eye, c, np.array([np.inf, 0.1, 0.1]))
    err = m.ellipsoid_errors(eye, jnp.array([jnp.nan, 0.0, 0.0]), r, eye, c, r)
    assert bool(jnp.isnan(err["position"]))
