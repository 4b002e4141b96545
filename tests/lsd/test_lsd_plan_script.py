"""infer/plan.py: defaults in --help, one-line flag errors, figures from a short run."""

import importlib.util
import pathlib

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[2]


def _module():
    spec = importlib.util.spec_from_file_location("plan_script", ROOT / "infer" / "plan.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_help_shows_defaults(capsys):
    with pytest.raises(SystemExit):
        _module().main(["--help"])
    out = capsys.readouterr().out
    assert "(default: 500)" in out and "(default: 2000)" in out and "(default: 0.0)" in out


def test_bad_flags_name_the_flag(tmp_path):
    mod = _module()
    with pytest.raises(SystemExit, match="--map"):
        mod.main(["--map", str(tmp_path / "missing.npz")])
    with pytest.raises(SystemExit, match="--n"):
        mod.main(["--n", "0"])
    with pytest.raises(SystemExit, match="--uniform-mix"):
        mod.main(["--uniform-mix", "1.5"])
    (tmp_path / "a_file").write_text("x")
    with pytest.raises(SystemExit, match="--out"):
        mod.main(["--out", str(tmp_path / "a_file" / "plan.png")])


@pytest.mark.parametrize(
    "given, missing", [(["--start", "1", "1"], "--goal"), (["--goal", "5", "5"], "--start")], ids=["start", "goal"]
)
def test_start_or_goal_alone_is_refused(given, missing, tmp_path):
    # One alone ran a sampled task to exit 0, the given point dropped without a word.
    with pytest.raises(SystemExit, match=f"^{missing}: needed with"):
        _module().main([*given, "--out", str(tmp_path / "p.png")])
    assert not (tmp_path / "p.png").exists()


@pytest.mark.slow
def test_short_run_writes_the_map_and_the_strip(tmp_path):
    out = tmp_path / "new" / "plan.png"  # regression: the figure's folder is made (it failed after the run)
    rc = _module().main(
        [
            "--building",
            "0",
            "--kind",
            "II",
            "--sampler",
            "lsd",
            "--max-steps",
            "25",
            "--out",
            str(out),
            "--no-progress",
            "--panels",
            "3",
        ]
    )
    assert rc == 0 and out.stat().st_size > 0
    assert (tmp_path / "new" / "plan_over_time.png").stat().st_size > 0


def test_a_map_declaring_more_cells_than_the_budget_is_refused_unread(tmp_path):
    # An .npz whose occupancy header declares 60000 x 60000 cells over a few bytes of data: refused
    # from the header (issue 45 item 4), naming the flag, the file and the declared shape.
    import io
    import zipfile

    import numpy as np

    head = io.BytesIO()
    np.lib.format.write_array_header_1_0(head, {"descr": "|b1", "fortran_order": False, "shape": (60000, 60000)})
    path = tmp_path / "claim.npz"
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("occupancy.npy", head.getvalue() + bytes(16))
    args = ["--map", str(path), "--start", "0", "0", "--goal", "1", "1", "--out", str(tmp_path / "p.png")]
    with pytest.raises(SystemExit, match=r"--map: .*claim.npz declares occupancy of shape \(60000, 60000\)"):
        _module().main([*args, "--run-dir", str(tmp_path / "run")])
