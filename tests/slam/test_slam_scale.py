"""Issue 27, item 2: a solver that follows the scene's scale.

The single-view start of an object without a depth measurement comes from its class size and its
box, so a tabletop object starts near its true 0.8 m and a car near its true 15 m (not at a fixed
10 m); the rescue step's depth threshold is the config's; a solve never reports success while
objects are unfixable."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsem import classes, quadrics as Q, slam
from jaxsem.slam._batch import solve_schur  # layers: white-box
from jaxsem.slam._results import RESULTS  # layers: white-box

K = np.array([[525.0, 0.0, 320.0], [0.0, 525.0, 240.0], [0.0, 0.0, 1.0]])
SIZE = (640, 480)


def _yaw(deg):
    a = np.deg2rad(deg)
    return np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])


# Jitted: run op by op the start compiled well over a hundred small programs per call.
_initialize = jax.jit(slam.initialize, static_argnums=1)


def _start_depths(eye, target, objects, config=slam.SolverConfig()):
    """True and initial camera depths of ``objects`` [(class, centre, yaw deg)] seen from one camera
    (boxes: the true ellipsoids' projections, each object its class-mean size)."""
    pose = np.asarray(Q.look_at(np.asarray(eye, float), np.asarray(target, float)))
    boxes, truth = [], []
    for name, centre, yaw in objects:
        radii = np.asarray(classes.get(name).radii)
        box, valid = Q.project_bbox(_yaw(yaw), np.asarray(centre, float), radii, K, pose)
        assert bool(valid)
        boxes.append(np.asarray(box))
        truth.append(float(Q.camera_depth(np.asarray(centre, float), pose)))
    n = len(objects)
    problem = slam.make_problem(K, SIZE, pose[None], boxes, [0] * n, list(range(n)), [o[0] for o in objects])
    init = _initialize(problem, config)
    return np.array(truth), np.asarray(Q.camera_depth(init.center, pose))


def test_tabletop_objects_start_near_their_true_depth():
    # A camera 0.8 m from a desk's middle, looking down at it at about 45 degrees.
    table = [
        ("cracker_box", (0.0, 0.0, 0.036), 15.0),
        ("soup_can", (0.12, 0.05, 0.051), 0.0),
        ("ball", (-0.15, -0.05, 0.039), 40.0),
        ("cereal_box", (0.05, 0.15, 0.075), -20.0),
    ]
    truth, start = _start_depths((0.0, -0.57, 0.57), (0.0, 0.0, 0.0), table)
    assert np.all((truth > 0.6) & (truth < 1.0)), truth
    np.testing.assert_allclose(start, truth, rtol=0.2)
    # The fixed depth (the behaviour before) is still reachable, and is 10 m off here.
    _, fixed = _start_depths((0.0, -0.57, 0.57), (0.0, 0.0, 0.0), table, slam.SolverConfig(depth_from_box=False))
    np.testing.assert_allclose(fixed, 10.0)


def test_street_objects_start_near_their_true_depth():
    # A car-mounted camera at 1.5 m looking down a street; cars and a person about 15 m ahead.
    street = [
        ("car", (15.0, 3.0, 0.725), 10.0),
        ("car", (16.0, -3.5, 0.725), -5.0),
        ("person", (14.0, 1.0, 0.85), 30.0),
    ]
    truth, start = _start_depths((0.0, 0.0, 1.5), (1.0, 0.0, 1.5), street)
    assert np.all((truth > 13.0) & (truth < 17.0)), truth
    np.testing.assert_allclose(start, truth, rtol=0.2)


def test_box_cut_by_the_border_gives_no_size_depth():
    # Only the cut side is left out: a box cut on its left still gives a depth from its height;
    # a box cut on every side gives none (the default depth is used).
    pose = np.asarray(Q.look_at(np.array([0.0, 0.0, 1.5]), np.array([1.0, 0.0, 1.5])))
    radii = np.asarray(classes.get("car").radii)
    box = np.array([0.0, 200.0, 300.0, 260.0])
    edges = np.array([False, True, True, True])
    depth, ok = Q.depth_from_box_size(box, K, pose, radii, edge_mask=edges)
    tall, _ = Q.depth_from_box_size(box, K, pose, radii)
    assert bool(ok) and float(depth) > float(tall)  # a cut (narrow) width would pull it closer
    _, ok = Q.depth_from_box_size(box, K, pose, radii, edge_mask=np.zeros(4, bool))
    assert not bool(ok)
    g = jax.grad(lambda b: Q.depth_from_box_size(b, K, pose, radii)[0])(jnp.asarray(box))
    assert bool(jnp.all(jnp.isfinite(g)))


@pytest.mark.slow
def test_no_success_with_unfixable_objects():
    """A small orbit map plus one object whose boxes contradict each other (a small box and a
    huge one from two nearby cameras): the object is unfixable, and the result says so."""
    base, _ = slam.toy_map(0, num_objects=2, num_frames=8, path="orbit")
    M = int(base.box_mask.sum())
    box = np.concatenate([np.asarray(base.box)[:M], [[300.0, 220.0, 310.0, 230.0], [20.0, 20.0, 620.0, 460.0]]])
    problem = slam.make_problem(
        base.K,
        base.image_size,
        base.pose_prior,
        box,
        np.concatenate([np.asarray(base.box_pose)[:M], [0, 1]]),
        np.concatenate([np.asarray(base.box_object)[:M], [2, 2]]),
        ["car", "car", "car"],
        np.concatenate(
            [np.where(np.asarray(base.texture_mask), np.asarray(base.texture_depth), np.nan)[:M], [np.nan, np.nan]]
        ),
    )
    cfg = slam.SolverConfig(max_steps=40)
    _, info = jax.jit(lambda p: solve_schur(p, None, cfg))(problem)
    assert bool(info.unfixable[2]) and not bool(info.unfixable[:2].any())
    assert not bool(info.success)
    assert bool(info.result == RESULTS.unfixable_objects), slam.result_message(info.result)


@pytest.mark.slow
def test_rescue_reaches_a_tabletop_with_the_configs_min_depth():
    """Objects started at a fixed 10 m (QuadricSLAM's start) on a desk seen from 0.8 m: the rescue
    triangulates them where they are, closer than 1 m, because its depth threshold is
    ``config.min_depth`` (0.1 m); with ``min_depth=1.0`` (the old hard-coded value) it refuses."""
    objects = [("cracker_box", (0.0, 0.0, 0.036)), ("soup_can", (0.12, 0.05, 0.051)), ("ball", (-0.12, 0.0, 0.039))]
    poses, boxes, box_pose, box_object = [], [], [], []
    for t, a in enumerate(np.deg2rad(np.linspace(-30.0, 30.0, 6))):
        eye = np.array([0.57 * np.sin(a), -0.57 * np.cos(a), 0.57])
        pose = np.asarray(Q.look_at(eye, np.zeros(3)))
        poses.append(pose)
        for j, (name, centre) in enumerate(objects):
            box, _ = Q.project_bbox(np.eye(3), np.asarray(centre), np.asarray(classes.get(name).radii), K, pose)
            boxes.append(np.asarray(box))
            box_pose.append(t)
            box_object.append(j)
    problem = slam.make_problem(K, SIZE, np.stack(poses), boxes, box_pose, box_object, [o[0] for o in objects])
    truth = np.array([o[1] for o in objects])
    cfg = slam.SolverConfig(depth_from_box=False, max_steps=60)
    solve = jax.jit(lambda p, c: solve_schur(p, None, c))
    est, info = solve(problem, cfg)
    assert bool(info.rescued.all()) and bool(info.success), slam.result_message(info.result)
    assert float(np.abs(np.asarray(est.center) - truth).max()) < 0.01
    _, old = solve(problem, cfg.replace(min_depth=1.0))
    assert not bool(old.rescued.any())
