"""Issue 12, online start-up: one program for every frame and the final optimisation, a traced
program kept on disk (jaxsem.slam._aot), and host-side set-up and figures that compile nothing."""

import equinox as eqx
import jax
import jax.numpy as jnp
import matplotlib
import numpy as np
import pytest

from jaxsem import quadrics as Q, slam
from jaxsem.slam import _aot  # layers: white-box (the exported-program mechanics themselves)
from jaxsem.slam._results import RESULTS  # layers: white-box
from jaxsem.slam._toy import frames_from_problem  # layers: white-box

matplotlib.use("Agg")

CFG = slam.SolverConfig(max_steps=30)


def _state_and_frames(seed=3):
    problem, _ = slam.toy_map(seed, num_objects=2, num_frames=8, path="orbit")
    frames = frames_from_problem(problem, max_detections=2)
    cap = slam.Capacity(max_poses=8, max_objects=2, max_boxes=16, max_detections=2)
    state = slam.online_init(CFG, cap, problem.K, problem.image_size, optimize_every=2, iterations=2)
    return state, frames


def _leaves_equal(a, b):
    la, lb = jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b)
    return len(la) == len(lb) and all(np.array_equal(np.asarray(x), np.asarray(y)) for x, y in zip(la, lb))


@pytest.mark.slow
def test_update_and_final_optimize_share_one_compiled_step(compiles):
    state, frames = _state_and_frames()
    with compiles() as c:
        for frame in frames:
            state = slam.online_update(state, frame)
        final = slam.online_optimize(state, 5)
        slam.online_optimize(state, 7)
    # One program for every frame and the final optimisation, whatever the mode or the number
    # of iterations (online_update once had a jit of its own around the step: online_optimize
    # then compiled a second program, 8 s; issue 23 friction 7).
    assert c.count <= 1
    assert int(final.frame_count) == len(frames)  # the final mode inserts nothing
    assert bool(final.result == RESULTS.successful) or bool(final.result == RESULTS.iterations_reached)
    total_cost = jax.jit(slam.total_cost)  # op by op: some 170 small programs
    cost = lambda s: float(total_cost(s.problem, s.estimate, s.config))
    assert cost(final) <= cost(state)
    # New data of the same shapes (another map, a new state): nothing compiles.
    state2, frames2 = _state_and_frames(seed=4)
    with compiles() as c:
        for frame in frames2:
            state2 = slam.online_update(state2, frame)
        short = slam.online_optimize(state2, 1)
    assert c.count == 0
    # Online, the budget that ran out is `iterations`, and the message says so.
    assert bool(short.result == RESULTS.iterations_reached)
    message = slam.result_message(short.result)
    assert "`iterations`" in message and "max_steps" not in message


class _Toy(eqx.Module):
    """A small state with a static field, like OnlineState (the program's tree includes it)."""

    x: jnp.ndarray
    n: jnp.ndarray
    scale: int = eqx.field(static=True)


def _toy_step(state, frame, final):
    y = jnp.where(final, state.x, state.x * state.scale + jnp.sin(frame))
    return _Toy(y, state.n + 1, state.scale)


def test_exported_program_is_saved_reloaded_and_identical(tmp_path, monkeypatch):
    state, frame, flag = _Toy(jnp.arange(3.0), jnp.asarray(0, jnp.int32), 2), jnp.ones(3), np.asarray(False)
    step = _aot.exported("toy", _toy_step, (state, frame, flag), state, folder=tmp_path)
    (saved,) = tmp_path.iterdir()
    assert saved.suffix == ".jaxexport"

    # A later process (here: a second call) loads the program instead of tracing it again.
    def no_trace(*a, **k):
        raise AssertionError("traced again although the program was on disk")

    monkeypatch.setattr(_aot, "_export", no_trace)
    monkeypatch.setattr(_aot, "_LOADED", {})  # a fresh process: nothing loaded yet
    again = _aot.exported("toy", _toy_step, (state, frame, flag), state, folder=tmp_path)
    plain = jax.jit(_toy_step)
    for final in (np.asarray(False), np.asarray(True)):
        ref = plain(state, frame, final)
        assert _leaves_equal(ref, step(state, frame, final))
        assert _leaves_equal(ref, again(state, frame, final))
        assert isinstance(again(state, frame, final), _Toy)


def test_exported_falls_back_on_a_bad_file_or_another_static_configuration(tmp_path, monkeypatch):
    state, frame, flag = _Toy(jnp.arange(3.0), jnp.asarray(0, jnp.int32), 2), jnp.ones(3), np.asarray(False)
    _aot.exported("toy", _toy_step, (state, frame, flag), state, folder=tmp_path)
    (path,) = tmp_path.iterdir()
    path.write_bytes(b"not a serialised program")
    monkeypatch.setattr(_aot, "_LOADED", {})  # a fresh process reads the bad file
    again = _aot.exported("toy", _toy_step, (state, frame, flag), state, folder=tmp_path)
    assert _leaves_equal(jax.jit(_toy_step)(state, frame, flag), again(state, frame, flag))
    other = _Toy(state.x, state.n, 3)  # another static field: another tree, the plain jit path
    assert _leaves_equal(jax.jit(_toy_step)(other, frame, flag), again(other, frame, flag))
    # Without a folder (JAX's persistent cache off) it is jax.jit itself.
    assert _aot.cache_folder() is None or _aot.cache_folder().name == "jaxsem-exports"


