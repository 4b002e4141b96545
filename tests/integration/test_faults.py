"""Quiet failures made loud (issue 26, items 3-4): one training run per workdir (a lock file naming
its holder, stale locks taken over), and a resume that falls back past a corrupt newest checkpoint,
bit-exact, with one line naming the checkpoint skipped and none of orbax's noise."""

import json
import os
import pathlib
import shutil
import socket
import subprocess
import sys
import time

import numpy as np
import pytest

from jaxsem.training import TrainingRun, WorkdirLock, WorkdirLockedError, read_metrics

ROOT = pathlib.Path(__file__).resolve().parents[2]
CONFIG = {"width": 4, "steps": 10}


def _toy_run(workdir, end, *, lines=None, every=3):
    """A toy 'training' through the scaffold (state: running sums of the step numbers)."""
    state = {"x": np.zeros(3), "step": np.zeros((), np.int64)}
    with TrainingRun(workdir, CONFIG, keep=3, resumable=("steps",), log=None if lines is None else lines.append) as run:
        if run.latest_step is not None:
            state = run.restore(state)
        run.begin()
        for step in run.steps(run.start, end, total=end, desc="toy", progress=False):
            state = {"x": state["x"] + step, "step": np.asarray(step + 1, np.int64)}
            run.log_metrics({"step": step + 1, "x0": float(state["x"][0])})
            if (step + 1) % every == 0 or step + 1 == end:
                run.save(step + 1, state)
    return state


def _write_lock(workdir, **fields):
    workdir.mkdir(parents=True, exist_ok=True)
    info = {"pid": os.getpid(), "host": socket.gethostname(), "started": "2025-01-01T00:00:00+00:00", **fields}
    (workdir / "train.lock").write_text(json.dumps(info))


# ---------------------------------------------------------------------------------- the lock


def test_the_lock_is_taken_and_released_also_on_an_exception(tmp_path):
    with TrainingRun(tmp_path, CONFIG) as run:
        info = json.loads((tmp_path / "train.lock").read_text())
        assert info["pid"] == os.getpid() and info["host"] == socket.gethostname() and info["started"]
        # a second run in the same workdir, even in this process, is refused naming dir and holder
        with pytest.raises(WorkdirLockedError, match=rf"{tmp_path}.*pid {os.getpid()} on host "):
            TrainingRun(tmp_path, CONFIG)
        assert run.latest_step is None
    assert not (tmp_path / "train.lock").exists()
    with pytest.raises(RuntimeError, match="boom"), TrainingRun(tmp_path, CONFIG):
        raise RuntimeError("boom")
    assert not (tmp_path / "train.lock").exists()
    TrainingRun(tmp_path, CONFIG).close()  # free again


def test_a_refused_config_releases_the_lock(tmp_path):
    _toy_run(tmp_path, 3)
    with pytest.raises(ValueError, match="width"):
        TrainingRun(tmp_path, {**CONFIG, "width": 5})
    assert not (tmp_path / "train.lock").exists()


def test_a_stale_lock_is_taken_over_with_one_line(tmp_path):
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()  # a pid that is gone (kill -9, a crash)
    _write_lock(tmp_path, pid=dead.pid)
    lines = []
    with TrainingRun(tmp_path, CONFIG, log=lines.append):
        assert json.loads((tmp_path / "train.lock").read_text())["pid"] == os.getpid()
    assert len(lines) == 1 and "stale lock" in lines[0] and f"pid {dead.pid}" in lines[0], lines
    # a reused pid (alive, but started after the lock was written) is stale too
    _write_lock(tmp_path, proc_start=1)
    lines.clear()
    with WorkdirLock(tmp_path, notice=lines.append):
        pass
    assert len(lines) == 1 and "stale lock" in lines[0]
    # an empty lock file (its holder killed between creating and writing it) is taken over as well
    (tmp_path / "train.lock").write_text("")
    with WorkdirLock(tmp_path, notice=lines.append):
        pass
    assert "stale lock of an empty lock file" in lines[-1]


@pytest.mark.parametrize("content", [b"garbage", b"\xff\xfe\x00lock", b'{"pid": "7"}'], ids=["text", "latin", "no-pid"])
def test_a_lock_file_that_is_no_lock_record_is_refused_naming_it(tmp_path, content):
    # Issue 45 item 7: a non-UTF-8 lock gave a decoding message naming neither the file nor the
    # workdir. A file that is not a lock record is nobody's known lock: named, and left in place.
    (tmp_path / "train.lock").write_bytes(content)
    with pytest.raises(WorkdirLockedError) as info:
        TrainingRun(tmp_path, CONFIG)
    message = str(info.value)
    assert str(tmp_path) in message and str(tmp_path / "train.lock") in message and "delete it" in message
    assert (tmp_path / "train.lock").read_bytes() == content  # not ours to remove


