"""Simulated ellipsoid maps: object placement, camera paths, detections against independent
references (projected surface points), noise statistics, masks, vmap, conversion to SlamProblem."""

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsem import factors, quadrics, slam
from jaxsem.slam import sim

# Small shared configs so the file compiles a handful of functions only.
FWD = sim.quadricslam_config("forward", num_objects=4, num_frames=16, forward_step=2.5, yaw_range=math.pi)
ORB = sim.thesis_config("orbit", num_objects=4, num_frames=16)
CLEAN = FWD.replace(box_noise_px=0.0, texture_noise_m=0.0, texture_noise_rel=0.0, pose_noise_m=0.0, pose_noise_deg=0.0)


@pytest.fixture(scope="module")
def fwd_maps():
    return sim.simulate_batch(0, 24, FWD)


@pytest.fixture(scope="module")
def orb_maps():
    return sim.simulate_batch(1, 24, ORB)


@pytest.fixture(scope="module")
def clean_maps():
    return sim.simulate_batch(2, 6, CLEAN)


def _np(tree):
    return jax.tree_util.tree_map(np.asarray, tree)


def test_shapes_masks_finite_and_seeded(fwd_maps):
    m = _np(fwd_maps)
    B, T, N = 24, FWD.num_frames, FWD.num_objects
    assert m.boxes.shape == (B, T, N, 4) and m.camera_T_world.shape == (B, T, 4, 4)
    assert m.object_rotation.shape == (B, N, 3, 3) and m.edge_mask.shape == (B, T, N, 4)
    for leaf in jax.tree_util.tree_leaves(m):
        if np.issubdtype(leaf.dtype, np.floating):
            assert np.all(np.isfinite(leaf))
    assert m.box_mask.sum() > 0 and (~m.box_mask).sum() > 0
    # Same seed, same maps; different seeds, different maps.
    again = _np(sim.simulate_batch(0, 24, FWD))
    np.testing.assert_array_equal(again.boxes, m.boxes)
    assert not np.allclose(m.object_center[0], m.object_center[1])
    # A dropped detection has no texture plane and no constraining edge.
    assert not np.any(m.texture_mask & ~m.box_mask)
    assert not np.any(m.edge_mask & ~m.box_mask[..., None])
    assert np.all(m.observed == (m.box_mask.any(1) & m.object_mask))


def test_objects_on_ground_class_sized_and_separated(fwd_maps, orb_maps):
    mean, sigma = (np.asarray(a) for a in factors.shape_prior_table())
    car = factors.class_index("car")
    for m, cfg in ((_np(fwd_maps), FWD), (_np(orb_maps), ORB)):
        assert np.all(m.object_class == car)
        mask = m.object_mask
        assert mask.sum() >= 0.9 * mask.size
        R, c, r = m.object_rotation, m.object_center, m.object_radii
        # Standing on the ground, rotated about z only.
        np.testing.assert_allclose(c[..., 2], r[..., 2], atol=1e-12)
        np.testing.assert_allclose(R[..., 2, :], np.broadcast_to([0, 0, 1.0], R[..., 2, :].shape), atol=1e-12)
        z = (r[mask] - mean[car]) / sigma[car]
        assert np.all(np.abs(z) < 6) and abs(z.mean()) < 0.3 and 0.7 < z.std() < 1.3
        half = cfg.patch_size / 2
        assert np.all(np.abs(c[mask][:, :2]) <= half + 1e-9)
        for b in range(m.object_center.shape[0]):
            idx = np.flatnonzero(mask[b])
            for i in idx:
                for j in idx[idx > i]:
                    d = np.linalg.norm(c[b, i, :2] - c[b, j, :2])
                    assert d >= r[b, i].max() + r[b, j].max() + cfg.object_gap - 1e-9
    fwd = _np(fwd_maps)
    assert np.all(np.abs(fwd.object_center[fwd.object_mask][:, 1]) >= FWD.corridor_half_width - 1e-9)


