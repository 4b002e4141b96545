"""train/lsd_house_gpu.py checks every flag before its data phase: a bad one exits 2 with one line
naming it (``--workers 0`` was a traceback from the process pool; a missing ``--init-from`` was
found only after minutes of shard generation)."""

import pathlib

import pytest


@pytest.mark.parametrize(
    "extra, words",
    [
        (["--workers", "0"], "--workers: expected a whole number >= 1, got 0"),
        (["--house-samples", "0"], "--house-samples"),
        (["--deadline", "nan"], "--data-deadline, --deadline"),
        (["--data-deadline", "600", "--deadline", "500"], "--data-deadline, --deadline"),
        (["--init-from", "nowhere.npz"], "--init-from: no such model file 'nowhere.npz'"),
        (["--set", "batch_size"], "--set: expected name=value, got 'batch_size'"),
        (["--out", "A_FILE"], "--out:"),
        (["--family", "house", "house"], "--family: each family once, got house house"),
    ],
    ids=["workers", "samples", "deadline-nan", "deadlines-swapped", "init-from", "set", "out-file", "family-twice"],
)
def test_bad_flags_exit_2_before_any_work(extra, words, tmp_path, capsys, script):
    mod = script("train/lsd_house_gpu.py")
    (tmp_path / "a_file").write_text("x")
    argv = ["--root", str(tmp_path / "root"), "--out", str(tmp_path / "out")]
    argv += [str(tmp_path / "a_file") if a == "A_FILE" else a for a in extra]
    with pytest.raises(SystemExit) as exc:
        mod.main(argv)
    assert exc.value.code == 2
    assert words in capsys.readouterr().err.splitlines()[-1]
    assert not (tmp_path / "root").exists()


def test_several_families_take_turns_with_the_train_family(script):
    """The mixed model's jobs: each new family in turn, then a train building, so that a run
    stopped at its data deadline keeps the mix; the model is named ``mixed``."""
    mod = script("train/lsd_house_gpu.py")
    args = mod.argparse.Namespace(family=["house", "campus"], house=3, train=3, house_samples=7, train_samples=5)
    jobs = mod.job_list(args, "out", "")
    assert [(f, s, n) for f, s, n, *_ in jobs[:4]] == [
        ("house", 0, 7),
        ("campus", 0, 7),
        ("train", 0, 5),
        ("house", 1, 7),
    ]
    assert sorted((f, s) for f, s, *_ in jobs) == sorted(
        [(f, s) for f in ("house", "campus", "train") for s in range(3)]
    )
    assert mod._model_name(["house", "campus"]) == "mixed"
    assert mod._model_name(["campus"]) == "campus"


def test_trainers_get_absolute_paths_under_a_relative_root(tmp_path, monkeypatch, script):
    """The trainers run with ``--root`` as their working directory: a relative ``--root`` handed
    on as it was named pointed them at ``root/root/data`` (no such folder, exit 2)."""
    mod = script("train/lsd_house_gpu.py")
    monkeypatch.chdir(tmp_path)
    (tmp_path / "model.npz").write_bytes(b"x")
    monkeypatch.setattr(mod, "make_data", lambda args, data, full: {"shards": 0})
    seen = []

    class _Proc:
        def __init__(self, cmd, env=None, cwd=None):
            seen.append((cmd, cwd))

        def wait(self, timeout=None):
            return 0

    monkeypatch.setattr(mod.subprocess, "Popen", _Proc)
    argv = ["--root", "rel", "--out", "out", "--init-from", "model.npz", "--data-deadline", "1", "--deadline", "2"]
    assert mod.main(argv + ["--oracle"]) == 0
    assert len(seen) == 2
    for cmd, cwd in seen:
        folders = [cmd[i + 1] for i, a in enumerate(cmd) if a in ("--data", "--workdir", "--run-dir")]
        assert len(folders) == 3 and all(pathlib.Path(f).is_absolute() for f in folders)
        assert pathlib.Path(cwd) == tmp_path / "rel"
