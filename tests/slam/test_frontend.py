"""Tests of the OpenCV front end (thesis 4.5.1) on tiny MuJoCo-rendered sequences.

The scenes are textured boxes (random-dot cube textures, so ORB finds corners) rendered headless
with ``MUJOCO_GL=egl`` at 320x240. References are independent of the code under test: the
rendered z-depth of the object's pixels for the texture plane, the rendering's segmentation for
boxes and identities, ``cv2.triangulatePoints`` for the DLT.
"""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")

import cv2
import numpy as np
import pytest

import jaxsem.slam._frontend_vision as fe_mod  # layers: white-box (the projection cache, one test)
from jaxsem.slam import FrontEndConfig
from jaxsem.slam._frontend import FrontEnd, to_frame  # layers: white-box
from jaxsem.slam._frontend_types import AssociatedDetection, LandmarkEstimates  # layers: white-box
from jaxsem.slam._frontend_vision import triangulate_points  # layers: white-box

mujoco = pytest.importorskip("mujoco")

WIDTH, HEIGHT, FOVY = 320, 240, 60.0
COLORS = {"red": (0.8, 0.15, 0.1), "blue": (0.1, 0.2, 0.8), "green": (0.15, 0.7, 0.2)}
MARKS = {"red": (1.0, 0.9, 0.3), "blue": (0.5, 1.0, 1.0), "green": (0.9, 1.0, 0.5)}


# --------------------------------------------------------------------------------------------
# A tiny renderer: textured boxes on a ground plane, a camera looking along +y.


def _scene_xml(objects):
    assets, geoms = [], []
    for i, (name, color, pos, half, yaw_deg) in enumerate(objects):
        rgb = " ".join(f"{c:g}" for c in COLORS[color])
        mark = " ".join(f"{c:g}" for c in MARKS[color])
        # a coarse random-dot texture: each texel covers a few pixels, so corners survive
        assets.append(
            f'<texture name="t{i}" type="cube" builtin="flat" mark="random" random="0.3" '
            f'rgb1="{rgb}" rgb2="{rgb}" markrgb="{mark}" width="20" height="20"/>'
            f'<material name="m{i}" texture="t{i}"/>'
        )
        p = " ".join(f"{c:g}" for c in pos)
        s = " ".join(f"{c:g}" for c in half)
        geoms.append(f'<geom name="{name}" type="box" pos="{p}" size="{s}" euler="0 0 {yaw_deg:g}" material="m{i}"/>')
    return f"""
<mujoco>
  <compiler angle="degree"/>
  <visual><global offwidth="{WIDTH}" offheight="{HEIGHT}"/>
    <headlight ambient="0.5 0.5 0.5" diffuse="0.5 0.5 0.5"/></visual>
  <asset>{"".join(assets)}
    <texture name="tg" type="2d" builtin="checker" rgb1="0.5 0.5 0.5" rgb2="0.55 0.55 0.55"
      width="64" height="64"/>
    <material name="mg" texture="tg" texrepeat="10 10"/>
  </asset>
  <worldbody>
    <geom name="ground" type="plane" size="20 20 0.1" material="mg"/>
    {"".join(geoms)}
    <camera name="cam" pos="0 -3 0.5" fovy="{FOVY:g}"/>
  </worldbody>
</mujoco>"""


def render_sequence(objects, cam_positions):
    """objects: [(name, colour, centre, half sizes, yaw deg)]; camera looks along world +y.

    Returns dict(rgb (N,H,W,3) uint8, depth (N,H,W) z-depth, seg (N,H,W) geom ids,
    poses (N,4,4) camera_T_world, K (3,3), ids {name: geom id}).
    """
    model = mujoco.MjModel.from_xml_string(_scene_xml(objects))
    data = mujoco.MjData(model)
    # OpenCV camera axes in the world: x = world x, y = -world z, z = world y
    R_cv = np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]])
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, (R_cv @ np.diag([1.0, -1, -1])).reshape(-1))
    renderer = mujoco.Renderer(model, HEIGHT, WIDTH)
    out = {"rgb": [], "depth": [], "seg": [], "poses": []}
    try:
        for position in cam_positions:
            model.cam_pos[0] = position
            model.cam_quat[0] = quat
            mujoco.mj_forward(model, data)
            R = data.cam_xmat[0].reshape(3, 3) @ np.diag([1.0, -1, -1])
            T = np.eye(4)
            T[:3, :3] = R.T
            T[:3, 3] = -R.T @ data.cam_xpos[0]
            renderer.update_scene(data, camera=0)
            out["rgb"].append(renderer.render().copy())
            renderer.enable_depth_rendering()
            renderer.update_scene(data, camera=0)
            out["depth"].append(renderer.render().copy())
            renderer.disable_depth_rendering()
            renderer.enable_segmentation_rendering()
            renderer.update_scene(data, camera=0)
            out["seg"].append(renderer.render()[..., 0].copy())
            renderer.disable_segmentation_rendering()
            out["poses"].append(T)
    finally:
        renderer.close()
    out = {k: np.stack(v) for k, v in out.items()}
    f = 0.5 * HEIGHT / np.tan(np.deg2rad(FOVY) / 2)
    out["K"] = np.array([[f, 0, (WIDTH - 1) / 2], [0, f, (HEIGHT - 1) / 2], [0, 0, 1.0]])
    out["ids"] = {o[0]: mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, o[0]) for o in objects}
    out["objects"] = {o[0]: o for o in objects}
    return out


