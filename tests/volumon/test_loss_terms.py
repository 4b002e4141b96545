"""Issue 45 item 13: each VoluMon loss term with every weight on, zero (or minimal) at the truth
and positive off it, and the total the weighted sum of the terms.

The other fast loss tests switch terms off (a term scored against the wrong label, or added with
the wrong sign, then hides behind a zero weight). Here one batch of four samples in two classes
(members of a class share one size, so the size-consistency term is at its floor ``eps_v`` at
the truth) is labelled from the truth by :func:`jaxsem.quadrics.project_bbox` in both cameras of
a stereo pair built by hand, and every term of :func:`jaxsem.volumon.volumon_loss` is checked:
zero at the truth, positive when the prediction (or only one camera's label) moves, equal to
its definition evaluated with numpy, and the total equal to the weighted sum (the volume prior,
which is not zero at the truth, included).
"""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsem import quadrics
from jaxsem.models import Ellipsoid
from jaxsem.volumon import LossConfig, volumon_loss

K = np.array([[110.0, 0, 63.5], [0, 110.0, 47.5], [0, 0, 1]])
BASELINE = 0.06
CLASS = np.array([0, 1, 0, 1])
# every weight on, none of them 1 (a term added with the wrong weight shows)
CONFIG = LossConfig(alpha_P=0.7, alpha_D=1.3, alpha_S=90.0, alpha_C=0.4, alpha_O=0.05, alpha_V=0.3, eps_v=0.1)


def _truth():
    """Four ellipsoids in the left camera frame, two classes; radii ascending along the axes
    (the oracle's convention), one size per class."""
    rng = np.random.default_rng(0)
    R = np.asarray(quadrics.random_rotation(jax.random.PRNGKey(3), (4,)))
    t = np.stack([rng.uniform(-0.1, 0.1, 4), rng.uniform(-0.08, 0.08, 4), rng.uniform(0.7, 1.0, 4)], -1)
    sizes = np.array([[0.03, 0.05, 0.08], [0.04, 0.06, 0.07]])
    return Ellipsoid(jnp.asarray(R), jnp.asarray(t), jnp.asarray(sizes[CLASS]))


def _right_T_left():
    """The right camera ``BASELINE`` along the left camera's +x (a left-frame point p is
    p - [b, 0, 0] there), written out by hand."""
    T = np.eye(4)
    T[0, 3] = -BASELINE
    return T


_project = jax.jit(lambda ell, pose: quadrics.project_bbox(*ell, K, pose))


def _labels(ell):
    bl, vl = _project(ell, np.eye(4))
    br, vr = _project(ell, _right_T_left())
    assert np.all(vl) and np.all(vr)
    return np.asarray(bl), np.asarray(br)


def _batch(ell):
    bl, br = _labels(ell)
    points = quadrics.surface_points(jax.random.PRNGKey(1), *ell, 12)
    logits = np.where(np.arange(2)[None] == CLASS[:, None], 30.0, -30.0)  # confident and right
    return {
        "box_left": jnp.asarray(bl),
        "box_right": jnp.asarray(br),
        "K": jnp.broadcast_to(jnp.asarray(K), (4, 3, 3)),
        "baseline": jnp.full(4, BASELINE),
        "points": points,
        "point_mask": jnp.ones((4, 12), bool),
        "class_id": jnp.asarray(CLASS, jnp.int32),
        "gt_rotation": ell.rotation,
        "gt_center": ell.center,
        "gt_half_extents": ell.radii,
    }, jnp.asarray(logits)


def _box_error(a, b):
    """e_b of eq. 5.11 with numpy: squared differences of box centres and sizes."""
    ca, cb = (a[..., :2] + a[..., 2:]) / 2, (b[..., :2] + b[..., 2:]) / 2
    sa, sb = a[..., 2:] - a[..., :2], b[..., 2:] - b[..., :2]
    return np.sum((ca - cb) ** 2, -1) + np.sum((sa - sb) ** 2, -1)


def _moved(ell, seed):
    """The truth with every centre, rotation and size moved a little (all still in view)."""
    rng = np.random.default_rng(seed)
    dR = np.asarray(quadrics.so3_exp(jnp.asarray(rng.normal(0, 0.1, (4, 3)))))
    return Ellipsoid(
        ell.rotation @ jnp.asarray(dR),
        ell.center + jnp.asarray(rng.normal(0, 0.02, (4, 3))),
        ell.radii * jnp.asarray(np.exp(rng.normal(0, 0.1, (4, 3)))),
    )


@pytest.fixture(scope="module")
def setup():
    ell = _truth()
    batch, logits = _batch(ell)
    return ell, batch, logits


