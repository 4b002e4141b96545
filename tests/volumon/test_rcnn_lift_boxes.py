"""The lift at given boxes (jaxsem.volumon.rcnn.lift_boxes) and the scene figures on the true
boxes: each ellipsoid's centre projects into its box in the photograph's pixels, a box's
ellipsoid does not depend on the other boxes asked with it, and ``evaluate_scene(truth_boxes=True)``
scores the lift on every true object."""

import dataclasses

import jax
import numpy as np
import pytest
from test_rcnn import INIT, TINY, _frames
from test_rcnn_scene import _evaluate
from test_volumon_bop_eval import _scene  # the small written BOP scene

from jaxsem.models._rcnn import VoluMonRCNN  # layers: white-box
from jaxsem.training import LoadedModel
from jaxsem.volumon import rcnn


def _loaded(cfg=TINY):
    v = INIT(jax.random.PRNGKey(3), cfg)
    config = rcnn.RCNNTrainConfig(model=cfg, class_names=("a", "b", "c"))
    return LoadedModel(VoluMonRCNN(cfg), v, config, {"name": "tiny"})


@pytest.mark.parametrize("rule", ["class", "expectation"])
def test_centres_project_into_their_boxes_and_boxes_do_not_interact(rule):
    loaded = _loaded(dataclasses.replace(TINY, param_rule=rule))
    frame = _frames(1, 4, W=256, H=192)[0]  # twice the network's input size
    image, K = frame["rgb"], frame["K"]
    boxes = np.array([[20.0, 30.0, 90.0, 100.0], [150.0, 20.0, 250.0, 60.0], [100.0, 120.0, 130.0, 185.0]])
    cls = np.array([0, 2, 1])
    out = rcnn.lift_boxes(loaded, image, K, boxes, cls)
    assert out["center"].shape == (3, 3) and out["rotation"].shape == (3, 3, 3) and out["radii"].shape == (3, 3)
    assert np.all(np.isfinite(out["center"])) and np.all(out["center"][:, 2] > 0)
    uvw = out["center"] @ K.T
    uv = uvw[:, :2] / uvw[:, 2:]
    assert np.all(uv >= boxes[:, :2] - 0.5) and np.all(uv <= boxes[:, 2:] + 0.5), (uv, boxes)
    for i in range(3):  # alone: the same ellipsoid (another padding, the same RoI features)
        one = rcnn.lift_boxes(loaded, image, K, boxes[i : i + 1], cls[i : i + 1])
        for key in out:
            np.testing.assert_allclose(one[key][0], out[key][i], rtol=1e-4, atol=1e-5)
    other = rcnn.lift_boxes(loaded, image, K, boxes[:1], cls[1:2])  # another class: another row
    if rule == "class":
        assert np.max(np.abs(other["radii"][0] - out["radii"][0])) > 1e-6


def test_bad_boxes_and_classes_are_named():
    loaded = _loaded()
    frame = _frames(1, 0)[0]
    with pytest.raises(ValueError, match="class_ids"):
        rcnn.lift_boxes(loaded, frame["rgb"], frame["K"], [[1.0, 1.0, 20.0, 20.0]], [3])
    with pytest.raises(ValueError, match="boxes"):
        rcnn.lift_boxes(loaded, frame["rgb"], frame["K"], [[30.0, 1.0, 20.0, 20.0]], [0])
    empty = rcnn.lift_boxes(loaded, frame["rgb"], frame["K"], np.zeros((0, 4)), [])
    assert empty["center"].shape == (0, 3)


def test_scene_figures_on_the_true_boxes(monkeypatch, tmp_path):
    """Every object at least half visible is lifted at its own box, detected or not; a lift 2 cm
    off the truth reads 2 cm there, while the matched detections keep their own figure."""
    scene = _scene(tmp_path)
    from jaxsem.volumon import data as vdata

    truth = {}
    for f in vdata.load_bop_split(scene, "tune").frames:
        truth[vdata.read_rgb(f.image_path).tobytes()] = {o.class_name: o for o in f.objects}

    def lift(loaded, image, K, boxes, class_ids):
        objs = list(truth[np.asarray(image).tobytes()].values())
        by_box = [next(o for o in objs if np.allclose(o.visible_box, b)) for b in boxes]
        return {
            "rotation": np.stack([o.rotation for o in by_box]),
            "center": np.stack([o.center + [0.0, 0.02, 0.0] for o in by_box]),
            "radii": np.stack([o.radii for o in by_box]),
        }

    monkeypatch.setattr(rcnn, "lift_boxes", lift)
    r = _evaluate(monkeypatch, scene, {}, truth_boxes=True)
    t = r["on_true_boxes"]
    assert t["num_objects"] == 3 == r["num_truth"]
    assert t["median_center_error_m"] == pytest.approx(0.02, abs=1e-6)
    assert r["median_center_error_m"] == pytest.approx(0.01, abs=1e-6)  # the stand-in detector's
    assert t["baseline"]["median_center_error_m"] < 1e-3 and "parallel" not in t