def seg_box(seg, geom_id, margin=2):
    """Tight box of a geom's pixels, or None if absent or touching the image border."""
    ys, xs = np.nonzero(seg == geom_id)
    if xs.size == 0:
        return None
    box = np.array([xs.min(), ys.min(), xs.max(), ys.max()], dtype=float)
    if box[0] < margin or box[1] < margin or box[2] > WIDTH - 1 - margin or box[3] > HEIGHT - 1 - margin:
        return None
    return box


def detections(seq, frame, names=None):
    """Boxes of the fully visible objects (from segmentation) and their names."""
    boxes, found = [], []
    for name, gid in seq["ids"].items():
        if names is not None and name not in names:
            continue
        box = seg_box(seq["seg"][frame], gid)
        if box is not None:
            boxes.append(box)
            found.append(name)
    return np.array(boxes).reshape(-1, 4), found


def check_rendered_depth(det, depth, mask, rtol, where) -> float:
    """A detection's texture plane is measured (status ok) at the median rendered depth of its
    object's pixels ``mask``, to ``rtol``; ``where`` (a tuple) names the case in a failure.
    Returns that rendered depth."""
    rendered = float(np.median(depth[mask]))
    assert det.texture_status == "ok", (*where, det)
    assert abs(det.texture_depth - rendered) < rtol * rendered, (*where, det.texture_depth, rendered)
    return rendered


def truth_estimates(seq, name_to_id):
    """Ground-truth ellipsoids (the boxes' inscribed ellipsoids) keyed by landmark id."""
    out = {}
    for name, lid in name_to_id.items():
        _, _, centre, half, yaw = seq["objects"][name]
        c, s = np.cos(np.deg2rad(yaw)), np.sin(np.deg2rad(yaw))
        rot = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
        out[lid] = (rot, np.array(centre, float), np.array(half, float))
    return out


# Red and blue boxes in view from the start; a green one enters on the right as the camera
# moves sideways (0.15 m per frame) along x.
THREE = [
    ("red", "red", (0.0, 0.0, 0.4), (0.4, 0.3, 0.4), 0.0),
    ("blue", "blue", (1.2, 0.3, 0.35), (0.3, 0.3, 0.35), 0.0),
    ("green", "green", (2.0, 0.0, 0.3), (0.25, 0.25, 0.3), 0.0),
]
SIDEWAYS = [(-0.4 + 0.15 * i, -3.0, 0.5) for i in range(6)]


@pytest.fixture(scope="module")
def three():
    return render_sequence(THREE, SIDEWAYS)


@pytest.fixture(scope="module")
def oblong():
    # a long box turned 50 degrees: its visible surface spans about 1.5 m of depth
    objects = [("long", "red", (0.0, 0.0, 0.3), (1.0, 0.15, 0.3), 50.0)]
    return render_sequence(objects, [(-0.3 + 0.15 * i, -3.5, 0.6) for i in range(4)])


def run(seq, frontend, frames=None, names=None, estimates_fn=None):
    """Feeds frames; returns per frame a dict name -> AssociatedDetection."""
    per_frame = []
    for f in range(len(seq["poses"])) if frames is None else frames:
        boxes, found = detections(seq, f, names)
        est = estimates_fn(per_frame) if estimates_fn is not None else None
        out = frontend.process(seq["rgb"][f], seq["poses"][f], boxes, landmark_estimates=est)
        assert [o.index for o in out] == list(range(len(found)))
        per_frame.append(dict(zip(found, out)))
    return per_frame


# --------------------------------------------------------------------------------------------
# Texture plane.


def test_texture_depth_matches_rendered_front_surface(three):
    frontend = FrontEnd(three["K"])
    per_frame = run(three, frontend)
    assert set(per_frame[0]) == {"red", "blue"}
    assert all(d.texture_status == "new_landmark" and d.texture_depth is None for d in per_frame[0].values())
    checked = 0
    for f, dets in enumerate(per_frame[1:], start=1):
        for name in ("red", "blue"):
            det = dets[name]
            check_rendered_depth(det, three["depth"][f], three["seg"][f] == three["ids"][name], 0.02, (f, name))
            assert det.num_points >= 20
            # a face parallel to the image plane: the points agree to a few millimetres
            assert 0.0 <= det.texture_variance < 1e-3
            assert det.baseline == pytest.approx(0.15 * f, abs=1e-6)
            checked += 1
    assert checked == 10
    # tracks survive the whole sequence (the baseline above grows with the frame index)
    assert frontend.num_tracks(per_frame[0]["red"].landmark_id) >= 20