def test_camera_paths():
    orbit = np.asarray(sim.camera_path(ORB))
    world_T_cam = np.linalg.inv(orbit)
    eye = world_T_cam[:, :3, 3]
    np.testing.assert_allclose(np.linalg.norm(eye[:, :2], axis=-1), ORB.orbit_radius, atol=1e-9)
    np.testing.assert_allclose(eye[:, 2], ORB.camera_height, atol=1e-9)
    # Every orbit camera looks at the target: it projects to the principal point.
    target = np.array([0.0, 0.0, ORB.orbit_target_height, 1.0])
    p = (orbit @ target)[:, :3]
    np.testing.assert_allclose(p[:, :2] / p[:, 2:], 0.0, atol=1e-9)
    fwd = np.asarray(sim.camera_path(FWD))
    eye = np.linalg.inv(fwd)[:, :3, 3]
    np.testing.assert_allclose(np.diff(eye[:, 0]), FWD.forward_step, atol=1e-9)
    np.testing.assert_allclose(eye[:, 1:], [[0.0, FWD.camera_height]] * FWD.num_frames, atol=1e-9)
    np.testing.assert_allclose(eye[-1, 0], FWD.patch_size / 2, atol=1e-9)
    np.testing.assert_allclose(np.linalg.inv(fwd)[:, :3, 2], [[1.0, 0, 0]] * FWD.num_frames, atol=1e-9)


@pytest.mark.slow
def test_noise_free_detections_match_projected_surface_points(clean_maps):
    """Independent reference: boxes = extent of densely projected surface points; texture
    depth = smallest camera z of the surface points."""
    m = _np(clean_maps)
    K = m.K[0]
    checked = 0
    for b in range(6):
        for t in range(0, CLEAN.num_frames, 2):
            for j in np.flatnonzero(m.box_mask[b, t]):
                pts = np.asarray(
                    quadrics.surface_points(
                        jax.random.key(t), m.object_rotation[b, j], m.object_center[b, j], m.object_radii[b, j], 20000
                    )
                )
                cam = pts @ m.camera_T_world[b, t, :3, :3].T + m.camera_T_world[b, t, :3, 3]
                uv = (cam @ K.T)[:, :2] / cam[:, 2:]
                ref = np.concatenate([uv.min(0), uv.max(0)])
                np.testing.assert_allclose(m.true_boxes[b, t, j], ref, atol=1.5)
                clipped = np.clip(ref, 0, [640, 480, 640, 480])
                np.testing.assert_allclose(m.boxes[b, t, j], clipped, atol=1.5)
                np.testing.assert_allclose(m.texture_depth[b, t, j], cam[:, 2].min(), atol=0.02)
                checked += 1
    assert checked > 10
    # Noise-free pose priors are the true poses.
    np.testing.assert_allclose(m.pose_prior, m.camera_T_world, atol=1e-12)


def test_edge_mask_and_truncation_rules(fwd_maps):
    m = _np(fwd_maps)
    W, H, margin = FWD.image_width, FWD.image_height, FWD.border_margin_px
    box, keep = m.boxes[m.box_mask], m.box_mask
    expected = np.stack([box[:, 0] > margin, box[:, 1] > margin, box[:, 2] < W - margin, box[:, 3] < H - margin], -1)
    np.testing.assert_array_equal(m.edge_mask[keep], expected)
    assert (~expected).any()  # some detections are truncated at the border
    assert np.all(box[:, :2] >= 0) and np.all(box[:, 2] <= W) and np.all(box[:, 3] <= H)
    assert np.all(box[:, 2:] - box[:, :2] >= FWD.min_box_px)
    # A detection needs its ellipsoid fully in front of the camera.
    depth, valid = quadrics.texture_plane_depth(
        m.object_rotation[:, None], m.object_center[:, None], m.object_radii[:, None], m.camera_T_world[:, :, None]
    )
    assert not np.any(keep & ~np.asarray(valid))
    # Truncation rule: the visible fraction of the unclipped noisy box is at least the minimum.
    tb = m.true_boxes[keep]
    area = np.prod(tb[:, 2:] - tb[:, :2], -1)
    vis = np.prod(np.clip(tb[:, 2:], 0, [W, H]) - np.clip(tb[:, :2], 0, [W, H]), -1) / area
    assert np.all(vis > FWD.min_visible_fraction - 0.1)  # 3 px noise moves it a little


