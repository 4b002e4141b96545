"""Checkpoints of a training run by step, and their parameter average (the export's
``--average-steps``)."""

import json

import jax
import numpy as np
import pytest
from test_rcnn import INIT, TINY

from jaxsem import volumon
from jaxsem._commands.volumon_eval import SHIPPED_NAMES  # layers: white-box
from jaxsem.checkpoint import save_checkpoint
from jaxsem.training import config_json
from jaxsem.volumon.rcnn import (  # layers: white-box
    ADOPTED_RCNNS,
    SHIPPED_RCNNS,
    RCNNTrainConfig,
    _opt_like,
    average_models,
    load_rcnn,
)


def _init(key):
    return dict(INIT(key, TINY))


def _workdir(tmp_path, steps):
    """A run folder with ``config.json`` and one checkpoint per step, each with other weights."""
    config = RCNNTrainConfig(model=TINY, class_names=("a", "b", "c"))
    (tmp_path / "config.json").write_text(json.dumps(config_json(config)))
    saved = {}
    for i, step in enumerate(steps):
        v = jax.tree.map(np.asarray, _init(jax.random.PRNGKey(10 + i)))
        state = {
            "params": v["params"],
            "batch_stats": v["batch_stats"],
            "opt_state": jax.tree.map(lambda a: np.zeros(a.shape, a.dtype), _opt_like(config, v)),
            "step": np.asarray(step, np.int64),
        }
        save_checkpoint(tmp_path / "checkpoints", step, state, max_to_keep=None)
        saved[step] = v
    return saved


@pytest.mark.slow
def test_a_run_loads_by_step_and_averages_its_checkpoints(tmp_path):
    saved = _workdir(tmp_path, [10, 20])
    latest, first = load_rcnn(tmp_path), load_rcnn(tmp_path, step=10)
    assert latest.meta["step"] == 20 and first.meta["step"] == 10
    leaf = lambda v: np.asarray(v["params"]["roi_fc0"]["kernel"])
    np.testing.assert_array_equal(leaf(first.variables), leaf(saved[10]))
    np.testing.assert_array_equal(leaf(latest.variables), leaf(saved[20]))

    avg = average_models([first, latest])
    assert avg.meta["averaged_steps"] == [10, 20]
    for got, a, b in zip(
        jax.tree.leaves(avg.variables), jax.tree.leaves(saved[10]), jax.tree.leaves(saved[20]), strict=True
    ):
        assert got.dtype == a.dtype
        np.testing.assert_allclose(got, (np.float64(a) + b) / 2, rtol=1e-6, atol=1e-7)
    # one model is its own average
    for got, want in zip(jax.tree.leaves(average_models([first]).variables), jax.tree.leaves(first.variables)):
        np.testing.assert_array_equal(got, want)


def test_a_missing_step_or_mixed_networks_are_refused(tmp_path):
    _workdir(tmp_path, [10])
    with pytest.raises(ValueError, match="step: no checkpoint 30"):
        load_rcnn(tmp_path, step=30)
    with pytest.raises(ValueError, match="step"):
        load_rcnn("lmo-rcnn", step=10)
    with pytest.raises(ValueError, match="models"):
        average_models([])
    one = load_rcnn(tmp_path)
    other = one._replace(variables=jax.tree.map(lambda x: np.zeros((1,) + np.shape(x)), one.variables))
    with pytest.raises(ValueError, match="models"):
        average_models([one, other])


def test_every_shipped_rcnn_name_loads_and_the_commands_know_it():
    assert set(SHIPPED_NAMES) == set(SHIPPED_RCNNS) | set(ADOPTED_RCNNS)
    for name in SHIPPED_NAMES:
        loaded = load_rcnn(name)
        W, H = loaded.config.model.input_size
        assert loaded.meta["step"] > 0 and W % 16 == 0 and H % 16 == 0
        assert len(loaded.config.class_names) == loaded.config.model.num_classes == 8
    assert load_rcnn("lmo-rcnn-448").config.model.input_size == (448, 336)
    # put together from two shipped models: the 448 detector's weights and the LM-O VoluMon's
    one, det, sep = load_rcnn("lmo-rcnn-448-volumon"), load_rcnn("lmo-rcnn-448"), volumon.load_pretrained(kind="lmo")
    assert one.config.model.lift_features == "volumon" and one.config.model.reconstruction == sep.config.recon
    assert load_rcnn("lmo-rcnn-volumon").config.model.input_size == (384, 288)  # its reading size
    np.testing.assert_array_equal(
        one.variables["params"]["cls_out"]["kernel"], det.variables["params"]["cls_out"]["kernel"]
    )
    np.testing.assert_array_equal(
        one.variables["params"]["volumon_net"]["global_out"]["kernel"], sep.variables["params"]["global_out"]["kernel"]
    )
