"""VoluMon-initialised ROSHAN (thesis 6.3): the Frame's initial-ellipsoid hook of the online
smoother, the world-frame glue of VoluMon's prediction, the stereo view renderer."""

import jax
import numpy as np
import pytest

from jaxsem import mapping, quadrics, slam, volumon
from jaxsem.slam._toy import frames_from_problem  # layers: white-box

CAP_D = 4
# one solver setting and smoother schedule for every test: the online step compiles once
CFG = slam.SolverConfig(max_steps=100)
SCHEDULE = dict(optimize_every=3, iterations=2)


@pytest.fixture(scope="module")
def toy():
    problem, truth = slam.toy_map(3, num_objects=3, num_frames=12, path="forward")
    frames = frames_from_problem(problem, max_detections=CAP_D)
    cap = slam.Capacity(max_poses=12, max_objects=3, max_boxes=int(problem.box.shape[0]) + 2, max_detections=CAP_D)
    return problem, truth, frames, cap


def _frame(problem, t, **init):
    """Frame ``t`` of the toy problem, with optional initial ellipsoids per detection."""
    sel = np.asarray(problem.box_mask) & (np.asarray(problem.box_pose) == t)
    obj = np.asarray(problem.box_object)[sel]
    td = np.where(np.asarray(problem.texture_mask)[sel], np.asarray(problem.texture_depth)[sel], np.nan)
    frame = slam.make_frame(
        np.asarray(problem.pose_prior[t]),
        np.asarray(problem.box)[sel],
        np.asarray(problem.object_class)[obj],
        obj,
        td,
        max_detections=CAP_D,
        dtype=problem.K.dtype,
        **{k: (v(obj) if callable(v) else v) for k, v in init.items()},
    )
    return frame, obj


def _first_with_detections(problem):
    return int(np.min(np.asarray(problem.box_pose)[np.asarray(problem.box_mask)]))


@pytest.mark.slow
def test_new_object_starts_at_its_given_ellipsoid_and_others_as_before(toy, compiles):
    problem, truth, _, cap = toy
    t = _first_with_detections(problem)
    plain, obj = _frame(problem, t)
    assert len(obj) >= 2
    # an arbitrary, clearly different ellipsoid for the first detection only
    R = np.asarray(quadrics.look_at(np.zeros(3), np.array([1.0, 2.0, 0.5]), np.array([0.0, 0.0, 1.0])))[:3, :3].T
    given = dict(
        init_rotation=lambda o: np.broadcast_to(R, (len(o), 3, 3)),
        init_center=lambda o: np.asarray(truth.center)[o] + np.array([0.3, -0.2, 0.1]),
        init_radii=lambda o: np.tile([0.7, 1.1, 0.4], (len(o), 1)),
        init_mask=lambda o: np.arange(len(o)) == 0,
    )
    seeded, _ = _frame(problem, t, **given)
    # no optimisation in the first two frames (every 3rd): the estimate is the initialisation itself
    state0 = slam.online_init(CFG, cap, problem.K, problem.image_size, **SCHEDULE)
    with compiles() as c:
        a = slam.online_update(state0, plain).estimate
        b = slam.online_update(state0, seeded).estimate
    assert c.count <= 1  # frames with and without inits: one program
    j0, j1 = int(obj[0]), int(obj[1])
    np.testing.assert_allclose(b.rotation[j0], R, atol=1e-12)
    np.testing.assert_allclose(b.center[j0], np.asarray(truth.center)[j0] + [0.3, -0.2, 0.1], atol=1e-12)
    np.testing.assert_allclose(b.radii[j0], [0.7, 1.1, 0.4], atol=1e-12)
    assert not np.allclose(a.center[j0], b.center[j0], atol=1e-3)
    # the detection without an initial ellipsoid: ROSHAN's single-view init, exactly as before
    for x, y in ((a.rotation, b.rotation), (a.center, b.center), (a.radii, b.radii)):
        np.testing.assert_array_equal(np.asarray(x)[j1], np.asarray(y)[j1])
    # an object that already exists ignores a later initial ellipsoid
    st = slam.online_update(state0, seeded)
    later, obj2 = _frame(problem, t + 1, **{**given, "init_mask": lambda o: np.ones(len(o), bool)})
    kept = [int(j) for j in obj2 if int(j) == j0]
    if kept:
        st2 = slam.online_update(st, later)
        np.testing.assert_array_equal(np.asarray(st2.estimate.center)[j0], np.asarray(st.estimate.center)[j0])


@pytest.mark.slow
def test_true_ellipsoid_as_init_stays_near_truth(toy):
    problem, truth, _, cap = toy
    R, c, r = (np.asarray(x) for x in (truth.rotation, truth.center, truth.radii))
    state = slam.online_init(CFG, cap, problem.K, problem.image_size, **SCHEDULE)
    seen = set()
    for t in range(int(problem.pose_prior.shape[0])):
        frame, _ = _frame(
            problem,
            t,
            init_rotation=lambda o: R[o],
            init_center=lambda o: c[o],
            init_radii=lambda o: r[o],
            init_mask=lambda o: np.array([int(j) not in seen for j in o], bool),
        )
        seen.update(int(j) for j in np.asarray(frame.object_id)[np.asarray(frame.box_mask)])
        state = slam.online_update(state, frame)
    est = slam.online_estimate(state)  # optimised every 3 frames
    pos = np.linalg.norm(np.asarray(est.center) - c, axis=-1)
    shape = np.linalg.norm(np.sort(np.asarray(est.radii), -1) - np.sort(r, -1), axis=-1)
    # the toy's measurements are noisy (2 px boxes, 0.1 m texture depth), so "near" is decimetres
    # on 5 m cars: the boxes and texture planes must not pull a true start away
    assert np.all(pos < 0.5), pos
    assert np.all(shape < 0.5), shape