def test_a_live_holder_on_another_host_is_refused_with_a_hint(tmp_path):
    _write_lock(tmp_path, host="elsewhere", pid=12345)
    with pytest.raises(WorkdirLockedError, match=r"pid 12345 on host elsewhere.*delete the lock file"):
        TrainingRun(tmp_path, CONFIG)
    assert (tmp_path / "train.lock").exists()  # not ours to remove


def test_two_volumon_trainings_in_one_workdir_the_second_is_refused_at_once(tmp_path, run_cli):
    work = tmp_path / "w"
    holder = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import sys, time\nfrom jaxsem.training import TrainingRun\n"
            f"run = TrainingRun({str(work)!r}, {{}})\nprint('ready', flush=True)\nsys.stdin.read()\nrun.close()",
        ],
        cwd=ROOT,
        env={**os.environ, "JAX_PLATFORMS": "cpu", "PYTHONPATH": str(ROOT)},
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "ready"
        t0 = time.perf_counter()
        status, out, err = run_cli(["volumon", "train", "--workdir", str(work), "--size", "tiny", "--steps", "2"])
        seconds = time.perf_counter() - t0
    finally:
        holder.communicate("", timeout=60)
    assert holder.returncode == 0 and not (work / "train.lock").exists()  # the holder released it
    assert status != 0 and "Traceback" not in err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    assert str(work) in lines[0] and f"pid {holder.pid} on host {socket.gethostname()}" in lines[0]
    assert seconds < 30 and not read_metrics(work)  # refused before any training


# ------------------------------------------------------------------ corrupt newest checkpoint


def _corrupt(step_dir: pathlib.Path) -> None:
    """Truncates every array data file of a checkpoint (what a full disk or a bad copy leaves)."""
    files = [p for p in step_dir.rglob("*") if p.is_file() and p.parent.name == "d"]
    assert files
    for p in files:
        p.write_bytes(p.read_bytes()[: p.stat().st_size // 2])


def test_resume_falls_back_past_a_corrupt_newest_checkpoint_bit_exact(tmp_path, capfd):
    whole = _toy_run(tmp_path / "whole", 9)
    work = tmp_path / "w"
    _toy_run(work, 6)  # checkpoints at 3 and 6
    ckpts = work / "checkpoints"
    assert sorted(int(p.name) for p in ckpts.iterdir() if p.name.isdigit()) == [3, 6]
    _corrupt(ckpts / "6")
    capfd.readouterr()
    lines = []
    state = {"x": np.zeros(3), "step": np.zeros((), np.int64)}
    with TrainingRun(work, CONFIG, keep=3, resumable=("steps",), log=lines.append) as run:
        restored = run.restore(state)
        run.save(6, restored)  # the step moved aside can be written again by the same run
        assert run._ckpt.all_steps() == [3, 6]
        shutil.rmtree(ckpts / "6")
        run._ckpt.reload()
    out, err = capfd.readouterr()
    # the state is the older checkpoint's, bit for bit
    np.testing.assert_array_equal(restored["x"], np.full(3, 0.0 + 1 + 2))
    assert int(restored["step"]) == 3 and run.start == 3
    assert len(lines) == 2 and lines[1] == "resumed from step 3", lines
    assert str(ckpts / "6") in lines[0] and "unreadable" in lines[0] and "step 3" in lines[0]
    assert "\n" not in lines[0] and len(lines[0]) < 500
    # orbax's own reports stay off the terminal
    assert not out.strip() and not err.strip(), (out, err)
    # the corrupt checkpoint was moved aside; the run goes on to the end bit-exact, one row per step
    assert not (ckpts / "6").exists() and (work / "corrupt_checkpoints" / "6").is_dir()
    resumed = _toy_run(work, 9)
    np.testing.assert_array_equal(resumed["x"], whole["x"])
    assert [r["step"] for r in read_metrics(work)] == list(range(1, 10))


def test_every_checkpoint_unreadable_is_refused_naming_the_newest(tmp_path):
    work = tmp_path / "w"
    _toy_run(work, 6)
    for step in ("3", "6"):
        _corrupt(work / "checkpoints" / step)
    with pytest.raises(ValueError, match=str(work / "checkpoints" / "6")):
        _toy_run(work, 9)
    assert (work / "checkpoints" / "6").is_dir()  # nothing moved when nothing could be read
    assert not (work / "train.lock").exists()