def test_texture_depth_on_a_forward_path_with_jittered_boxes():
    """Camera flying towards the objects (little parallax near the image centre), detector boxes
    jittered by up to 3 px: ids hold and depths stay within 3 % of the rendered ones."""
    seq = render_sequence(THREE[:2], [(0.3, -3.0 + 0.2 * i, 0.6) for i in range(6)])
    rng = np.random.default_rng(3)
    frontend = FrontEnd(seq["K"])
    for f in range(6):
        boxes, names = detections(seq, f)
        boxes = boxes + rng.uniform(-3, 3, size=boxes.shape)
        out = frontend.process(seq["rgb"][f], seq["poses"][f], boxes)
        assert [d.landmark_id for d in out] == [0, 1]
        for name, det in zip(names, out[: (0 if f == 0 else 2)]):
            check_rendered_depth(det, seq["depth"][f], seq["seg"][f] == seq["ids"][name], 0.03, (f, name))


def test_on_the_library_renderer_in_a_cluttered_scene():
    """The front end on :func:`jaxsem.data.render_views` images: block-textured ellipsoid, box and
    cylinder in front of a cluttered wall and floor (background corners inside the boxes)."""
    from jaxsem import quadrics
    from jaxsem.data import SceneObject, render_views

    f = 250.0
    K = np.array([[f, 0, (WIDTH - 1) / 2], [0, f, (HEIGHT - 1) / 2], [0, 0, 1.0]])

    def yaw(a):
        c, s = np.cos(a), np.sin(a)
        return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])

    objects = [
        SceneObject(
            "chair",
            "ellipsoid",
            np.array([0.8, 0.6, 1.0]),
            yaw(0.3),
            np.array([0.0, 0.0, 0.5]),
            1,
            np.array([0.8, 0.2, 0.1]),
        ),
        SceneObject(
            "box", "box", np.array([0.6, 0.5, 0.7]), yaw(-0.2), np.array([1.3, 0.6, 0.35]), 2, np.array([0.1, 0.3, 0.8])
        ),
        SceneObject(
            "bin",
            "cylinder",
            np.array([0.5, 0.5, 0.8]),
            np.eye(3),
            np.array([-1.2, 0.4, 0.4]),
            3,
            np.array([0.2, 0.8, 0.2]),
        ),
    ]
    R_cv = np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]])  # OpenCV camera axes (columns) in the world
    poses = []
    for i in range(5):
        T = np.eye(4)
        T[:3, :3] = R_cv.T
        T[:3, 3] = -R_cv.T @ np.array([-0.4 + 0.15 * i, -3.2, 0.7])
        poses.append(T)
    views = render_views(objects, quadrics.Camera(K, np.stack(poses)), WIDTH, HEIGHT, floor_z=0.0)
    frontend = FrontEnd(K)
    for t in range(5):
        boxes = np.array([seg_box(views["seg"][t], j) for j in range(3)])
        out = frontend.process(views["rgb"][t], poses[t], boxes)
        assert [d.landmark_id for d in out] == [0, 1, 2]
        if t == 0:
            continue
        for j, det in enumerate(out):
            obj = objects[j]
            rendered = check_rendered_depth(det, views["depth"][t], views["seg"][t] == j, 0.03, (t, obj.shape))
            tangent, valid = quadrics.texture_plane_depth(obj.rotation, obj.center, obj.extents / 2, poses[t])
            assert bool(valid)
            # the points lie on the surface, behind (or on) the tangent plane of eq. 4.11
            assert det.texture_depth > float(tangent) - 0.01 * rendered


def test_partial_occlusion_keeps_ids_and_depths():
    """A near red box passes in front of a far blue one: the boxes overlap, the blue one's
    occluded corners are lost by the tracker, and neither id nor depth is confused."""
    objects = [
        ("red", "red", (0.3, -0.8, 0.35), (0.2, 0.2, 0.35), 0.0),
        ("blue", "blue", (0.0, 0.8, 0.5), (0.5, 0.3, 0.5), 0.0),
    ]
    seq = render_sequence(objects, [(-1.0 + 0.2 * i, -3.0, 0.6) for i in range(8)])
    frontend = FrontEnd(seq["K"])
    overlapped = 0
    for f in range(8):
        boxes, names = detections(seq, f)
        assert names == ["red", "blue"]
        overlap = min(boxes[0, 2], boxes[1, 2]) - max(boxes[0, 0], boxes[1, 0])
        overlapped += overlap > 10
        out = frontend.process(seq["rgb"][f], seq["poses"][f], boxes)
        assert [d.landmark_id for d in out] == [0, 1]
        for name, det in zip(names, out[: (0 if f == 0 else 2)]):
            check_rendered_depth(det, seq["depth"][f], seq["seg"][f] == seq["ids"][name], 0.02, (f, name))
    assert overlapped >= 3


def test_short_baseline_rejected_with_stationary_camera(three):
    frontend = FrontEnd(three["K"])
    boxes, _ = detections(three, 0)
    frontend.process(three["rgb"][0], three["poses"][0], boxes)
    out = frontend.process(three["rgb"][0], three["poses"][0], boxes)
    assert [d.texture_status for d in out] == ["short_baseline"] * 2
    assert all(d.texture_depth is None and d.baseline == 0.0 for d in out)
    assert [d.landmark_id for d in out] == [0, 1]


