"""Semantics for scanned maps (issue 25 item 2): doors found on drawn maps with known doors, the
footprint, the stand-in outside, annotations, resampling against a brute-force overlap, task
bounds, and a real-map trial end to end (a written MRPT gridmap; the real lab map when present)."""

import gzip
import json
import os
import pathlib
import struct
import subprocess
import sys

import jax
import numpy as np
import pytest
import scipy.ndimage as ndi

from jaxsem import planning
from jaxsem.lsd import read_records, run_trials
from jaxsem.planning import DOOR, FREE, OCCUPIED, UNKNOWN, WINDOW
from jaxsem.planning._maps import resample_occupancy  # layers: white-box
from jaxsem.planning._semantics import (  # layers: white-box
    building_footprint,
    find_doors,
    largest_open_region,
    read_annotations,
)
from jaxsem.training import ConfigMismatchError

ROOT = pathlib.Path(__file__).resolve().parents[2]
RES = 0.1


def _two_rooms(gap_m: float, gap_at: float = 3.0, column: bool = False):
    """Two 5 x 4 m rooms side by side (0.2 m walls), a doorway of ``gap_m`` in the shared wall
    whose lower edge is ``gap_at`` metres up; optionally a column in the left room."""
    h, w = 44, 104
    occ = np.full((h, w), FREE, np.int8)
    occ[:2, :] = occ[-2:, :] = OCCUPIED
    occ[:, :2] = occ[:, -2:] = OCCUPIED
    occ[:, 51:53] = OCCUPIED
    if gap_m > 0:
        r0 = int(round(gap_at / RES))
        occ[r0 : r0 + int(round(gap_m / RES)), 51:53] = FREE
    if column:
        occ[20:24, 25:29] = OCCUPIED
    return occ


def test_a_door_is_found_where_it_was_drawn():
    occ = _two_rooms(0.9, gap_at=1.5)
    doors = find_doors(occ, RES)
    labels, n = ndi.label(doors, np.ones((3, 3)))
    assert n == 1
    rows, cols = np.nonzero(doors)
    # The doorway cells themselves are door; nothing far from the doorway is.
    assert doors[15:24, 51:53].all()
    assert rows.min() >= 15 - 8 and rows.max() < 24 + 8
    assert cols.min() >= 51 - 8 and cols.max() < 53 + 8


@pytest.mark.parametrize(
    "occ, why",
    [
        (_two_rooms(0.0), "no opening"),
        (_two_rooms(2.6, gap_at=0.8), "an opening wider than any door"),
        (_two_rooms(0.0, column=True), "a gap beside a column joins one room to itself"),
    ],
)
def test_no_door_where_there_is_none(occ, why):
    assert not find_doors(occ, RES).any(), why


def test_door_finding_rejects_bad_arguments():
    with pytest.raises(ValueError, match="width"):
        find_doors(_two_rooms(0.9), RES, width=(1.2, 0.8))
    with pytest.raises(ValueError, match="resolution"):
        find_doors(_two_rooms(0.9), 0.0)
    with pytest.raises(ValueError, match="occupancy"):
        find_doors(np.zeros(5), RES)


def _house_in_a_yard():
    """A 6 x 6 m closed house with a 1 m front door, in the middle of a 14 x 14 m free yard."""
    occ = np.full((140, 140), FREE, np.int8)
    occ[:1, :] = occ[-1:, :] = OCCUPIED
    occ[:, :1] = occ[:, -1:] = OCCUPIED
    occ[40:100, 40:42] = occ[40:100, 98:100] = OCCUPIED
    occ[40:42, 40:100] = occ[98:100, 40:100] = OCCUPIED
    occ[40:42, 65:75] = FREE  # the door
    return occ


def test_footprint_of_a_closed_house_is_its_inside():
    indoor = building_footprint(_house_in_a_yard(), RES, method="walls")
    assert indoor[70, 70] and indoor[45, 45] and indoor[95, 95]
    assert not indoor[10, 10] and not indoor[20, 120] and not indoor[130, 70]
    # What lies a metre outside the door is outside, a metre inside is inside.
    assert not indoor[30, 70] and indoor[52, 70]


