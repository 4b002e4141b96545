"""Regression tests of the architecture issue's error path: three bad inputs whose message named
no file (a corrupt LSD shard, an existing folder as a figure path) now fail in one line naming it."""

import os
import pathlib
import subprocess
import sys

import numpy as np
import pytest

from jaxsem.lsd import load_expert_dataset

ROOT = pathlib.Path(__file__).resolve().parents[2]


def _run(argv):
    env = {**os.environ, "JAX_PLATFORMS": "cpu", "PYTHONWARNINGS": "ignore"}
    proc = subprocess.run(
        [sys.executable, str(ROOT / argv[0]), *argv[1:]],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    return proc.returncode, lines, proc.stderr


@pytest.mark.filterwarnings("error")  # regression: a truncated zip's file was left open (ResourceWarning)
@pytest.mark.parametrize("content", [b"not a zip file at all", b"PK\x03\x04 truncated zip"])
def test_corrupt_shard_is_named(tmp_path, content):
    shard = tmp_path / "expert_000.npz"
    shard.write_bytes(content)
    with pytest.raises(ValueError, match="expert_000.npz"):
        load_expert_dataset(tmp_path)


def test_foreign_npz_is_named_with_missing_keys(tmp_path):
    np.savez(tmp_path / "expert_001.npz", context=np.zeros((2, 3)))
    with pytest.raises(ValueError, match=r"expert_001\.npz.*missing.*occupancy"):
        load_expert_dataset(tmp_path)


def test_train_lsd_names_corrupt_shard(tmp_path):
    data = tmp_path / "shards"
    data.mkdir()
    (data / "expert_000.npz").write_bytes(b"garbage")
    status, lines, stderr = _run(["train/lsd.py", "--data", str(data), "--workdir", str(tmp_path / "w")])
    assert status != 0
    assert "Traceback" not in stderr, stderr[-2000:]
    assert lines and "expert_000.npz" in lines[-1], lines[-3:]


def test_plan_out_folder_refused_before_work(tmp_path):
    folder = tmp_path / "figs"
    folder.mkdir()
    status, lines, stderr = _run(["infer/plan.py", "--out", str(folder)])
    assert status != 0
    assert "Traceback" not in stderr, stderr[-2000:]
    assert lines and "--out" in lines[-1] and "folder" in lines[-1], lines[-3:]
    assert not list(tmp_path.glob("*.png")) and not list(folder.iterdir())
