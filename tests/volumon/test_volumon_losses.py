"""VoluMon losses (eq. 5.8-5.14): zeros at the truth, gradients, masking, no NaN on bad input."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsem import quadrics
from jaxsem.models import Ellipsoid
from jaxsem.quadrics import stereo_right_T_left
from jaxsem.volumon import LossConfig, make_batch, volumon_loss
from jaxsem.volumon._losses import box_error, dual_loss, primal_loss, size_variance_loss  # layers: white-box
from jaxsem.volumon._synthetic import SceneConfig  # layers: white-box

_primal_loss = jax.jit(primal_loss, static_argnames="config")

K = jnp.array([[110.0, 0, 63.5], [0, 110.0, 47.5], [0, 0, 1]])


def _random_ellipsoids(seed, n):
    rng = np.random.default_rng(seed)
    R = np.asarray(quadrics.random_rotation(jax.random.PRNGKey(seed), (n,)))
    t = np.stack([rng.uniform(-0.15, 0.15, n), rng.uniform(-0.1, 0.1, n), rng.uniform(0.6, 1.2, n)], -1)
    r = rng.uniform(0.03, 0.12, (n, 3))
    return Ellipsoid(jnp.asarray(R), jnp.asarray(t), jnp.asarray(r))


def _stereo_boxes(ell, baseline=0.06):
    T_r = stereo_right_T_left(jnp.full(ell.center.shape[:-1], baseline), dtype=ell.center.dtype)
    bl, vl = quadrics.project_bbox(*ell, K, jnp.eye(4))
    br, vr = quadrics.project_bbox(*ell, K, T_r)
    assert np.all(vl) and np.all(vr)
    return bl, br, T_r


@pytest.mark.slow
def test_dual_loss_zero_with_zero_gradient_at_truth():
    ell = _random_ellipsoids(0, 6)
    bl, br, T_r = _stereo_boxes(ell)
    loss = dual_loss(ell, bl, br, K, T_r)
    assert float(loss) < 1e-16
    g = jax.grad(lambda c, r: dual_loss(Ellipsoid(ell.rotation, c, r), bl, br, K, T_r))(ell.center, ell.radii)
    assert np.max(np.abs(g[0])) < 1e-6 and np.max(np.abs(g[1])) < 1e-6
    # and it is positive, with a non-zero gradient, elsewhere
    moved = Ellipsoid(ell.rotation, ell.center + jnp.array([0.01, 0.0, 0.05]), ell.radii)
    assert float(dual_loss(moved, bl, br, K, T_r)) > 1e-3


def test_box_term_matches_definition():
    rng = np.random.default_rng(1)
    a = rng.uniform(0, 50, (5, 4))
    a[:, 2:] += a[:, :2]
    b = a + rng.normal(size=(5, 4))
    ref = []
    for x, y in zip(a, b):
        cx, cy = (x[:2] + x[2:]) / 2, (y[:2] + y[2:]) / 2
        ref.append(np.sum((cx - cy) ** 2) + np.sum(((x[2:] - x[:2]) - (y[2:] - y[:2])) ** 2))
    np.testing.assert_allclose(box_error(jnp.asarray(a), jnp.asarray(b)), ref, rtol=1e-10)
    np.testing.assert_allclose(box_error(jnp.asarray(a), jnp.asarray(b), 10.0), np.asarray(ref) / 100, rtol=1e-10)


@pytest.mark.slow
def test_dual_loss_on_rendered_data():
    """Boxes of the ray-cast renderer's masks agree with the projected dual quadric (ellipsoid
    objects), and the dual loss is ~0 at the true ellipsoid of those objects."""
    scene = SceneConfig(height=48, width=64, focal=55.0, classes=(1, 2), num_points=16)
    b = make_batch(3, np.arange(6), scene, input_size=32, keep_images=True)
    ell = Ellipsoid(
        b["gt_rotation"].astype(jnp.float64),
        b["gt_center"].astype(jnp.float64),
        b["gt_half_extents"].astype(jnp.float64),
    )
    # mask box (pixel centres) vs label box: within a pixel
    img = np.asarray(b["image"])
    for i in range(6):
        # the object is the only region differing from a re-render without it: use the points instead
        pts = np.asarray(b["points"][i])[np.asarray(b["point_mask"][i])]
        uv = pts @ np.asarray(scene.K(), np.float64).T
        uv = uv[:, :2] / uv[:, 2:]
        box = np.asarray(b["box_left"][i])
        assert np.all(uv >= box[:2] - 1e-3) and np.all(uv <= box[2:] + 1e-3)
    assert img.shape == (6, 48, 64, 3)
    loss = dual_loss(
        ell,
        b["box_left"].astype(jnp.float64),
        b["box_right"].astype(jnp.float64),
        b["K"].astype(jnp.float64),
        stereo_right_T_left(b["baseline"].astype(jnp.float64)),
    )
    assert float(loss) < 1e-6


@pytest.mark.parametrize("power", [None, 0.5, 0.0])
def test_primal_loss_zero_on_surface_and_formula(power):
    ell = _random_ellipsoids(2, 4)
    pts = quadrics.surface_points(jax.random.PRNGKey(0), *ell, 50)
    mask = jnp.ones(pts.shape[:-1], bool)
    assert float(_primal_loss(ell, pts, mask)) < 1e-20
    # independent reference: eq. 5.12 with the primal quadric matrix, sizes in cm; the default
    # weight is Solina and Bajcsy's (sqrt(d0 d1 d2) x^T Q x)^2, 0.5 the literal eq. 5.12
    off = pts * 1.1
    cfg = LossConfig() if power is None else LossConfig(primal_size_power=power)
    p = 1.0 if power is None else power
    Q = np.asarray(quadrics.primal_quadric(*ell))
    ref = []
    for k in range(4):
        X = np.concatenate([np.asarray(off[k]), np.ones((50, 1))], -1)
        q = np.einsum("ni,ij,nj->n", X, Q[k], X)
        d = 2 * np.asarray(ell.radii[k]) / cfg.length_unit
        ref.append(np.prod(d) ** p * np.mean(q**2))
    np.testing.assert_allclose(_primal_loss(ell, off, mask, config=cfg), np.mean(ref), rtol=1e-8)


def test_primal_size_weight_does_not_favour_large_ellipsoids():
    """The size weight is there to "mitigate the bias of fitting to larger primitive sizes": at the
    same geometric distance of the points from the surface, a larger ellipsoid must not score
    better. With eq. 5.12 read literally (weight sqrt(d0 d1 d2)) it does (error ~ delta^2 / sqrt(r)),
    which let Optimise from scratch grow boxes' ellipsoids to a metre and recede."""
    dirs = np.asarray(quadrics.surface_points(jax.random.PRNGKey(3), jnp.eye(3), jnp.zeros(3), jnp.ones(3), 40))
    delta = 0.005
    eye, zero, mask = jnp.eye(3)[None], jnp.zeros((1, 3)), jnp.ones((1, 40), bool)

    def loss(r, cfg):
        pts = jnp.asarray(dirs * (r + delta))[None]  # all points delta outside a sphere of radius r
        return float(primal_loss(Ellipsoid(eye, zero, jnp.full((1, 3), r)), pts, mask, config=cfg))

    default = LossConfig()
    for r in (0.03, 0.06, 0.12):
        assert loss(2 * r, default) > loss(r, default)
    literal = LossConfig(primal_size_power=0.5)
    assert loss(0.12, literal) < loss(0.06, literal)  # the documented flaw of the literal reading


