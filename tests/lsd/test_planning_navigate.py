"""The online loop end to end on tiny worlds, local inputs, expert data and test tasks."""

import dataclasses
import pathlib

import jax
import numpy as np
import pytest

from jaxsem import quadrics as Q
from jaxsem.lsd import ExpertConfig, generate_expert_samples, load_expert_dataset, write_expert_dataset
from jaxsem.lsd._expert import SCHEMA_KEYS  # layers: white-box
from jaxsem.planning import (
    CROP_SIZE,
    DOOR,
    EXIT_SIGN,
    FREE,
    OCCUPIED,
    UNKNOWN,
    NavConfig,
    SoftCostGraph,
    Trial,
    empty_map_state,
    generate_building,
    local_inputs,
    navigate,
    sample_tasks,
)

RES = 0.1


@dataclasses.dataclass
class World:
    occupancy: np.ndarray
    semantic: np.ndarray
    indoor: np.ndarray
    origin: np.ndarray
    resolution: float = RES

    @property
    def grid(self) -> Q.Grid:
        return Q.Grid.host(self.origin, self.resolution, self.occupancy.shape)


def _two_rooms():
    """12 x 6 m: two rooms joined by a door in a wall at x = 6 m; the door is off the line."""
    occ = np.zeros((60, 120), bool)
    occ[[0, -1], :] = True
    occ[:, [0, -1]] = True
    occ[:, 59:61] = True
    sem = np.where(occ, 1, 0).astype(np.int8)
    occ[45:55, 59:61] = False
    sem[45:55, 59:61] = DOOR
    indoor = np.ones_like(occ)
    return World(occ, sem, indoor, np.array([0.0, 0.0]))


CFG = NavConfig(n_samples=400, radius=1.5, max_steps=600)
# CFG with unknown cells charged 3x in the edge weights: the fast tests of the uniform planner
# both use it, so they share the compiled grow and query (about 17 s of compiling per setting).
CFG_UNKNOWN_3X = dataclasses.replace(CFG, unknown_weight=3.0)


@pytest.mark.slow
def test_navigate_reaches_goal_through_the_door():
    w = _two_rooms()
    start, goal = np.array([2.0, 2.0]), np.array([10.0, 2.0])
    res = navigate(w, start, goal, jax.random.PRNGKey(0), CFG, yaw0=0.0)
    assert res.success and res.reason == "goal", res.reason
    assert np.allclose(res.path[0], start) and np.linalg.norm(res.path[-1] - goal) <= CFG.goal_tolerance
    # The cost is the travelled length; it can only exceed the geodesic through the door.
    seg = np.linalg.norm(np.diff(res.path, axis=0), axis=1)
    assert res.cost == pytest.approx(seg.sum())
    assert np.all(seg <= CFG.step_length + 1e-9)
    c_star = SoftCostGraph(w.occupancy, w).path(start, goal).length
    via_door = np.linalg.norm([4.0, 3.0]) * 2
    assert via_door - 0.3 <= res.cost <= 2.5 * c_star
    # Never inside an occupied cell; it went through the door.
    rc = np.floor((res.path - w.origin) / RES).astype(int)[:, ::-1]
    assert not w.occupancy[rc[:, 0], rc[:, 1]].any()
    crossing = res.path[np.argmin(np.abs(res.path[:, 0] - 6.0))]
    assert 4.4 <= crossing[1] <= 5.6
    # The door was seen by the object camera.
    assert (np.asarray(res.final_state.semantic) == DOOR).any()
    assert res.steps <= len(res.path) - 1
    # Uniform sampling: one roadmap, reused (rechecked against the growing map) by every replan.
    assert res.searches >= 2 and res.plans == 1


@pytest.mark.slow
def test_without_reuse_the_uniform_planner_samples_a_fresh_roadmap_at_every_replan():
    # The thesis' protocol as written (3.3.3): every planning timestep draws its own roadmap.
    w = _two_rooms()
    start, goal = np.array([2.0, 2.0]), np.array([10.0, 2.0])
    fresh = dataclasses.replace(CFG, reuse_roadmap=False)
    res = navigate(w, start, goal, jax.random.PRNGKey(0), fresh, yaw0=0.0)
    assert res.success, res.reason
    assert res.searches >= 2 and res.plans == res.searches - res.grown


