"""Headless MuJoCo renderer: masks against independent projections, depth, labels, bad input."""

import cv2
import jax
import numpy as np
import pytest

from jaxsem import quadrics
from jaxsem.data import SceneObject, SceneRenderer, render_views
from jaxsem.quadrics import Camera

W, H, F = 160, 120, 150.0
K = np.array([[F, 0.0, (W - 1) / 2], [0.0, F, (H - 1) / 2], [0.0, 0.0, 1.0]])


def _mask_box(mask):
    """Box of a mask in OpenCV pixel coordinates: pixel i covers [i - 0.5, i + 0.5]."""
    ys, xs = np.nonzero(mask)
    return np.array([xs.min() - 0.5, ys.min() - 0.5, xs.max() + 0.5, ys.max() + 0.5])


def _points_box(points_cam):
    p = points_cam @ K.T
    p = p[:, :2] / p[:, 2:]
    return np.array([p[:, 0].min(), p[:, 1].min(), p[:, 0].max(), p[:, 1].max()])


def _cylinder_rim(ob, n=2000):
    a = np.linspace(0, 2 * np.pi, n, endpoint=False)
    r, h = ob.extents[0] / 2, ob.extents[2] / 2
    local = np.concatenate([np.stack([r * np.cos(a), r * np.sin(a), np.full(n, s * h)], 1) for s in (-1, 1)])
    return local @ ob.rotation.T + ob.center


@pytest.fixture(scope="module")
def scene():
    """Three objects side by side (no occlusion), seen from two cameras; camera 0 is the world."""
    R = [np.asarray(quadrics.random_rotation(jax.random.PRNGKey(s))) for s in (11, 12, 13)]
    objects = [
        SceneObject("cracker_box", "box", np.array([0.164, 0.213, 0.0718]), R[0], np.array([-0.22, 0.0, 1.1]), 1),
        SceneObject("soup_can", "cylinder", np.array([0.068, 0.068, 0.102]), R[1], np.array([0.0, 0.02, 0.9]), 2),
        SceneObject("ball", "ellipsoid", np.array([0.07, 0.09, 0.12]), R[2], np.array([0.17, -0.03, 0.8]), 3),
    ]
    c, s = np.cos(0.1), np.sin(0.1)
    T1 = np.eye(4)
    T1[:3, :3] = np.array([[c, 0, -s], [0, 1, 0], [s, 0, c]])
    T1[:3, 3] = [0.08, 0.01, 0.05]
    poses = np.stack([np.eye(4), T1])
    out = render_views(objects, Camera(K, poses), W, H, background_seed=3, light_seed=4)
    return objects, poses, out


def test_shapes_and_dtypes(scene):
    _, _, out = scene
    assert out["rgb"].shape == (2, H, W, 3) and out["rgb"].dtype == np.uint8
    assert out["depth"].shape == (2, H, W) and out["depth"].dtype == np.float32
    assert out["seg"].shape == (2, H, W) and out["seg"].dtype == np.int32
    assert set(np.unique(out["seg"])) == {-1, 0, 1, 2}
    # No floor: the background is the skybox, with depth 0; every object pixel has depth.
    assert np.all(out["depth"][out["seg"] == -1] == 0)
    assert np.all(out["depth"][out["seg"] >= 0] > 0.5)


def test_mask_boxes_match_projections(scene):
    objects, poses, out = scene
    for v, T in enumerate(poses):
        for i, ob in enumerate(objects):
            mask_box = _mask_box(out["seg"][v] == i)
            if ob.shape == "box":
                ref = _points_box(ob.corners() @ T[:3, :3].T + T[:3, 3])
            elif ob.shape == "cylinder":
                ref = _points_box(_cylinder_rim(ob) @ T[:3, :3].T + T[:3, 3])
            else:
                ref, valid = quadrics.project_bbox(ob.rotation, ob.center, ob.extents / 2, K, T)
                ref = np.asarray(ref)
                assert bool(valid)
            assert ref[0] > 1 and ref[1] > 1 and ref[2] < W - 2 and ref[3] < H - 2, "setup: not truncated"
            np.testing.assert_allclose(mask_box, ref, atol=1.0, err_msg=f"view {v}, {ob.shape}")


def test_depth_on_object_matches_geometry(scene):
    """Back-projected ellipsoid pixels lie on the true ellipsoid (algebraic distance ~ 0)."""
    objects, poses, out = scene
    ob = objects[2]
    for v, T in enumerate(poses):
        vs, us = np.nonzero(out["seg"][v] == 2)
        z = out["depth"][v][vs, us].astype(np.float64)
        pts_cam = np.stack([(us - K[0, 2]) * z / F, (vs - K[1, 2]) * z / F, z], 1)
        pts_world = (pts_cam - T[:3, 3]) @ T[:3, :3]
        # Interior pixels only: at the silhouette a pixel centre may miss the surface.
        eroded = cv2.erode((out["seg"][v] == 2).astype(np.uint8), np.ones((3, 3), np.uint8))[vs, us] > 0
        d = np.asarray(quadrics.algebraic_distance(pts_world[eroded], ob.rotation, ob.center, ob.extents / 2))
        assert np.median(np.abs(d)) < 0.02 and np.max(np.abs(d)) < 0.1


