"""The LSD building as a MuJoCo scene: MJCF, rendering conventions, the segmentation detector."""

import numpy as np
import pytest

from jaxsem import mapping, planning, quadrics
from jaxsem.mapping import (
    BuildingRenderer,
    building_mjcf,
    detect_from_segmentation,
    ellipsoids_from_depth,
    robot_camera,
    robot_intrinsics,
)

W, H = 160, 120


@pytest.fixture(scope="module")
def scene(building):
    with BuildingRenderer(building, W, H) as sc:
        yield sc


def _entrance_door(building, objects):
    r0, c0, r1, c1 = building.exterior_doors[0]
    k = int(np.flatnonzero(np.all(objects.cells == [r0, c0, r1, c1], axis=1))[0])
    return k


def _view_of_door(building, objects, k, distance=3.0):
    """A camera outside the building, ``distance`` m in front of door k, looking at its centre."""
    centre = 0.5 * (objects.box_min[k] + objects.box_max[k])
    # The outward direction: from the building's centre through the door.
    mid = np.asarray(building.origin) + 0.5 * building.resolution * np.array(building.shape[::-1])
    r0, c0, r1, c1 = objects.cells[k]
    normal = np.array([0.0, 1.0]) if (c1 - c0) >= (r1 - r0) else np.array([1.0, 0.0])
    normal *= np.sign(np.dot(centre[:2] - mid, normal)) or 1.0
    eye = centre[:2] + distance * normal
    yaw = float(np.arctan2(-normal[1], -normal[0]))
    return robot_camera(eye, yaw, height=1.05), centre


def test_mjcf_labels_every_object(building):
    xml, geom_object, geom_class, objects = building_mjcf(building)
    assert xml.startswith("<mujoco") and '<camera name="robot"' in xml
    labelled = {k for k in geom_object.values() if k >= 0}
    assert labelled == set(range(len(objects)))
    for name, k in geom_object.items():
        if k >= 0:
            assert geom_class[name] == objects.class_id[k]
        else:
            assert geom_class[name] == planning.WALL


def test_door_box_from_segmentation_matches_projected_box(building, scene):
    objects = scene.objects
    k = _entrance_door(building, objects)
    T, centre = _view_of_door(building, objects, k)
    K = robot_intrinsics(W, H)
    out = scene.render(K, T)
    assert out["rgb"].shape == (H, W, 3) and out["rgb"].dtype == np.uint8
    assert set(np.unique(out["seg_class"])) >= {planning.WALL, planning.DOOR}
    dets = scene.detect(out["seg"])
    assert k in dets.object_index
    box = dets.box[list(dets.object_index).index(k)]
    half = 0.5 * (objects.box_max[k] - objects.box_min[k])
    corners = quadrics.cuboid_corners(np.eye(3), centre, half)
    uv, depth = quadrics.project_points(corners, K, T)
    uv = np.asarray(uv)
    assert np.all(np.asarray(depth) > 0)
    want = [uv[:, 0].min(), uv[:, 1].min(), uv[:, 0].max(), uv[:, 1].max()]
    np.testing.assert_allclose(box, want, atol=1.5)


def test_depth_back_projects_onto_the_door_frame(building, scene):
    objects = scene.objects
    k = _entrance_door(building, objects)
    T, _ = _view_of_door(building, objects, k)
    K = robot_intrinsics(W, H)
    out = scene.render(K, T, outputs=("depth", "seg"))
    rows, cols = np.nonzero(out["seg"] == k)
    assert len(rows) > 50
    depth = out["depth"][rows, cols].astype(float)  # the render's float32, with float64 K and T
    pts = np.asarray(quadrics.back_project(np.stack([cols, rows], -1).astype(float), depth, K, T))
    lo, hi = objects.box_min[k] - 0.02, objects.box_max[k] + 0.02
    inside = np.all((pts >= lo) & (pts <= hi), axis=1)
    assert inside.mean() > 0.99
    # The sky has depth 0, everything else is in front of the camera.
    assert np.all(out["depth"] >= 0) and out["depth"].max() > 3.0


