"""A BOP scene as ROSHAN sequences (issue 27 item 4): stretches and still spells on a scene with a
known move, camera poses from object poses on a constructed case, drifting odometry, user class
priors, the front end with a tracker's ids and descriptor matching, the texture plane at the mean
visible surface, and an end-to-end run on a tiny BOP scene the test writes (slow)."""

import json

import jax
import numpy as np
import pytest

from jaxsem import data, factors as F, quadrics as q, slam
from jaxsem.slam._batch import solve_schur  # layers: white-box
from jaxsem.slam._bop_slam import (  # layers: white-box
    OdometryModel,
    camera_from_anchors,
    odometry_poses,
    pose_prior_weights,
)
from jaxsem.slam._frontend import FrontEnd  # layers: white-box
from jaxsem.slam._multistart import solve_yaw_starts  # layers: white-box
from jaxsem.volumon import data as vdata

K = np.array([[500.0, 0.0, 160.0], [0.0, 500.0, 120.0], [0.0, 0.0, 1.0]])


def _rot(axis, deg):
    a = np.radians(deg)
    c, s = np.cos(a), np.sin(a)
    i, j = [k for k in range(3) if k != axis]
    R = np.eye(3)
    R[i, i], R[i, j], R[j, i], R[j, j] = c, -s, s, c
    return R


def _look(eye, target):
    """camera_T_world of a camera at ``eye`` looking at ``target`` (world z up)."""
    return np.asarray(q.look_at(np.asarray(eye, float), np.asarray(target, float), np.array([0.0, 0.0, 1.0]), xp=np))


def _cube_mesh(half):
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float) * half
    return data.Mesh(vertices=corners)


# Four objects on a desk (world z up), each (position, yaw deg, half extents m).
OBJECTS = {
    1: ([0.0, 0.0, 0.03], 10.0, [0.04, 0.03, 0.03]),
    5: ([0.15, 0.05, 0.05], -20.0, [0.03, 0.03, 0.05]),
    6: ([-0.1, 0.12, 0.04], 45.0, [0.05, 0.02, 0.04]),
    8: ([0.05, -0.15, 0.06], 0.0, [0.06, 0.04, 0.06]),
}


def _synthetic_scene(moves=None, frames=8):
    """A BopScene built in memory: a camera circling the desk; ``moves`` = {frame index: {obj_id:
    new world position}} applies from that frame on."""
    meshes = {i: _cube_mesh(np.array(h)) for i, (_, _, h) in OBJECTS.items()}
    world = {i: (np.array(p), _rot(2, yaw)) for i, (p, yaw, _) in OBJECTS.items()}
    out, cams = [], []
    for t in range(frames):
        for i, pos in (moves or {}).get(t, {}).items():
            world[i] = (np.array(pos), world[i][1])
        a = np.radians(-90 + 8 * t)
        cTw = _look([0.6 * np.cos(a), 0.6 * np.sin(a), 0.45], [0.0, 0.0, 0.03])
        cams.append(cTw)
        objs = []
        for i, (p, R) in world.items():
            Rc, tc = cTw[:3, :3] @ R, cTw[:3, :3] @ p + cTw[:3, 3]
            objs.append(data.BopObject(i, f"c{i}", Rc, tc, tc, meshes[i].radii, np.array([0.0, 0.0, 10.0, 10.0]), 1.0))
        out.append(data.BopFrame(10 * t, K, (320, 240), None, tuple(objs)))  # type: ignore[arg-type]
    return data.BopScene(None, tuple(out), meshes), np.stack(cams)  # type: ignore[arg-type]


def test_an_object_that_moves_starts_a_new_spell_and_leaves_the_anchors():
    scene, cams = _synthetic_scene({4: {5: [0.25, 0.1, 0.05]}})
    (st,) = slam.find_stretches(scene)
    assert st.frame_ids == tuple(10 * t for t in range(8))
    assert st.anchors == (1, 6, 8)
    spells = {s.id: s.frames for s in st.spells}
    assert spells[500] == (0, 1, 2, 3) and spells[501] == (4, 5, 6, 7)
    assert spells[100] == tuple(range(8))
    # the fitted poses are the true ones up to the stretch's world frame: relative motions agree
    rel = lambda T: T[0] @ np.linalg.inv(T)  # camera t in camera 0: free of the world frame
    np.testing.assert_allclose(rel(st.camera_T_world), rel(cams), atol=1e-9)
    # the second spell's centre is where object 5 went, in the stretch's world frame
    wT0 = np.linalg.inv(st.camera_T_world[0]) @ cams[0]  # stretch world <- true world
    s501 = next(s for s in st.spells if s.id == 501)
    np.testing.assert_allclose(s501.center, wT0[:3, :3] @ [0.25, 0.1, 0.05] + wT0[:3, 3], atol=1e-9)
    np.testing.assert_allclose(s501.radii, [0.03, 0.03, 0.05])