def test_short_baseline_threshold_is_configurable(three):
    frontend = FrontEnd(three["K"], FrontEndConfig(min_baseline=0.5))
    per_frame = run(three, frontend, names=("red",))
    statuses = [per_frame[f]["red"].texture_status for f in range(6)]
    # 0.15 m per frame: the baseline reaches 0.5 m only from frame 4 on
    assert statuses == ["new_landmark"] + ["short_baseline"] * 3 + ["ok"] * 2
    assert per_frame[3]["red"].baseline == pytest.approx(0.45, abs=1e-6)


def test_high_variance_rejected_for_rotated_oblong_object(oblong):
    frontend = FrontEnd(oblong["K"])
    per_frame = run(oblong, frontend)
    for dets in per_frame[1:]:
        det = dets["long"]
        assert det.texture_status == "high_variance"
        assert det.texture_depth is None
        # the variance is still reported (the texture factor's sigma^2 when accepted)
        assert det.texture_variance > FrontEndConfig().max_depth_variance
    # a looser threshold accepts it, with the mean depth of the visible surface
    loose = FrontEnd(oblong["K"], FrontEndConfig(max_depth_variance=1.0))
    last = run(oblong, loose)[-1]["long"]
    assert last.texture_status == "ok"
    f = len(oblong["poses"]) - 1
    mask = oblong["seg"][f] == oblong["ids"]["long"]
    z = oblong["depth"][f][mask]
    assert z.min() < last.texture_depth < z.max()
    assert last.texture_variance == pytest.approx(np.var(z), rel=0.5)
    # the scale-free criterion rejects it too, and keeps the frontal faces of the other scene
    relative = FrontEndConfig(max_depth_variance=1.0, max_relative_depth_std=0.05)
    assert run(oblong, FrontEnd(oblong["K"], relative))[-1]["long"].texture_status == "high_variance"


def test_relative_depth_spread_keeps_frontal_faces(three):
    relative = FrontEndConfig(max_depth_variance=1.0, max_relative_depth_std=0.05)
    per_frame = run(three, FrontEnd(three["K"], relative), frames=range(3))
    assert all(per_frame[f][n].texture_status == "ok" for f in (1, 2) for n in ("red", "blue"))


def test_triangulation_matches_opencv_and_truth():
    rng = np.random.default_rng(0)
    K = np.array([[300.0, 0, 160], [0, 310.0, 120], [0, 0, 1]])
    points = rng.uniform([-1, -1, 3], [1, 1, 6], size=(50, 3))
    pose_a = np.eye(4)
    angle = 0.1
    pose_b = np.eye(4)
    pose_b[:3, :3] = cv2.Rodrigues(np.array([0.0, angle, 0.0]))[0]
    pose_b[:3, 3] = [-0.4, 0.05, 0.1]

    def project(pose):
        cam = points @ pose[:3, :3].T + pose[:3, 3]
        uv = cam @ K.T
        return uv[:, :2] / uv[:, 2:]

    uv_a, uv_b = project(pose_a), project(pose_b)
    est, ok = triangulate_points(K, pose_a, pose_b, uv_a, uv_b)
    assert ok.all()
    np.testing.assert_allclose(est, points, atol=1e-8)
    noisy_b = uv_b + rng.normal(scale=0.5, size=uv_b.shape)
    est, ok = triangulate_points(K, pose_a, pose_b, uv_a, noisy_b)
    ref = cv2.triangulatePoints(K @ pose_a[:3], K @ pose_b[:3], uv_a.T, noisy_b.T)
    ref = (ref[:3] / ref[3]).T
    # both are linear triangulations; they agree far better than either matches the truth
    assert np.median(np.linalg.norm(est - ref, axis=-1)) < 0.1 * np.median(np.linalg.norm(est - points, axis=-1))
    # per-point anchor poses broadcast
    est2, _ = triangulate_points(K, np.broadcast_to(pose_a, (50, 4, 4)), pose_b, uv_a, uv_b)
    np.testing.assert_allclose(est2, points, atol=1e-8)
    # empty input
    e, o = triangulate_points(K, pose_a, pose_b, np.zeros((0, 2)), np.zeros((0, 2)))
    assert e.shape == (0, 3) and o.shape == (0,)


# --------------------------------------------------------------------------------------------
# Data association.


def _ids(per_frame):
    return {name: [dets[name].landmark_id for dets in per_frame if name in dets] for name in ("red", "blue", "green")}


def test_association_keeps_ids_and_creates_new_landmark(three):
    frontend = FrontEnd(three["K"])
    per_frame = run(three, frontend)
    ids = _ids(per_frame)
    assert ids["red"] == [0] * 6 and ids["blue"] == [1] * 6
    # green becomes fully visible on a later frame and gets the next id, then keeps it
    first_green = min(f for f, dets in enumerate(per_frame) if "green" in dets)
    assert first_green >= 2
    assert per_frame[first_green]["green"].is_new
    assert set(ids["green"]) == {2}
    assert not any(d.is_new for dets in per_frame[1:] for n, d in dets.items() if n != "green")
    assert frontend.landmark_ids == [0, 1, 2]
    for dets in per_frame[1:]:
        for name in ("red", "blue"):
            assert dets[name].correlation > 0.9
            assert dets[name].centroid_distance < 10.0


