"""Every ``jaxsem`` subcommand records its run (issue 13 item 6): a run directory named at the
start and printed as the first line, ``config.json`` with every argument after defaults, the
versions and the command line, ``summary.json`` at the end (status ok, or status error with the
one-line message of a failed run), and the compilation cache with its opt-out.

The default tests run each subcommand on an input that fails after the run started (cheap: no
solve, no training) and the cheap commands to the end; ``@pytest.mark.slow`` runs every
subcommand to the end on tiny settings."""

import json
import pathlib

import jax
import pytest

from jaxsem import cli, scripting as sc
from jaxsem.scripting._runs import RUN_DIR_ENV  # layers: white-box


@pytest.fixture(autouse=True)
def _isolated(tmp_path, monkeypatch):
    """Default run directories under tmp_path; the compilation-cache setting restored after."""
    monkeypatch.setenv(RUN_DIR_ENV, str(tmp_path / "runs"))
    monkeypatch.delenv(cli.NO_CACHE_ENV, raising=False)
    before = jax.config.jax_compilation_cache_dir
    yield
    jax.config.update("jax_compilation_cache_dir", before)


def _run_dir(out: str) -> pathlib.Path:
    first = out.splitlines()[0]
    assert first.startswith("run directory: "), out[:500]
    return pathlib.Path(first.removeprefix("run directory: "))


def _read(run_dir: pathlib.Path):
    config = json.loads((run_dir / "config.json").read_text())
    summary = json.loads((run_dir / "summary.json").read_text())
    assert not [p.name for p in run_dir.iterdir() if p.name.endswith(".tmp")], "half-written files left"
    return config, summary


def _check_ok(argv, run_cli, expect_args):
    status, out, err = run_cli(argv)
    assert status == 0, err[-2000:]
    run_dir = _run_dir(out)
    config, summary = _read(run_dir)
    words = [w for w in argv if not w.startswith("-")][:2]
    assert config["command"] in (" ".join(words), words[0])
    assert config["command_line"].startswith(f"jaxsem {config['command']}")
    assert config["versions"]["jax"] == jax.__version__ and config["versions"]["jaxsem"]
    for key, value in expect_args.items():
        assert config["args"][key] == value, (key, config["args"][key])
    assert summary["status"] == "ok" and summary["exit_status"] == 0 and summary["wall_seconds"] >= 0
    return run_dir, config, summary, out


def _check_error(argv, run_cli, words):
    status, out, err = run_cli(argv)
    assert status != 0
    assert "Traceback" not in err, err[-2000:]
    lines = [line for line in err.splitlines() if line.strip()]
    assert all(line.startswith(("usage:", " ")) for line in lines[:-1]), err
    run_dir = _run_dir(out)
    config, summary = _read(run_dir)
    assert summary["status"] == "error" and summary["exit_status"] == status
    for word in words:
        assert word in lines[-1] and word in summary["error"], (word, lines[-1], summary["error"])
    return run_dir, config, summary


@pytest.fixture(scope="module")
def bad(tmp_path_factory):
    d = tmp_path_factory.mktemp("bad_inputs")
    (d / "empty").mkdir()
    (d / "no_sequence").mkdir()
    (d / "corrupt.png").write_bytes(b"\x89PNG\r\n\x1a\n garbage")
    (d / "boxes.json").write_text("[[1, 2, 30, 40]]")
    (d / "corrupt.npz").write_bytes(b"not a zip file")
    return d


def _failing(d: pathlib.Path, out: pathlib.Path):
    """Per subcommand: arguments that parse but fail once the run started, and the words the one
    error line names."""
    return {
        "roshan": (["roshan", "--sequence", str(d / "no_sequence"), "--out", str(out)], ["no_sequence"]),
        "volumon train": (["volumon", "train", "--workdir", str(out), "--eval-data", str(d)], ["--eval-data"]),
        "volumon predict": (
            [
                "volumon",
                "predict",
                "--image",
                str(d / "corrupt.png"),
                "--boxes",
                str(d / "boxes.json"),
                "--out",
                str(out),
            ],
            ["corrupt.png"],
        ),
        "volumon eval": (["volumon", "eval", "--workdir", str(d / "empty"), "--num", "2"], ["empty"]),
        "volumon export": (["volumon", "export", "--workdir", str(d / "empty"), "--out", str(out)], ["empty"]),
        "lsd train": (["lsd", "train", "--data", str(d / "empty"), "--workdir", str(out)], ["--data", "empty"]),
        "lsd plan": (["lsd", "plan", "--map", str(d / "corrupt.npz"), "--out", str(out / "p.png")], ["corrupt.npz"]),
    }


