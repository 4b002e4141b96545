"""``jaxsem`` has a subcommand for every job (issue 13 item 6): each one's ``--help`` names its main
flags with defaults and the run options every command shares, a bad argument fails with one line
naming it (before any run directory is made), the scripts in train/ and infer/
run the same code, and ``jaxsem bench`` finds (or clearly fails to find) the benchmarks. In-process
and fast: nothing here trains, plans or solves."""

import importlib.util
import pathlib
import subprocess
import sys

import pytest

from jaxsem import cli

ROOT = pathlib.Path(__file__).resolve().parents[2]

# words -> flags its --help must name
HELP = {
    ("data", "fetch"): ["--out", "--from", "lmo", "maps"],
    ("demo",): ["--out", "--parts", "--quick"],
    ("roshan",): ["--sequence", "--simulate", "--out", "--optimize-every", "map.json"],
    ("volumon", "train"): ["--workdir", "--variant", "--size", "--steps", "--data", "--set"],
    ("volumon", "predict"): ["--workdir", "--image", "--boxes", "--split", "--num", "--out", "ellipsoids.json"],
    ("volumon", "detect"): ["--model", "--image", "--K", "--out", "detections.json", "detections.png"],
    ("volumon", "eval"): ["--seed", "--num", "--json", "--workdir", "--data"],
    ("volumon", "export"): ["--workdir", "--step", "--out", "volumon_fast.npz"],
    ("lsd", "data"): ["--out", "--family", "--buildings", "--samples-per-building", "--workers"],
    ("lsd", "train"): ["--data", "--workdir", "--config", "--stage1-steps", "--chunk-steps"],
    ("lsd", "plan"): ["--map", "--start", "--goal", "--sampler", "--n", "--out", "Outputs:"],
    ("bench",): ["--list", "--dir", "NAME", "benchmarks/results"],
}

# what every subcommand's --help names: the run directory, its files and the compilation cache
RUN_OPTIONS = ["--run-dir", "config.json", "summary.json", "--no-compilation-cache", "--debug"]

# The scripts that wrap a subcommand.
WRAPPERS = {
    "train/volumon.py": "volumon train",
    "train/export_volumon.py": "volumon export",
    "train/lsd.py": "lsd train",
    "infer/volumon.py": "volumon predict",
    "infer/roshan.py": "roshan",
    "infer/plan.py": "lsd plan",
    "infer/make_expert_data.py": "lsd data",
}


@pytest.fixture(autouse=True)
def _runs_in_tmp(tmp_path, monkeypatch):
    """Run directories of the commands run here go under tmp_path, not the working directory."""
    monkeypatch.setenv("JAXSEM_RUNS_DIR", str(tmp_path / "runs"))


def test_every_job_has_a_subcommand():
    assert {" ".join(words) for words, _, _ in cli.COMMANDS} == {" ".join(w) for w in HELP}
    assert set(WRAPPERS.values()) <= {" ".join(w) for w in HELP}


@pytest.mark.parametrize("words", list(HELP), ids=[" ".join(w) for w in HELP])
def test_help_names_the_main_flags_and_defaults(words, run_cli):
    status, out, err = run_cli([*words, "--help"])
    assert status == 0, err
    assert out.startswith(f"usage: jaxsem {' '.join(words)} ")
    for flag in HELP[words] + RUN_OPTIONS:
        assert flag in out, f"{flag} missing from jaxsem {' '.join(words)} --help"
    assert "(default: " in out


def test_top_level_and_group_help_list_the_subcommands(run_cli):
    status, out, _ = run_cli(["--help"])
    assert status == 0
    for name in ("demo", "roshan", "volumon", "lsd", "data", "bench"):
        assert f"    {name} " in out
    for group, leaves in (("volumon", ("train", "predict", "eval", "export")), ("lsd", ("data", "train", "plan"))):
        status, out, _ = run_cli([group, "--help"])
        assert status == 0 and all(f"    {leaf} " in out for leaf in leaves)


def test_help_does_not_import_the_commands():
    code = (
        "import sys, contextlib, io\nfrom jaxsem import cli\n"
        "with contextlib.redirect_stdout(io.StringIO()), contextlib.suppress(SystemExit): cli.main(['--help'])\n"
        "print(sorted(m for m in sys.modules if m.startswith('jaxsem._commands.')))"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True)
    assert proc.stdout.strip() == "[]"