def test_association_with_estimates_from_the_smoother(three):
    frontend = FrontEnd(three["K"])
    name_to_id = {}

    def estimates(per_frame):
        for dets in per_frame:
            for name, det in dets.items():
                name_to_id.setdefault(name, det.landmark_id)
        return truth_estimates(three, name_to_id)

    per_frame = run(three, frontend, estimates_fn=estimates)
    ids = _ids(per_frame)
    assert ids["red"] == [0] * 6 and ids["blue"] == [1] * 6 and set(ids["green"]) == {2}
    for dets in per_frame[1:]:
        # predicted from the ellipsoid: the box centre and the projected centre differ by a few px
        assert dets["red"].centroid_distance < 15.0


def test_gate_uses_the_estimates(three):
    """An estimate that projects far from the detection rules the landmark out."""
    frontend = FrontEnd(three["K"], FrontEndConfig(gate_pixels=40.0))
    boxes, names = detections(three, 0, ("red",))
    frontend.process(three["rgb"][0], three["poses"][0], boxes)
    # the red box estimated 1.5 m to the left: it projects about 110 px away
    rot, centre, half = truth_estimates(three, {"red": 0})[0]
    far = {0: (rot, centre - np.array([1.5, 0, 0]), half)}
    boxes, _ = detections(three, 1, ("red",))
    out = frontend.process(three["rgb"][1], three["poses"][1], boxes, landmark_estimates=far)
    assert out[0].is_new and out[0].landmark_id == 1
    # the right estimate associates it again
    frontend2 = FrontEnd(three["K"], FrontEndConfig(gate_pixels=40.0))
    frontend2.process(three["rgb"][0], three["poses"][0], detections(three, 0, ("red",))[0])
    near = {0: (rot, centre, half)}
    out = frontend2.process(
        three["rgb"][1], three["poses"][1], boxes, landmark_estimates=LandmarkEstimates.from_mapping(near)
    )
    assert not out[0].is_new and out[0].landmark_id == 0


def test_histogram_decides_among_gated_candidates(three):
    """With a gate wide enough for every landmark, colour alone keeps the ids right, whatever
    the order of the detections."""
    frontend = FrontEnd(three["K"], FrontEndConfig(gate_pixels=1e4))
    rng = np.random.default_rng(1)
    seen = {}
    for f in range(6):
        boxes, names = detections(three, f)
        order = rng.permutation(len(names))
        out = frontend.process(three["rgb"][f], three["poses"][f], boxes[order])
        for k, det in zip(order, out):
            seen.setdefault(names[k], set()).add(det.landmark_id)
    assert all(len(v) == 1 for v in seen.values()), seen
    assert len({next(iter(v)) for v in seen.values()}) == 3


def test_new_colour_at_a_known_position_is_a_new_landmark():
    """Same place, different colour: the histogram correlation is below threshold."""
    rng = np.random.default_rng(2)
    K = np.array([[200.0, 0, 79.5], [0, 200.0, 59.5], [0, 0, 1]])

    def image(color):
        img = np.full((120, 160, 3), 40, np.uint8)
        patch = rng.integers(0, 60, size=(50, 60, 3))
        img[30:80, 50:110] = np.clip(patch + np.array(color), 0, 255).astype(np.uint8)
        return img

    box = np.array([[50.0, 30.0, 109.0, 79.0]])
    frontend = FrontEnd(K)
    a = frontend.process(image((190, 30, 20)), np.eye(4), box)[0]
    b = frontend.process(image((190, 30, 20)), np.eye(4), box)[0]
    c = frontend.process(image((20, 40, 190)), np.eye(4), box)[0]
    assert a.is_new and not b.is_new and b.landmark_id == a.landmark_id
    assert c.is_new and c.landmark_id == 1
    # classes separate landmarks too
    d = frontend.process(image((20, 40, 190)), np.eye(4), box, class_ids=[3])[0]
    assert d.is_new and d.class_id == 3


def test_no_detections_and_missed_frames(three):
    frontend = FrontEnd(three["K"], FrontEndConfig(max_missed_frames=1))
    boxes, _ = detections(three, 0, ("red",))
    frontend.process(three["rgb"][0], three["poses"][0], boxes)
    assert frontend.num_tracks(0) > 0
    assert frontend.process(three["rgb"][1], three["poses"][1], np.zeros((0, 4))) == []
    assert frontend.num_tracks(0) > 0
    frontend.process(three["rgb"][2], three["poses"][2], [])
    assert frontend.num_tracks(0) == 0  # forgotten after max_missed_frames
    boxes, _ = detections(three, 3, ("red",))
    out = frontend.process(three["rgb"][3], three["poses"][3], boxes)[0]
    assert out.landmark_id == 0 and out.texture_status == "no_tracks"
    out = frontend.process(three["rgb"][4], three["poses"][4], detections(three, 4, ("red",))[0])[0]
    assert out.texture_status == "ok"  # re-seeded at frame 3


