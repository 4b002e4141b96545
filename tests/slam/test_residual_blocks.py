"""Issue 45 item 13: every block of ROSHAN's cost against its factor function, off the truth.

The other fast SLAM tests are noise-free and solve at the truth, where every residual is zero:
a block that drops a row (the texture plane), pairs the wrong poses (odometry) or forwards the
wrong setting there still looks right. Here the cost is evaluated at a perturbed state, on a
scene whose camera path is irregular (on a regular orbit every odometry step is the same motion,
so pairing the wrong poses costs nothing), with every optional block on, non-default sigmas and
a different robust loss per block, and each block is compared with :mod:`jaxsem.factors`
evaluated directly on the poses and objects its rows name. The block normal equations
(``linearize``, hand-written chain rule and its own odometry pairing) are checked against
central differences of the cost.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsem import factors as F, quadrics as Q, slam
from jaxsem.slam._cost import Delta, linearize, retract  # layers: white-box
from jaxsem.slam._solver_config import NoiseModel  # layers: white-box

T_REAL, J_REAL = 6, 3
CAPACITY = (T_REAL + 1, 40, J_REAL + 1)  # one padded pose, padded boxes and one padded object
_blocks = jax.jit(slam.residual_blocks)  # one compile for every state and config value here
_retract = jax.jit(retract)


@jax.jit
def _measure(R, c, r, K, poses):
    box, valid = Q.project_bbox(R[None], c[None], r[None], K, poses[:, None])
    depth, _ = Q.texture_plane_depth(R[None], c[None], r[None], poses[:, None])
    return box, valid, depth


def _scene(seed=0):
    """``(problem, truth)``: three cars (yawed, on the ground) seen from six cameras on an
    irregular path (an orbit jittered per frame), exact boxes and texture depths (some texture
    missing), exact odometry, pose priors at the truth with per-pose weights, padded to
    :data:`CAPACITY`."""
    rng = np.random.default_rng(seed)
    yaw = rng.uniform(-np.pi, np.pi, J_REAL)
    R = np.zeros((J_REAL, 3, 3))
    R[:, 0, 0], R[:, 0, 1], R[:, 1, 0], R[:, 1, 1], R[:, 2, 2] = np.cos(yaw), -np.sin(yaw), np.sin(yaw), np.cos(yaw), 1
    r = np.tile(np.asarray(F.shape_prior("car").mean), (J_REAL, 1))  # the class mean: shape rows zero
    c = np.concatenate([rng.uniform(-5, 5, (J_REAL, 2)), r[:, 2:]], -1)  # resting on z = 0
    a = np.linspace(0, 2 * np.pi, T_REAL, endpoint=False) + rng.uniform(-0.3, 0.3, T_REAL)
    eyes = np.stack([20 * np.cos(a), 20 * np.sin(a), np.full(T_REAL, 1.5)], -1) + rng.normal(0, 1.0, (T_REAL, 3))
    poses = np.asarray(Q.look_at(eyes, rng.normal(0, 1.0, (T_REAL, 3))))
    K = np.array([[525.0, 0, 320.0], [0, 525.0, 240.0], [0, 0, 1.0]])
    box, valid, depth = (np.asarray(x) for x in _measure(R, c, r, K, poses))
    inside = (box[..., 0] > -100) & (box[..., 1] > -100) & (box[..., 2] < 740) & (box[..., 3] < 580)
    t_idx, j_idx = np.nonzero(valid & inside)
    tex = depth[t_idx, j_idx].copy()
    tex[::3] = np.nan  # every third box without a texture depth
    odometry = np.asarray(Q.relative_pose(poses[:-1], poses[1:]))
    weight = rng.uniform(0.5, 2.0, (T_REAL, 2))
    problem = slam.make_problem(
        K,
        [640, 480],
        poses,
        np.clip(box[t_idx, j_idx], [0, 0, 0, 0], [640, 480, 640, 480]),
        t_idx,
        j_idx,
        ["car"] * J_REAL,
        tex,
        capacity=CAPACITY,
        odometry=odometry,
        pose_prior_weight=weight,
    )
    Tc, _, Jc = CAPACITY
    truth = slam.SlamEstimate(
        jnp.asarray(np.concatenate([poses, np.broadcast_to(np.eye(4), (Tc - T_REAL, 4, 4))])),
        jnp.asarray(np.concatenate([R, np.broadcast_to(np.eye(3), (Jc - J_REAL, 3, 3))])),
        jnp.asarray(np.concatenate([c, np.zeros((Jc - J_REAL, 3))])),
        jnp.asarray(np.concatenate([r, np.ones((Jc - J_REAL, 3))])),
    )
    return problem, truth


def _config():
    """Every optional block on, sigmas unlike the defaults and each other, a different robust
    loss per block (a setting forwarded to the wrong block changes the values)."""
    noise = NoiseModel(
        pose_rotation_sigma=0.03,
        pose_translation_sigma=0.07,
        odometry_rotation_sigma=0.011,
        odometry_translation_sigma=0.045,
        box_sigma=2.5,
        texture_sigma=0.2,
        shape_prior_scale=1.3,
    )
    return slam.SolverConfig(
        noise=noise,
        box_loss="huber",
        texture_loss="cauchy",
        shape_loss="huber",
        pose_loss="cauchy",
        robust_scale=1.5,
        texture_plane_fraction=0.8,
        silhouette_scale=1.1,
        use_upright=True,
        upright_sigma=0.1,
        use_support=True,
        support_height=0.05,
        support_sigma=0.02,
    )


def _perturbed(problem, truth, seed=1):
    """The truth moved by a random tangent step (poses, rotations, centres and radii), one
    object moved around a camera."""
    rng = np.random.default_rng(seed)
    T, J = truth.camera_T_world.shape[0], truth.center.shape[0]
    delta = Delta(
        jnp.asarray(np.concatenate([rng.normal(0, 0.3, (T, 3)), rng.normal(0, 0.02, (T, 3))], -1)),
        jnp.asarray(rng.normal(0, 0.1, (J, 3))),
        jnp.asarray(rng.normal(0, 0.4, (J, 3))),
        jnp.asarray(rng.normal(0, 0.2, (J, 3))),
    )
    est = _retract(truth, delta)
    # Object 0 around a camera that sees it: its box there takes the invalid-geometry branch
    # and both barrier rows (near depth, camera inside) are non-zero.
    t = int(np.asarray(problem.box_pose)[np.flatnonzero(np.asarray(problem.box_object) == 0)[0]])
    cam = -est.camera_T_world[t, :3, :3].T @ est.camera_T_world[t, :3, 3]
    return eqx.tree_at(lambda e: e.center, est, est.center.at[0].set(cam + 0.2))


@jax.jit
def _factor_values(box_args, pose_args, object_args, odometry_args):
    """The factor functions of :mod:`jaxsem.factors` with :func:`_config`'s settings written
    out, on the poses and objects each row names (gathered by the caller); one compile."""
    P, R, c, r, box, K, size, depth = box_args
    edges = F.box_residual(
        P,
        R,
        c,
        r * 1.1,
        box,
        K,
        size,
        box_sigma=2.5,
        border_margin=10.0,
        barrier_weight=10.0,
        min_depth=0.1,
        degenerate_residual=1000.0,
        loss="huber",
        robust_scale=1.5,
    )
    tex = F.robust_residual(F.texture_residual(P, R, c, r, depth, 0.2, 0.8), "cauchy", 1.5)
    poses, prior, weight = pose_args
    pr = F.pose_prior_residual(poses, prior, 0.03, 0.07) * jnp.repeat(weight, 3, axis=-1)
    R, c, r, mean, sigma = object_args
    up = jnp.array([0.0, 0.0, 1.0])
    shape = F.robust_residual(F.shape_prior_residual(r, mean, sigma) / 1.3, "huber", 1.5)
    upright = F.robust_residual(F.upright_residual(R, up, 0.1), "huber", 1.5)
    support = F.robust_residual(F.support_residual(R, c, r, up, 0.05, 0.02), "huber", 1.5)
    a, b, measured = odometry_args
    odo = F.robust_residual(F.between_residual(a, b, measured, 0.011, 0.045), "cauchy", 1.5)
    return (
        jnp.concatenate([edges, tex[:, None]], -1),
        F.robust_residual(pr, "cauchy", 1.5),
        jnp.concatenate([shape, upright, support], -1),
        odo,
    )


def _reference_blocks(problem, est):
    """Each block of :func:`_config`'s cost from the factor functions, evaluated on numpy
    gathers of the poses and objects that its rows name: box ``m`` on pose ``box_pose[m]`` and
    object ``box_object[m]``, odometry row ``t`` on poses ``t`` and ``t + 1`` (real rows only;
    the rest zero)."""
    P, R, c, r = (np.asarray(x) for x in (est.camera_T_world, est.rotation, est.center, est.radii))
    real = np.flatnonzero(np.asarray(problem.box_mask))
    bp, bo = np.asarray(problem.box_pose)[real], np.asarray(problem.box_object)[real]
    mean, sigma = (np.asarray(x)[np.asarray(problem.object_class)] for x in F.shape_prior_table(jnp.float64))
    steps = np.flatnonzero(np.asarray(problem.odometry_mask))
    got = _factor_values(
        (
            P[bp],
            R[bo],
            c[bo],
            r[bo],
            np.asarray(problem.box)[real],
            np.asarray(problem.K),
            np.asarray(problem.image_size),
            np.asarray(problem.texture_depth)[real],
        ),
        (P, np.asarray(problem.pose_prior), np.asarray(problem.pose_prior_weight)),
        (R, c, r, mean, sigma),
        (P[steps], P[steps + 1], np.asarray(problem.odometry)[steps]),
    )
    boxes, poses, shapes, odo = (np.array(x) for x in got)
    boxes[:, 6] = np.where(np.asarray(problem.texture_mask)[real], boxes[:, 6], 0.0)
    out_boxes = np.zeros(problem.box.shape[:1] + (7,))
    out_boxes[real] = boxes
    out_odo = np.zeros((P.shape[0], 6))
    out_odo[steps] = odo
    poses = np.where(np.asarray(problem.pose_mask)[:, None], poses, 0.0)
    shapes = np.where(np.asarray(problem.object_mask)[:, None], shapes, 0.0)
    return out_boxes, poses, shapes, out_odo


@pytest.fixture(scope="module")
def scene():
    problem, truth = _scene()
    return problem, truth, _config(), _perturbed(problem, truth)


def test_the_scene_exercises_every_block(scene):
    """The scene is what the other tests rely on: boxes with and without texture, odometry on
    the real steps only, a padded pose and object, a camera path whose steps differ."""
    problem, truth, _, _ = scene
    tm, bm = np.asarray(problem.texture_mask), np.asarray(problem.box_mask)
    assert 10 <= bm.sum() < bm.size and 0 < tm.sum() < bm.sum()
    assert np.asarray(problem.odometry_mask).tolist() == [True] * (T_REAL - 1) + [False] * (CAPACITY[0] - T_REAL + 1)
    steps = np.asarray(problem.odometry)[: T_REAL - 1]
    assert np.min(np.linalg.norm(steps[1:] - steps[:-1], axis=(-2, -1))) > 0.05


def test_every_block_is_zero_at_the_truth(scene):
    """Exact measurements: every block (odometry included) vanishes at the truth."""
    problem, truth, cfg, _ = scene
    cfg = cfg.replace(silhouette_scale=1.0, texture_plane_fraction=1.0, support_height=0.0)
    blocks = _blocks(problem, truth, cfg)
    assert len(blocks) == 4
    for name, block in zip(("boxes", "poses", "shapes", "odometry"), blocks):
        np.testing.assert_allclose(block, 0.0, atol=1e-7, err_msg=name)


@pytest.mark.parametrize("name", ["boxes", "poses", "shapes", "odometry"])
def test_each_block_equals_its_factors_at_a_perturbed_state(scene, name):
    """Off the truth every row is the factor function of the poses and objects it names, with
    the config's sigmas and robust loss; padded rows are exactly zero."""
    problem, _, cfg, est = scene
    got = _blocks(problem, est, cfg)
    want = _reference_blocks(problem, est)
    i = ("boxes", "poses", "shapes", "odometry").index(name)
    assert got[i].shape == want[i].shape
    # every column of the block carries information here (nothing compared is trivially zero)
    real = {"boxes": problem.box_mask, "poses": problem.pose_mask, "shapes": problem.object_mask}.get(
        name, problem.odometry_mask
    )
    assert np.all(np.max(np.abs(want[i][np.asarray(real)]), axis=0) > 1e-3)
    np.testing.assert_allclose(got[i], want[i], rtol=1e-9, atol=1e-9)