def test_plane_depth_and_floor():
    """A wide thin slab facing the camera at 0.75 m: its front face reads 0.75 - thickness / 2."""
    slab = SceneObject("wall", "box", np.array([3.0, 3.0, 0.02]), np.eye(3), np.array([0.0, 0.0, 0.76]), 0)
    out = render_views([slab], Camera(K, np.eye(4)), W, H, textured=False)
    np.testing.assert_allclose(out["depth"][0], 0.75, atol=1e-3)
    assert np.all(out["seg"][0] == 0)
    only = render_views([slab], Camera(K, np.eye(4)), W, H, textured=False, outputs=("depth",))
    assert set(only) == {"depth"}
    np.testing.assert_array_equal(only["depth"], out["depth"])
    # A floor is depth but not an object: z up world, camera 1 m above looking down at the floor.
    T = np.asarray(quadrics.look_at(np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.001, 0.0])))
    out = render_views([], Camera(K, T[None]), W, H, floor_z=0.0)
    assert np.all(out["seg"] == -1)
    np.testing.assert_allclose(out["depth"][0], 1.0, atol=2e-3)


def test_textures_have_features_and_seeds_matter(scene):
    objects, poses, out = scene
    orb = cv2.ORB_create(nfeatures=500, edgeThreshold=8, patchSize=15)
    gray = cv2.cvtColor(out["rgb"][0], cv2.COLOR_RGB2GRAY)
    keypoints = orb.detect(gray, None)
    on_objects = [kp for kp in keypoints if out["seg"][0][int(kp.pt[1]), int(kp.pt[0])] >= 0]
    assert len(on_objects) >= 10
    other = render_views(objects, Camera(K, poses[:1]), W, H, background_seed=99, light_seed=4)
    np.testing.assert_array_equal(other["seg"][0], out["seg"][0])
    background = out["seg"][0] == -1
    assert np.mean(np.abs(other["rgb"][0][background].astype(int) - out["rgb"][0][background])) > 5
    again = render_views(objects, Camera(K, poses[:1]), W, H, background_seed=3, light_seed=4)
    np.testing.assert_array_equal(again["rgb"][0], out["rgb"][0])


def test_bad_input():
    ob = SceneObject("ball", "ellipsoid", np.full(3, 0.07), np.eye(3), np.array([0, 0, 1.0]))
    with pytest.raises(ValueError, match="skew"):
        render_views([ob], Camera(K + np.array([[0, 1.0, 0], [0, 0, 0], [0, 0, 0]]), np.eye(4)), W, H)
    with pytest.raises(ValueError, match="fx, fy > 0"):
        render_views([ob], Camera(K * np.array([[1, 1, 1], [1, -1, 1], [1, 1, 1]]), np.eye(4)), W, H)
    with pytest.raises(ValueError, match="outputs"):
        render_views([ob], Camera(K, np.eye(4)), W, H, outputs=("normals",))
    with pytest.raises(ValueError, match="camera_T_world"):
        render_views([ob], Camera(K, np.eye(3)), W, H)
    with pytest.raises(ValueError, match="shape"):
        SceneObject("x", "cone", np.ones(3), np.eye(3), np.zeros(3))
    with pytest.raises(ValueError, match="cylinder"):
        SceneObject("x", "cylinder", np.array([0.1, 0.2, 0.1]), np.eye(3), np.zeros(3))
    with pytest.raises(ValueError, match="extents"):
        SceneObject("x", "box", np.array([0.1, -0.2, 0.1]), np.eye(3), np.zeros(3))
    with pytest.raises(ValueError, match="rotation"):
        SceneObject("x", "box", np.ones(3), 2 * np.eye(3), np.zeros(3))
    with SceneRenderer([ob], W, H) as scene:
        scene.render(K, np.eye(4))
    with pytest.raises(ValueError, match="close"):
        scene.render(K, np.eye(4))


def test_move_object_matches_fresh_scene():
    """Regression: geoms compiled with an identity pose ignored later rotations (geom_sameframe)."""
    R = np.asarray(quadrics.random_rotation(jax.random.PRNGKey(5)))
    ext = np.array([0.164, 0.213, 0.0718])
    fresh = render_views([SceneObject("b", "box", ext, R, np.array([0.05, 0.02, 0.7]))], Camera(K, np.eye(4)), W, H)
    start = SceneObject("b", "box", ext * 1.2, np.eye(3), np.array([1.0, 1.0, 1.0]))
    with SceneRenderer([start], W, H) as scene:
        scene.move_object(0, R, np.array([0.05, 0.02, 0.7]), ext)
        moved = scene.render(K, np.eye(4))
        scene.move_object(0, R, np.zeros(3), hidden=True)
        hidden = scene.render(K, np.eye(4))
    np.testing.assert_array_equal(moved["seg"], fresh["seg"][0])
    assert np.all(hidden["seg"] == -1)


@pytest.mark.parametrize("fx, fy, cx, cy", [(150.0, 150.0, W / 2, H / 2), (140.0, 175.0, 66.0, 70.0)])
def test_general_intrinsics(fx, fy, cx, cy):
    """Unequal focal lengths and an off-centre principal point are rendered exactly."""
    Kg = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    R = np.asarray(quadrics.random_rotation(jax.random.PRNGKey(21)))
    ob = SceneObject("ball", "ellipsoid", np.array([0.08, 0.1, 0.14]), R, np.array([0.04, -0.03, 0.8]))
    box = SceneObject("b", "box", np.array([0.1, 0.12, 0.06]), R, np.array([-0.2, 0.05, 0.9]))
    out = render_views([ob, box], Camera(Kg, np.eye(4)), W, H, textured=False)
    ref, valid = quadrics.project_bbox(R, ob.center, ob.extents / 2, Kg, np.eye(4))
    np.testing.assert_allclose(_mask_box(out["seg"][0] == 0), np.asarray(ref), atol=1.0)
    p = box.corners() @ Kg.T
    p = p[:, :2] / p[:, 2:]
    np.testing.assert_allclose(
        _mask_box(out["seg"][0] == 1), [p[:, 0].min(), p[:, 1].min(), p[:, 0].max(), p[:, 1].max()], atol=1.0
    )