@pytest.mark.slow
def test_failed_roadmap_is_grown_not_the_end():
    w = _two_rooms()
    start, goal = np.array([2.0, 2.0]), np.array([10.0, 2.0])
    thesis = dataclasses.replace(CFG, n_samples=12, max_growth=0, max_steps=300)
    grow = dataclasses.replace(thesis, max_growth=40)
    keys = [jax.random.PRNGKey(s) for s in range(3)]
    first = [navigate(w, start, goal, k, thesis) for k in keys]
    assert any(r.reason == "no_plan" for r in first)  # 12 samples rarely find the door
    grown = [navigate(w, start, goal, k, grow) for k in keys]
    assert all(r.reason != "no_plan" for r in grown) and sum(r.grown for r in grown) > 0
    assert sum(r.success for r in grown) > sum(r.success for r in first)


@pytest.mark.slow  # a navigation trial grows its roadmap to the limit (about 15 s)
def test_navigate_fails_when_goal_is_sealed_off():
    w = _two_rooms()
    w.occupancy[45:55, 59:61] = True  # close the door
    w.semantic[45:55, 59:61] = 1
    cfg = dataclasses.replace(CFG, max_steps=300)
    res = navigate(w, [2.0, 2.0], [10.0, 2.0], jax.random.PRNGKey(1), cfg)
    assert not res.success and res.reason in ("no_plan", "max_steps")
    assert res.steps <= 300


@pytest.mark.slow
def test_learned_sampler_hook_gets_local_inputs():
    w = _two_rooms()
    seen = []

    def sampler(inputs):
        seen.append(inputs)
        p = np.ones((CROP_SIZE, CROP_SIZE))
        return p / p.sum()

    res = navigate(w, [2.0, 2.0], [10.0, 2.0], jax.random.PRNGKey(2), CFG, sampler=sampler)
    assert res.success and len(seen) == res.plans == res.searches - res.grown
    inp = seen[0]
    assert inp.occupancy.shape == (CROP_SIZE, CROP_SIZE) and inp.occupancy.dtype == np.int8
    assert inp.semantic.shape == (CROP_SIZE, CROP_SIZE) and inp.context.shape == (4,)
    assert res.last_distribution.shape == w.occupancy.shape
    assert res.last_distribution.sum() == pytest.approx(1.0, rel=1e-5)