def test_the_stretch_world_up_is_the_normal_of_the_surface_the_objects_rest_on():
    # Objects of different heights on one desk: their centres span 3 cm of height, so the plane
    # through them is tilted (the frame before stop 26); the plane through their lowest points
    # is the desk, and every object's up axis is the stretch's world z.
    scene, cams = _synthetic_scene()
    (st,) = slam.find_stretches(scene)
    ups = np.stack([s.rotation[:, 2] for s in st.spells])
    np.testing.assert_allclose(ups, np.tile([0.0, 0.0, 1.0], (len(ups), 1)), atol=1e-9)
    bottoms = [s.center[2] - s.radii[2] for s in st.spells]
    np.testing.assert_allclose(bottoms, bottoms[0], atol=1e-9)


def test_a_stretch_ends_when_fewer_than_three_objects_stay():
    moves = {5: {1: [0.3, 0.3, 0.03], 5: [-0.3, 0.2, 0.05]}}  # two of four move: two stay
    scene, _ = _synthetic_scene(moves, frames=10)
    first, second = slam.find_stretches(scene, min_frames=3)
    assert first.frame_ids == (0, 10, 20, 30, 40) and second.frame_ids == (50, 60, 70, 80, 90)
    with pytest.raises(ValueError, match="min_objects"):
        slam.find_stretches(scene, min_objects=2)


def test_camera_from_anchors_recovers_a_constructed_pose_and_drops_a_moved_object():
    scene, cams = _synthetic_scene()
    frame = scene.frames[3]
    # world corners of every object from the true world poses
    world = {}
    for o in scene.frames[0].objects:
        wTc = np.linalg.inv(cams[0])
        mesh = scene.meshes[o.obj_id]
        local = mesh.center + np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) * mesh.radii
        world[o.obj_id] = (local @ o.rotation.T + o.translation) @ wTc[:3, :3].T + wTc[:3, 3]
    world[8] = world[8] + [0.1, 0.0, 0.0]  # object 8 "moved" since
    T, kept, rms = camera_from_anchors(world, frame, scene, tol_m=0.01)
    assert kept == (1, 5, 6) and rms < 1e-9
    np.testing.assert_allclose(T, cams[3], atol=1e-9)


def test_fit_rigid_transform_against_a_known_transform_and_weights():
    rng = np.random.default_rng(0)
    P = rng.normal(size=(6, 3))
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = _rot(0, 30) @ _rot(2, -70), [0.3, -1.0, 2.0]
    Q = P @ T[:3, :3].T + T[:3, 3]
    np.testing.assert_allclose(q.fit_rigid_transform(P, Q, xp=np), T, atol=1e-12)
    np.testing.assert_allclose(np.asarray(q.fit_rigid_transform(P, Q)), T, atol=1e-5)
    Q_bad = Q.copy()
    Q_bad[0] += 5.0  # weight zero: ignored
    w = np.r_[0.0, np.ones(5)]
    np.testing.assert_allclose(q.fit_rigid_transform(P, Q_bad, w, xp=np), T, atol=1e-12)
    with pytest.raises(ValueError, match="weights"):
        q.fit_rigid_transform(P, Q, -w, xp=np)


def test_odometry_without_noise_is_exact_and_with_noise_starts_at_the_truth():
    _, cams = _synthetic_scene()
    zero = OdometryModel(0.0, 0.0, 0.0, 0.0)
    np.testing.assert_allclose(odometry_poses(cams, zero, np.random.default_rng(0)), cams, atol=1e-12)
    noisy = odometry_poses(cams, OdometryModel(), np.random.default_rng(0))
    np.testing.assert_allclose(noisy[0], cams[0])
    off = np.linalg.norm(np.linalg.inv(noisy[-1])[:3, 3] - np.linalg.inv(cams[-1])[:3, 3])
    assert 0 < off < 0.05
    with pytest.raises(ValueError, match="drift_translation"):
        OdometryModel(drift_translation=-1.0)


