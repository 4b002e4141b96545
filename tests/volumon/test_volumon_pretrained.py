"""The shipped VoluMon model: loads, and ``jaxsem volumon eval`` beats a constant-size predictor."""

import json

import numpy as np
import pytest

from jaxsem.cli import main
from jaxsem.volumon import PRETRAINED_DIR, load_pretrained

FIELDS = (
    "num",
    "median_size_rel_error",
    "size_corr",
    "median_center_error_m",
    "trans_auc",
    "adi_auc",
    "iou_auc",
    "network_ms_per_detection",
)


def test_shipped_model_files_and_size():
    npz = PRETRAINED_DIR / "volumon_fast.npz"
    assert npz.exists() and (PRETRAINED_DIR / "volumon_fast.json").exists()
    assert (PRETRAINED_DIR / "MODEL_CARD.md").exists()
    assert npz.stat().st_size < 25e6
    _, _, cfg, meta = load_pretrained()
    assert meta["step"] > 0 and cfg.model.num_classes == 4


@pytest.mark.slow
def test_eval_command_beats_constant_size_predictor(tmp_path):
    out = tmp_path / "eval.json"
    assert main(["volumon", "eval", "--seed", "424242", "--num", "48", "--json", str(out)]) == 0
    r = json.loads(out.read_text())
    for k in FIELDS:
        assert k in r and np.isfinite(r[k]), k
    assert r["num"] > 40
    # sizes follow the class: better than the mean size of all classes for every object
    assert r["median_size_rel_error"] < r["baseline_median_size_rel_error"]
    assert r["size_corr"] > 0.5
    assert r["ceiling_median_size_rel_error"] == 0.0
