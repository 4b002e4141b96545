"""Issue 45 item 13: the detect-and-lift network's loss (``rcnn_loss``) with every weight on.

Its VoluMon part (the stereo box term and the size consistency) is summed apart from
:func:`jaxsem.volumon.volumon_loss`, and only slow tests ran it: a size term added with the
wrong sign, or the right camera scored against the left label, went unseen. One jitted
evaluation on a hand-made forward pass (random heads, the RoIs on the labelled boxes) checks
the total against its weighted terms, with and without the VoluMon terms, and that each
camera's label box moves the stereo term.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_rcnn import TINY  # the tiny network of the R-CNN tests

from jaxsem.models._rcnn import RCNNOutput, anchors  # layers: white-box
from jaxsem.volumon.rcnn import RCNNLossConfig, rcnn_batch, rcnn_loss

# every weight on, none of them 1
LOSS = RCNNLossConfig(rpn=0.7, classification=1.3, box=0.9, dual=1.7, size=2.3, distill=0.03)
_loss = jax.jit(rcnn_loss, static_argnums=(2, 3))  # one compile


def _object(c, box, z):
    box = np.asarray(box, float)
    d = 120.0 * 0.06 / z  # the disparity of a rectified pair, 6 cm apart
    return {
        "class_name": "abc"[c],
        "visible_box": box,
        "box_left": box,
        "box_right": box - [d, 0, d, 0],
        "rotation": np.eye(3),
        "center": np.array([0.0, 0.0, z]),
        "radii": np.full(3, 0.05),
    }


@pytest.fixture(scope="module")
def setup():
    K = np.array([[120.0, 0, 64], [0, 120, 48], [0, 0, 1]])
    image = np.zeros((96, 128, 3), np.uint8)
    frames = [
        {"rgb": image, "K": K, "objects": [_object(0, [20, 20, 50, 60], 0.8), _object(0, [70, 30, 100, 70], 1.0)]},
        {"rgb": image, "K": K, "objects": [_object(1, [30, 10, 70, 50], 0.9), _object(1, [80, 40, 110, 80], 0.7)]},
    ]
    batch = rcnn_batch(frames, TINY, ["a", "b", "c"], 4)
    rng = np.random.default_rng(0)
    B, A, R, N = 2, len(anchors(TINY)), TINY.proposals, TINY.num_classes
    rois = np.tile([[10.0, 10, 40, 40]], (B, R, 1)) + rng.uniform(0, 40, (B, R, 1))
    rois[:, :4] = np.asarray(batch["boxes"])  # each labelled object has its RoI: all foreground
    f32 = lambda x: jnp.asarray(x, jnp.float32)
    out = RCNNOutput(
        f32(rng.normal(size=(B, A))),
        f32(rng.normal(size=(B, A, 4)) * 0.1),
        f32(rois),
        jnp.ones((B, R), bool),
        f32(rng.normal(size=(B, R, N + 1))),
        f32(rng.normal(size=(B, R, 4)) * 0.1),
        f32(rng.normal(size=(B, R, N, 10)) * 0.3),
    )
    return out, batch


@pytest.mark.parametrize("volumon_on", [0.0, 1.0])
def test_the_total_is_the_weighted_sum_of_its_terms(setup, volumon_on):
    out, batch = setup
    total, t = _loss(out, batch, TINY, LOSS, jnp.float32(volumon_on))
    assert min(float(t[k]) for k in ("rpn_cls", "rpn_box", "cls", "box", "dual")) > 1e-3
    assert float(t["size"]) > LOSS.volumon.eps_v + 1e-3  # the two members of a class differ in size
    detection = LOSS.rpn * (t["rpn_cls"] + t["rpn_box"]) + LOSS.classification * t["cls"] + LOSS.box * t["box"]
    want = detection + volumon_on * (LOSS.dual * t["dual"] + LOSS.size * t["size"])
    np.testing.assert_allclose(total, want, rtol=1e-6)
    np.testing.assert_allclose(t["total"], total, rtol=1e-7)


@pytest.mark.parametrize("camera", ["left", "right"])
def test_each_cameras_label_moves_the_stereo_term(setup, camera):
    out, batch = setup
    _, t = _loss(out, batch, TINY, LOSS, jnp.float32(1.0))
    key = f"box_{camera}"
    moved = {**batch, key: batch[key] + jnp.asarray([5.0, 0.0, 5.0, 0.0], batch[key].dtype)}
    _, t2 = _loss(out, moved, TINY, LOSS, jnp.float32(1.0))
    assert abs(float(t2["dual"]) - float(t["dual"])) > 1e-3 * float(t["dual"])
    np.testing.assert_allclose(t2["size"], t["size"], rtol=1e-7)  # the labels do not enter the size term


DISTILL = LOSS  # one config, one compile


@pytest.fixture(scope="module")
def taught(setup):
    """The setup's batch with a teacher's ellipsoid on three of its four labels (the first
    frame's second object has none)."""
    out, batch = setup
    rng = np.random.default_rng(1)
    valid = np.array([[True, False, False, False], [True, True, False, False]])
    q = np.linalg.qr(rng.normal(size=(2, 4, 3, 3)))[0]
    extra = {
        "teacher_rotation": jnp.asarray(q, jnp.float32),
        "teacher_center": jnp.asarray(rng.uniform([-0.1, -0.1, 0.6], [0.1, 0.1, 1.2], (2, 4, 3)), jnp.float32),
        "teacher_half_extents": jnp.asarray(rng.uniform(0.02, 0.08, (2, 4, 3)), jnp.float32),
        "teacher_valid": jnp.asarray(valid),
    }
    return out, {**batch, **extra}


def test_the_distillation_term_adds_with_its_weight(taught):
    out, batch = taught
    total, t = _loss(out, batch, TINY, DISTILL, jnp.float32(1.0))
    assert float(t["distill"]) > 1.0
    detection = DISTILL.rpn * (t["rpn_cls"] + t["rpn_box"]) + DISTILL.classification * t["cls"] + DISTILL.box * t["box"]
    weak = DISTILL.dual * t["dual"] + DISTILL.size * t["size"]
    np.testing.assert_allclose(total, detection + weak + DISTILL.distill * t["distill"], rtol=1e-6)
    burn_in, _ = _loss(out, batch, TINY, DISTILL, jnp.float32(0.0))  # no VoluMon term in the burn-in
    np.testing.assert_allclose(burn_in, detection, rtol=1e-6)


def test_only_labels_with_a_teacher_move_the_distillation_term(taught):
    out, batch = taught
    _, t = _loss(out, batch, TINY, DISTILL, jnp.float32(1.0))
    for frame, label, moves in ((0, 1, False), (1, 0, True), (0, 0, True)):
        c = np.array(batch["teacher_center"])
        c[frame, label, 2] += 0.3
        _, t2 = _loss(out, {**batch, "teacher_center": jnp.asarray(c)}, TINY, DISTILL, jnp.float32(1.0))
        changed = abs(float(t2["distill"]) - float(t["distill"])) > 1e-4 * float(t["distill"])
        assert changed == moves, (frame, label)
        np.testing.assert_allclose(t2["dual"], t["dual"], rtol=1e-7)


def test_no_teacher_anywhere_leaves_no_distillation_term(setup):
    out, batch = setup  # rcnn_batch of frames without teachers: teacher_valid all False
    assert not np.any(np.asarray(batch["teacher_valid"]))
    _, t = _loss(out, batch, TINY, DISTILL, jnp.float32(1.0))
    assert float(t["distill"]) == 0.0


PRIMAL = RCNNLossConfig(rpn=0.7, classification=1.3, box=0.9, dual=1.7, size=2.3, distill=0.03, primal=0.4)


@pytest.fixture(scope="module")
def pointed(setup):
    """The setup's batch with depth points on three of its four labels (the first frame's second
    object has none), and the last two points of every label masked out."""
    out, batch = setup
    rng = np.random.default_rng(2)
    P = 6
    pts = rng.uniform([-0.1, -0.1, 0.6], [0.1, 0.1, 1.1], (2, 4, P, 3))
    mask = np.zeros((2, 4, P), bool)
    mask[0, 0, :4] = mask[1, 0, :4] = mask[1, 1, :4] = True
    return out, {**batch, "points": jnp.asarray(pts, jnp.float32), "point_mask": jnp.asarray(mask)}


def test_the_primal_term_adds_with_its_weight(pointed):
    out, batch = pointed
    total, t = _loss(out, batch, TINY, PRIMAL, jnp.float32(1.0))
    assert float(t["primal"]) > 1e-3
    detection = PRIMAL.rpn * (t["rpn_cls"] + t["rpn_box"]) + PRIMAL.classification * t["cls"] + PRIMAL.box * t["box"]
    weak = PRIMAL.dual * t["dual"] + PRIMAL.size * t["size"]
    np.testing.assert_allclose(total, detection + weak + PRIMAL.primal * t["primal"], rtol=1e-6)
    burn_in, _ = _loss(out, batch, TINY, PRIMAL, jnp.float32(0.0))
    np.testing.assert_allclose(burn_in, detection, rtol=1e-6)


def test_only_the_marked_points_of_labels_move_the_primal_term(pointed):
    out, batch = pointed
    _, t = _loss(out, batch, TINY, PRIMAL, jnp.float32(1.0))
    for frame, label, point, moves in ((0, 1, 0, False), (0, 0, 5, False), (0, 0, 1, True), (1, 1, 3, True)):
        p = np.array(batch["points"])
        p[frame, label, point] += [0.05, -0.03, 0.2]
        _, t2 = _loss(out, {**batch, "points": jnp.asarray(p)}, TINY, PRIMAL, jnp.float32(1.0))
        changed = abs(float(t2["primal"]) - float(t["primal"])) > 1e-5 * float(t["primal"])
        assert changed == moves, (frame, label, point)


def test_no_points_anywhere_leaves_no_primal_term(pointed):
    out, batch = pointed
    _, t = _loss(out, {**batch, "point_mask": jnp.zeros_like(batch["point_mask"])}, TINY, PRIMAL, jnp.float32(1.0))
    assert float(t["primal"]) == 0.0