def test_shifted_odometry_pairs_are_not_zero(scene):
    """The odometry block vanishes for the measured steps and not when every step is assigned
    to the next pair of poses (what an off-by-one in the pairing looks like)."""
    problem, truth, cfg, _ = scene
    odo = np.asarray(problem.odometry)
    shifted = eqx.tree_at(lambda p: p.odometry, problem, jnp.asarray(np.concatenate([odo[1:], odo[:1]])))
    row = _blocks(shifted, truth, cfg)[3]
    real = np.asarray(problem.odometry_mask)
    assert np.all(np.linalg.norm(np.asarray(row)[real][:-1], axis=-1) > 1.0)


def test_linearize_cost_and_gradient_at_a_perturbed_state(scene):
    """``linearize``'s cost and gradient (its own 9-column chain rule and odometry pairing)
    equal half the squared norm of the factor rows and its central differences along every
    tangent coordinate (poses ``[v, omega]``, then per object rotation, centre, radii)."""
    problem, _, cfg, est = scene
    want = 0.5 * sum(np.sum(np.square(b)) for b in _reference_blocks(problem, est))
    n = jax.jit(linearize)(problem, est, cfg, jnp.ones(est.camera_T_world.shape[0]))
    np.testing.assert_allclose(n.cost, want, rtol=1e-10)

    T, J = est.camera_T_world.shape[0], est.center.shape[0]
    sizes = [T * 6, J * 3, J * 3, J * 3]  # Delta's fields in order, flattened

    def cost(i, h):
        x = np.zeros(sum(sizes))
        x[i] = h
        p, w, c, r = np.split(x, np.cumsum(sizes)[:-1])
        moved = _retract(est, Delta(p.reshape(T, 6), w.reshape(J, 3), c.reshape(J, 3), r.reshape(J, 3)))
        return 0.5 * sum(np.sum(np.square(np.asarray(b))) for b in _blocks(problem, moved, cfg))

    eps = 1e-6
    fd = np.array([(cost(i, eps) - cost(i, -eps)) / (2 * eps) for i in range(sum(sizes))])
    go = np.asarray(n.go)
    got = np.concatenate([np.asarray(n.gp).ravel()] + [go[:, k : k + 3].ravel() for k in (0, 3, 6)])
    assert np.max(np.abs(fd)) > 1.0
    np.testing.assert_allclose(got, fd, rtol=1e-5, atol=1e-6 * np.max(np.abs(fd)))