def test_primal_loss_masks_and_empty_masks():
    primal_loss = _primal_loss  # compiled whole: one program per shape, not one per operation
    ell = _random_ellipsoids(3, 3)
    pts = quadrics.surface_points(jax.random.PRNGKey(1), *ell, 10) * 1.2
    mask = np.ones((3, 10), bool)
    mask[1] = False  # an empty mask: this sample is skipped
    mask[2, 5:] = False
    full = primal_loss(ell, pts, jnp.asarray(mask))
    only0 = primal_loss(Ellipsoid(*(x[:1] for x in ell)), pts[:1], jnp.asarray(mask[:1]))
    only2 = primal_loss(Ellipsoid(*(x[2:] for x in ell)), pts[2:, :5], jnp.ones((1, 5), bool))
    np.testing.assert_allclose(full, (only0 + only2) / 2, rtol=1e-10)
    # all empty: zero, finite gradient
    g = jax.grad(lambda c: primal_loss(Ellipsoid(ell.rotation, c, ell.radii), pts, jnp.zeros((3, 10), bool)))(
        ell.center
    )
    assert float(primal_loss(ell, pts, jnp.zeros((3, 10), bool))) == 0.0
    assert np.all(np.isfinite(g))


def test_size_variance_per_class():
    rng = np.random.default_rng(4)
    sizes = rng.uniform(0.05, 0.3, (7, 3))
    cls = np.array([0, 1, 0, 2, 1, 0, 1])
    cfg = LossConfig()
    ref = cfg.eps_v
    for c in range(3):
        m = cls == c
        if m.sum() >= 2:
            ref += np.sum(np.var(sizes[m] / cfg.length_unit, axis=0))
    got = size_variance_loss(jnp.asarray(sizes), jnp.asarray(cls), 3, config=cfg)
    np.testing.assert_allclose(got, ref, rtol=1e-10)
    mask = np.ones(7, bool)
    mask[3] = False  # the lone class-2 sample is masked: nothing changes
    np.testing.assert_allclose(
        size_variance_loss(jnp.asarray(sizes), jnp.asarray(cls), 3, jnp.asarray(mask), cfg), ref, rtol=1e-10
    )


