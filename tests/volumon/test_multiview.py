"""Photographs paired for the dual loss: the second view's boxes and the camera motion agree with
the truth, and only whole, static objects get a stereo label."""

from __future__ import annotations

import numpy as np
import pytest

from jaxsem.quadrics import project_bbox
from jaxsem.volumon import data as df
from jaxsem.volumon._losses import LossConfig, dual_loss_per_sample  # layers: white-box

K = np.array([[300.0, 0.0, 160.0], [0.0, 300.0, 120.0], [0.0, 0.0, 1.0]])
NAMES = ("ape", "can", "cat", "duck")


def _rot(axis, angle):
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    A = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle) * A + (1 - np.cos(angle)) * A @ A


def _world():
    rng = np.random.default_rng(5)
    objs = {}
    for i, name in enumerate(NAMES):
        R = _rot(rng.normal(size=3), rng.uniform(0, np.pi))
        objs[name] = (R, np.array([0.12 * i - 0.18, rng.uniform(-0.05, 0.05), 0.0]), rng.uniform(0.02, 0.05, 3))
    return objs


def _frame(fid, cam_x, world, moved=(), hidden=()):
    """A camera 0.9 m from the objects at ``cam_x`` along the row, looking at it; ``moved``
    objects are shifted 5 cm in this frame, ``hidden`` ones half visible."""
    c_R_w = _rot([0, 1, 0], -0.3 * cam_x)
    c_t_w = -c_R_w @ np.array([cam_x, 0.0, -0.9])
    objects = []
    for name, (R, p, r) in world.items():
        p = p + (np.array([0.05, 0.0, 0.0]) if name in moved else 0.0)
        Rc, tc = c_R_w @ R, c_R_w @ p + c_t_w
        box, _ = project_bbox(Rc, tc, r, K, np.eye(4))
        objects.append(
            {
                "class_name": name,
                "visible_box": np.asarray(box, np.float64),
                "visible_fraction": 0.5 if name in hidden else 1.0,
                "rotation": Rc,
                "center": tc,
                "radii": r,
            }
        )
    return {"rgb": np.zeros((240, 320, 3), np.uint8), "K": K, "objects": objects, "frame_id": fid}


def _dual(frame):
    """The dual loss of each stereo-labelled object's true ellipsoid, by name."""
    T = frame["right_T_left"]
    out = {}
    for o in frame["objects"]:
        if "box_right" in o:
            ell = (np.asarray(o["rotation"]), np.asarray(o["center"]), np.asarray(o["radii"]))
            loss = dual_loss_per_sample(ell, o["box_left"], o["box_right"], K, T, LossConfig(pixel_scale=10.0))
            out[o["class_name"]] = float(loss)
    return out


def test_pairs_agree_with_the_truth_and_skip_moved_and_hidden_objects():
    world = _world()
    frames = [
        _frame(0, -0.2, world),
        _frame(1, 0.05, world, hidden=("cat",)),
        _frame(2, 0.25, world, moved=("duck",)),
    ]
    out = df.multiview_frames(frames, baseline=(0.1, 0.5))
    for f in out:
        assert "right_T_left" in f and f["partner_id"] != f["frame_id"]
        losses = _dual(f)
        assert losses and max(losses.values()) < 1e-6
        labelled = set(losses)
        if 1 in (f["frame_id"], f["partner_id"]):
            assert "cat" not in labelled  # half hidden in frame 1
        if 2 in (f["frame_id"], f["partner_id"]):
            assert "duck" not in labelled  # it moved between the two photographs
    assert any(1 in (f["frame_id"], f["partner_id"]) for f in out if f["frame_id"] != 1)
    assert all("box_right" not in o for f in frames for o in f["objects"])  # the input is not changed


def test_baseline_range_and_no_partner():
    world = _world()
    frames = [_frame(i, x, world) for i, x in enumerate((0.0, 0.03, 0.3))]
    out = df.multiview_frames(frames, baseline=(0.2, 0.6))
    for f in out:
        dist = np.linalg.norm(np.linalg.inv(f["right_T_left"])[:3, 3])
        assert 0.2 <= dist <= 0.6
    assert out[0]["partner_id"] == 2 and out[1]["partner_id"] == 2
    lone = df.multiview_frames(frames[:2], baseline=(0.2, 0.6))
    assert all("right_T_left" not in f for f in lone)
    assert all("box_right" not in o for f in lone for o in f["objects"])


def test_frame_arrays_carry_each_pairs_motion():
    world = _world()
    frames = df.multiview_frames([_frame(0, -0.15, world), _frame(1, 0.15, world)])
    arr = df.frame_arrays(frames, (160, 120), class_names=NAMES, max_objects=6)
    np.testing.assert_allclose(arr["right_T_left"][0], frames[0]["right_T_left"], atol=1e-6)
    np.testing.assert_allclose(arr["right_T_left"][1], np.linalg.inv(frames[0]["right_T_left"]), atol=1e-5)
    assert arr["stereo_valid"][:, :4].all()
    np.testing.assert_allclose(arr["box_right"][0, 0], frames[0]["objects"][0]["box_right"] / 2, atol=1e-4)


def test_bad_baseline_is_refused():
    with pytest.raises(ValueError, match="baseline"):
        df.multiview_frames([], baseline=(0.5, 0.1))
