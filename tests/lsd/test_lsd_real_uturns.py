"""benchmarks/lsd/lsd_real_uturns.py: U-turns counted on drawn paths, and the script on written records."""

import json

import numpy as np
import pytest


def _walk(*legs, step=0.25):
    """A driven path: 0.25 m steps along each (dx, dy, metres) leg in turn."""
    p = [np.zeros(2)]
    for dx, dy, length in legs:
        d = np.array([dx, dy], float) / np.hypot(dx, dy)
        for _ in range(int(round(length / step))):
            p.append(p[-1] + step * d)
    return np.array(p)


def test_uturns_on_drawn_paths(script):
    u = script("benchmarks/lsd/lsd_real_uturns.py").uturns
    assert u(_walk((1, 0, 10))) == 0
    assert u(_walk((1, 0, 10), (0, 1, 10))) == 0  # a corner is not a U-turn
    assert u(_walk((1, 0, 10), (-1, 0, 6))) == 1  # out and back
    assert u(_walk((1, 0, 10), (-1, 0, 6), (1, 0, 6))) == 2  # dithering
    assert u(_walk((1, 0, 10), (0, 1, 0.25), (-1, 0, 6))) == 1  # a hairpin one step wide
    assert u(_walk((1, 0, 10), (0, 1, 2.0), (-1, 0, 6))) == 0  # two corners 2 m apart: a loop, not a U-turn
    assert u(np.zeros((30, 2))) == 0  # standing still has no heading
    assert u(_walk((1, 0, 1))) == 0  # too short to tell


def test_script_lists_the_detours(tmp_path, capsys, script):
    mod = script("benchmarks/lsd/lsd_real_uturns.py")
    walk = _walk((1, 0, 10), (-1, 0, 10), (1, 0, 20))
    straight = _walk((1, 0, 10))

    def rec(trial, lsd_path):
        lsd_cost = float(np.sum(np.hypot(*np.diff(lsd_path, axis=0).T)))
        run = lambda path, cost: {"success": True, "cost": cost, "path": path.tolist()}
        return {
            "set": "II",
            "n": 500,
            "trial": trial,
            "c_star": 10.0,
            "uniform": run(straight, 10.0),
            "lsd": run(lsd_path, lsd_cost),
        }

    records = tmp_path / "run.records.jsonl"
    records.write_text("\n".join(json.dumps(r) for r in (rec(0, straight), rec(1, walk))))
    (tmp_path / "run.json").write_text(json.dumps({"benchmark": "lsd_real", "records": str(records)}))
    out = tmp_path / "u.json"
    assert mod.main(["--json", str(tmp_path / "run.json"), "--out", str(out)]) == 0
    row = json.loads(out.read_text())["rows"][0]
    assert row["mutual"] == 2 and row["uturns_uniform"] == 0.0 and row["uturns_lsd"] == 1.0
    assert [d["trial"] for d in row["detours"]] == [1] and row["detours"][0]["cl_over_cstar"] == pytest.approx(4.0)
    assert row["replans_blocked_lsd"] is None  # records from before the replan reasons
    # Records with replan reasons: their means per task, per planner.
    recs = [rec(0, straight), rec(1, walk)]
    for r, (bu, pu, bl, pl) in zip(recs, [(0, 1, 2, 3), (0, 3, 4, 5)]):
        r["uniform"].update(replans_blocked=bu, replans_periodic=pu)
        r["lsd"].update(replans_blocked=bl, replans_periodic=pl)
    records.write_text("\n".join(json.dumps(r) for r in recs))
    assert mod.main(["--json", str(tmp_path / "run.json"), "--out", str(out)]) == 0
    row = json.loads(out.read_text())["rows"][0]
    got = [row[f"replans_{k}_{p}"] for p in ("uniform", "lsd") for k in ("blocked", "periodic")]
    assert got == [0.0, 2.0, 3.0, 4.0]
    assert "0.0 / 2.0; 3.0 / 4.0" in capsys.readouterr().out
    (tmp_path / "other.json").write_text(json.dumps({"benchmark": "lsd_table31"}))
    with pytest.raises(SystemExit, match="not an lsd_real.py output"):
        mod.main(["--json", str(tmp_path / "other.json"), "--out", str(tmp_path / "x.json")])
    assert not (tmp_path / "x.json").exists()