def _bad_cases(tmp):
    return [
        # (argv, words the last stderr line must contain)
        (["roshan", "--simulate", "forward", "--frames", "0", "--out", str(tmp / "r")], ["--frames"]),
        (["roshan", "--out", str(tmp / "r")], ["--sequence", "--simulate"]),
        (["volumon", "train", "--workdir", str(tmp / "t"), "--steps", "-5"], ["--steps"]),
        (["volumon", "train", "--workdir", str(tmp / "t"), "--variant", "bogus"], ["--variant", "bogus"]),
        (["volumon", "predict", "--split", "test", "--num", "0", "--out", str(tmp / "p")], ["--num"]),
        (["volumon", "eval", "--num", "0"], ["--num"]),
        (["volumon", "export", "--workdir", str(tmp / "nope")], ["--workdir", "nope"]),
        (["volumon", "export", "--workdir", str(tmp), "--step", "last"], ["--step", "last"]),
        (["lsd", "data", "--workers", "0", "--out", str(tmp / "e")], ["--workers"]),
        (["lsd", "train", "--data", str(tmp / "nope"), "--workdir", str(tmp / "w")], ["--data", "nope"]),
        (["lsd", "plan", "--n", "0"], ["--n"]),
        (["lsd", "plan", "--sampler", "magic"], ["--sampler", "magic"]),
        (["data", "fetch", "everything", "--out", str(tmp / "d")], ["everything"]),
        (["data", "fetch", "lmo", "--out", str(tmp / "d"), "--from", str(tmp / "nope.whl")], ["nope.whl"]),
        (["bench", "nonexistent"], ["nonexistent", "benchmarks"]),
        (["bench", "--dir", str(tmp / "no_benchmarks"), "geometry"], ["no_benchmarks"]),
        (["volumon", "bogus"], ["bogus"]),
        (["bogus"], ["bogus"]),
    ]


CASES = [" ".join(argv[:3]) + f" [{i}]" for i, (argv, _) in enumerate(_bad_cases(pathlib.Path("/x")))]


@pytest.mark.parametrize("case", CASES)
def test_bad_argument_gives_one_line_naming_it(case, tmp_path, run_cli):
    argv, words = _bad_cases(tmp_path)[CASES.index(case)]
    status, out, err = run_cli(argv)
    assert status != 0, out[-500:]
    assert "Traceback" not in err, err[-2000:]
    lines = [line for line in err.splitlines() if line.strip()]
    assert lines, "no error message"
    # argparse prints its usage (indented continuation lines) before the error: one line of error.
    assert all(line.startswith(("usage:", " ")) for line in lines[:-1]), err
    for word in words:
        assert word in lines[-1], f"{word!r} not named in: {lines[-1]}"
    assert not any(tmp_path.rglob("*.png")) and not any(tmp_path.rglob("*.json"))
    assert not (tmp_path / "runs").exists()  # a bad argument is not a run


def test_scripts_run_the_subcommands_code():
    for script, name in WRAPPERS.items():
        spec = importlib.util.spec_from_file_location(f"wrapper_{pathlib.Path(script).stem}", ROOT / script)
        assert spec is not None and spec.loader is not None
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        assert module.main is cli.command(name), script


def test_bench_lists_the_benchmarks(run_cli):
    status, out, _ = run_cli(["bench", "--list"])
    assert status == 0
    names = [line.split()[0] for line in out.splitlines() if line.strip()]
    scripts = [*(ROOT / "benchmarks").glob("*.py"), *(ROOT / "benchmarks").glob("*/*.py")]
    expected = sorted(p.stem for p in scripts if not p.stem.startswith("_"))
    assert names == expected and "geometry" in names and "scaling" in names and "roshan_real" in names


def test_bench_runs_a_script_with_its_arguments(tmp_path, capfd):
    (tmp_path / "hello.py").write_text('"""Says hello."""\nimport sys\nprint("hello", sys.argv[1:])\nsys.exit(3)\n')
    (tmp_path / "_helper.py").write_text("")
    (tmp_path / "method").mkdir()
    (tmp_path / "method" / "in_a_folder.py").write_text('"""Lives in a method\'s folder."""\nprint("found")\n')
    assert cli.main(["bench", "--dir", str(tmp_path), "--list"]) == 0
    assert capfd.readouterr().out.split() == [
        "hello",
        "Says",
        "hello",
        "in_a_folder",
        "Lives",
        "in",
        "a",
        "method's",
        "folder",
    ]
    assert cli.main(["bench", "--dir", str(tmp_path), "in_a_folder"]) == 0
    assert "found" in capfd.readouterr().out
    assert cli.main(["bench", "--dir", str(tmp_path), "hello", "--flag", "1", "--list"]) == 3
    assert "hello ['--flag', '1', '--list']" in capfd.readouterr().out


def test_bench_without_a_source_checkout_says_so(tmp_path, monkeypatch, run_cli):
    from jaxsem._commands import bench  # layers: white-box

    monkeypatch.setattr(bench, "default_dir", lambda: tmp_path / "site-packages" / "benchmarks")
    status, _, err = run_cli(["bench", "--list"])
    lines = err.strip().splitlines()
    assert status == 2 and len(lines) == 1
    assert "site-packages/benchmarks" in lines[0] and "source checkout" in lines[0]


@pytest.mark.parametrize("score", ["2", "-0.1", "nan"])
def test_volumon_detect_refuses_a_score_outside_zero_one(score, capsys):
    from jaxsem._commands.volumon_detect import build_parser  # layers: white-box

    with pytest.raises(SystemExit) as info:
        build_parser("jaxsem volumon detect").parse_args(
            ["--image", __file__, "--K", "500,500,320,240", "--out", "o", "--min-score", score]
        )
    assert info.value.code == 2 and "--min-score" in capsys.readouterr().err