def test_a_coarser_sampler_sees_pooled_maps_and_its_distribution_covers_their_cells():
    # sampler_scale=2: the network's 160 cells span 32 m; each of its cells is a 2 x 2 block of
    # the robot's map (occupied if any cell is, else free if any is), and the distribution it
    # returns lands on those blocks. Reference: the pooling done cell by cell here.
    w = _two_rooms()
    seen, one_hot = [], np.zeros((CROP_SIZE, CROP_SIZE))
    one_hot[CROP_SIZE // 2 + 3, CROP_SIZE // 2 - 5] = 1.0  # 3 sampler cells down, 5 left

    def sampler(inputs):
        seen.append((inputs, np.asarray(trial.state.occupancy)))
        return one_hot * 0.9 + 0.1 / one_hot.size

    cfg = dataclasses.replace(CFG, sampler_scale=2)
    trial = Trial(w, [4.0, 2.5], [10.0, 2.0], jax.random.PRNGKey(2), cfg, sampler=sampler)
    trial.step()
    inp, known = seen[0]
    r0, c0 = (int(v) for v in np.asarray(inp.center_cell))
    robot = np.floor((trial.start[::-1] - w.origin[::-1]) / RES).astype(int)
    assert (r0, c0) == (robot[0] // 2, robot[1] // 2)
    crop = np.asarray(inp.occupancy)
    for dr, dc in [(0, 0), (3, -5), (-7, 9), (10, 2), (-12, -20)]:
        block = known[2 * (r0 + dr) : 2 * (r0 + dr) + 2, 2 * (c0 + dc) : 2 * (c0 + dc) + 2]
        want = OCCUPIED if (block == OCCUPIED).any() else FREE if (block == FREE).any() else UNKNOWN
        assert crop[CROP_SIZE // 2 + dr, CROP_SIZE // 2 + dc] == want
    assert (crop == FREE).sum() > 50 and (crop == OCCUPIED).sum() > 10
    dist = np.asarray(trial.last_distribution)
    assert dist.shape == known.shape and dist.sum() == pytest.approx(1.0, rel=1e-5)
    peak = np.argwhere(dist == dist.max())
    r, c = 2 * (r0 + 3), 2 * (c0 - 5)
    assert sorted(map(tuple, peak)) == [(r, c), (r, c + 1), (r + 1, c), (r + 1, c + 1)]


@pytest.mark.slow
def test_a_coarser_sampler_navigates_to_the_goal():
    # The whole loop under sampler_scale=2 (its own compiled programs): the pooled crops and the
    # distribution spread back over the blocks carry the robot through the doorway.
    one_hot = np.zeros((CROP_SIZE, CROP_SIZE))
    one_hot[CROP_SIZE // 2 + 3, CROP_SIZE // 2 - 5] = 1.0
    cfg = dataclasses.replace(CFG, sampler_scale=2)
    res = navigate(
        _two_rooms(),
        [2.0, 2.0],
        [10.0, 2.0],
        jax.random.PRNGKey(2),
        cfg,
        sampler=lambda _: one_hot * 0.9 + 0.1 / one_hot.size,
    )
    assert res.success, res.reason


def test_local_inputs_crop_and_context():
    w = _two_rooms()
    st = empty_map_state(w.occupancy.shape)
    occ = np.asarray(st.occupancy).copy()
    occ[20, 30] = FREE
    occ[21, 30] = OCCUPIED
    st = st._replace(
        occupancy=occ,
        semantic=np.where(np.arange(120)[None] == 33, EXIT_SIGN, 0).astype(np.int8) * np.ones((60, 1), np.int8),
    )
    xy = np.array([3.05, 2.05])  # cell (20, 30)
    inp = local_inputs(st, xy, [3.05 + 30.0, 2.05], True, w)
    c = CROP_SIZE // 2
    o = np.asarray(inp.occupancy)
    assert o[c, c] == FREE and o[c + 1, c] == OCCUPIED and o[c, c + 1] == UNKNOWN
    assert o[0, 0] == OCCUPIED  # off the map
    assert np.all(np.asarray(inp.semantic)[c - 20 : c + 39, c + 3] == EXIT_SIGN)
    np.testing.assert_allclose(np.asarray(inp.context), [1.0, 0.0, 1.0, 1.0], atol=1e-6)
    inp = local_inputs(st, xy, [3.05, 2.05 - 5.0], False, w)
    np.testing.assert_allclose(np.asarray(inp.context), [0.0, -1.0, 0.25, 0.0], atol=1e-6)
    assert tuple(np.asarray(inp.center_cell)) == (20, 30)


def test_navigate_bad_input():
    w = _two_rooms()
    key = jax.random.PRNGKey(0)
    with pytest.raises(ValueError, match="start"):
        navigate(w, [6.0, 2.0], [10.0, 2.0], key, CFG)  # inside the wall
    with pytest.raises(ValueError, match="goal"):
        navigate(w, [2.0, 2.0], [10.0, 20.0], key, CFG)  # off the map
    with pytest.raises(ValueError, match="start"):
        navigate(w, [2.0, 2.0, 0.0], [10.0, 2.0], key, CFG)
    bad = World(w.occupancy.astype(np.uint8), w.semantic, w.indoor, w.origin)
    with pytest.raises(ValueError, match="world.occupancy"):
        navigate(bad, [2.0, 2.0], [10.0, 2.0], key, CFG)
    bad = World(w.occupancy, w.semantic[:, :-1], w.indoor, w.origin)
    with pytest.raises(ValueError, match="world.semantic"):
        navigate(bad, [2.0, 2.0], [10.0, 2.0], key, CFG)
    with pytest.raises(ValueError, match="sampler"):
        navigate(
            w,
            [2.0, 2.0],
            [10.0, 2.0],
            key,
            CFG,
            sampler=lambda inputs: np.ones((10, 10)),
        )
    with pytest.raises(ValueError, match="sampler_scale"):
        navigate(w, [2.0, 2.0], [10.0, 2.0], key, dataclasses.replace(CFG, sampler_scale=0))
    for uw in (0.0, float("inf")):
        with pytest.raises(ValueError, match="unknown_weight"):
            navigate(w, [2.0, 2.0], [10.0, 2.0], key, dataclasses.replace(CFG, unknown_weight=uw))


class _CellSampler:
    """A learned sampler's stand-in that says the cell size it was trained on."""

    cell_size = 0.1

    def __call__(self, inputs):
        k = np.shape(inputs.occupancy)[-1]
        return np.full((k, k), 1.0 / k**2)


def test_a_sampler_on_cells_it_was_not_trained_on_is_refused():
    fine = dataclasses.replace(_two_rooms(), resolution=0.05)  # the same rooms drawn at 0.05 m: 6 x 3 m
    key = jax.random.PRNGKey(0)
    with pytest.raises(ValueError, match=r"sampler: the network was trained on 0.1 m cells, but world.resolution "
                       r"is 0.05 m; .*cell_size=0.1.* or NavConfig\(sampler_scale=2\)"):  # fmt: skip
        Trial(fine, [1.0, 1.0], [5.0, 1.0], key, CFG, sampler=_CellSampler())
    # the same map with the sampler on 2 x 2 pooled cells (0.1 m), and the sampler's own cells, pass
    Trial(fine, [1.0, 1.0], [5.0, 1.0], key, dataclasses.replace(CFG, sampler_scale=2), sampler=_CellSampler())
    Trial(_two_rooms(), [2.0, 2.0], [10.0, 2.0], key, CFG, sampler=_CellSampler())


@pytest.mark.slow
def test_the_planners_roadmap_charges_unknown_cells_as_configured():
    w = _two_rooms()
    cfg = CFG_UNKNOWN_3X
    trial = Trial(w, [2.0, 2.0], [10.0, 2.0], jax.random.PRNGKey(0), cfg)
    for _ in range(3):
        trial.step()
    assert trial.prm is not None and trial.prm.unknown_weight == 3.0
    res = navigate(w, [2.0, 2.0], [10.0, 2.0], jax.random.PRNGKey(0), cfg)
    assert res.success, res.reason


@pytest.fixture(scope="module")
def building():
    return generate_building(5, "train")


@pytest.mark.slow
def test_expert_samples_schema_and_paths(building, tmp_path):
    cfg = ExpertConfig(
        samples_per_building=6,
        sample_prob=0.5,
        goals_per_moment=3,
        nav=NavConfig(n_samples=400, max_steps=60),
    )
    d = generate_expert_samples(building, 5, cfg)  # the shard job uses the building seed
    S = len(d["context"])
    assert S == 6
    assert d["occupancy"].shape == (S, CROP_SIZE, CROP_SIZE) and d["occupancy"].dtype == np.int8
    assert d["semantic"].dtype == np.int8 and d["path_mask"].dtype == bool
    assert set(np.unique(d["occupancy"])) <= {UNKNOWN, FREE, OCCUPIED}
    c = CROP_SIZE // 2
    for i in range(S):
        # The path starts at the robot (crop centre) and the crop centre is known free.
        assert d["path_mask"][i, c, c] and d["occupancy"][i, c, c] == FREE
        cells = d["path_cells"][d["path_offsets"][i] : d["path_offsets"][i + 1]]
        m = np.zeros((CROP_SIZE, CROP_SIZE), bool)
        m[cells[:, 0], cells[:, 1]] = True
        assert np.array_equal(m, d["path_mask"][i])
        # Path cells are free in the true map.
        rc = cells.astype(int) - c + np.floor((d["robot_xy"][i] - building.origin) / RES).astype(int)[::-1]
        assert not building.occupancy[rc[:, 0], rc[:, 1]].any()
        # Context: unit direction to the goal, clipped distance, outdoor flag from the true map.
        rel = d["goal_xy"][i] - d["robot_xy"][i]
        np.testing.assert_allclose(d["context"][i, :2], rel / np.linalg.norm(rel), atol=1e-4)
        assert d["context"][i, 2] == pytest.approx(min(np.linalg.norm(rel), 20.0) / 20.0, abs=1e-4)
        g = np.floor((d["goal_xy"][i] - building.origin) / RES).astype(int)[::-1]
        assert bool(d["context"][i, 3]) == (not building.indoor[g[0], g[1]]) == d["goal_outdoors"][i]
    # Shards round-trip through disk (one process here; the script uses two workers).
    paths = write_expert_dataset(tmp_path, "train", [5], cfg, workers=1, progress=False)
    assert len(paths) == 1 and (tmp_path / "schema.json").exists()
    with np.load(paths[0]) as z:
        assert set(z.files) == set(SCHEMA_KEYS)
    loaded = load_expert_dataset(tmp_path)
    for k in ("occupancy", "semantic", "context", "path_mask", "path_cells"):
        np.testing.assert_array_equal(loaded[k], d[k])
    assert loaded["family"][0] == "train" and loaded["building_seed"][0] == 5
    with pytest.raises(ValueError, match="paths"):
        load_expert_dataset([])


def test_sample_tasks(building):
    graph = SoftCostGraph(building.occupancy, building)
    for kind in ("II", "IO"):
        tasks = sample_tasks(building, kind, 4, seed=0, graph=graph)
        assert len(tasks) == 4
        for t in tasks:
            s = np.floor((t.start - building.origin) / RES).astype(int)[::-1]
            g = np.floor((t.goal - building.origin) / RES).astype(int)[::-1]
            assert building.indoor[s[0], s[1]] and not building.occupancy[s[0], s[1]]
            assert building.indoor[g[0], g[1]] == (kind == "II") and not building.occupancy[g[0], g[1]]
            assert t.goal_outdoors == (kind == "IO")
            assert t.c_star >= np.linalg.norm(t.goal - t.start) - 2 * RES
    again = sample_tasks(building, "II", 4, seed=0, graph=graph)
    assert all(np.array_equal(a.goal, b.goal) for a, b in zip(again, sample_tasks(building, "II", 4, 0, graph=graph)))
    with pytest.raises(ValueError, match="kind"):
        sample_tasks(building, "OO", 1, 0)


def test_sample_tasks_says_why_none_came_back(building):
    graph = SoftCostGraph(building.occupancy, building)
    diagonal = float(np.hypot(*building.occupancy.shape)) * RES
    # no pair can be farther apart than the map's diagonal
    with pytest.warns(UserWarning, match=r"no II task in 20 tries: 20 start-goal pairs outside the distance bounds"):
        assert sample_tasks(building, "II", 2, seed=0, graph=graph, min_distance=diagonal + 1, max_tries=20) == []
    # no free cell is a kilometre from every obstacle
    with pytest.warns(UserWarning, match=r"no indoor free cell 1000 m from an obstacle"):
        assert sample_tasks(building, "IO", 2, seed=0, graph=graph, clearance=1000.0) == []


@pytest.mark.slow
def test_informed_sampler_beats_uniform_at_few_samples():
    # Known answer: the mass on the true soft-cost path through the door finds plans that 40
    # uniform samples in a 12 x 6 m map mostly do not.
    w = _two_rooms()
    start, goal = np.array([2.0, 2.0]), np.array([10.0, 2.0])
    opt = SoftCostGraph(w.occupancy, w).path(start, goal)
    truth = np.full(w.occupancy.shape, 1e-6)
    truth[opt.cells[:, 0], opt.cells[:, 1]] = 1.0

    def oracle(inputs):
        r, c = (int(v) for v in np.asarray(inputs.center_cell))
        pad = np.pad(truth, CROP_SIZE, constant_values=1e-6)
        h = CROP_SIZE // 2
        return pad[r - h + CROP_SIZE : r + h + CROP_SIZE, c - h + CROP_SIZE : c + h + CROP_SIZE]

    cfg = dataclasses.replace(CFG, n_samples=40, max_steps=300, max_growth=0)
    keys = [jax.random.PRNGKey(s) for s in range(4)]
    uni = [navigate(w, start, goal, k, cfg).success for k in keys]
    inf = [navigate(w, start, goal, k, cfg, sampler=oracle) for k in keys]
    assert sum(r.success for r in inf) >= 3 and sum(r.success for r in inf) > sum(uni)
    for r in inf:
        if r.success:
            assert r.cost <= 1.3 * opt.length


@pytest.mark.slow  # about 8 s of compiling the navigation loop: the fast suite stays under 6 minutes
def test_robot_in_a_known_obstacle_ends_the_trial_as_a_collision():
    # Regression: a robot that moved through unknown space into a wall used to crash the trial
    # runner ("start: ... lies in an occupied cell" from the next roadmap query); it is a
    # collision, a failed trial with its own reason.
    from jaxsem.planning import Trial

    w = _two_rooms()
    trial = Trial(w, [2.0, 2.0], [10.0, 2.0], jax.random.PRNGKey(0), CFG, yaw0=0.0)
    assert trial.step()  # plans and moves
    occ = np.asarray(trial.state.occupancy).copy()
    trial.xy = np.array([5.95, 2.05])  # inside the wall at x = 5.9-6.1 m
    occ[20, 59] = OCCUPIED
    trial.state = trial.state._replace(occupancy=jax.numpy.asarray(occ))
    assert not trial.step()
    res = trial.result()
    assert not res.success and res.reason == "collision"


def test_a_look_that_finds_the_robot_in_a_wall_ends_the_trial_as_a_collision():
    # Regression (a benchmark run on test building 444, uniform planner, IO task 1, step 952):
    # the look a step takes before it replans revealed the robot's own cell as occupied, and the
    # roadmap query then refused the start ("start: ... lies in an occupied cell"), which ended
    # the whole run. The look's finding is the same collision as the start-of-step check.
    # (The edge weights play no part here: CFG_UNKNOWN_3X shares the compiled roadmap with
    # test_the_planners_roadmap_charges_unknown_cells_as_configured.)
    from jaxsem.planning import Trial

    w = _two_rooms()
    trial = Trial(w, [2.0, 2.0], [10.0, 2.0], jax.random.PRNGKey(0), CFG_UNKNOWN_3X, yaw0=0.0)
    assert trial.step()
    trial.since_plan = CFG_UNKNOWN_3X.replan_every  # this step looks, then replans
    real_sense = trial._sense

    def sense_and_find_the_wall():  # the look marks the robot's own cell occupied
        real_sense()
        occ = np.asarray(trial.state.occupancy).copy()
        col, row = np.floor((trial.xy - np.asarray(w.origin)) / w.resolution).astype(int)
        occ[row, col] = OCCUPIED
        trial.state = trial.state._replace(occupancy=jax.numpy.asarray(occ))

    trial._sense = sense_and_find_the_wall
    assert not trial._in_known_obstacle()  # the start-of-step check passes
    assert not trial.step()
    res = trial.result()
    assert not res.success and res.reason == "collision"


def _job_that_dies_on_seed_1(job):
    """A per-building job for write_expert_dataset: the worker process dies (no exception) on
    seed 1, as an XLA abort or the OOM killer ends it; other seeds write a small shard."""
    import os
    import pathlib

    _, seed, _, out_dir, _ = job
    if seed == 1:
        os._exit(3)
    path = pathlib.Path(out_dir) / f"expert_train_{seed:05d}.npz"
    np.savez(path, building_seed=np.int64(seed))
    return str(path), 1


def test_a_dead_expert_worker_raises_naming_the_seed_instead_of_hanging(tmp_path):
    """Regression: under multiprocessing.Pool a worker that died left its building unfinished and
    the command waiting forever (240 buildings: 2 missing, no error, at 0 % CPU)."""
    from jaxsem.lsd import write_expert_dataset

    with pytest.raises(ChildProcessError, match=r"workers: a worker process died .*seeds \[.*1.*\].*rerun"):
        write_expert_dataset(tmp_path, "train", [0, 1, 2], workers=2, progress=False, job_fn=_job_that_dies_on_seed_1)
    assert not (tmp_path / "expert_train_00001.npz").exists()


def _job_tiny_shard(job):
    import pathlib

    _, seed, _, out_dir, _ = job
    path = pathlib.Path(out_dir) / f"expert_train_{seed:05d}.npz"
    np.savez(path, building_seed=np.int64(seed))
    return str(path), 1


def test_expert_shards_of_other_settings_are_not_mixed(tmp_path):
    """A rerun into the same folder resumes only under the same family settings; more seeds
    extend it; another resolution is refused naming it, before any shard is written."""
    from jaxsem.lsd import write_expert_dataset
    from jaxsem.training import ConfigMismatchError

    kw = dict(workers=1, progress=False, job_fn=_job_tiny_shard)
    assert len(write_expert_dataset(tmp_path, "train", [0, 1], **kw)) == 2
    assert len(write_expert_dataset(tmp_path, "train", [0, 1, 2], **kw)) == 3
    with pytest.raises(ConfigMismatchError, match="resolution: made with 0.1, now 0.05"):
        write_expert_dataset(tmp_path, "train", [0, 1, 2, 3], resolution=0.05, **kw)
    assert not (tmp_path / "expert_train_00003.npz").exists()


def _job_small_shard(job):
    """A per-building job for write_expert_dataset that runs a jitted function (as the real job
    does: the hang needed JAX in the workers) and writes a tiny shard."""
    import pathlib

    import jax.numpy as jnp

    _, seed, _, out_dir, _ = job
    assert float(jax.jit(lambda a: a * 2)(jnp.ones(3)).sum()) == 6.0
    path = pathlib.Path(out_dir) / f"expert_train_{seed:05d}.npz"
    np.savez(path, building_seed=np.int64(seed))
    return str(path), 1


@pytest.mark.slow
def test_expert_workers_are_replaced_without_hanging(tmp_path):
    """Regression: workers retired through ProcessPoolExecutor(max_tasks_per_child=16) on Python
    3.11 left the command waiting forever once both had retired (32 of 240 buildings written, no
    live worker, no error; reproduced with 12 jitting jobs and max_tasks_per_child=2). More
    buildings than workers x worker_tasks must all be written."""
    import threading

    from jaxsem.lsd import write_expert_dataset

    result = {}
    th = threading.Thread(
        target=lambda: result.setdefault(
            "paths",
            write_expert_dataset(
                tmp_path, "train", range(5), workers=2, progress=False, job_fn=_job_small_shard, worker_tasks=1
            ),
        ),
        daemon=True,
    )
    th.start()
    th.join(120)
    assert not th.is_alive(), "write_expert_dataset hung"
    assert len(result["paths"]) == 5 and all(pathlib.Path(p).exists() for p in result["paths"])


def test_expert_data_moved_to_lsd_with_a_message():
    # LSD's expert data is the method's (issue 23, layout by method): the planner says where it went.
    import jaxsem.planning as planning

    for name in ("ExpertConfig", "generate_expert_samples", "EXPERT_SCHEMA"):
        with pytest.raises(AttributeError, match=f"jaxsem.lsd.{name}"):
            getattr(planning, name)
    with pytest.raises(AttributeError, match="no attribute 'nonexistent'"):
        planning.nonexistent
    assert "path_cells" in __import__("jaxsem.lsd", fromlist=["EXPERT_SCHEMA"]).EXPERT_SCHEMA


def test_task_pools_keep_their_clearance_and_side(tiny_building_for_pools):
    from jaxsem.planning import task_pools

    b = tiny_building_for_pools
    inside, outside = task_pools(b, 0.3)
    occ = np.argwhere(b.occupancy)
    rng = np.random.default_rng(0)
    for pool, indoor in ((inside, True), (outside, False)):
        assert len(pool) > 0
        assert np.all(b.indoor[pool[:, 0], pool[:, 1]] == indoor)
        # brute force on a sample: each pooled cell's nearest occupied cell is >= 0.3 m away
        some = pool[rng.choice(len(pool), 50)]
        d = np.min(np.linalg.norm(some[:, None, :] - occ[None, :, :], axis=-1), axis=1) * b.resolution
        assert np.all(d >= 0.3 - 1e-9)
    # and a free cell next to a wall is in neither pool
    free = b.free_cells()
    near = free[np.min(np.abs(free[:, None, :] - occ[None, :200, :]).sum(-1), axis=1) == 1]
    pooled = {tuple(c) for c in np.concatenate([inside, outside])}
    assert near.size and not any(tuple(c) in pooled for c in near)


@pytest.fixture(scope="module")
def tiny_building_for_pools():
    return generate_building(3, "train")


def _walled_room(rows: int, cols: int, inner=None):
    """``rows`` x ``cols`` cells at RES with a wall on the border; ``inner``: (row slice, col
    slice) of one more wall inside."""
    occ = np.zeros((rows, cols), bool)
    occ[[0, -1], :] = True
    occ[:, [0, -1]] = True
    if inner is not None:
        occ[inner] = True
    sem = np.where(occ, 1, 0).astype(np.int8)
    return World(occ, sem, np.ones_like(occ), np.array([0.0, 0.0]))


@pytest.mark.slow
def test_replan_reasons_in_an_open_room_are_all_periodic():
    # Nothing inside the room can block a plan, so every replan after the first is the timer's;
    # a shorter timer replans more often, and a timer longer than the trial never fires.
    w = _walled_room(40, 100)  # 10 x 4 m, nothing inside
    start, goal = np.array([1.0, 2.0]), np.array([9.0, 2.0])
    runs = {}
    for every in (5, 20, 1000):
        cfg = dataclasses.replace(CFG, replan_every=every, step_length=0.1)
        res = navigate(w, start, goal, jax.random.PRNGKey(0), cfg, yaw0=0.0)
        assert res.success, res.reason
        assert res.blocked_replans == 0
        assert res.searches - res.grown == 1 + res.periodic_replans
        assert res.periodic_replans <= res.steps // every
        runs[every] = res.periodic_replans
    assert runs[5] > runs[20] > 0 and runs[1000] == 0


@pytest.mark.slow
def test_replan_reasons_behind_a_wall_are_blocked_plans():
    # The first plan runs straight at the unseen wall; coming within range of it blocks the plan.
    # With the timer off, only blocked plans (and first legs the turn showed blocked) replan.
    # 20 x 6 m, a wall across x = 12 m with a 1.5 m gap at the top: beyond the depth camera's 5 m
    w = _walled_room(60, 200, (slice(0, 45), slice(119, 121)))
    start, goal = np.array([2.0, 2.0]), np.array([18.0, 2.0])
    cfg = dataclasses.replace(CFG, replan_every=CFG.max_steps + 1)
    res = navigate(w, start, goal, jax.random.PRNGKey(0), cfg, yaw0=0.0)
    assert res.success, res.reason
    assert res.periodic_replans == 0 and res.blocked_replans >= 1
    assert res.searches - res.grown >= 1 + res.blocked_replans
    crossing = res.path[np.argmin(np.abs(res.path[:, 0] - 12.0))]
    assert crossing[1] >= 4.4  # through the gap