def test_user_class_table_is_seeded_and_within_the_stated_factors():
    ext = {"duck": [0.1, 0.08, 0.09], "can": [0.1, 0.18, 0.19]}
    table, factors = slam.user_class_table(ext, seed=27)
    again, _ = slam.user_class_table(ext, seed=27)
    assert table == again and table.names == ("can", "duck")
    for name, f in factors.items():
        assert 0.8 <= f <= 1.25
        row = table.get(name)
        np.testing.assert_allclose(row.dimensions, f * np.asarray(ext[name]))
        np.testing.assert_allclose(row.sigma, 0.3 * np.asarray(row.dimensions))


def test_stretch_sequence_never_carries_object_poses_and_drops_single_views(tmp_path):
    scene, _ = _synthetic_scene({4: {5: [0.25, 0.1, 0.05]}})
    frames = []
    for f in scene.frames:  # boxes from the core's projection of each object's corners
        objs = []
        for o in f.objects:
            pts = (
                o.center
                + (np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) * o.radii) @ o.rotation.T
            )
            uv, _ = q.project_points(pts, K, np.eye(4), xp=np)
            box = np.r_[uv.min(0), uv.max(0)]
            objs.append(data.BopObject(o.obj_id, o.class_name, o.rotation, o.translation, o.center, o.radii, box, 1.0))
        frames.append(
            data.BopFrame(f.frame_id, K, f.image_size, tmp_path / "rgb" / f"{f.frame_id:06d}.png", tuple(objs))
        )
    scene = data.BopScene(tmp_path, tuple(frames), scene.meshes)
    (st,) = slam.find_stretches(scene)
    table, _ = slam.user_class_table({f"c{i}": 2 * np.array(h) for i, (_, _, h) in OBJECTS.items()})
    seq, odo = slam.stretch_sequence(st, table, seed=1, min_views=5)
    assert set(seq.object_ids) == {100, 600, 800}  # both spells of object 5 have 4 views only
    assert odo.shape == (7, 4, 4)
    np.testing.assert_allclose(
        odo[2], q.relative_pose(seq.frames[2].camera_T_world, seq.frames[3].camera_T_world, xp=np)
    )
    assert seq.frames[0].image == "rgb/000000.png"
    assert all(np.all(np.isnan(f.texture_depth)) for f in seq.frames)
    missed, _ = slam.stretch_sequence(st, table, setting="missed", seed=1, miss_rate=0.5, min_views=1)
    assert sum(len(f.ids) for f in missed.frames) < 8 * 4
    with pytest.raises(ValueError, match="setting"):
        slam.stretch_sequence(st, table, setting="dirty")
    with pytest.raises(ValueError, match="classes"):
        slam.stretch_sequence(st, slam.user_class_table({"c1": [0.1, 0.1, 0.1]})[0])


def test_texture_plane_fraction_moves_the_plane_from_the_tangent_to_the_centre():
    pose = np.eye(4)
    R, c, r = np.eye(3), np.array([0.0, 0.0, 1.0]), np.array([0.1, 0.1, 0.3])
    for frac, depth in ((1.0, 0.7), (2.0 / 3.0, 0.8), (0.0, 1.0)):
        res = F.texture_residual(pose, R, c, r, depth, 0.01, frac)
        assert abs(float(res)) < 1e-5
    np.testing.assert_allclose(F.texture_residual(pose, R, c, r, 0.75, 0.01), -5.0, rtol=1e-5)  # default: tangent


def _textured_plane_pair(shift_px):
    import cv2

    rng = np.random.default_rng(3)
    base = rng.uniform(0, 255, (60, 80)).astype(np.float32)
    tex = cv2.GaussianBlur(cv2.resize(base, (320, 240), interpolation=cv2.INTER_CUBIC), (5, 5), 1.0)
    a = np.stack([np.clip(tex, 0, 255).astype(np.uint8)] * 3, -1)
    b = np.roll(a, -shift_px, axis=1)
    return a, b