_loss = jax.jit(functools.partial(volumon_loss, config=CONFIG, num_classes=2))  # one compile


def test_every_term_is_zero_at_the_truth_with_every_weight_on(setup):
    ell, batch, logits = setup
    terms = _loss(ell, batch, class_logits=logits)
    assert float(terms.dual) < 1e-12  # both cameras' boxes are the truth's
    assert float(terms.primal) < 1e-12  # the points are on the surface
    assert float(terms.oracle) < 1e-12
    np.testing.assert_allclose(terms.size, CONFIG.eps_v, rtol=1e-12)  # one size per class
    assert float(terms.cls) < 1e-12


@pytest.mark.parametrize("seed", [1, 2])
def test_the_total_is_minimal_at_the_truth_and_each_term_positive_off_it(setup, seed):
    """Every weight on: the total grows off the truth, and so does each term that the move
    touches (the size term because the members of a class no longer share a size)."""
    ell, batch, logits = setup
    at = _loss(ell, batch, class_logits=logits)
    off = _loss(_moved(ell, seed), batch, class_logits=logits)
    assert float(off.total) > float(at.total) + 1.0
    assert float(off.dual) > 1.0 and float(off.primal) > 1e-3 and float(off.oracle) > 1.0
    assert float(off.size) > CONFIG.eps_v + 1.0


def test_the_total_is_the_weighted_sum_of_the_terms(setup):
    """Each field of the result against its definition evaluated here (numpy boxes, variances
    and cross-entropy), and the total against their weighted sum."""
    ell, batch, logits = setup
    moved = _moved(ell, 3)
    terms = _loss(moved, batch, class_logits=logits)
    pl, _ = _project(moved, np.eye(4))
    pr, _ = _project(moved, _right_T_left())
    dual = np.mean(
        _box_error(np.asarray(batch["box_left"]), np.asarray(pl))
        + _box_error(np.asarray(batch["box_right"]), np.asarray(pr))
    )
    np.testing.assert_allclose(terms.dual, dual, rtol=1e-9)
    d = 2 * np.asarray(moved.radii) / CONFIG.length_unit
    size = CONFIG.eps_v + sum(np.sum(np.var(d[CLASS == c], axis=0)) for c in (0, 1))
    np.testing.assert_allclose(terms.size, size, rtol=1e-9)
    lg = np.asarray(logits)
    ce = np.mean(np.log(np.sum(np.exp(lg - lg.max(-1, keepdims=True)), -1)) + lg.max(-1) - lg[np.arange(4), CLASS])
    np.testing.assert_allclose(terms.cls, ce, rtol=1e-9, atol=1e-20)
    want = (
        CONFIG.alpha_D * terms.dual
        + CONFIG.alpha_P * terms.primal
        + CONFIG.alpha_S * terms.size
        + CONFIG.alpha_C * terms.cls
        + CONFIG.alpha_O * terms.oracle
        + CONFIG.alpha_V * np.mean(np.sum(np.log(d), -1))  # the volume prior (sizes in length units)
    )
    np.testing.assert_allclose(terms.total, want, rtol=1e-12)
    assert min(float(x) for x in (terms.dual, terms.primal, terms.size, terms.oracle)) > 1e-3


@pytest.mark.parametrize("camera", ["left", "right"])
def test_each_cameras_label_is_scored(setup, camera):
    """Moving only one camera's label box (by 3 pixels) raises the dual term at the truth by
    exactly that box's e_b: each camera is scored against its own label."""
    ell, batch, logits = setup
    key = f"box_{camera}"
    shift = jnp.array([3.0, 0.0, 3.0, 0.0])
    moved = {**batch, key: batch[key].at[0].add(shift)}
    dual = _loss(ell, moved, class_logits=logits).dual
    np.testing.assert_allclose(dual, _box_error(np.zeros(4), np.asarray(shift)) / 4, rtol=1e-9)


def test_size_term_grows_with_the_spread_within_a_class(setup):
    """Spreading one class's sizes apart raises L_S (a variance, never rewarded), while
    scaling every member of a class alike leaves it at its floor."""
    ell, batch, logits = setup
    same = Ellipsoid(ell.rotation, ell.center, ell.radii * 1.2)
    np.testing.assert_allclose(_loss(same, batch, class_logits=logits).size, CONFIG.eps_v, rtol=1e-12)
    spread = [
        _loss(Ellipsoid(ell.rotation, ell.center, ell.radii.at[0].multiply(f)), batch, class_logits=logits).size
        for f in (1.05, 1.1, 1.2)
    ]
    assert float(spread[0]) > CONFIG.eps_v and float(spread[0]) < float(spread[1]) < float(spread[2])