def test_density_footprint_cuts_a_scans_ray_tips():
    occ = np.full((200, 200), UNKNOWN, np.int8)
    occ[60:140, 60:140] = FREE  # the densely seen building
    for k in range(0, 60, 6):  # thin rays escaping to the right through a window
        occ[95 + k // 6, 140:195] = FREE
    indoor = building_footprint(occ, RES, method="density")
    assert indoor[100, 100] and indoor[65, 65]
    assert not indoor[97, 190]  # a ray's tip


def test_largest_open_region_is_the_hall_not_the_corridor():
    occ = np.full((120, 220), OCCUPIED, np.int8)
    occ[10:110, 10:110] = FREE  # a 10 x 10 m hall
    occ[55:70, 110:210] = FREE  # a 1.5 m corridor off it
    hall = largest_open_region(occ, RES)
    assert hall[60, 60] and hall[15, 60] and hall[60, 105]
    assert not hall[60, 200]


def test_a_map_without_outside_gets_its_hall_as_outside(tmp_path):
    occ = np.full((120, 220), OCCUPIED, np.int8)
    occ[10:110, 10:110] = FREE
    occ[55:70, 110:210] = FREE
    grid = planning.OccupancyGrid(occ, np.zeros(2), RES)
    b = planning.grid_to_building(grid)
    assert not b.indoor[60, 60]  # the hall stands in for the outside
    assert b.indoor[62, 200]  # the corridor stays inside
    # Its Inside-Outside goals come from the hall, but the network is told they are indoors.
    assert not b.outside_is_outdoors
    io = planning.sample_tasks(b, "IO", 3, seed=1, min_distance=6.0)
    assert io and all(not b.indoor[tuple(np.floor(t.goal / RES).astype(int)[::-1])] for t in io)
    assert not any(t.goal_outdoors for t in io)
    trial = planning.Trial(b, io[0].start, io[0].goal, jax.random.key(0))
    assert trial.goal_outdoors is False
    # Hand-drawn outdoor boxes are the outside: no stand-in, and their goals are outdoors.
    note = tmp_path / "out.json"
    note.write_text(json.dumps({"outdoor": [[18.0, 5.5, 21.0, 7.0]]}))
    drawn = planning.grid_to_building(grid, annotations=note)
    assert drawn.outside_is_outdoors and drawn.indoor[60, 60] and not drawn.indoor[62, 200]
    assert all(t.goal_outdoors for t in planning.sample_tasks(drawn, "IO", 2, seed=1, min_distance=6.0))


def _resample_brute(occ, src_res, dst_res):
    """Every output cell looks at every source cell whose area overlaps its own."""
    h, w = occ.shape
    H = int(np.ceil(h * src_res / dst_res - 1e-9))
    W = int(np.ceil(w * src_res / dst_res - 1e-9))
    rank = {UNKNOWN: 1, FREE: 0, OCCUPIED: 2}
    out = np.empty((H, W), np.int8)
    for R in range(H):
        for C in range(W):
            best = 0
            y0, y1 = R * dst_res, (R + 1) * dst_res
            x0, x1 = C * dst_res, (C + 1) * dst_res
            any_cell = False
            for r in range(h):
                if not (r * src_res < y1 - 1e-9 and (r + 1) * src_res > y0 + 1e-9):
                    continue
                for c in range(w):
                    if c * src_res < x1 - 1e-9 and (c + 1) * src_res > x0 + 1e-9:
                        best = max(best, rank[int(occ[r, c])])
                        any_cell = True
            covers_all = (y1 <= h * src_res + 1e-9) and (x1 <= w * src_res + 1e-9)
            if not covers_all or not any_cell:  # past the map's edge: unknown at least
                best = max(best, 1)
            out[R, C] = {0: FREE, 1: UNKNOWN, 2: OCCUPIED}[best]
    return out


@pytest.mark.parametrize("src_res, dst_res", [(0.08, 0.1), (0.04, 0.1), (0.1, 0.25), (0.05, 0.1), (0.1, 0.07)])
def test_resampling_against_brute_force_overlap(src_res, dst_res):
    rng = np.random.default_rng(7)
    occ = rng.choice(np.array([FREE, FREE, FREE, UNKNOWN, OCCUPIED], np.int8), size=(13, 17))
    grid = planning.OccupancyGrid(occ, np.array([1.0, -2.0]), src_res)
    got = resample_occupancy(grid, dst_res)
    assert got.resolution == dst_res
    np.testing.assert_allclose(got.origin, [1.0, -2.0])
    np.testing.assert_array_equal(got.occupancy, _resample_brute(occ, src_res, dst_res))


def test_annotations_mark_windows_and_doors_and_name_bad_boxes(tmp_path):
    occ = _two_rooms(0.0)
    grid = planning.OccupancyGrid(occ, np.zeros(2), RES)
    note = tmp_path / "a.json"
    # A window on the left outer wall (x 0-0.2 m, y 1-2 m) and a door cut through the shared wall.
    note.write_text(json.dumps({"windows": [[0.0, 1.0, 0.2, 2.0]], "doors": [[5.1, 2.0, 5.3, 3.0]]}))
    b = planning.grid_to_building(grid, annotations=note)
    assert (b.semantic[10:20, 0:2] == WINDOW).all()
    assert (b.semantic[20:30, 51:53] == DOOR).all() and not b.occupancy[20:30, 51:53].any()
    note.write_text(json.dumps({"windows": [[2.0, 2.0, 2.5, 2.5]]}))  # on the floor: no wall there
    with pytest.raises(ValueError, match=r"windows\[0\]"):
        planning.grid_to_building(grid, annotations=note)
    note.write_text(json.dumps({"doorz": []}))
    with pytest.raises(ValueError, match="doorz"):
        read_annotations(note)
    note.write_text(json.dumps({"doors": [[1.0, 2.0, 0.5, 3.0]]}))
    with pytest.raises(ValueError, match="'doors'"):
        read_annotations(note)


def _write_gridmap(path, occ, res, x_min=0.0, y_min=0.0):
    """A three-state grid as an MRPT gridmap (free +50, occupied -50, unknown 0)."""
    cells = np.where(occ == FREE, 50, np.where(occ == OCCUPIED, -50, 0)).astype(np.int8)
    sy, sx = cells.shape
    name = b"COccupancyGridMap2D"
    head = bytes([0x80 | len(name)]) + name + bytes([3, 8])
    head += struct.pack("<II", sx, sy) + struct.pack("<5f", x_min, x_min + sx * res, y_min, y_min + sy * res, res)
    path.write_bytes(gzip.compress(head + cells.tobytes()))


def test_task_bounds_and_a_scanned_maps_seed():
    occ = _two_rooms(0.9, gap_at=1.5)
    b = planning.grid_to_building(planning.OccupancyGrid(occ, np.zeros(2), RES))
    assert b.seed == -1
    tasks = planning.sample_tasks(b, "II", 6, seed=3, min_distance=3.0, max_distance=6.0, clearance=0.4)
    assert len(tasks) == 6
    dt = ndi.distance_transform_edt(~b.occupancy) * RES
    for t in tasks:
        assert 3.0 <= np.linalg.norm(t.goal - t.start) <= 6.0
        for p in (t.start, t.goal):
            r, c = np.floor((p - b.origin) / RES).astype(int)[::-1]
            assert dt[r, c] >= 0.4
    again = planning.sample_tasks(b, "II", 6, seed=3, min_distance=3.0, max_distance=6.0, clearance=0.4)
    assert [t.goal.tolist() for t in again] == [t.goal.tolist() for t in tasks]
    with pytest.raises(ValueError, match="max_distance"):
        planning.sample_tasks(b, "II", 1, seed=0, min_distance=5.0, max_distance=4.0)


@pytest.mark.slow
def test_real_map_trial_end_to_end_streams_and_resumes(tmp_path, script, capsys):
    """The benchmark on a written gridmap at 0.05 m (resampled to 0.1 m): records stream as
    trials end, a rerun resumes without running them again, a torn last line is redone."""
    occ = np.kron(_two_rooms(0.9, gap_at=1.5), np.ones((2, 2), np.int8))  # 0.05 m cells
    path = tmp_path / "rooms.gridmap.gz"
    _write_gridmap(path, occ, 0.05, x_min=-3.0, y_min=4.0)
    mod = script("benchmarks/lsd/lsd_real.py")
    out = tmp_path / "r.json"
    argv = [
        "--map", str(path), "--trials", "2", "--n", "60", "--sets", "II", "--protocol", "thesis",
        "--seed", "1", "--min-distance", "3", "--max-distance", "9", "--max-steps", "30",
        "--json", str(out), "--no-progress",
    ]  # fmt: skip
    assert mod.main(argv) == 0
    result = json.loads(out.read_text())
    assert result["map_facts"]["resolution_m"] == pytest.approx(0.1)
    assert result["map_facts"]["doors_found"] == 1
    assert set(result["summary"]) == {"II-60"}
    records_file = pathlib.Path(result["records"])
    lines = records_file.read_text().splitlines()
    assert len(lines) == 3  # the stamp, then one record per trial
    first = read_records(records_file)
    for r in first:
        assert len(r["uniform"]["path"]) >= 2 and r["uniform"]["steps"] <= 30
    assert pathlib.Path(result["map_facts"]["figure"]).stat().st_size > 0
    # Resume: a torn last line is dropped and that trial alone runs again.
    records_file.write_text("\n".join(lines[:2]) + "\n" + lines[2][: len(lines[2]) // 2])
    assert mod.main(argv) == 0
    again = read_records(records_file)
    assert len(again) == 2 and again[0] == first[0]
    assert again[1]["uniform"]["success"] == first[1]["uniform"]["success"]
    assert again[1]["uniform"]["path"] == first[1]["uniform"]["path"]  # same key: same trial
    # A rerun under another step limit does not reuse the 30-step records; --fresh starts over.
    other = [("40" if a == "30" else a) for a in argv]
    assert mod.main(other) == 2
    assert "--max-steps" in capsys.readouterr().err
    assert read_records(records_file) == again  # the refused run wrote nothing
    assert mod.main(other + ["--fresh"]) == 0
    assert all(r["uniform"]["steps"] <= 40 for r in read_records(records_file))
    assert json.loads(out.read_text())["command"].endswith("--fresh")


@pytest.mark.slow
def test_real_map_other_model_paired_on_the_same_tasks(tmp_path, script):
    """``--other`` runs a second LSD model on the same tasks; with the same model as
    ``--checkpoint`` it drives the same trials, so the pairing finds no task only one solved."""
    path = tmp_path / "rooms.gridmap.gz"
    _write_gridmap(path, _two_rooms(0.9, gap_at=1.5), 0.1)
    mod = script("benchmarks/lsd/lsd_real.py")
    out = tmp_path / "r.json"
    run_argv = [
        "--map", str(path), "--trials", "2", "--n", "60", "--sets", "II", "--protocol", "thesis",
        "--seed", "1", "--min-distance", "3", "--max-distance", "9", "--max-steps", "40",
        "--checkpoint", "default", "--other", "default", "--json", str(out), "--no-progress",
    ]  # fmt: skip
    assert mod.main(run_argv) == 0
    row = json.loads(out.read_text())["summary"]["II-60"]
    records = read_records(out.with_name("r.records.jsonl"))
    assert len(records) == 2
    for r in records:
        assert r["lsd_other"]["success"] == r["lsd"]["success"] and r["lsd_other"]["path"] == r["lsd"]["path"]
    pair = row["other_vs_lsd"]
    assert pair["tasks"] == 2 and pair["other_only"] == pair["lsd_only"] == 0
    assert pair["success_other"] == pair["success_lsd"] == row["success_lsd"]


@pytest.mark.slow
def test_real_map_variant_that_replans_only_when_blocked(tmp_path, script):
    """``--replan-when-blocked`` adds an LSD row on the same tasks whose route is kept until it
    is blocked: it never draws more roadmaps than the default LSD, which draws one every 20 steps."""
    occ = _two_rooms(0.9, gap_at=1.5)
    path = tmp_path / "rooms.gridmap.gz"
    _write_gridmap(path, occ, 0.1)
    mod = script("benchmarks/lsd/lsd_real.py")
    out = tmp_path / "r.json"
    run_argv = [
        "--map", str(path), "--trials", "2", "--n", "60", "--sets", "II", "--protocol", "defaults",
        "--seed", "1", "--min-distance", "3", "--max-distance", "9", "--max-steps", "60",
        "--replan-when-blocked", "--json", str(out), "--no-progress",
    ]  # fmt: skip
    assert mod.main(run_argv) == 0
    result = json.loads(out.read_text())
    assert "success_lsd_blocked" in result["summary"]["II-60"]
    records = read_records(result["records"])
    assert len(records) == 2
    for r in records:
        assert r["lsd_blocked"]["plans"] <= r["lsd"]["plans"]
    assert any(r["lsd"]["steps"] > 20 and r["lsd_blocked"]["plans"] < r["lsd"]["plans"] for r in records)
    # Every trial records why its planners replanned; the route-kept row never on the timer.
    for r in records:
        assert r["lsd_blocked"]["replans_periodic"] == 0
        assert r["lsd"]["replans_periodic"] + r["lsd"]["replans_blocked"] < r["lsd"]["plans"] + r["lsd"]["grown"]
    assert any(r["lsd"]["replans_periodic"] > 0 for r in records if r["lsd"]["steps"] > 20)
    # A trial replayed from its record (benchmarks/lsd/lsd_real_replay.py) drives as it was recorded.
    rep = script("benchmarks/lsd/lsd_real_replay.py")
    t = max(records, key=lambda r: r["lsd"]["steps"])["trial"]
    fig = tmp_path / "replay.png"
    argv = ["--json", str(out), "--trial", str(t), "--planner", "lsd_blocked", "--out", str(fig), "--panels", "3"]
    assert rep.main(argv) == 0
    got = json.loads(fig.with_suffix(".json").read_text())
    rec = [r for r in records if r["trial"] == t][0]["lsd_blocked"]
    assert got["replayed_as_recorded"] and got["steps"] == rec["steps"]
    assert got["replans_blocked"] == rec["replans_blocked"] and fig.stat().st_size > 0
    assert [e["reason"] for e in got["replans"]][0] == "first plan"
    assert sum(e["reason"] == "blocked" for e in got["replans"]) == rec["replans_blocked"]
    # A variant added later on the same tasks runs alone; uniform and LSD come from the earlier run,
    # whose model is the same one however it is named (no --checkpoint there, 'default' here).
    more = tmp_path / "more.json"
    argv2 = [
        *run_argv[: run_argv.index("--replan-when-blocked")],
        *("--euclid", "--unknown-weight", "3", "--reuse-base", str(out), "--checkpoint", "default"),
    ]
    assert mod.main([*argv2, "--json", str(more), "--no-progress"]) == 0
    joined = read_records(tmp_path / "more.records.jsonl")
    rows = {"uniform", "lsd", "lsd_blocked", "lsd_euclid", "uniform_unk", "lsd_unk"}
    assert len(joined) == 2 and all(rows <= set(r) for r in joined)
    assert [r["lsd"] for r in joined] == [r["lsd"] for r in records]  # taken, not run again
    row = json.loads(more.read_text())["summary"]["II-60"]
    assert "success_lsd_euclid" in row and "mutual" in row["paired_unk"]
    bad = [*argv2, "--seed", "2", "--json", str(tmp_path / "bad.json")]
    with pytest.raises(SystemExit, match="--seed is 2 here but 1"):
        mod.main(bad)
    other = [*argv2, "--checkpoint", "generated", "--json", str(tmp_path / "bad.json")]
    with pytest.raises(SystemExit, match="--checkpoint 'generated' is another model"):
        mod.main(other)
    with pytest.raises(SystemExit, match="name at least one variant"):
        mod.main(
            [
                *run_argv[: run_argv.index("--replan-when-blocked")],
                "--reuse-base",
                str(out),
                "--json",
                str(tmp_path / "bad.json"),
            ]
        )
    assert not (tmp_path / "bad.json").exists()
    with pytest.raises(SystemExit, match="--planner"):
        rep.main([*argv[:4], "--planner", "lsd_nosem", "--out", str(tmp_path / "x.png")])
    with pytest.raises(SystemExit, match="--trial"):
        rep.main(["--json", str(out), "--trial", "7", "--out", str(tmp_path / "x.png")])
    assert not (tmp_path / "x.png").exists()


def test_streamed_records_read_back_past_a_torn_tail(tmp_path):
    f = tmp_path / "r.jsonl"
    f.write_text('{"a": 1}\n{"a": 2}\n{"a": ')
    assert read_records(f) == [{"a": 1}, {"a": 2}]
    f.write_text('{"a": 1}\n{"a": \n{"a": 3}\n')
    with pytest.raises(ValueError, match="line 2"):
        read_records(f)


def test_real_map_command_names_bad_flags(tmp_path, capsys, script):
    mod = script("benchmarks/lsd/lsd_real.py")
    with pytest.raises(SystemExit, match="--map"):
        mod.main(["--map", str(tmp_path / "none.yaml"), "--json", str(tmp_path / "o.json")])
    path = tmp_path / "m.gridmap.gz"
    _write_gridmap(path, _two_rooms(0.9), 0.1)
    with pytest.raises(SystemExit, match="--max-distance"):
        mod.main(["--map", str(path), "--min-distance", "9", "--max-distance", "3", "--json", str(tmp_path / "o.json")])
    with pytest.raises(SystemExit, match="--unknown-weight"):
        mod.main(["--map", str(path), "--unknown-weight", "0", "--json", str(tmp_path / "o.json")])
    with pytest.raises(SystemExit, match="--oracle"):
        mod.main(["--map", str(path), "--oracle", str(tmp_path / "none.npz"), "--json", str(tmp_path / "o.json")])
    with pytest.raises(SystemExit, match="lsd_real: --other: .*'hous'"):
        mod.main(["--map", str(path), "--other", "hous", "--json", str(tmp_path / "o.json")])
    assert not (tmp_path / "o.json").exists()


def test_floor_of_real_map_tasks_against_straight_lines_and_the_door_corner(tmp_path, capsys, script):
    """benchmarks/lsd/lsd_real_floor.py reloads the run's map from its command and measures each
    task's shortest possible length: a straight line inside one room, the polyline round the
    doorway's corner between the rooms (the visibility path, drawn by hand)."""
    path = tmp_path / "rooms.gridmap.gz"
    _write_gridmap(path, _two_rooms(0.9, gap_at=1.5), RES)
    records = tmp_path / "run.records.jsonl"
    same = ([1.05, 1.05], [4.05, 3.05])
    across = ([2.05, 3.85], [8.05, 3.85])
    corner = [[2.05, 3.85], [5.15, 2.35], [5.25, 2.35], [8.05, 3.85]]  # the door's top cells
    around = float(np.sum(np.linalg.norm(np.diff(corner, axis=0), axis=1)))
    straight = float(np.linalg.norm(np.subtract(same[1], same[0])))
    rows = []
    for trial, ((s, g), ref) in enumerate([(same, straight), (across, around)]):
        run = lambda cost: {"success": True, "cost": cost}
        rows.append(
            {"building": -1, "set": "II", "trial": trial, "n": 60, "c_star": 1.1 * ref, "start": s, "goal": g,
             "uniform": run(ref), "lsd": run(0.9 * ref)}
        )  # fmt: skip
    records.write_text("".join(json.dumps(r) + "\n" for r in rows))
    run_json = tmp_path / "run.json"
    command = f"python benchmarks/lsd/lsd_real.py --map {path} --json {run_json}"
    run_json.write_text(json.dumps({"benchmark": "lsd_real", "command": command, "records": str(records)}))
    mod = script("benchmarks/lsd/lsd_real_floor.py")
    out = tmp_path / "floor.json"
    assert mod.main(["--json", str(run_json), "--out", str(out)]) == 0
    row = json.loads(out.read_text())["runs"]["run"]["rows"]["II-60"]
    assert row["mutual"] == 2
    # uniform drove the shortest paths: the 16-connected floor is at most 2.7 % above them, never
    # below; LSD 10 % below uniform; no room below a planner that is on the floor
    assert 1 / 1.0275 - 1e-3 <= row["cb_over_floor"] <= 1.0 + 1e-3
    assert row["floor_over_cstar"] == pytest.approx(1 / 1.1, rel=0.03)
    assert row["lsd_below_uniform"] == pytest.approx(0.1)
    assert -0.03 <= row["room_below_uniform"] <= 1e-3 <= row["room_below_uniform_bound"] <= 0.03
    assert "| run | II-60 | 2 / 2 |" in capsys.readouterr().out
    assert (tmp_path / "floor.png").stat().st_size > 0
    bad = tmp_path / "other.json"
    bad.write_text(json.dumps({"benchmark": "lsd_prm"}))
    with pytest.raises(SystemExit, match="--json"):
        mod.main(["--json", str(bad), "--out", str(tmp_path / "o.json")])
    assert not (tmp_path / "o.json").exists()


def test_real_lab_map_semantics_when_present(tmp_path):
    root = os.environ.get("JAXSEM_MAPS_DIR")
    path = pathlib.Path(root or "/nonexistent") / "uwb_ro-localization_demo_map.gridmap.gz"
    if not path.is_file():
        pytest.skip("real maps absent (set JAXSEM_MAPS_DIR to the folder of `jaxsem data fetch maps`)")
    b = planning.load_map(path)
    assert b.resolution == pytest.approx(0.1) and b.shape == (260, 280)
    assert (~b.occupancy & b.indoor).sum() > 0 and (~b.occupancy & ~b.indoor).sum() > 0
    tasks = planning.sample_tasks(b, "II", 2, seed=0, min_distance=3.0, max_distance=20.0)
    assert len(tasks) == 2
    planning.plot_semantics(b, tmp_path / "lab.png")
    assert (tmp_path / "lab.png").stat().st_size > 0


def test_hatched_drawing_fills_obstacles_and_drops_the_plot_padding(tmp_path):
    import cv2

    img = np.full((120, 100), 255, np.uint8)
    img[10:12, :] = 0  # the drawing's frame lines; rows 0-9 and 108-119 are the plot's padding
    img[108:110, :] = 0
    img[30:70, 20:60] = 255
    cv2.rectangle(img, (20, 30), (59, 69), 0, 1)  # an obstacle drawn as a hatched outline
    for k in range(-40, 40, 8):
        cv2.line(img, (20 + max(k, 0), 30 + max(-k, 0)), (59 + min(k, 0), 69 - max(k, 0)), 0, 1)
    path = tmp_path / "house.png"
    cv2.imwrite(str(path), img)
    plain = planning.load_occupancy(path, resolution=0.05)
    filled = planning.load_occupancy(path, resolution=0.05, hatch_px=4)
    inside = filled.occupancy[::-1][32:68, 22:58]  # back to image rows
    assert (inside == OCCUPIED).all()
    assert (plain.occupancy[::-1][32:68, 22:58] == FREE).any()  # the gaps between hatch lines
    assert (filled.occupancy[::-1][80:100, 70:95] == FREE).all()  # the open floor stays free
    assert (filled.occupancy[::-1][:10] == OCCUPIED).all() and (filled.occupancy[::-1][110:] == OCCUPIED).all()
    with pytest.raises(ValueError, match="hatch_px"):
        planning.load_occupancy(path, resolution=0.05, hatch_px=-1)


def test_a_floor_drawing_is_all_inside_but_its_largest_room_stands_in_for_outside():
    occ = np.full((60, 160), OCCUPIED, np.int8)
    occ[5:55, 5:55] = FREE  # a 5 x 5 m living room
    occ[25:35, 55:155] = FREE  # a 1 m hallway
    b = planning.grid_to_building(planning.OccupancyGrid(occ, np.zeros(2), RES), footprint="none")
    assert not b.indoor[30, 30]  # the room is the stand-in outside
    assert b.indoor[30, 150]
    with pytest.raises(ValueError, match="footprint"):
        planning.grid_to_building(planning.OccupancyGrid(occ, np.zeros(2), RES), footprint="yard")


def _trials_on(path, b, **kw):
    """run_trials on no tasks: only the records file's stamp is checked (nothing runs)."""
    return run_trials([b], lambda x: x, sets=("II",), ns=(50,), tasks={(0, "II"): []}, records_path=path, **kw)


def test_records_of_other_settings_are_refused_naming_them(tmp_path):
    b = planning.generate_building(3)
    f = tmp_path / "r.records.jsonl"
    assert _trials_on(f, b, seed=1, max_steps=30, provenance={"--protocol": "thesis"}) == []
    assert _trials_on(f, b, seed=1, max_steps=30, provenance={"--protocol": "thesis"}) == []  # same: resumes
    with pytest.raises(ConfigMismatchError, match="max_steps: made with 30, now 40"):
        _trials_on(f, b, seed=1, max_steps=40, provenance={"--protocol": "thesis"})
    with pytest.raises(ConfigMismatchError, match="--protocol: made with 'thesis', now 'defaults'"):
        _trials_on(f, b, seed=1, max_steps=30, provenance={"--protocol": "defaults"})
    with pytest.raises(ConfigMismatchError, match="maps"):  # another map into the same file
        _trials_on(f, planning.generate_building(4), seed=1, max_steps=30, provenance={"--protocol": "thesis"})
    assert _trials_on(f, b, seed=1, max_steps=40, provenance={}, fresh=True) == []  # starts over
    assert _trials_on(f, b, seed=1, max_steps=40) == []


def test_records_without_a_stamp_are_refused_and_a_stranger_file_kept(tmp_path):
    b = planning.generate_building(3)
    old = tmp_path / "old.records.jsonl"
    old.write_text(
        json.dumps({"building": 3, "set": "II", "trial": 0, "n": 50, "start": [0, 0], "goal": [1, 1]}) + "\n"
    )
    with pytest.raises(ConfigMismatchError, match="no stamp"):
        _trials_on(old, b)
    mine = tmp_path / "notes.jsonl"
    mine.write_text('{"my": "notes"}\n')
    with pytest.raises(ValueError, match="not a records file"):
        _trials_on(mine, b, fresh=True)
    assert mine.read_text() == '{"my": "notes"}\n'


def test_real_map_tasks_thesis_or_map_wide(tmp_path, script):
    # --tasks thesis bounds start-to-goal at 40 m unless told; --tasks map at the map's diagonal,
    # and refuses a --max-distance beside it (which bound would it be?).
    mod = script("benchmarks/lsd/lsd_real.py")
    path = tmp_path / "m.gridmap.gz"
    _write_gridmap(path, _two_rooms(0.9), 0.1)
    base = ["--map", str(path), "--json", str(tmp_path / "o.json")]
    thesis = mod._parse(base)
    wide = mod._parse(base + ["--tasks", "map", "--min-distance", "6", "--trials", "5", "--clearance", "0.2"])
    b = mod.load_run_map(wide, str(path))
    assert mod.task_max_distance(thesis, b) == 40.0
    assert mod.task_max_distance(mod._parse(base + ["--max-distance", "9"]), b) == 9.0
    diagonal = mod.task_max_distance(wide, b)
    assert 10.4 <= diagonal <= 11.5  # the 10.4 x 4.4 m map's
    tasks = mod.run_tasks(wide, b, "II")
    assert len(tasks) == 5
    assert all(6.0 <= np.linalg.norm(t.goal - t.start) <= diagonal for t in tasks)
    with pytest.raises(SystemExit, match="--max-distance"):
        mod._parse(base + ["--tasks", "map", "--max-distance", "30"])


def test_real_map_command_flags_exit_2_naming_them(tmp_path, script):
    # Run as a script its flag errors exit 2 (bad usage; they exited 1) and NaN or impossible
    # values are named by their flag before any map is read.
    mod = script("benchmarks/lsd/lsd_real.py")
    path = tmp_path / "m.gridmap.gz"
    _write_gridmap(path, _two_rooms(0.9), 0.1)
    (tmp_path / "a_file").write_text("x")
    base = ["--map", str(path), "--json", str(tmp_path / "o.json")]
    for extra, flag in (
        (["--clearance", "nan"], "--clearance"),
        (["--max-distance", "inf"], "--max-distance"),
        (["--max-steps", "0"], "--max-steps"),
        (["--json", str(tmp_path / "a_file" / "o.json")], "--json"),
    ):
        with pytest.raises(SystemExit, match=f"lsd_real: {flag}:"):
            mod.main(base + extra)
    proc = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks/lsd/lsd_real.py"), *base, "--trials", "0"],
        capture_output=True, text=True, check=False, env={**os.environ, "JAX_PLATFORMS": "cpu"},
    )  # fmt: skip
    assert proc.returncode == 2 and proc.stderr.strip().splitlines()[-1].startswith("lsd_real: --trials:"), proc.stderr