def test_noise_statistics(orb_maps):
    m = _np(orb_maps)
    keep = m.box_mask & (m.edge_mask.all(-1))
    err = (m.boxes - m.true_boxes)[keep]
    assert abs(err.mean()) < 0.2
    np.testing.assert_allclose(err.std(), ORB.box_noise_px, rtol=0.1)
    # Pose prior: camera position noise per axis and rotation noise (deg) per axis.
    dpos = np.linalg.inv(m.pose_prior)[..., :3, 3] - np.linalg.inv(m.camera_T_world)[..., :3, 3]
    np.testing.assert_allclose(dpos.std(), ORB.pose_noise_m, rtol=0.15)
    rel = np.swapaxes(m.camera_T_world[..., :3, :3], -1, -2) @ m.pose_prior[..., :3, :3]
    angle = np.degrees(np.arccos(np.clip((np.trace(rel, axis1=-2, axis2=-1) - 1) / 2, -1, 1)))
    # |omega| of a 3-D Gaussian with sigma per axis has RMS sqrt(3) sigma.
    np.testing.assert_allclose(np.sqrt(np.mean(angle**2)), math.sqrt(3) * ORB.pose_noise_deg, rtol=0.15)
    tex = (
        m.texture_depth
        - np.asarray(
            quadrics.texture_plane_depth(
                m.object_rotation[:, None],
                m.object_center[:, None],
                m.object_radii[:, None],
                m.camera_T_world[:, :, None],
            )[0]
        )
    )[m.texture_mask]
    z = tex / m.texture_sigma[m.texture_mask]
    assert abs(z.mean()) < 0.1 and 0.9 < z.std() < 1.1
    # Thesis preset init: noisy truth.
    d = (m.init_center - m.object_center)[m.observed]
    np.testing.assert_allclose(d.std(), ORB.init_position_noise_m, rtol=0.2)


def test_single_view_init_on_the_ray(fwd_maps):
    m = _np(fwd_maps)
    b, j = np.argwhere(m.observed)[0]
    t = m.first_frame[b, j]
    assert m.box_mask[b, t, j] and not m.box_mask[b, :t, j].any()
    p = m.pose_prior[b, t] @ np.append(m.init_center[b, j], 1.0)
    np.testing.assert_allclose(p[2], FWD.init_depth, rtol=1e-9)
    uv = (m.K[b] @ p[:3])[:2] / p[2]
    box = m.boxes[b, t, j]
    np.testing.assert_allclose(uv, [(box[0] + box[2]) / 2, (box[1] + box[3]) / 2], atol=1e-6)
    np.testing.assert_allclose(m.init_radii[b, j], [1.0, 1.0, 1.0])
    np.testing.assert_allclose(m.init_rotation[b, j], np.eye(3))


