"""VoluMon R-CNN's scene figures (jaxsem.volumon.rcnn.evaluate_scene) with a stand-in detector of
known output on a small written BOP scene: AP counted by hand, the less visible objects neither
right nor wrong, the 3D figures of the matched detections, the baseline on the same boxes."""

import numpy as np
import pytest
from test_volumon_bop_eval import _scene  # the small written BOP scene

from jaxsem.training import LoadedModel
from jaxsem.volumon import data as vdata, rcnn
from jaxsem.volumon.data import LMO_CLASS_NAMES


def _stand_in(scene_dir, extra):
    """A detector answering each tuning photo with its objects' visible boxes (scores by object,
    centres 1 cm off the truth along x) plus ``extra`` (frame id -> rows of (class, box, score))."""
    scene = vdata.load_bop_split(scene_dir, "tune")
    by_image = {}
    for f in scene.frames:
        rows = [(o.class_name, o.visible_box, 0.9 - 0.1 * i, o.center + [0.01, 0, 0]) for i, o in enumerate(f.objects)]
        rows += [(c, np.asarray(b, float), s, np.array([0.0, 0.0, 1.0])) for c, b, s in extra.get(f.frame_id, [])]
        by_image[vdata.read_rgb(f.image_path).tobytes()] = rows

    def detect(loaded, image, K):
        rows = by_image[np.asarray(image).tobytes()]
        n = len(rows)
        return {
            "box": np.array([r[1] for r in rows], float).reshape(n, 4),
            "class_id": np.array([LMO_CLASS_NAMES.index(r[0]) for r in rows], np.int64),
            "class_name": [r[0] for r in rows],
            "score": np.array([r[2] for r in rows]),
            "probabilities": np.full((n, 8), 1 / 8),
            "rotation": np.tile(np.eye(3), (n, 1, 1)),
            "center": np.array([r[3] for r in rows], float).reshape(n, 3),
            "radii": np.full((n, 3), 0.02),
        }

    return detect


def _evaluate(monkeypatch, scene_dir, extra, min_visible=0.5, **kw):
    monkeypatch.setattr(rcnn, "detect_image", _stand_in(scene_dir, extra))
    loaded = LoadedModel(None, None, rcnn.RCNNTrainConfig(), {"name": "stand-in"})
    return rcnn.evaluate_scene(loaded, scene_dir, "tune", min_visible=min_visible, warmup=0, **kw)


def test_exact_boxes_score_ap_one_and_the_centres_offset(monkeypatch, tmp_path):
    scene = _scene(tmp_path)
    r = _evaluate(monkeypatch, scene, {})
    # frames 3 and 7: ape, can, ape at least half visible; the can of frame 7 (0.3) is not truth,
    # and its exact detection is left out rather than counted wrong
    assert r["num_truth"] == 3 and r["num_matched"] == 3 and r["frames"] == 2
    assert r["detection"]["ap50_per_class"]["ape"] == 1.0 and r["detection"]["ap50_per_class"]["can"] == 1.0
    assert r["detection"]["ap50_per_class"]["duck"] is None
    assert r["detection"]["ap50"] == 1.0 and r["detection"]["recall50"] == 1.0
    assert r["median_center_error_m"] == pytest.approx(0.01, abs=1e-6)
    assert r["baseline"]["median_center_error_m"] < 1e-3  # known sizes, exact boxes
    assert "parallel" not in r and r["ms_per_image"] >= 0


@pytest.mark.slow
def test_a_false_detection_costs_ap_and_a_lower_threshold_counts_the_hidden_can(monkeypatch, tmp_path):
    scene = _scene(tmp_path)
    # a can where there is none, scored above the true can of frame 3: can AP 1/2 (precision 1/2
    # at recall 1 after a miss at recall 0)
    r = _evaluate(monkeypatch, scene, {3: [("can", [200.0, 200.0, 230.0, 230.0], 0.99)]})
    assert r["detection"]["ap50_per_class"]["can"] == pytest.approx(0.5)
    assert r["detection"]["ap50_per_class"]["ape"] == 1.0 and r["num_matched"] == 3
    r = _evaluate(monkeypatch, scene, {}, min_visible=0.2)
    assert r["num_truth"] == 4 and r["num_matched"] == 4 and r["detection"]["ap50"] == 1.0
    with pytest.raises(ValueError, match="min_visible"):
        _evaluate(monkeypatch, scene, {}, min_visible=2.0)