@pytest.mark.parametrize("matcher", ["lk", "orb"])
def test_front_end_takes_a_trackers_ids_and_measures_a_fronto_parallel_plane(matcher):
    # a textured plane at z = 1 m; the camera moves 4 cm along x: the image moves 20 px left
    a, b = _textured_plane_pair(20)
    pose_a = np.eye(4)
    pose_b = np.eye(4)
    pose_b[0, 3] = -0.04  # camera_T_world of a camera at x = +0.04
    fe = FrontEnd(K, slam.FrontEndConfig(matcher=matcher, min_baseline=0.01, max_depth_variance=0.01))
    box_a, box_b = np.array([[100.0, 60.0, 220.0, 180.0]]), np.array([[80.0, 60.0, 200.0, 180.0]])
    (first,) = fe.process(a, pose_a, box_a, ["duck"], track_ids=[7])
    assert first.landmark_id == 7 and first.texture_status == "new_landmark"
    (second,) = fe.process(b, pose_b, box_b, ["duck"], track_ids=[7])
    assert second.landmark_id == 7 and second.texture_status == "ok", second
    assert second.texture_depth == pytest.approx(1.0, abs=0.02)
    with pytest.raises(ValueError, match="track_ids"):
        fe.process(b, pose_b, box_b, ["duck"], track_ids=[-1])


def _write_tiny_bop(root):
    """A BOP scene folder: three cuboids on a desk, 8 frames of a circling camera, in mm."""
    scene = root / "lmo" / "test" / "000002"
    (scene / "models").mkdir(parents=True)
    (scene / "rgb").mkdir()
    gt = {}
    sel = {i: OBJECTS[i] for i in (1, 5, 6, 8)}
    for i, (_, _, h) in sel.items():
        corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float) * np.array(h) * 1e3
        # a dense point cloud on the cuboid's faces (the visible-box splat needs ~1 px spacing)
        g = np.linspace(-1, 1, 41)
        pts = []
        for ax in range(3):
            u, v = [k for k in range(3) if k != ax]
            U, V = np.meshgrid(g, g)
            for s in (-1, 1):
                p = np.zeros((U.size, 3))
                p[:, ax], p[:, u], p[:, v] = s, U.ravel(), V.ravel()
                pts.append(p * np.array(h) * 1e3)
        pts = np.concatenate(pts + [corners])
        head = f"ply\nformat ascii 1.0\nelement vertex {len(pts)}\nproperty float x\nproperty float y\nproperty float z\nend_header\n"
        (scene / "models" / f"obj_{i:06d}.ply").write_text(
            head + "\n".join(" ".join(f"{x:.3f}" for x in p) for p in pts) + "\n"
        )
    for t in range(8):
        a = np.radians(-90 + 8 * t)
        cTw = _look([0.6 * np.cos(a), 0.6 * np.sin(a), 0.45], [0.0, 0.0, 0.03])
        rows = []
        for i, (p, yaw, _) in sel.items():
            R = cTw[:3, :3] @ _rot(2, yaw)
            tt = cTw[:3, :3] @ np.array(p) + cTw[:3, 3]
            rows.append({"obj_id": i, "cam_R_m2c": R.ravel().tolist(), "cam_t_m2c": (tt * 1e3).tolist()})
        gt[str(t)] = rows
    (scene / "scene_gt.json").write_text(json.dumps(gt))
    cam = {"fx": 500.0, "fy": 500.0, "cx": 160.0, "cy": 120.0, "width": 320, "height": 240}
    (scene / "camera.json").write_text(json.dumps(cam))
    return scene