def test_to_problem_is_a_valid_slam_problem(fwd_maps):
    one = jax.tree_util.tree_map(lambda x: x[0], fwd_maps)
    prob = _np(sim.to_problem(one, FWD))
    T, N = FWD.num_frames, FWD.num_objects
    assert prob.box.shape == (T * N, 4)
    m = _np(one)
    t, j = np.argwhere(m.box_mask)[0]
    k = t * N + j
    assert prob.box_pose[k] == t and prob.box_object[k] == j and prob.box_mask[k]
    np.testing.assert_array_equal(prob.box[k], m.boxes[t, j])
    # The validating constructor accepts exactly this data (boxes of unobserved objects are none).
    ref = slam.make_problem(
        prob.K,
        prob.image_size,
        prob.pose_prior,
        prob.box,
        prob.box_pose,
        prob.box_object,
        prob.object_class,
        np.where(prob.texture_mask, prob.texture_depth, np.nan),
        box_mask=prob.box_mask,
        object_mask=prob.object_mask,
    )
    for name in ("box_pose", "box_object", "box_mask", "texture_mask", "object_class"):
        np.testing.assert_array_equal(np.asarray(getattr(ref, name)), getattr(prob, name))
    keep = prob.box_mask
    np.testing.assert_array_equal(np.asarray(ref.box)[keep], prob.box[keep])
    np.testing.assert_allclose(np.asarray(ref.texture_depth)[prob.texture_mask], prob.texture_depth[prob.texture_mask])


@pytest.mark.slow
def test_ground_truth_fits_the_solver_factors_exactly(clean_maps):
    """Noise-free measurements: the solver's box and texture residuals vanish at the truth
    (sim and factors agree on every convention), and the initial estimate is far worse."""
    one = jax.tree_util.tree_map(lambda x: x[0], clean_maps)
    prob = sim.to_problem(one, CLEAN)
    cfg = sim.solver_config("roshan", CLEAN)
    # jitted: op by op the residuals and the costs compiled some hundreds of small programs
    boxes, poses, _ = jax.jit(slam.residual_blocks)(prob, sim.ground_truth(one), cfg)
    np.testing.assert_allclose(np.asarray(boxes), 0.0, atol=1e-6)
    np.testing.assert_allclose(np.asarray(poses), 0.0, atol=1e-9)
    total_cost = jax.jit(slam.total_cost)
    gt_cost = float(total_cost(prob, sim.ground_truth(one), cfg))
    init_cost = float(total_cost(prob, sim.initial_estimate(one), cfg))
    assert gt_cost < 1e-3 * init_cost


@pytest.mark.slow
def test_views_study_maps():
    cfg = sim.thesis_config(box_noise_px=0.0)
    f = jax.jit(jax.vmap(lambda k, n, yr: sim.simulate_views(k, n, yr, cfg, max_views=8)))
    keys = jax.random.split(jax.random.key(3), 6)
    n = jnp.array([1, 3, 8, 8, 8, 8])
    yr = jnp.array([0.0, 0.5, 0.0, 1.0, 2.0, 6.0])
    v = _np(f(keys, n, yr))
    assert v.object_center.shape == (6, 1, 3)
    np.testing.assert_allclose(v.object_center[:, 0, :2], 0.0)
    eye = np.linalg.inv(v.camera_T_world)[..., :3, 3]
    dist = np.linalg.norm(eye[..., :2], axis=-1)
    assert np.all((dist >= cfg.view_distance_min - 1e-9) & (dist <= cfg.view_distance_max + 1e-9))
    yaw0 = np.arctan2(v.object_rotation[:, 0, 1, 0], v.object_rotation[:, 0, 0, 0])
    az = np.arctan2(eye[..., 1], eye[..., 0]) - yaw0[:, None]
    spread = np.abs(np.angle(np.exp(1j * (az - az[:, :1]))))  # relative to the first view
    assert np.all(spread[0] < 1e-9) and np.all(spread[2] < 1e-9)  # zero range: one azimuth
    for i in (3, 4):
        assert np.all(spread[i] <= yr[i] + 1e-9) and spread[i].max() > 0.05
    assert v.box_mask[:, :, 0].sum(1).tolist()[:3] == [1, 3, 8]
    assert np.all(v.observed[:, 0])


