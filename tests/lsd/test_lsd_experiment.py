"""Table 3.1 experiment (jaxsem.lsd + benchmarks/lsd/lsd_table31.py): statistics and a tiny end-to-end."""

import json
import pathlib

import numpy as np
import pytest

from jaxsem.lsd import PRETRAINED_CPU, summarise
from jaxsem.lsd._experiment import format_table  # layers: white-box

ROOT = pathlib.Path(__file__).resolve().parents[2]


def _rec(kind, n, cs, cl, cb, sl=True, su=True):
    return {
        "set": kind,
        "n": n,
        "c_star": cs,
        "lsd": {"success": sl, "cost": cl},
        "uniform": {"success": su, "cost": cb},
    }


def test_summarise_against_hand_computed_statistics():
    recs = [
        _rec("II", 500, 10.0, 12.0, 15.0),
        _rec("II", 500, 20.0, 22.0, 30.0),
        _rec("II", 500, 10.0, 11.0, 99.0, su=False),
        _rec("II", 500, 10.0, 50.0, 12.0, sl=False),
        _rec("IO", 100, 10.0, 10.0, 10.0, sl=False, su=False),
    ]
    s = summarise(recs)
    ii = s["II-500"]
    assert ii["trials"] == 4 and ii["mutual"] == 2
    assert ii["success_lsd"] == 0.75 and ii["success_uniform"] == 0.75
    assert ii["lsd_only"] == 1 and ii["uniform_only"] == 1
    np.testing.assert_allclose(ii["success_lsd_sem"], np.sqrt(0.75 * 0.25 / 4))
    ratios_l = np.array([1.2, 1.1])
    np.testing.assert_allclose(ii["cl_over_cstar"], (ratios_l.mean(), ratios_l.std(ddof=1) / np.sqrt(2)))
    np.testing.assert_allclose(ii["cb_over_cstar"][0], (1.5 + 1.5) / 2)
    # Zero-intercept least squares of C_b on C_l over the mutual trials only.
    np.testing.assert_allclose(ii["slope_cb_on_cl"], (12 * 15 + 22 * 30) / (12**2 + 22**2))
    io = s["IO-100"]
    assert io["mutual"] == 0 and io["success_lsd"] == 0.0 and np.isnan(io["slope_cb_on_cl"])
    table = format_table(s)
    assert "| II | 500 | 4 | 75 % | 75 % | 1 / 1 | 2 |" in table and "| IO | 100 |" in table


@pytest.mark.slow
def test_table_script_end_to_end_tiny(tmp_path, script):
    mod = script("benchmarks/lsd/lsd_table31.py")
    rc = mod.main(
        [
            # The bundled CPU model keeps this test short; training is covered by test_lsd_train.
            "--checkpoint",
            str(PRETRAINED_CPU),
            "--out",
            str(tmp_path / "res"),
            "--name",
            "t31",
            "--test-buildings",
            "1",
            "--trials",
            "1",
            "--n",
            "100",
            "--sets",
            "II",
            "IO",
            "--max-steps",
            "40",
            "--no-progress",
        ]
    )
    assert rc == 0
    out = json.loads((tmp_path / "res" / "t31.json").read_text())
    assert set(out["summary"]) == {"II-100", "IO-100"}
    assert len(out["records"]) == 2
    for r in out["records"]:
        for planner in ("lsd", "uniform"):
            assert r[planner]["reason"] in ("goal", "no_plan", "max_steps")
            assert r[planner]["steps"] <= 40 and r[planner]["cost"] <= 40 * 0.25 + 1e-9
        assert r["c_star"] > 0
    assert not out["model"]["trained_here"] and out["args"]["uniform_mix"] == 0.0
    assert {
        "success_lsd_sem",
        "success_uniform_sem",
        "lsd_only",
        "uniform_only",
    } <= set(out["summary"]["II-100"])
    assert (tmp_path / "res" / "t31.png").stat().st_size > 0
    md = (tmp_path / "res" / "t31.md").read_text()
    assert "Machine: 2-core CPU (shared, noisy)" in md and "| II | 100 | 1 |" in md
    with pytest.raises(SystemExit):
        mod.main(["--help"])
    with pytest.raises(SystemExit, match="--sets"):
        mod.main(["--sets", "OO", "--out", str(tmp_path)])