@pytest.mark.slow
def test_end_to_end_roshan_on_a_tiny_bop_scene(tmp_path):
    scene = data.load_bop_scene(_write_tiny_bop(tmp_path), class_names={i: f"c{i}" for i in OBJECTS})
    (st,) = slam.find_stretches(scene)
    table, _ = slam.user_class_table(vdata.bop_class_extents(scene), low=1.0, high=1.0)
    seq, odo = slam.stretch_sequence(st, table, seed=0, box_sigma=0.5)
    slot = {i: j for j, i in enumerate(seq.object_ids)}
    rows = [(t, slot[i], b) for t, f in enumerate(seq.frames) for i, b in zip(f.ids, f.boxes)]
    problem = slam.make_problem(
        seq.K,
        seq.image_size,
        np.stack([f.camera_T_world for f in seq.frames]),
        np.stack([b for _, _, b in rows]),
        [t for t, _, _ in rows],
        [j for _, j, _ in rows],
        list(seq.object_classes),
        classes=table,
        odometry=odo,
    )
    # The desk frame's up is the cuboids' own (the plane they rest on), so every object starts
    # upright at heading 0 and the solve spends its last ~50 steps turning the headings along a
    # flat valley (cost 215.5 -> 215.0): 146 steps, past the default 100.
    config = slam.SolverConfig(noise=slam.noise_model(seq), unfixable_rms=10.0, max_steps=200)
    est, info = solve_schur(problem, slam.initialize(problem, config), config)
    assert bool(info.success)
    truth = {o["id"]: o for o in seq.truth["objects"]}
    err = np.array([np.linalg.norm(np.asarray(est.center)[slot[i]] - truth[i]["center"]) for i in seq.object_ids])
    # cuboids seen as ellipsoids inscribed in them: the boxes agree to a few pixels
    assert np.median(err) < 0.02, err


@pytest.mark.slow
def test_roshan_command_names_the_stretch_flag_and_shows_the_layouts(tmp_path, run_cli):
    scene = _write_tiny_bop(tmp_path)
    status, _, err = run_cli(["roshan", "--bop", str(scene), "--stretch", "5", "--out", str(tmp_path / "out")])
    assert status == 2 and "--stretch" in err and "1 stretches" in err and "Traceback" not in err
    status, out, _ = run_cli(["roshan", "--help"])
    assert status == 0 and "--bop" in out and "groundtruth.txt" in out and "scene_gt.json" in out


@pytest.mark.slow
def test_heading_starts_keep_per_object_the_start_with_the_lowest_cost():
    # a small toy map: the heading starts end no worse than the single start on the total cost
    problem, _ = slam.toy_map(0, num_objects=3, num_frames=10)
    config = slam.SolverConfig()
    # the initialisation and the cost jitted (op by op they compiled some hundreds of small
    # programs); solve_yaw_starts's final joint solve reuses the compiled single solve
    init = jax.jit(slam.initialize)(problem, config)
    single, _ = solve_schur(problem, init, config)
    est, info, start = solve_yaw_starts(problem, init, config, yaws_deg=(0.0, 90.0))
    J = problem.object_class.shape[0]
    assert start.shape == (J,) and set(np.asarray(start).tolist()) <= {0, 1}
    total_cost = jax.jit(lambda e: slam.total_cost(problem, e, config))
    cost = lambda e: float(total_cost(e))
    assert np.isfinite(cost(est)) and cost(est) <= cost(single) * 1.05
    with pytest.raises(ValueError, match="yaws_deg"):
        solve_yaw_starts(problem, init, config, yaws_deg=())


def test_pose_prior_weights_follow_the_stated_drift():
    rng = np.random.default_rng(3)
    T = 12
    cams = np.stack([np.eye(4)] * T)
    cams[:, 0, 3] = -0.05 * np.arange(T)  # the camera moves 5 cm along x per step
    model = OdometryModel()
    assert np.all(pose_prior_weights(cams, "all") == 1.0)
    first = pose_prior_weights(cams, "first", model, prior_translation=0.02, prior_rotation_deg=1.0)
    assert np.all(first[1:] == 0) and np.all(first[0] > 1)  # tighter than 2 cm / 1 deg
    drift = pose_prior_weights(cams, "drift", model, prior_translation=0.02, prior_rotation_deg=1.0)
    assert np.all(np.diff(drift, axis=0) < 0)  # looser at every step
    # after 11 steps the stated model's spread: sampled drifts agree with the weight's sigma
    ends = np.stack([odometry_poses(cams, model, rng)[-1] for _ in range(400)])
    centres = np.einsum("nji,nj->ni", ends[:, :3, :3], -ends[:, :3, 3])
    spread = np.sqrt(np.mean(np.sum((centres - centres.mean(0)) ** 2, axis=1)) / 3)
    assert 0.02 / drift[-1, 0] == pytest.approx(spread, rel=0.35)
    with pytest.raises(ValueError, match="mode"):
        pose_prior_weights(cams, "none")
    with pytest.raises(ValueError, match="poses"):
        pose_prior_weights(cams[0])