@pytest.mark.parametrize("name", list(_failing(pathlib.Path("/x"), pathlib.Path("/y"))))
def test_a_failed_run_records_its_failure(name, bad, tmp_path, run_cli):
    argv, words = _failing(bad, tmp_path / "out")[name]
    run_dir, config, _ = _check_error(argv, run_cli, words)
    assert run_dir.parent == tmp_path / "runs" and run_dir.name.startswith(name.replace(" ", "-") + "-")
    assert config["command"] == name
    assert not (tmp_path / "out").exists() or not any(p.is_file() for p in (tmp_path / "out").rglob("*"))


def test_demo_records_its_run_and_says_where_the_figures_are(tmp_path, monkeypatch, run_cli):
    from jaxsem.demos import geometry

    def fake(out_dir, quick):  # the part's figure, without the part's compile time
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(2, 2))
        ax.plot([0, 1], [0, quick])
        sc.atomic_savefig(fig, pathlib.Path(out_dir) / "geometry_boxes.png", dpi=50)
        plt.close(fig)
        return "| table |"

    monkeypatch.setattr(geometry, "run", fake)
    out_dir = tmp_path / "demo"
    run_dir, config, summary, out = _check_ok(
        ["demo", "--parts", "geometry", "--quick", "--out", str(out_dir)],
        run_cli,
        {"parts": ["geometry"], "quick": True, "out": str(out_dir), "run_dir": None},
    )
    assert run_dir == out_dir  # the demo's folder is its run directory
    assert summary["figures"] == [str(out_dir / "geometry_boxes.png")]
    assert set(summary["results"]["seconds"]) == {"geometry"}
    assert out.strip().splitlines()[-1] == f"figures (1) are in {out_dir}/: geometry_boxes.png"

    def broken(out_dir, quick):
        raise ValueError("geometry: something went wrong")

    monkeypatch.setattr(geometry, "run", broken)
    run_dir, _, summary = _check_error(
        ["demo", "--parts", "geometry", "--run-dir", str(tmp_path / "chosen")], run_cli, ["something went wrong"]
    )
    assert run_dir == tmp_path / "chosen" and summary["figures"] == []


def test_lsd_data_records_a_failure_while_writing(tmp_path, monkeypatch, run_cli):
    from jaxsem import lsd

    def full(*args, **kwargs):
        raise OSError(28, "No space left on device", str(tmp_path / "shards" / "expert_0.npz"))

    monkeypatch.setattr(lsd, "write_expert_dataset", full)
    argv = ["lsd", "data", "--out", str(tmp_path / "shards"), "--buildings", "2", "--workers", "1"]
    _, config, _ = _check_error(argv, run_cli, ["expert_0.npz", "No space left"])
    assert config["args"]["buildings"] == 2 and config["args"]["samples_per_building"] == 200


def _bench_dir(tmp_path):
    folder = tmp_path / "benchmarks"
    (folder / "results").mkdir(parents=True)
    (folder / "probe.py").write_text(
        '"""Writes what it sees."""\nimport json, os, pathlib, sys\n'
        "out = pathlib.Path(__file__).parent / 'results' / 'probe.json'\n"
        "out.write_text(json.dumps({'cache': os.environ.get('JAX_COMPILATION_CACHE_DIR'), 'argv': sys.argv[1:]}))\n"
        "sys.exit(int(sys.argv[1]) if len(sys.argv) > 1 else 0)\n"
    )
    return folder