def test_success_figure_names_the_trial_counts_of_every_n(tmp_path, axes_titles):
    # regression: the title gave the first N's trial count when a merged table had 100 trials at
    # N = 500 and 30 at the other N
    from jaxsem.lsd import plot_success

    row = dict(set="II", success_lsd=0.9, success_uniform=0.8, success_lsd_sem=0.03, success_uniform_sem=0.04)
    summary = {"II-200": dict(row, n=200, trials=30), "II-500": dict(row, n=500, trials=100)}
    plot_success(summary, tmp_path / "s.png")
    assert (tmp_path / "s.png").stat().st_size > 0
    assert axes_titles == ["II: 30-100 trials per N"]


def test_a_variant_both_planners_ran_is_paired_like_the_defaults():
    def rec(sl, su, cl=12.0, cb=15.0):
        r = _rec("II", 500, 10.0, 11.0, 11.0)
        r["lsd_thesis"] = {"success": sl, "cost": cl}
        r["uniform_thesis"] = {"success": su, "cost": cb}
        return r

    s = summarise([rec(True, True), rec(True, False), rec(True, False), rec(False, True), rec(False, False)])
    pv = s["II-500"]["paired_thesis"]
    assert (pv["lsd_only"], pv["uniform_only"], pv["mutual"]) == (2, 1, 1)
    assert pv["cl_over_cstar"][0] == pytest.approx(1.2) and pv["cb_over_cstar"][0] == pytest.approx(1.5)
    assert s["II-500"]["success_lsd_thesis"] == pytest.approx(0.6)
    assert s["II-500"]["success_uniform_thesis"] == pytest.approx(0.4)
    assert "| II | 500 | thesis | 40 +- 22 % | 60 +- 22 % | 2 / 1 | 1 |" in format_table(s)
    # A planner without a partner is not paired.
    for r in (recs := [rec(True, True)]):
        del r["uniform_thesis"]
    assert not any(k.startswith("paired_") for k in summarise(recs)["II-500"])


@pytest.mark.slow
def test_thesis_ablation_runs_both_planners_without_reuse_or_growth(tmp_path, script):
    mod = script("benchmarks/lsd/lsd_table31.py")
    args = ["--checkpoint", str(PRETRAINED_CPU), "--out", str(tmp_path), "--test-buildings", "1", "--trials", "1"]
    args += ["--n", "100", "--sets", "II", "--max-steps", "60", "--no-progress", "--ablations", "thesis"]
    assert mod.main([*args, "--name", "th"]) == 0
    out = json.loads((tmp_path / "th.json").read_text())
    (r,) = out["records"]
    for name in ("uniform_thesis", "lsd_thesis"):
        assert r[name]["grown"] == 0 and r[name]["reason"] in ("goal", "no_plan", "max_steps")
    # Replans at steps 0, 20 and 40 at least; reuse (without growth) draws at most two roadmaps:
    # the kept one and one fresh one when it fails.
    assert r["uniform_thesis"]["steps"] >= 40 and r["uniform_thesis"]["plans"] >= 3
    assert "paired_thesis" in out["summary"]["II-100"]
    assert "| II | 100 | thesis |" in (tmp_path / "th.md").read_text()


@pytest.mark.slow
def test_other_model_runs_beside_the_first_on_the_same_tasks(tmp_path, script, capsys):
    """``--other`` with the same model as ``--checkpoint`` drives every trial as the first does,
    under the defaults and the thesis' protocol, and the pairing finds no task only one solved."""
    mod = script("benchmarks/lsd/lsd_table31.py")
    args = ["--checkpoint", str(PRETRAINED_CPU), "--other", str(PRETRAINED_CPU), "--out", str(tmp_path)]
    args += ["--test-buildings", "1", "--trials", "1", "--n", "100", "--sets", "II", "--max-steps", "60"]
    args += ["--no-progress", "--ablations", "thesis", "--name", "other"]
    assert mod.main(args) == 0
    (r,) = json.loads((tmp_path / "other.json").read_text())["records"]
    for a, b in (("lsd_other", "lsd"), ("lsd_other_thesis", "lsd_thesis")):
        assert (r[a]["success"], r[a]["steps"], r[a]["plans"]) == (r[b]["success"], r[b]["steps"], r[b]["plans"])
    assert mod.main([*args, "--only-ablations", "--name", "only"]) == 0
    assert "lsd_other_thesis vs lsd_thesis II: 0 / 0 tasks only one solved, of 1" in capsys.readouterr().out
    with pytest.raises(SystemExit, match="--other:"):
        mod.main([*args[:2], "--other", str(tmp_path / "none.npz"), *args[4:]])