def test_fallback_prediction_follows_the_tracks_through_missed_frames(three):
    """Without estimates, a landmark missed for a few frames is predicted where its corners went:
    the red box moves about 11 px per frame, 45 px over the gap, beyond a 20 px gate."""
    frontend = FrontEnd(three["K"], FrontEndConfig(gate_pixels=20.0))
    frontend.process(three["rgb"][0], three["poses"][0], detections(three, 0, ("red",))[0])
    for f in (1, 2, 3):
        frontend.process(three["rgb"][f], three["poses"][f], np.zeros((0, 4)))
    boxes, _ = detections(three, 4, ("red",))
    out = frontend.process(three["rgb"][4], three["poses"][4], boxes)[0]
    first, _ = detections(three, 0, ("red",))
    assert np.linalg.norm(0.5 * (boxes[0, :2] + boxes[0, 2:] - first[0, :2] - first[0, 2:])) > 40
    assert not out.is_new and out.landmark_id == 0
    assert out.centroid_distance < 5.0
    assert out.texture_status == "ok" and out.baseline == pytest.approx(0.6, abs=1e-6)


def test_random_frames_never_give_nan():
    """Noise images, random boxes and random rigid poses (some identical, some far apart): every
    number the front end returns is finite, and rejected measurements are None."""
    rng = np.random.default_rng(4)
    K = np.array([[150.0, 0, 79.5], [0, 150.0, 59.5], [0, 0, 1]])
    frontend = FrontEnd(K, FrontEndConfig(gate_pixels=1e3, min_correlation=-1.0, min_points=3))
    base = rng.integers(0, 256, size=(120, 160, 3), dtype=np.uint8)
    statuses = set()
    for f in range(12):
        shift = rng.integers(-3, 4, size=2)
        image = np.roll(base, tuple(shift), axis=(0, 1))
        pose = np.eye(4)
        if f % 3:
            pose[:3, :3] = cv2.Rodrigues(rng.normal(scale=0.05, size=3))[0]
            pose[:3, 3] = rng.normal(scale=[0.3, 0.3, 0.3])
        corners = rng.uniform([0, 0], [120, 80], size=(3, 2))
        boxes = np.concatenate([corners, corners + rng.uniform(10, 40, size=(3, 2))], axis=1)
        for det in frontend.process(image, pose, boxes):
            statuses.add(det.texture_status)
            assert np.all(np.isfinite(det.box))
            assert np.isfinite(det.baseline)
            for value in (det.texture_depth, det.texture_variance, det.correlation, det.centroid_distance):
                assert value is None or np.isfinite(value)
            assert (det.texture_depth is None) == (det.texture_status != "ok")
    assert len(statuses) >= 3, statuses


# --------------------------------------------------------------------------------------------
# Output conversion.


def test_to_frame_and_slam_estimate_input(three):
    from jaxsem.slam import Frame, SlamEstimate

    frontend = FrontEnd(three["K"])
    frontend.process(three["rgb"][0], three["poses"][0], detections(three, 0)[0])
    boxes, names = detections(three, 1)
    truth = truth_estimates(three, {"red": 0, "blue": 1})
    est = SlamEstimate(
        camera_T_world=three["poses"][:2],
        rotation=np.stack([truth[0][0], truth[1][0]]),
        center=np.stack([truth[0][1], truth[1][1]]),
        radii=np.stack([truth[0][2], truth[1][2]]),
    )
    out = frontend.process(three["rgb"][1], three["poses"][1], boxes, class_ids=[0, 0], landmark_estimates=est)
    assert [d.landmark_id for d in out] == [0, 1]
    frame = to_frame(out, three["poses"][1], max_detections=4, max_objects=8)
    assert isinstance(frame, Frame)
    np.testing.assert_array_equal(np.asarray(frame.object_id), [0, 1, 0, 0])
    np.testing.assert_array_equal(np.asarray(frame.box_mask), [True, True, False, False])
    np.testing.assert_array_equal(np.asarray(frame.texture_mask), [True, True, False, False])
    np.testing.assert_allclose(np.asarray(frame.texture_depth)[:2], [out[0].texture_depth, out[1].texture_depth])
    np.testing.assert_allclose(np.asarray(frame.box)[:2], boxes)
    assert np.all(np.isfinite(np.asarray(frame.texture_depth)))
    with pytest.raises(ValueError, match="max_objects|object_id"):
        to_frame(out, three["poses"][1], max_detections=4, max_objects=1)
    # class names pass through to the smoother's class indices
    from jaxsem import factors

    named = FrontEnd(three["K"]).process(three["rgb"][0], three["poses"][0], boxes, class_ids=["chair", "car"])
    assert [d.class_id for d in named] == ["chair", "car"]
    frame = to_frame(named, three["poses"][0], max_detections=2)
    assert np.asarray(frame.box_class).tolist() == [factors.class_index("chair"), factors.class_index("car")]
    assert not np.asarray(frame.texture_mask).any()
    with pytest.raises(ValueError, match="class"):
        to_frame(
            FrontEnd(three["K"]).process(three["rgb"][0], three["poses"][0], boxes, class_ids=["chair", "ufo"]),
            three["poses"][0],
        )


CHAIRS = [
    ("red", "red", (0.0, 0.0, 0.45), (0.25, 0.25, 0.45), 0.0),
    ("blue", "blue", (1.0, 0.4, 0.45), (0.25, 0.25, 0.45), 0.0),
]


