"""``SolverConfig.for_detector``: the solver's settings for a learned detector's boxes (a wider
box sigma, robust box factors), and ``jaxsem roshan --detector`` taking them."""

from __future__ import annotations

import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_roshan_from_pixels import _write_posed_photos, stand_in_detector  # noqa: F401 (a fixture)

from jaxsem import slam
from jaxsem._commands import roshan as roshan_command  # layers: white-box


def test_for_detector_changes_the_box_factors_only():
    base = slam.SolverConfig(use_support=True, max_steps=17)
    cfg = base.for_detector(box_sigma=5.0)
    assert float(cfg.noise.box_sigma) == 5.0
    assert cfg.box_loss != "l2"
    kept = ("use_support", "max_steps", "texture_loss", "shape_loss", "robust_scale", "use_texture")
    assert all(getattr(cfg, k) == getattr(base, k) for k in kept)
    assert float(cfg.noise.texture_sigma) == float(base.noise.texture_sigma)
    assert float(base.for_detector(box_sigma=np.float32(6.0)).noise.box_sigma) == 6.0
    batched = jax.vmap(lambda s: base.for_detector(box_sigma=s).noise.box_sigma)(jnp.array([4.0, 9.0]))
    np.testing.assert_array_equal(np.asarray(batched), [4.0, 9.0])
    plain = slam.baseline_config().for_detector(box_sigma=5.0, robust=False)
    assert plain.box_loss == "l2" and float(plain.noise.box_sigma) == 5.0 and not plain.use_texture


@pytest.mark.parametrize("sigma", [0.0, -2.0, float("nan"), float("inf"), True, "8", np.ones(2)])
def test_for_detector_refuses_a_bad_sigma(sigma):
    with pytest.raises(ValueError, match="box_sigma"):
        slam.SolverConfig().for_detector(box_sigma=sigma)


@pytest.mark.parametrize("field", ["box_loss", "texture_loss", "shape_loss", "pose_loss"])
def test_an_unknown_loss_is_refused_when_the_config_is_made(field):
    with pytest.raises(ValueError, match=field):
        slam.SolverConfig(**{field: "tukey"})


def _args(folder, tmp_path, *extra):
    return roshan_command.parse_args(["--sequence", str(folder), "--out", str(tmp_path / "o"), *extra])


def test_the_command_takes_a_detectors_box_noise(tmp_path, stand_in_detector):  # noqa: F811
    folder = tmp_path / "desk"
    _write_posed_photos(folder, stand_in_detector)
    seq = json.loads((folder / "sequence.json").read_text())
    seq["noise"] = {"box_sigma": 2.0}  # the sequence's own boxes: 2 px
    (folder / "sequence.json").write_text(json.dumps(seq))
    sequence = slam.load_sequence(folder, require_detections=False)

    def config(*extra):
        cfg = roshan_command.solver_config(_args(folder, tmp_path, *extra), None, sequence)
        return float(cfg.noise.box_sigma), cfg.box_loss

    own_sigma, own_loss = config()
    assert (own_sigma, own_loss) == (2.0, "l2")
    det_sigma, det_loss = config("--detector", "lmo-rcnn")
    assert det_sigma > own_sigma and det_loss != "l2"
    assert config("--detector", "lmo-rcnn", "--baseline") == (det_sigma, "l2")
    assert config("--detector", "lmo-rcnn", "--box-sigma", "3", "--box-loss", "huber") == (3.0, "huber")


def test_an_unknown_box_loss_flag_is_refused_while_parsing(tmp_path, capsys):
    with pytest.raises(SystemExit):
        _args(tmp_path, tmp_path, "--box-loss", "tukey")
    assert "--box-loss" in capsys.readouterr().err


def _with_wrong_boxes(seed, share=0.2, shift=80.0):
    """A toy map whose boxes are off by 6 px an edge, a fifth of them moved 80 px sideways (the
    box of something else, as a detector's false track holds)."""
    problem, truth = slam.toy_map(seed, num_objects=4, num_frames=20, box_noise=6.0)
    box = np.asarray(problem.box).copy()
    rng = np.random.default_rng(seed)
    real = np.flatnonzero(np.asarray(problem.box_mask))
    wrong = rng.choice(real, int(share * len(real)), replace=False)
    box[wrong] += shift * np.array([1.0, 0.0, 1.0, 0.0])
    return dataclasses.replace(problem, box=jnp.asarray(box, problem.box.dtype)), truth


@pytest.mark.slow
@pytest.mark.parametrize("seed", [1, 3])
def test_robust_box_factors_keep_wrong_boxes_from_pulling_the_map(seed):
    problem, truth = _with_wrong_boxes(seed)
    errors = {}
    for robust in (False, True):
        config = slam.SolverConfig().for_detector(box_sigma=6.0, robust=robust)
        est, _ = slam.solve_batch(problem, config=config)
        err = np.linalg.norm(np.asarray(est.center - truth.center), axis=-1)[np.asarray(problem.object_mask)]
        assert np.all(np.isfinite(err))
        errors[robust] = float(np.median(err))
    assert errors[True] < 0.5 * errors[False], errors