def test_frame_init_arguments_are_checked(toy):
    problem, *_ = toy
    t = _first_with_detections(problem)
    with pytest.raises(ValueError, match="init_rotation, init_center, init_radii"):
        _frame(problem, t, init_center=lambda o: np.zeros((len(o), 3)))
    with pytest.raises(ValueError, match="init_radii"):
        _frame(
            problem,
            t,
            init_rotation=lambda o: np.broadcast_to(np.eye(3), (len(o), 3, 3)),
            init_center=lambda o: np.zeros((len(o), 3)),
            init_radii=lambda o: np.full((len(o), 3), -1.0),
        )
    with pytest.raises(ValueError, match="init_center"):
        _frame(
            problem,
            t,
            init_rotation=lambda o: np.broadcast_to(np.eye(3), (len(o), 3, 3)),
            init_center=lambda o: np.full((len(o), 3), np.nan),
            init_radii=lambda o: np.ones((len(o), 3)),
        )
    f, _ = _frame(problem, t)
    with pytest.raises(ValueError, match="init_mask"):
        slam.Frame(**{**{k: getattr(f, k) for k in f.__dataclass_fields__}, "init_mask": np.zeros(CAP_D + 1, bool)})


@pytest.fixture(scope="module")
def shipped():
    model, variables, config, _ = volumon.load_pretrained()
    return model, variables, config


@pytest.mark.slow
def test_volumon_world_ellipsoids_reproject_to_the_camera_frame_prediction(shipped, compiles):
    model, variables, config = shipped
    scene = config.scene
    K = np.asarray(scene.K(), np.float64)
    R_obj = np.asarray(quadrics.random_rotation(jax.random.key(4)))
    view = volumon.render_object_stereo(
        R_obj, [0.05, -0.02, 0.7], [0.08, 0.1, 0.035], 0, K, scene.baseline, scene.height, scene.width, seed=3
    )
    # the mask lies inside the exact box of the rendered shape
    rows, cols = np.nonzero(np.asarray(view.mask))
    box = np.asarray(view.box_left, np.float64)
    assert cols.min() >= box[0] - 0.5 and cols.max() <= box[2] + 0.5
    assert rows.min() >= box[1] - 0.5 and rows.max() <= box[3] + 0.5
    # a camera away from the world origin, looking at the object
    eye, target = np.array([1.0, -2.0, 0.8]), np.array([1.5, -1.0, 0.6])
    camera_T_world = np.asarray(quadrics.look_at(eye, target, np.array([0.0, 0.0, 1.0])))
    (R, c, r), ok = mapping.volumon_initial_ellipsoids(
        model, variables, config, np.asarray(view.left), box[None], 0, quadrics.Camera(K, camera_T_world)
    )
    assert bool(ok[0])
    # independent reference: the network's camera-frame ellipsoid through the public predictor
    local, glob = volumon.prepare_inputs(
        np.asarray(view.left), box[None], config.model.input_size, config.model.global_padding
    )
    predict = volumon.make_predict_fn(model, config)
    _, ell, _ = predict(
        variables, local, glob, box[None].astype(np.float32), K[None].astype(np.float32), np.zeros(1, np.int32)
    )
    ell64 = [np.asarray(x[0], np.float64) for x in (ell.rotation, ell.center, ell.radii)]  # the network's float32
    box_cam, _ = quadrics.project_bbox(*ell64, K, np.eye(4))
    box_world, valid = quadrics.project_bbox(R[0], c[0], r[0], K, camera_T_world)
    assert bool(valid)
    np.testing.assert_allclose(np.asarray(box_world), np.asarray(box_cam), atol=2e-2)
    np.testing.assert_allclose(np.asarray(r[0]), np.asarray(ell.radii[0]), rtol=1e-5)
    # the world centre seen from the camera is the camera-frame centre
    back = quadrics.transform_points(camera_T_world, c[0])
    np.testing.assert_allclose(np.asarray(back), np.asarray(ell.center[0]), atol=1e-5)
    # a second call with new values compiles nothing
    with compiles() as c:
        view2 = volumon.render_object_stereo(
            R_obj, [-0.05, 0.03, 0.9], [0.08, 0.1, 0.035], 0, K, scene.baseline, scene.height, scene.width, seed=4
        )
        box2 = np.asarray(view2.box_left, np.float64)[None]
        out = mapping.volumon_initial_ellipsoids(
            model, variables, config, np.asarray(view2.left), box2, 0, quadrics.Camera(K, camera_T_world.copy())
        )
        jax.block_until_ready(out)
    assert c.count == 0
    with pytest.raises(ValueError, match="class_id"):
        mapping.volumon_initial_ellipsoids(
            model, variables, config, np.asarray(view.left), box[None], 9, quadrics.Camera(K, camera_T_world)
        )
    with pytest.raises(ValueError, match="camera_T_world"):
        mapping.volumon_initial_ellipsoids(
            model, variables, config, np.asarray(view.left), box[None], 0, quadrics.Camera(K, np.eye(3))
        )
    with pytest.raises(ValueError, match=r"camera: expected a jaxsem\.quadrics\.Camera"):
        mapping.volumon_initial_ellipsoids(model, variables, config, np.asarray(view.left), box[None], 0, K)