def test_texture_depth_places_single_view_initialisation():
    """Front end -> ROSHAN's single-view initialisation (section 4.3.5): with the measured texture
    plane, chair-sized boxes are initialised within a few centimetres of their true centres,
    where the default-depth initialisation is metres off."""
    from jaxsem import factors

    seq = render_sequence(CHAIRS, [(-0.5 + 0.15 * i, -3.0, 0.8) for i in range(4)])
    chair = factors.class_index("chair")
    mean = np.asarray(factors.shape_prior("chair").mean)
    frontend = FrontEnd(seq["K"])
    for f in range(4):
        boxes, names = detections(seq, f)
        dets = frontend.process(seq["rgb"][f], seq["poses"][f], boxes, class_ids=[chair] * len(names))
    assert all(d.texture_status == "ok" for d in dets)
    depth = np.array([d.texture_depth for d in dets])
    _, center, _ = factors.single_view_init(
        seq["poses"][3], boxes, seq["K"], mean, texture_depth=depth, default_depth=10.0
    )
    truth = np.array([o[2] for o in CHAIRS])
    assert np.all(np.linalg.norm(np.asarray(center) - truth, axis=-1) < 0.05), center
    _, far, _ = factors.single_view_init(
        seq["poses"][3], boxes, seq["K"], mean, default_depth=10.0, depth_from_box=False
    )
    assert np.all(np.linalg.norm(np.asarray(far) - truth, axis=-1) > 5.0)


@pytest.mark.slow
def test_end_to_end_with_the_online_smoother():
    """Rendered images -> front end -> online smoother: two chair-sized boxes are recovered, and
    the estimates fed back into the front end keep the association.

    Marked slow: about 30-90 s on the shared 2-core CPU, almost all of it compiling
    ``online_update`` (the front end itself takes a few tens of ms per frame)."""
    from jaxsem import factors
    from jaxsem.slam import Capacity, SolverConfig, online_estimate, online_init, online_optimize, online_update

    objects = CHAIRS
    seq = render_sequence(objects, [(-0.5 + 0.15 * i, -3.0, 0.8) for i in range(8)])
    capacity = Capacity(max_poses=8, max_objects=4, max_boxes=32, max_detections=4)
    state = online_init(
        SolverConfig(default_depth=3.0), capacity, seq["K"], (WIDTH, HEIGHT), optimize_every=2, iterations=5
    )
    frontend = FrontEnd(seq["K"], FrontEndConfig(gate_pixels=30.0))
    chair = factors.class_index("chair")
    for f in range(8):
        boxes, names = detections(seq, f)
        assert names == ["red", "blue"]
        estimates = LandmarkEstimates.from_estimate(online_estimate(state), mask=state.problem.object_mask)
        dets = frontend.process(
            seq["rgb"][f], seq["poses"][f], boxes, class_ids=[chair, chair], landmark_estimates=estimates
        )
        assert [d.landmark_id for d in dets] == [0, 1]
        assert all(d.has_texture for d in dets) == (f > 0)
        state = online_update(state, to_frame(dets, seq["poses"][f], max_detections=4, max_objects=4))
    estimate = online_estimate(online_optimize(state))
    centers = np.asarray(estimate.center)[:2]
    truth = np.array([objects[0][2], objects[1][2]])
    assert np.all(np.linalg.norm(centers - truth, axis=-1) < 0.1), centers
    np.testing.assert_allclose(np.asarray(estimate.radii)[:2], [objects[0][3], objects[1][3]], atol=0.08)


# --------------------------------------------------------------------------------------------
# Bad input.