def test_bench_records_its_run_and_the_cache_flag_is_honoured(tmp_path, monkeypatch, run_cli):
    folder = _bench_dir(tmp_path)
    cache = tmp_path / "cache"
    monkeypatch.setenv("JAXSEM_CACHE_DIR", str(cache))
    monkeypatch.delenv("JAX_COMPILATION_CACHE_DIR", raising=False)
    run_dir, config, summary, _ = _check_ok(
        ["bench", "--dir", str(folder), "probe", "0"], run_cli, {"name": "probe", "args": ["0"]}
    )
    result = folder / "results" / "probe.json"
    assert config["compilation_cache"] == str(cache) and jax.config.jax_compilation_cache_dir == str(cache)
    assert json.loads(result.read_text())["cache"] == str(cache)  # the benchmark's process uses it too
    assert summary["outputs"] == [str(result)] and summary["results"] == {"benchmark": "probe", "exit_status": 0}

    # --no-compilation-cache: off here and in the benchmark's process
    _, config, _, _ = _check_ok(
        ["bench", "--no-compilation-cache", "--dir", str(folder), "probe"], run_cli, {"no_compilation_cache": True}
    )
    assert config["compilation_cache"] is None and jax.config.jax_compilation_cache_dir is None
    assert json.loads(result.read_text())["cache"] is None
    # ... and the environment variable does the same
    monkeypatch.setenv(cli.NO_CACHE_ENV, "1")
    _, config, _, _ = _check_ok(["bench", "--dir", str(folder), "probe"], run_cli, {"no_compilation_cache": False})
    assert config["compilation_cache"] is None and jax.config.jax_compilation_cache_dir is None

    # a failing benchmark: exit status passed on, summary status error
    _, _, summary = _check_error(["bench", "--dir", str(folder), "probe", "3"], run_cli, [])
    assert summary["exit_status"] == 3 and summary["error"] == "exit status 3"


def test_bench_list_and_help_make_no_run_directory(tmp_path, run_cli):
    folder = _bench_dir(tmp_path)
    assert run_cli(["bench", "--dir", str(folder), "--list"])[0] == 0
    for words in (["bench"], ["roshan"], ["volumon", "train"], ["lsd", "plan"]):
        status, out, _ = run_cli([*words, "--help"])
        assert status == 0
        for flag in ("--run-dir", "--no-compilation-cache", "--debug", "summary.json", "JAXSEM_NO_COMPILATION_CACHE"):
            assert flag in out, (words, flag)
    # a usage error is not a run either
    assert run_cli(["lsd", "plan", "--n", "0"])[0] != 0
    assert not (tmp_path / "runs").exists()


def test_runs_in_the_same_second_get_their_own_directories(tmp_path, run_cli):
    folder = _bench_dir(tmp_path)
    dirs = {_run_dir(run_cli(["bench", "--dir", str(folder), "probe"])[1]) for _ in range(3)}
    assert len(dirs) == 3 and all((d / "summary.json").exists() for d in dirs)


def test_run_dir_may_not_be_a_training_workdir(tmp_path, run_cli):
    status, _, err = run_cli(["volumon", "train", "--workdir", str(tmp_path), "--run-dir", str(tmp_path)])
    assert status == 2 and "--run-dir" in err.strip().splitlines()[-1]
    assert not any(tmp_path.iterdir())


def test_record_outside_a_run_is_a_no_op(tmp_path):
    assert sc.active_run() is None
    sc.record(x=1)
    sc.record_output(tmp_path / "a.png")
    path = sc.atomic_write_text(tmp_path / "x.json", "{}")
    assert path.stat().st_mode & 0o044  # readable like a file open() made, not mkstemp's 0600


# ------------------------------------------------------------------------------------------
# Every subcommand to the end on tiny settings (slow: each compiles its solver or network).