def test_robot_camera_looks_along_its_heading():
    K = robot_intrinsics(W, H, hfov_deg=69.4)
    T = robot_camera([1.0, 2.0], np.pi / 2, height=1.2)
    uv, depth = quadrics.project_points(np.array([1.0, 7.0, 1.2]), K, T)
    np.testing.assert_allclose(np.asarray(uv), [(W - 1) / 2, (H - 1) / 2], atol=1e-9)
    np.testing.assert_allclose(float(depth), 5.0, atol=1e-9)
    # The horizontal field of view reaches the image edges.
    edge = np.array([1.0 - 5.0 * np.tan(np.radians(69.4 / 2)), 7.0, 1.2])
    uv, _ = quadrics.project_points(edge, K, T)
    np.testing.assert_allclose(float(np.asarray(uv)[0]), -0.5, atol=1e-6)


def test_detector_boxes_filters_and_bad_input():
    seg = -np.ones((20, 30), np.int32)
    seg[2:6, 3:9] = 0  # a door: rows 2..5, cols 3..8
    seg[10:12, 28:30] = 1  # a sign at the right border
    seg[15, 15] = 2  # a window (not reported by default)
    classes = np.array([planning.DOOR, planning.EXIT_SIGN, planning.WINDOW])
    d = detect_from_segmentation(seg, classes)
    np.testing.assert_array_equal(d.object_index, [0, 1])
    np.testing.assert_allclose(d.box[0], [2.5, 1.5, 8.5, 5.5])
    np.testing.assert_array_equal(d.area, [24, 4])
    assert len(detect_from_segmentation(seg, classes, border=2)) == 1
    assert len(detect_from_segmentation(seg, classes, min_area=5)) == 1
    d = detect_from_segmentation(seg, classes, classes=[planning.WINDOW])
    np.testing.assert_array_equal(d.class_id, [planning.WINDOW])
    with pytest.raises(ValueError, match="seg"):
        detect_from_segmentation(np.zeros(5, int), classes)
    with pytest.raises(ValueError, match="hfov_deg"):
        robot_intrinsics(W, H, hfov_deg=0.0)


def test_objects_are_the_mapping_ground_truth(building, scene):
    objs = mapping.building_objects(building)
    np.testing.assert_array_equal(scene.objects.cells, objs.cells)
    np.testing.assert_array_equal(scene.objects.class_id, objs.class_id)


def test_pixels_to_object_map_to_semantic_grid(building, scene):
    """Render -> segmentation + depth -> ellipsoids -> object map -> LSD's semantic grid."""
    objects = scene.objects
    k = _entrance_door(building, objects)
    T, centre = _view_of_door(building, objects, k)
    K = robot_intrinsics(W, H)
    state = mapping.init(16)
    for dx in (-0.3, 0.0, 0.3):  # three views from slightly different places
        Tv = T.copy()
        Tv[:3, 3] -= np.array([dx, 0.0, 0.0])  # the camera moves dx along its own x axis
        out = scene.render(K, Tv, outputs=("depth", "seg"))
        ell, idx = ellipsoids_from_depth(out["seg"], out["depth"], quadrics.Camera(K, Tv), objects.class_id, capacity=8)
        assert k in idx
        state = mapping.update(state, ell, gate=0.5)
    # The entrance door was associated across views, and its estimate is the true box's.
    j = int(np.argmin(np.linalg.norm(np.asarray(state.center) - centre, axis=1)))
    assert int(state.observations[j]) == 3
    np.testing.assert_allclose(np.asarray(state.center[j]), centre, atol=0.05)
    half = 0.5 * (objects.box_max[k] - objects.box_min[k])
    np.testing.assert_allclose(np.asarray(state.radii[j]), half, atol=0.05)
    grid = np.asarray(mapping.semantic_grid(state, building.grid))
    r0, c0, r1, c1 = objects.cells[k]
    truth = np.zeros(building.shape, bool)
    truth[r0:r1, c0:c1] = True
    got = grid == planning.DOOR
    overlap = (got & truth).sum() / truth.sum()
    assert overlap > 0.6


def test_renderer_checks_outputs_and_closes(building):
    # the lifecycle and pass selection shared with SceneRenderer (jaxsem.data._render.MujocoScene)
    with BuildingRenderer(building, 32, 24) as sc:
        K, T = robot_intrinsics(32, 24), robot_camera(building.entrance, 0.0)
        assert set(sc.render(K, T, outputs="seg")) == {"seg", "seg_class"}
        assert set(sc.render(K, T, outputs=("rgb",))) == {"rgb"}
        with pytest.raises(ValueError, match="outputs"):
            sc.render(K, T, outputs=("normals",))
    with pytest.raises(ValueError, match="BuildingRenderer: render"):
        sc.render(K, T)
    sc.close()  # a second close does nothing