@pytest.mark.slow
def test_degenerate_inputs_no_nan():
    """Ellipsoid behind / around the camera, zero-size label box, zero depth points: finite
    loss and gradients, and the invalid case has a gradient leading back in front."""
    ell = _random_ellipsoids(5, 3)
    bl, br, T_r = _stereo_boxes(ell)
    bad_center = ell.center.at[0, 2].set(-0.5).at[1].set(0.0)  # behind; camera inside
    bl = bl.at[2].set(jnp.array([10.0, 10.0, 10.0, 10.0]))  # degenerate label: skipped

    def f(c):
        return dual_loss(Ellipsoid(ell.rotation, c, ell.radii), bl, br, K, T_r)

    val, g = jax.value_and_grad(f)(bad_center)
    assert np.isfinite(val) and np.all(np.isfinite(g))
    assert float(g[0, 2]) < 0  # increasing the depth of the object behind the camera lowers the loss
    pts = jnp.zeros((3, 4, 3))  # zero-depth points (at the camera centre)
    val, g = jax.value_and_grad(
        lambda c: primal_loss(Ellipsoid(ell.rotation, c, ell.radii), pts, jnp.ones((3, 4), bool))
    )(ell.center)
    assert np.isfinite(val) and np.all(np.isfinite(g))


@pytest.mark.slow
def test_volumon_loss_weights_and_float32():
    ell = _random_ellipsoids(6, 4)
    bl, br, _ = _stereo_boxes(ell)
    pts = quadrics.surface_points(jax.random.PRNGKey(2), *ell, 8) * 1.05
    batch = {
        "box_left": bl,
        "box_right": br,
        "K": jnp.broadcast_to(K, (4, 3, 3)),
        "baseline": jnp.full(4, 0.06),
        "points": pts,
        "point_mask": jnp.ones((4, 8), bool),
        "class_id": jnp.zeros(4, jnp.int32),
    }
    moved = Ellipsoid(ell.rotation, ell.center * 1.05, ell.radii)
    both = volumon_loss(moved, batch, LossConfig(alpha_S=0.0))
    dual_only = volumon_loss(moved, batch, LossConfig(alpha_P=0.0, alpha_S=0.0))
    np.testing.assert_allclose(both.total, both.dual + both.primal, rtol=1e-10)
    np.testing.assert_allclose(dual_only.total, both.dual, rtol=1e-10)
    assert float(dual_only.primal) == 0.0
    b32 = jax.tree.map(lambda x: x.astype(jnp.float32) if x.dtype == jnp.float64 else x, batch)
    e32 = Ellipsoid(*(x.astype(jnp.float32) for x in moved))
    t32 = volumon_loss(e32, b32)
    assert t32.total.dtype == jnp.float32
    np.testing.assert_allclose(t32.total, volumon_loss(moved, batch).total, rtol=1e-3)


def test_loss_config_validation():
    with pytest.raises(ValueError, match="alpha_D"):
        LossConfig(alpha_D=-1.0)
    with pytest.raises(ValueError, match="length_unit"):
        LossConfig(length_unit=0.0)
    with pytest.raises(ValueError, match="primal_size_power"):
        LossConfig(primal_size_power=-0.5)