def test_bad_inputs_raise_naming_the_argument(three):
    K = three["K"]
    frontend = FrontEnd(K)
    img, pose = three["rgb"][0], three["poses"][0]
    boxes, _ = detections(three, 0)
    frontend.process(img, pose, boxes)
    state = (frontend.frame_index, frontend.landmark_ids)

    def raises(match, *args, **kwargs):
        with pytest.raises(ValueError, match=match):
            frontend.process(*args, **kwargs)
        assert (frontend.frame_index, frontend.landmark_ids) == state  # nothing changed

    raises("image.*uint8", img.astype(np.float32), pose, boxes)
    raises(r"image.*\(H, W, 3\)", img[..., 0], pose, boxes)
    raises("image.*previous frames", img[:100], pose, boxes)
    nan_pose = pose.copy()
    nan_pose[0, 3] = np.nan
    raises("camera_T_world.*finite", img, nan_pose, boxes)
    raises(r"camera_T_world.*\(4, 4\)", img, pose[:3], boxes)
    sheared = pose.copy()
    sheared[0, 1] += 0.3
    raises("camera_T_world.*rotation", img, sheared, boxes)
    raises(r"boxes\[0\].*outside the image", img, pose, [[400.0, 10.0, 450.0, 50.0]])
    raises(r"boxes\[1\].*outside the image", img, pose, [[10.0, 10.0, 50.0, 50.0], [-30.0, 10, 20, 50]])
    raises(r"boxes\[0\].*u_min < u_max", img, pose, [[50.0, 10.0, 40.0, 50.0]])
    raises(r"boxes\[0\].*finite", img, pose, [[np.nan, 10.0, 40.0, 50.0]])
    raises(r"boxes.*\(M, 4\)", img, pose, [[1.0, 2.0, 3.0]])
    raises("class_ids", img, pose, boxes, class_ids=[0])
    raises(
        "landmark_estimates.center",
        img,
        pose,
        boxes,
        landmark_estimates=LandmarkEstimates(np.array([0]), np.eye(3)[None], np.zeros((2, 3)), np.ones((1, 3))),
    )
    raises(
        "landmark_estimates.radii",
        img,
        pose,
        boxes,
        landmark_estimates={0: (np.eye(3), np.zeros(3), np.array([1.0, -1.0, 1.0]))},
    )
    raises("landmark_estimates", img, pose, boxes, landmark_estimates="nope")
    # boxes a pixel beyond the border are clipped, not refused
    out = frontend.process(img, pose, [[-1.0, -1.0, 40.0, 50.0]])
    np.testing.assert_allclose(out[0].box, [0.0, 0.0, 40.0, 50.0])

    with pytest.raises(ValueError, match="K"):
        FrontEnd(np.full((3, 3), np.nan))
    with pytest.raises(ValueError, match="K"):
        FrontEnd(np.eye(4))
    with pytest.raises(ValueError, match="FrontEndConfig.min_baseline"):
        FrontEndConfig(min_baseline=-1.0)
    with pytest.raises(ValueError, match="FrontEndConfig.gate_pixels"):
        FrontEndConfig(gate_pixels=float("nan"))
    with pytest.raises(ValueError, match="FrontEndConfig.color_order"):
        FrontEndConfig(color_order="hsv")
    with pytest.raises(ValueError, match="config"):
        FrontEnd(K, config={"min_baseline": 0.1})
    with pytest.raises(ValueError, match="landmark_id"):
        frontend.num_tracks(99)


def test_jaxlie_pose_accepted(three):
    import jaxlie

    plain, lie = FrontEnd(three["K"]), FrontEnd(three["K"])
    for f in (0, 2):
        boxes, _ = detections(three, f)
        a = plain.process(three["rgb"][f], three["poses"][f], boxes)
        b = lie.process(three["rgb"][f], jaxlie.SE3.from_matrix(three["poses"][f]), boxes)
    assert [d.texture_status for d in b] == ["ok", "ok"]
    np.testing.assert_allclose([d.texture_depth for d in b], [d.texture_depth for d in a], rtol=1e-6)


def test_bgr_input_gives_the_same_result(three):
    a = run(three, FrontEnd(three["K"]), frames=range(3))
    bgr = dict(three, rgb=three["rgb"][..., ::-1].copy())
    b = run(bgr, FrontEnd(three["K"], FrontEndConfig(color_order="bgr")), frames=range(3))
    for da, db in zip(a, b):
        for name in da:
            assert da[name].landmark_id == db[name].landmark_id
            assert da[name].texture_depth == db[name].texture_depth
            assert da[name].correlation == db[name].correlation


def test_prediction_cache_pads_to_capacity():
    """A growing map compiles the projection once per power-of-two bucket.

    Regression (CI): jax shares one compilation cache between all ``jax.jit`` wrappers of the
    same function, so an absolute cache size depends on which tests ran before; count the
    compilations this map adds instead.
    """
    K = np.array([[200.0, 0, 79.5], [0, 200.0, 59.5], [0, 0, 1]])
    fe_mod._PROJECT_CACHE.clear()

    def predict(n):
        est = LandmarkEstimates(
            np.arange(n), np.tile(np.eye(3), (n, 1, 1)), np.tile([0.0, 0.0, 5.0], (n, 1)), np.ones((n, 3))
        )
        centres, valid = fe_mod._predicted_centroids(K, np.eye(4), est)
        np.testing.assert_allclose(centres, np.tile([79.5, 59.5], (n, 1)), atol=1e-9)
        assert valid.all()
        return fe_mod._PROJECT_CACHE["fn"]._cache_size()

    first = predict(1)
    assert [predict(n) for n in (3, 8)] == [first, first]  # same bucket: no new compilation
    assert predict(9) <= first + 1  # the next bucket compiles at most once
    assert predict(16) == predict(12)


def test_to_frame_refuses_an_off_image_box_given_the_image_size():
    # A box beside a 640 x 480 image passes without the size (the smoother cannot tell), and is
    # refused, naming the box, once the frame knows its image.
    def detection(box):
        return AssociatedDetection(
            index=0, box=np.asarray(box, float), class_id=0, landmark_id=0, is_new=True, texture_depth=None,
            texture_variance=None, texture_status="new_landmark", num_points=0, baseline=0.0, correlation=None,
            centroid_distance=None,
        )  # fmt: skip

    pose = np.eye(4)
    inside = to_frame([detection([10, 20, 50, 60])], pose, max_detections=2, image_size=(640, 480))
    assert np.asarray(inside.box_mask).tolist() == [True, False]
    beside = [detection([2000, 20, 2100, 60])]
    assert np.asarray(to_frame(beside, pose, max_detections=2).box_mask)[0]
    with pytest.raises(ValueError, match="box"):
        to_frame(beside, pose, max_detections=2, image_size=(640, 480))