def test_a_second_load_in_one_process_reuses_the_loaded_program(tmp_path, compiles):
    # run_sequence asks for its step on every call: the second time in a process, nothing is read,
    # lowered or compiled again.
    state, frame, flag = _Toy(jnp.arange(3.0), jnp.asarray(0, jnp.int32), 2), jnp.ones(3), np.asarray(False)
    first = _aot.exported("toy", _toy_step, (state, frame, flag), state, folder=tmp_path)
    jax.block_until_ready(first(state, frame, flag))
    with compiles() as c:
        again = _aot.exported("toy", _toy_step, (state, frame, flag), state, folder=tmp_path)
        out = jax.block_until_ready(again(state, frame, flag))
    assert c.count == 0
    assert _leaves_equal(jax.jit(_toy_step)(state, frame, flag), out)


def test_exported_keeps_only_the_newest_programs(tmp_path, monkeypatch):
    import os

    for k in range(5):
        stale = tmp_path / f"toy-stale{k}.jaxexport"
        stale.write_bytes(b"old")
        os.utime(stale, (1000 + k, 1000 + k))
    monkeypatch.setattr(_aot, "_KEEP", 3)
    state, frame, flag = _Toy(jnp.arange(3.0), jnp.asarray(0, jnp.int32), 2), jnp.ones(3), np.asarray(False)
    _aot.exported("toy", _toy_step, (state, frame, flag), state, folder=tmp_path)
    kept = sorted(p.name for p in tmp_path.glob("toy-*.jaxexport"))
    assert len(kept) == 3 and "toy-stale4.jaxexport" in kept and "toy-stale0.jaxexport" not in kept


@pytest.mark.slow
def test_online_init_and_make_frame_compile_nothing(compiles):
    problem, _ = slam.toy_map(0, num_objects=2, num_frames=4, path="orbit")
    cap = slam.Capacity(max_poses=4, max_objects=2, max_boxes=8, max_detections=2)
    with compiles() as c:
        for dtype in (jnp.float32, None):
            slam.online_init(CFG, cap, np.asarray(problem.K), np.asarray(problem.image_size), dtype=dtype)
            slam.make_frame(np.eye(4), [[1.0, 2.0, 30.0, 40.0]], ["car"], [1], [5.0], max_detections=3, dtype=dtype)
    assert c.count == 0


@pytest.mark.slow
def test_figures_compile_nothing_and_match_the_jax_geometry(compiles):
    import matplotlib.pyplot as plt

    problem, truth = slam.toy_map(1, num_objects=3, num_frames=4, path="orbit")
    R, c, r = (np.asarray(x, np.float64) for x in (truth.rotation, truth.center, truth.radii))
    K, pose = np.asarray(problem.K, np.float64), np.asarray(truth.camera_T_world[0], np.float64)
    fig, ax = plt.subplots()
    with compiles() as comp:
        slam.draw_top_down(ax, Q.Ellipsoid(R, c, r))
        slam.draw_overlay(ax, None, Q.Camera(K, pose), np.asarray(problem.image_size), None, None, Q.Ellipsoid(R, c, r))
    plt.close(fig)
    assert comp.count == 0
    # The host (numpy) geometry the figures use is the library's jnp geometry.
    conic_np = Q.project_dual_conic(Q.dual_quadric(R, c, r, xp=np), K, pose, xp=np)
    conic_j = Q.project_dual_conic(Q.dual_quadric(R, c, r), K, pose)
    for xp_out, j_out in zip(Q.conic_outline(conic_np, 16, xp=np), Q.conic_outline(conic_j, 16)):
        np.testing.assert_allclose(xp_out, np.asarray(j_out), rtol=1e-6, atol=1e-6)
    g_np = Q.conic_outline(Q.ground_conic(R, c, r, xp=np), 8, xp=np)[0]
    np.testing.assert_allclose(g_np, np.asarray(Q.conic_outline(Q.ground_conic(R, c, r), 8)[0]), rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(Q.camera_depth(c, pose, xp=np), np.asarray(Q.camera_depth(c, pose)), rtol=1e-6)
    box_np, ok_np = Q.conic_bbox(conic_np, xp=np)
    box_j, ok_j = Q.project_bbox(R, c, r, K, pose)
    ok = ok_np & (Q.camera_depth(c, pose, xp=np) > 0)
    assert np.array_equal(ok, np.asarray(ok_j))
    np.testing.assert_allclose(box_np[ok], np.asarray(box_j)[ok], rtol=1e-5, atol=1e-3)


def test_host_geometry_rejects_other_namespaces():
    with pytest.raises(ValueError, match="xp"):
        Q.conic_outline(np.eye(3), 4, xp=object())