def _inside(local, half, shape):
    """Brute-force inside test of points (..., 3) in the object frame."""
    if shape == 0:
        return np.all(np.abs(local) <= half, -1)
    if shape == 1:
        return np.sum((local / half) ** 2, -1) <= 1
    return (np.sum((local[..., :2] / half[:2]) ** 2, -1) <= 1) & (np.abs(local[..., 2]) <= half[2])


# The ray casts compared with ray marching below run jitted (one compile per input shape; the
# shape code is an argument, so the three shapes share it): run op by op they compiled some two
# hundred small programs. Their eager checks of concrete input are tested in
# test_ray_entry_range_finite_gradients_in_degenerate_rays.
_ray_cast_local = jax.jit(quadrics.ray_cast_local)
_ray_entry_range = jax.jit(quadrics.ray_entry_range)


@pytest.mark.parametrize("shape", [0, 1, 2])
def test_ray_entry_range_matches_ray_marching(shape):

    ell = _random_ellipsoids(7 + shape, 6)
    rng = np.random.default_rng(shape)
    # rays towards points scattered around each object (some miss), at the range of each object
    targets = np.asarray(ell.center)[:, None, :] + rng.normal(scale=0.08, size=(6, 40, 3))
    s, hit = _ray_entry_range(jnp.asarray(targets), ell.rotation, ell.center, ell.radii, jnp.full((6,), shape))
    s, hit = np.asarray(s), np.asarray(hit)
    steps = np.linspace(0.0, 2.5, 25001)  # 0.1 mm marching
    for i in range(6):
        R, t, h = (np.asarray(x[i]) for x in ell)
        for j in range(40):
            d = targets[i, j] / np.linalg.norm(targets[i, j])
            inside = _inside((steps[:, None] * d - t) @ R, h, shape)
            if inside.any():
                first = steps[np.argmax(inside)]
                # grazing rays may straddle the sampling; otherwise the first inside sample is the entry
                if inside.sum() > 20:
                    assert hit[i, j]
                    assert abs(s[i, j] - first) < 3e-4
            else:
                assert not hit[i, j]


@pytest.mark.parametrize("shape", [0, 1, 2])
def test_ray_cast_local_entry_and_normal(shape):
    # the object-frame ray cast under ray_entry_range and VoluMon's renderer: rays of camera z = 1
    # (not unit length), the parameter is the z-depth; the normal is the surface's at the entry
    rng = np.random.default_rng(10 + shape)
    half = np.array([0.05, 0.04, 0.07])
    R = np.asarray(quadrics.random_rotation(jax.random.PRNGKey(shape)))
    t = np.array([0.01, -0.02, 0.6])
    uv = rng.normal(scale=0.08, size=(200, 2)) + t[:2] / t[2]
    rays = np.concatenate([uv, np.ones((200, 1))], -1)
    o, d = np.broadcast_to(-t @ R, rays.shape), rays @ R
    s, hit, normal = (np.asarray(x) for x in _ray_cast_local(o, d, half, shape))
    steps = np.linspace(0.0, 1.2, 24001)  # 0.05 mm marching
    for j in range(200):
        inside = _inside(o[j] + steps[:, None] * d[j], half, shape)
        if inside.sum() > 20:  # grazing rays may straddle the sampling
            assert hit[j] and abs(s[j] - steps[np.argmax(inside)]) < 2e-4
        elif not inside.any():
            assert not hit[j] and s[j] == 0
    assert hit.sum() > 50
    # the normal: unit, against the ray, and outward (a step along it leaves the object)
    p = o[hit] + s[hit, None] * d[hit]
    n = normal[hit]
    np.testing.assert_allclose(np.linalg.norm(n, axis=-1), 1.0, atol=1e-6)
    assert np.all(np.sum(n * d[hit], -1) < 0)
    assert not _inside(p + 1e-3 * n, half, shape).any()
    # ray_entry_range is this ray cast along unit rays: the range, not the z-depth
    s_range, hit_range = _ray_entry_range(jnp.asarray(rays[None]), R[None], t[None], half[None], np.array([shape]))
    np.testing.assert_array_equal(np.asarray(hit_range)[0], hit)
    np.testing.assert_allclose(np.asarray(s_range)[0], s * np.linalg.norm(rays, axis=-1), rtol=1e-5)