def test_eval_command_scores_the_rcnn_on_a_bop_scene_only(run_cli, tmp_path):
    status, _, err = run_cli(["volumon", "eval", "--model", "lmo-rcnn"])
    assert status != 0 and "--model" in err.strip().splitlines()[-1] and "BOP scene" in err
    scene = _scene(tmp_path)
    status, _, err = run_cli(
        ["volumon", "eval", "--model", "lmo-rcnn", "--data", str(scene), "--split", "tune", "--postopt", "3"]
    )
    assert status != 0 and "--postopt" in err.strip().splitlines()[-1]


def test_centre_miss_split_into_distance_and_direction():
    rng = np.random.default_rng(3)
    for _ in range(20):
        g = rng.uniform([-0.3, -0.3, 0.5], [0.3, 0.3, 1.5])
        s = rng.uniform(0.7, 1.4)
        err, depth, ray = rcnn.centre_errors(g * s, g)  # on the true ray, another distance
        assert err == pytest.approx(abs(s - 1) * np.linalg.norm(g)) and depth == pytest.approx(abs(np.log(s)))
        assert ray == pytest.approx(0.0, abs=1e-12)
        a = rng.uniform(0.01, 0.2)  # turned about the camera: the same distance, another ray
        c, si = np.cos(a), np.sin(a)
        turned = np.array([[c, 0, si], [0, 1, 0], [-si, 0, c]]) @ g
        err, depth, ray = rcnn.centre_errors(turned, g)
        assert depth == pytest.approx(0.0, abs=1e-12) and ray == pytest.approx(err)
        assert err == pytest.approx(2 * np.hypot(g[0], g[2]) * np.sin(a / 2))  # the chord about y


def test_eval_command_hands_the_rcnn_its_test_time_settings(run_cli, tmp_path, monkeypatch):
    scene = _scene(tmp_path)
    run = ["volumon", "eval", "--data", str(scene), "--split", "tune"]
    status, _, err = run_cli(run + ["--model", "lmo", "--lift-at", "proposal"])
    assert status == 2 and "--lift-at: only with the R-CNN" in err.strip().splitlines()[-1]
    seen = []

    def scored(loaded, *args, **kwargs):
        seen.append(loaded.config.model)
        raise SystemExit(0)  # the settings are what is checked, not the scoring

    monkeypatch.setattr(rcnn, "evaluate_scene", scored)
    run = run + ["--model", "lmo-rcnn"]
    run_cli(run + ["--lift-at", "proposal", "--input-size", "256,192", "--json", str(tmp_path / "a.json")])
    run_cli(run + ["--json", str(tmp_path / "b.json")])
    assert [(c.lift_at, tuple(c.input_size)) for c in seen] == [("proposal", (256, 192)), ("refined", (320, 240))]


def test_truth_boxes_flag_is_for_the_rcnn_only(run_cli, tmp_path):
    scene = _scene(tmp_path)
    status, _, err = run_cli(
        ["volumon", "eval", "--model", "lmo", "--data", str(scene), "--split", "tune", "--truth-boxes"]
    )
    assert status != 0 and err.strip().splitlines()[-1].endswith(
        "--truth-boxes: only with the R-CNN (--model lmo-rcnn or an R-CNN run)"
    )


def test_frame_range_keeps_the_photographs_within_it(monkeypatch, tmp_path):
    scene = _scene(tmp_path)
    r = _evaluate(monkeypatch, scene, {}, frame_range=(0, 5))  # frame 3 only: its ape and can
    assert r["frames"] == 1 and r["num_truth"] == 2 and r["frame_ids"] == [3, 3]
    with pytest.raises(ValueError, match=r"no frame with an id in \[8, 9\]"):
        _evaluate(monkeypatch, scene, {}, frame_range=(8, 9))