def test_vmappable_float32_and_under_jit():
    cfg = FWD.replace(num_objects=2, num_frames=4)
    m = jax.jit(jax.vmap(lambda k: sim.simulate(k, cfg, jnp.float32)))(jax.random.split(jax.random.key(0), 3))
    assert m.boxes.dtype == jnp.float32 and m.boxes.shape == (3, 4, 2, 4)
    assert all(
        bool(jnp.all(jnp.isfinite(x))) for x in jax.tree_util.tree_leaves(m) if jnp.issubdtype(x.dtype, jnp.floating)
    )


def test_bad_input_raises():
    with pytest.raises(ValueError, match="path"):
        sim.SimConfig(path="spiral")
    with pytest.raises(ValueError, match="unknown class"):
        sim.SimConfig(classes=("unicorn",))
    with pytest.raises(ValueError, match="box_noise_px"):
        sim.SimConfig(box_noise_px=-1.0)
    with pytest.raises(ValueError, match="num_frames"):
        sim.SimConfig(num_frames=0)
    with pytest.raises(ValueError, match="min_objects"):
        sim.SimConfig(num_objects=3, min_objects=5)
    with pytest.raises(ValueError, match="key"):
        sim.simulate(jax.random.split(jax.random.key(0), 2), FWD)
    with pytest.raises(ValueError, match="config"):
        sim.simulate(jax.random.key(0), {"path": "orbit"})
    with pytest.raises(ValueError, match="num_maps"):
        sim.simulate_batch(0, 0, FWD)


def test_sim_imports_without_mujoco_and_rendering_says_what_to_install():
    # Regression: the simulator (now jaxsem.slam.sim) imported mujoco at module load, so the simulated maps (no renderer)
    # failed on an install without the optional 'sim' extra (seen on the GPU machine).
    import subprocess
    import sys
    import textwrap

    code = textwrap.dedent(
        """
        import sys
        class Block:
            def find_spec(self, name, path=None, target=None):
                if name == "mujoco" or name.startswith("mujoco."):
                    raise ImportError("no mujoco here")
        sys.meta_path.insert(0, Block())
        from jaxsem.slam import sim
        sim.quadricslam_config("orbit", num_frames=4, num_objects=2, min_objects=2)
        from jaxsem.data import _render  # layers: white-box
        try:
            _render.mujoco.MjSpec
        except ImportError as exc:
            print("refused:", exc)
        """
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert "jaxsem[sim]" in out.stdout


@pytest.mark.parametrize("scale", [1.0, 1.6])
def test_online_reinitialisation_follows_the_batch_rule_and_the_silhouette_scale(scale):
    """An object the online protocol re-initialises from its latest box lands where the batch
    initialisation puts an object seen only in that box, silhouette scale included (the online
    rule once ignored ``SolverConfig.silhouette_scale`` and always read the box as the object)."""
    from jaxsem.slam.sim._experiments import _reinitialise  # layers: white-box (one round, no solve)

    problem, _ = slam.toy_map(3, num_objects=2, num_frames=8, path="orbit")
    cfg = slam.SolverConfig(silhouette_scale=scale)
    idx = np.arange(problem.box.shape[0])
    obj, mask = np.asarray(problem.box_object), np.asarray(problem.box_mask)
    last = np.array([idx[(obj == j) & mask].max() for j in range(2)])
    only_last = eqx.tree_at(lambda p: p.box_mask, problem, jnp.asarray(np.isin(idx, last) & mask))
    # jitted, the config an argument (op by op both compiled some hundreds of small programs;
    # the two scales share the programs)
    batch = jax.jit(slam.initialize)(only_last, cfg)
    stranded = slam.SlamEstimate(batch.camera_T_world, batch.rotation, batch.center + 1e4, batch.radii)
    online, lost = jax.jit(_reinitialise)(problem, stranded, problem.box_mask, cfg, batch.radii, 0.0)
    assert bool(jnp.all(lost))
    for a, b in ((online.rotation, batch.rotation), (online.center, batch.center), (online.radii, batch.radii)):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-6, atol=1e-9)
