"""Shared command-line plumbing: one-line errors, flag types, atomic outputs."""

import argparse
import json

import numpy as np
import pytest

from jaxsem import scripting as sc
from jaxsem._atomic import atomic_path  # layers: white-box


def _main_raising(exc):
    def main(argv=None):
        raise exc

    return main


@pytest.mark.parametrize(
    "exc, expect",
    [
        (sc.UsageError("--data: empty directory"), "--data: empty directory"),
        (FileNotFoundError(2, "No such file or directory", "/x/seq.json"), "/x/seq.json: no such file"),
        (json.JSONDecodeError("Expecting value", "{", 1), "Expecting value"),
        (KeyError("intrinsics"), "missing key 'intrinsics'"),
        (ValueError("radii: expected positive values"), "radii: expected positive values"),
    ],
)
def test_run_main_prints_one_line_and_exits_2(exc, expect, capsys):
    assert sc.run_main(_main_raising(exc), argv=[], prog="tool") == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("tool: error: ") and expect in err
    assert "Traceback" not in err


def test_exit_status_rule_input_2_work_1(capsys):
    from jaxsem.data import FetchError

    # A failure during the work (the registry cannot be reached) exits 1; a message-carrying
    # SystemExit (a command's check of its input) exits 2, as argparse's own usage errors do.
    assert sc.run_main(_main_raising(FetchError("pip download x: failed")), argv=[], prog="tool") == 1
    assert sc.run_main(_main_raising(SystemExit("tool: --map: no such file")), argv=[], prog="tool") == 2
    assert capsys.readouterr().err.splitlines() == ["tool: error: pip download x: failed", "tool: --map: no such file"]
    with pytest.raises(SystemExit):  # a bare status passes through
        sc.run_main(_main_raising(SystemExit(3)), argv=[])


def test_run_main_debug_reraises():
    with pytest.raises(ValueError):
        sc.run_main(_main_raising(ValueError("x")), argv=["--debug"])


def test_run_main_passes_status_and_unexpected_failures():
    assert sc.run_main(lambda argv: 0, argv=[]) == 0
    assert sc.run_main(lambda argv: None, argv=[]) == 0
    with pytest.raises(ZeroDivisionError):  # a bug is not bad input: keep its traceback
        sc.run_main(_main_raising(ZeroDivisionError()), argv=[])


@pytest.mark.parametrize(
    "kind, text",
    [
        (sc.positive_int, "0"),
        (sc.positive_int, "abc"),
        (sc.nonnegative_int, "-1"),
        (sc.positive_float, "nan"),
        (sc.positive_float, "-2"),
        (sc.finite_float, "inf"),
        (sc.probability, "1.5"),
        (sc.probability, "nan"),
        (sc.int_list, ","),
        (sc.image_size, "480,360"),
        (sc.image_size, "320"),
        (sc.image_size, "16,16"),
        (sc.existing_file, "/definitely/not/here"),
        (sc.existing_dir, "/definitely/not/here"),
    ],
)
def test_flag_types_refuse_bad_values_naming_the_flag(kind, text, capsys):
    parser = argparse.ArgumentParser(prog="tool")
    parser.add_argument("--flag", type=kind)
    with pytest.raises(SystemExit) as exit_info:
        parser.parse_args(["--flag", text])
    assert exit_info.value.code == 2
    assert "--flag" in capsys.readouterr().err


def test_image_size_reads_width_then_height():
    assert sc.image_size("448,336") == (448, 336)


def test_output_paths_refuse_files_and_directories(tmp_path):
    f = tmp_path / "a_file"
    f.write_text("x")
    with pytest.raises(argparse.ArgumentTypeError):
        sc.output_dir(str(f))
    with pytest.raises(argparse.ArgumentTypeError):
        sc.output_file(str(tmp_path))
    assert sc.output_dir(str(tmp_path / "new" / "dir")) == tmp_path / "new" / "dir"


def test_atomic_writes_leave_nothing_on_failure(tmp_path):
    target = tmp_path / "out.json"
    sc.atomic_write_text(target, "old")
    with pytest.raises(RuntimeError), atomic_path(target) as tmp:
        tmp.write_text("half")
        raise RuntimeError("crash mid-write")
    assert target.read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.json"]
    sc.atomic_save_npz(tmp_path / "a.npz", x=np.arange(3))
    np.testing.assert_array_equal(np.load(tmp_path / "a.npz")["x"], np.arange(3))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.npz", "out.json"]
