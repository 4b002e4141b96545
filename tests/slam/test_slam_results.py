"""Issue 12: result codes never lie (NaN / inf input, step budget), throw=, float32 under x64,
no recompile within a capacity bucket, online codes per frame, pose priors hold under
QuadricSLAM's plain initialisation on a small Forward problem."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsem import factors as F, slam
from jaxsem.slam._batch import solve_schur  # layers: white-box
from jaxsem.slam._problem import bucket_capacity, has_measurements  # layers: white-box
from jaxsem.slam._results import RESULTS, result_code  # layers: white-box
from jaxsem.slam._toy import frames_from_problem  # layers: white-box

CFG = slam.SolverConfig(max_steps=30)
SOLVE = jax.jit(lambda p, i: solve_schur(p, i, CFG))
# The solver tests share programs (each costs some 20 s of compiles): their problems are padded
# to one capacity bucket, so that SOLVE compiles once for all of them, and the step-budget and
# non-finite tests throw through one program (max_steps=1, throw=True).
CAP = bucket_capacity(9, 18, 2)
INIT = jax.jit(lambda p: slam.initialize(p, CFG))  # op by op: hundreds of small compiles


def _small(seed=0, capacity=None, num_frames=8):
    return slam.toy_map(seed, num_objects=2, num_frames=num_frames, path="orbit", capacity=capacity)


def _bucket(seed=0, num_frames=8):
    return _small(seed, capacity=CAP, num_frames=num_frames)


@pytest.mark.slow
def test_clean_problem_succeeds_and_reports_steps():
    problem, _ = _bucket()
    _, info = SOLVE(problem, INIT(problem))
    assert bool(info.success) and bool(info.result == RESULTS.successful)
    assert int(info.accepted) >= 1 and int(info.steps) >= int(info.accepted)
    assert float(info.cost) < float(info.initial_cost)


@pytest.mark.slow
@pytest.mark.parametrize("where", ["init_center", "init_pose", "box", "prior_inf"])
def test_nonfinite_input_is_never_success(where):
    problem, _ = _bucket()
    init = INIT(problem)
    if where == "init_center":
        init = eqx.tree_at(lambda e: e.center, init, init.center.at[0, 0].set(jnp.nan))
    elif where == "init_pose":
        init = eqx.tree_at(
            lambda e: e.camera_T_world,
            init,
            init.camera_T_world.at[1, 0, 3].set(jnp.nan),
        )
    elif where == "box":
        problem = eqx.tree_at(lambda p: p.box, problem, problem.box.at[0, 2].set(jnp.nan))
    else:
        problem = eqx.tree_at(lambda p: p.pose_prior, problem, problem.pose_prior.at[2, 1, 3].set(jnp.inf))
    _, info = SOLVE(problem, init)
    assert not bool(info.success)
    assert bool(info.result == RESULTS.nonfinite)
    with pytest.raises(Exception, match="(?i)non-?finite"):  # not the step budget's message
        jax.block_until_ready(solve_schur(problem, init, CFG, max_steps=1, throw=True))


@pytest.mark.slow
def test_step_budget_is_not_success_and_throw_raises():
    problem, _ = _bucket()
    init = INIT(problem)
    init = eqx.tree_at(lambda e: e.center, init, init.center + 3.0)
    _, info = solve_schur(problem, init, CFG, max_steps=1)
    assert bool(info.result == RESULTS.max_steps_reached) and not bool(info.success)
    with pytest.raises(Exception, match="maximum number of"):
        jax.block_until_ready(solve_schur(problem, init, CFG, max_steps=1, throw=True))


@pytest.mark.slow
def test_float32_problem_under_x64():
    assert jax.config.jax_enable_x64
    problem, _ = _small()
    f32 = jax.tree_util.tree_map(lambda x: x.astype(jnp.float32) if x.dtype == jnp.float64 else x, problem)
    init = INIT(f32)
    est, info = solve_schur(f32, init, CFG)
    assert est.center.dtype == jnp.float32 and info.cost.dtype == jnp.float32
    assert bool(info.success), slam.result_message(info.result)


@pytest.mark.slow
def test_no_recompile_for_another_size_in_the_same_bucket():
    assert CAP == bucket_capacity(12, 20, 2)
    a, _ = _bucket(1, num_frames=7)
    b, _ = _bucket(2, num_frames=9)
    # SOLVE may have compiled this bucket's program in the tests above: count what a adds (at
    # most that one program) and what b adds (nothing)
    start = SOLVE._cache_size()
    SOLVE(a, INIT(a))
    before = SOLVE._cache_size()
    _, info = SOLVE(b, INIT(b))
    assert SOLVE._cache_size() == before <= start + 1
    assert before == 1  # every solve of this module's SOLVE in the one bucket
    assert bool(jnp.isfinite(info.cost))


@pytest.mark.slow
def test_online_update_returns_a_code_per_frame():
    problem, _ = _small(3)
    frames = frames_from_problem(problem, max_detections=2)
    cap = slam.Capacity(max_poses=8, max_objects=2, max_boxes=16, max_detections=2)
    state = slam.online_init(CFG, cap, problem.K, problem.image_size, optimize_every=2, iterations=3)
    codes = []
    for frame in frames:
        state = slam.online_update(state, frame)
        codes.append(int(result_code(state.result)))
    budget = int(result_code(RESULTS.iterations_reached))
    assert set(codes) <= {0, budget}, codes  # successful or step budget; never a failure here
    bad = eqx.tree_at(lambda f: f.box, frames[1], frames[1].box.at[0, 0].set(jnp.nan))
    state = slam.online_update(state, bad)
    assert bool(state.result == RESULTS.nonfinite)


@pytest.mark.slow
def test_pose_priors_hold_under_plain_initialisation_forward():
    """QuadricSLAM's initial values (10 m along the first bearing, identity, radii 1 m) on a
    Forward path: cameras stay within 3 sigma of their priors; no object drags them."""
    problem, _ = slam.toy_map(4, num_objects=4, num_frames=24, path="forward", pose_noise=(0.05, 0.0175))
    cfg = slam.baseline_config(baseline_shape_weight=0.0, max_steps=60, depth_from_box=False)
    init = slam.initialize(problem, cfg)  # fixed default depth 10 m, class-mean radii ...
    init = slam.SlamEstimate(init.camera_T_world, init.rotation, init.center, jnp.ones_like(init.radii))
    est, info = jax.jit(lambda p, i: solve_schur(p, i, cfg))(problem, init)
    assert bool(jnp.isfinite(info.cost))
    n = cfg.noise
    w = F.pose_prior_residual(
        est.camera_T_world,
        problem.pose_prior,
        n.pose_rotation_sigma,
        n.pose_translation_sigma,
    )
    # Mahalanobis distance per pose (6 dof): 3 sigma per axis at most, as a norm.
    r = jnp.linalg.norm(w, axis=-1)
    assert float(jnp.max(r)) < 3.0 * np.sqrt(6.0), np.asarray(r)


@pytest.mark.slow
@pytest.mark.parametrize("method", ["schur", "optimistix"])
def test_a_problem_whose_boxes_were_all_dropped_is_not_success(method):
    # Box noise of 2000 px: the simulator drops every box; the solve has nothing to fit.
    problem, _ = slam.toy_map(1, num_objects=2, num_frames=4, path="orbit", box_noise=2000.0)
    assert not bool(jnp.any(problem.box_mask))
    # jitted: the optimistix path's initialisation and costs op by op compiled hundreds of programs
    solve = jax.jit(lambda p: slam.solve_batch(p, config=slam.SolverConfig(max_steps=3), method=method))
    _, info = solve(problem)
    assert not bool(info.success)
    assert bool(info.result == RESULTS.no_measurements), slam.result_message(info.result)


def test_usable_measurements_need_a_real_box_pose_and_object():
    clean, _ = _small(num_frames=4)
    assert bool(jax.jit(has_measurements)(clean))
    no_box = eqx.tree_at(lambda p: p.box_mask, clean, jnp.zeros_like(clean.box_mask))
    no_obj = eqx.tree_at(lambda p: p.object_mask, clean, jnp.zeros_like(clean.object_mask))
    assert not bool(has_measurements(no_box)) and not bool(has_measurements(no_obj))
    masked = eqx.tree_at(lambda p: p.pose_mask, clean, jnp.zeros_like(clean.pose_mask))
    assert not bool(has_measurements(masked)) and bool(has_measurements(clean))


@pytest.mark.slow  # over 10 s of compiles: the fast suite keeps its margin
def test_online_run_of_empty_frames_is_not_success():
    problem, _ = _small(3, num_frames=4)
    frames = frames_from_problem(problem, max_detections=2)
    cap = slam.Capacity(max_poses=8, max_objects=2, max_boxes=16, max_detections=2)
    state = slam.online_init(CFG, cap, problem.K, problem.image_size, optimize_every=2, iterations=3)
    assert bool(state.result == RESULTS.no_measurements)  # nothing seen yet
    for frame in frames:
        empty = eqx.tree_at(lambda f: f.box_mask, frame, jnp.zeros_like(frame.box_mask))
        state = slam.online_update(state, empty)
        assert bool(state.result == RESULTS.no_measurements)
    state = slam.online_optimize(state, 3)
    assert bool(state.result == RESULTS.no_measurements)
    state = slam.online_update(state, frames[0])  # a frame with boxes: something to fit
    assert not bool(state.result == RESULTS.no_measurements)


@pytest.mark.parametrize(
    "box", [[0.0, 0.0, 1e30, 1e30], [700.0, 10.0, 800.0, 50.0], [-50.0, 10.0, -1.0, 50.0], [10.0, -2e3, 50.0, 40.0]]
)
def test_make_problem_refuses_a_box_off_the_image(box):
    with pytest.raises(ValueError, match=r"box: boxes at indices \[0\] lie off the 640 x 480 image"):
        slam.make_problem(np.eye(3) * [500, 500, 1], [640, 480], np.eye(4)[None], [box], [0], [0], ["car"])
    # A box touching the border, or a few pixels over it (a truncated object), is a measurement.
    slam.make_problem(np.eye(3) * [500, 500, 1], [640, 480], np.eye(4)[None], [[600.0, 0, 645, 40]], [0], [0], ["car"])


@pytest.mark.parametrize("box", [[700.0, 10.0, 800.0, 50.0], [10.0, -2e3, 50.0, 40.0]])
def test_make_frame_refuses_a_box_off_the_image_as_make_problem_does(box):
    with pytest.raises(ValueError, match=r"box: boxes at indices \[1\] lie off the 640 x 480 image"):
        slam.make_frame(np.eye(4), [[10.0, 10, 50, 40], box], ["car", "car"], [0, 1], image_size=[640, 480])
    # Without an image size there is nothing to check against; a truncated box is a measurement.
    slam.make_frame(np.eye(4), [[10.0, 10, 50, 40], box], ["car", "car"], [0, 1])
    frame = slam.make_frame(np.eye(4), [[600.0, 0, 645, 40]], ["car"], [0], image_size=[640, 480])
    assert frame.box_mask.tolist()[0]
    with pytest.raises(ValueError, match="image_size"):
        slam.make_frame(np.eye(4), [[10.0, 10, 50, 40]], ["car"], [0], image_size=[640, 0])