@pytest.mark.slow
def test_every_subcommand_runs_to_the_end_and_records_it(tmp_path, run_cli):
    o = tmp_path
    _, _, summary, _ = _check_ok(
        ["roshan", "--simulate", "forward", "--frames", "4", "--objects", "2", "--final-iterations", "1"]
        + ["--overlays", "1", "--quiet", "--out", str(o / "roshan")],
        run_cli,
        {"simulate": "forward", "frames": 4, "objects": 2, "final_iterations": 1, "out": str(o / "roshan")},
    )
    assert str(o / "roshan" / "map.json") in summary["outputs"] and len(summary["figures"]) == 2
    assert summary["results"]["frames"] == 4 and "mean_error" in summary["results"]

    _, _, summary, _ = _check_ok(
        ["volumon", "predict", "--split", "test", "--num", "2", "--out", str(o / "vp")], run_cli, {"num": 2}
    )
    assert summary["results"]["ellipsoids"] == 2 and len(summary["figures"]) == 2

    # No evaluation during training (its periodic evaluation is tested in test_volumon_train):
    # `volumon eval` below scores this run's tiny model (the shipped model's eval is
    # test_volumon_pretrained's), a smaller network to compile than the shipped one.
    work = o / "vt"
    _, config, summary, _ = _check_ok(
        ["volumon", "train", "--workdir", str(work), "--size", "tiny", "--steps", "2", "--num-eval", "0"]
        + ["--checkpoint-every", "2"],
        run_cli,
        {"steps": 2, "size": "tiny", "workdir": str(work), "num_eval": 0},
    )
    assert config["train_config"]["num_steps"] == 2 and (work / "config.json").exists()
    _, _, summary, _ = _check_ok(
        ["volumon", "eval", "--workdir", str(work), "--num", "4", "--json", str(o / "ve.json")],
        run_cli,
        {"num": 4, "workdir": str(work)},
    )
    assert summary["results"]["num"] == 4 and summary["outputs"] == [str(o / "ve.json")]
    _, _, summary, _ = _check_ok(["volumon", "export", "--workdir", str(work), "--out", str(o / "ve")], run_cli, {})
    assert summary["results"]["megabytes"] > 0 and summary["figures"]

    shards = o / "shards"
    _, _, summary, _ = _check_ok(
        ["lsd", "data", "--out", str(shards), "--buildings", "1", "--samples-per-building", "4"]
        + ["--nav-samples", "200", "--workers", "1", "--sample-prob", "0.5"],
        run_cli,
        {"buildings": 1, "samples_per_building": 4, "workers": 1},
    )
    assert summary["results"]["shards"] == 1 and summary["results"]["samples"] > 0
    _, config, summary, _ = _check_ok(
        ["lsd", "train", "--data", str(shards), "--workdir", str(o / "lt"), "--config", "tiny"]
        + ["--stage1-steps", "2", "--stage2-steps", "2", "--eval-every", "2"],
        run_cli,
        {"config": "tiny", "stage1_steps": 2},
    )
    assert config["train_config"]["stage1_steps"] == 2
    _, _, summary, _ = _check_ok(
        # --n as --nav-samples of `lsd data` above: the roadmap's growth compiled once for both
        ["lsd", "plan", "--sampler", "uniform", "--n", "200", "--max-steps", "20", "--no-progress"]
        + ["--out", str(o / "plan.png")],
        run_cli,
        {"sampler": "uniform", "n": 200, "max_steps": 20},
    )
    assert summary["results"]["uniform"]["steps"] <= 20 and summary["figures"] == [str(o / "plan.png")]
    assert all(pathlib.Path(p).exists() for p in summary["figures"])


def test_library_calls_use_the_compilation_cache_unless_told_not_to(tmp_path, monkeypatch):
    from jaxsem._cache import library_default  # layers: white-box (what `import jaxsem` runs)

    monkeypatch.setenv("JAXSEM_CACHE_DIR", str(tmp_path / "cache"))
    jax.config.update("jax_compilation_cache_dir", None)
    assert library_default() == str(tmp_path / "cache")
    assert jax.config.jax_compilation_cache_dir == str(tmp_path / "cache")
    # A folder the user chose is kept; the environment switch leaves JAX's setting alone.
    jax.config.update("jax_compilation_cache_dir", str(tmp_path / "mine"))
    assert library_default() == str(tmp_path / "mine")
    jax.config.update("jax_compilation_cache_dir", None)
    monkeypatch.setenv(cli.NO_CACHE_ENV, "1")
    assert library_default() is None and jax.config.jax_compilation_cache_dir is None