@pytest.mark.slow
def test_ray_entry_range_finite_gradients_in_degenerate_rays():

    R = jnp.eye(3)[None]
    t = jnp.array([[0.0, 0.0, 1.0]])
    r = jnp.array([[0.05, 0.05, 0.1]])
    # on the axis (parallel to a cylinder's axis and the cuboid's faces), grazing, missing, at the origin
    pts = jnp.array([[[0.0, 0.0, 0.9], [0.05, 0.0, 1.0], [0.5, 0.5, 1.0], [0.0, 0.0, 0.0]]])
    for shape in (0, 1, 2):

        def f(pts, t, r, shape=shape):
            s, hit = quadrics.ray_entry_range(pts, R, t, r, jnp.array([shape]))
            return jnp.sum(jnp.where(hit, s, 0.0))

        s, hit = quadrics.ray_entry_range(pts, R, t, r, jnp.array([shape]))
        assert bool(hit[0, 0]) and abs(float(s[0, 0]) - 0.9) < 1e-9
        assert not bool(hit[0, 2])
        for g in jax.grad(f, argnums=(0, 1, 2))(pts, t, r):
            assert np.all(np.isfinite(np.asarray(g)))
    # the core's door: bad concrete input is named
    with pytest.raises(ValueError, match="points"):
        quadrics.ray_entry_range(pts.at[0, 0, 0].set(jnp.nan), R, t, r, jnp.array([1]))
    with pytest.raises(ValueError, match="radii"):
        quadrics.ray_entry_range(pts, R, t, -r, jnp.array([1]))


def test_ray_primal_distance_sees_the_extent_along_the_view_ray():
    """Regression (issue 10): a ball predicted 3x too long along the viewing ray cost ~1 cm rms
    under the radial distance, so training never shrank that axis."""
    rng = np.random.default_rng(0)
    t = np.array([0.0, 0.0, 0.8])
    r_true = 0.035
    # visible hemisphere of the true ball: rays through the silhouette, first intersection
    uv = rng.uniform(-1, 1, (400, 2))
    uv = uv[np.sum(uv**2, -1) < 0.95][:64] * (r_true / 0.8)
    d = np.concatenate([uv, np.ones((len(uv), 1))], -1)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    b = d @ t
    s = b - np.sqrt(b**2 - (t @ t - r_true**2))
    pts = jnp.asarray((s[:, None] * d)[None])
    mask = jnp.ones(pts.shape[:2], bool)
    excess = 0.07
    inflated = Ellipsoid(jnp.eye(3)[None], jnp.asarray(t)[None], jnp.array([[r_true, r_true, r_true + excess]]))
    truth = Ellipsoid(jnp.eye(3)[None], jnp.asarray(t)[None], jnp.full((1, 3), r_true))
    losses = {}
    for mode in ("radial", "ray"):
        cfg = LossConfig(primal_distance=mode, length_unit=1.0)
        assert float(_primal_loss(truth, pts, mask, config=cfg)) < 1e-10
        losses[mode] = float(_primal_loss(inflated, pts, mask, config=cfg))
    # along its ray every visible point lies at least ~excess/2 behind the inflated front surface
    assert np.sqrt(losses["ray"]) > 0.5 * excess
    assert losses["ray"] > 4 * losses["radial"]


def test_outline_of_a_float32_prediction_draws_under_strict_promotion():
    # regression (strict promotion of the slow suite): a float32 prediction and K met the float64
    # identity pose inside ellipsoid_outline (`jaxsem volumon predict` figures)
    from jaxsem.volumon._draw import ellipsoid_outline  # layers: white-box

    K = np.array([[100.0, 0, 32], [0, 100.0, 24], [0, 0, 1]], np.float32)
    R, t, r = np.eye(3, dtype=np.float32), np.array([0, 0, 2], np.float32), np.full(3, 0.2, np.float32)
    out = ellipsoid_outline(Ellipsoid(R, t, r), K, n=16)
    ref = ellipsoid_outline(Ellipsoid(*(np.asarray(x, np.float64) for x in (R, t, r))), np.asarray(K, np.float64), n=16)
    assert out is not None and ref is not None and out.shape == (16, 2)
    np.testing.assert_array_equal(out, ref)
    # a sphere of radius 0.2 at 2 m, f = 100 px: a circle of radius 100 * 0.2 / sqrt(4 - 0.04) (to
    # float32 input rounding)
    np.testing.assert_allclose(np.hypot(out[:, 0] - 32, out[:, 1] - 24), 20 / np.sqrt(3.96), rtol=1e-6)
