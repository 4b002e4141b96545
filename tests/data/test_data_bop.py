"""BOP scene reader and PLY meshes on small scenes the tests write: poses in mm to metres, the
ellipsoid of the mesh extent, visible boxes against the core's projection of the mesh points,
occlusion, ``scene_gt_info.json`` when present, bad files named; the real LM-O scene when
``JAXSEM_DATA_DIR`` points at ``jaxsem data fetch lmo``'s folder (else skipped)."""

import json
import os
import pathlib

import numpy as np
import pytest

from jaxsem import data, quadrics as q

K = [[500.0, 0.0, 160.0], [0.0, 500.0, 120.0], [0.0, 0.0, 1.0]]


def _box_points(half_mm, step_mm=2.0):
    """Dense points on the surface of a box with half extents ``half_mm`` (a point-only mesh)."""
    axes = [np.arange(-h, h + 1e-9, step_mm) for h in half_mm]
    pts = []
    for a in range(3):
        b, c = [i for i in range(3) if i != a]
        B, C = np.meshgrid(axes[b], axes[c], indexing="ij")
        for sign in (-1, 1):
            p = np.zeros((B.size, 3))
            p[:, a], p[:, b], p[:, c] = sign * half_mm[a], B.ravel(), C.ravel()
            pts.append(p)
    return np.concatenate(pts)


def _write_ply(path, pts, binary=False, colors=True):
    n = len(pts)
    head = ["ply", f"format {'binary_little_endian' if binary else 'ascii'} 1.0", f"element vertex {n}"]
    head += [f"property float {a}" for a in "xyz"]
    if colors:
        head += [f"property uchar {c}" for c in ("red", "green", "blue")]
    head += ["end_header"]
    text = "\n".join(head) + "\n"
    if binary:
        dt = np.dtype(
            [("x", "<f4"), ("y", "<f4"), ("z", "<f4")] + ([("r", "u1"), ("g", "u1"), ("b", "u1")] if colors else [])
        )
        rows = np.zeros(n, dt)
        rows["x"], rows["y"], rows["z"] = pts.T
        if colors:
            rows["r"] = 200
        path.write_bytes(text.encode() + rows.tobytes())
    else:
        lines = [" ".join(f"{v:.4f}" for v in p) + (" 200 10 10" if colors else "") for p in pts]
        path.write_text(text + "\n".join(lines) + "\n")


def _scene(tmp_path, gt, info=None):
    scene = tmp_path / "lmo" / "test" / "000002"
    (scene / "models").mkdir(parents=True)
    _write_ply(scene / "models" / "obj_000001.ply", _box_points([30.0, 20.0, 10.0]))
    _write_ply(scene / "models" / "obj_000005.ply", _box_points([15.0, 15.0, 15.0]), binary=True)
    cam = {"fx": 500.0, "fy": 500.0, "cx": 160.0, "cy": 120.0, "width": 320, "height": 240, "depth_scale": 1.0}
    (scene / "camera.json").write_text(json.dumps(cam))
    (scene / "scene_gt.json").write_text(json.dumps(gt))
    if info is not None:
        (scene / "scene_gt_info.json").write_text(json.dumps(info))
    return scene


EYE = np.eye(3).ravel().tolist()
GT = {
    "3": [
        {"obj_id": 1, "cam_R_m2c": EYE, "cam_t_m2c": [0.0, 0.0, 500.0]},
        {"obj_id": 5, "cam_R_m2c": EYE, "cam_t_m2c": [100.0, 0.0, 600.0]},
    ],
    "7": [
        {"obj_id": 1, "cam_R_m2c": EYE, "cam_t_m2c": [0.0, 0.0, 400.0]},
        {"obj_id": 5, "cam_R_m2c": EYE, "cam_t_m2c": [0.0, 0.0, 800.0]},  # behind object 1
    ],
}


def test_poses_ellipsoids_and_names(tmp_path):
    scene = data.load_bop_scene(_scene(tmp_path, GT))
    assert [f.frame_id for f in scene.frames] == [3, 7]
    a, b = scene.frames[0].objects
    assert (a.class_name, b.class_name) == ("ape", "can")  # Linemod names for an lmo path
    np.testing.assert_allclose(a.translation, [0, 0, 0.5])
    np.testing.assert_allclose(a.center, [0, 0, 0.5], atol=1e-6)
    np.testing.assert_allclose(a.radii, [0.03, 0.02, 0.01], atol=1e-6)
    np.testing.assert_allclose(b.center, [0.1, 0, 0.6], atol=1e-6)
    np.testing.assert_allclose(scene.frames[0].K, K)
    assert scene.frames[0].image_size == (320, 240)
    tune, test = scene.split(5)
    assert [f.frame_id for f in tune] == [3] and [f.frame_id for f in test] == [7]


def test_visible_box_matches_the_projection_of_the_mesh_points(tmp_path):
    scene = data.load_bop_scene(_scene(tmp_path, GT))
    frame = scene.frames[0]
    for obj in frame.objects:
        pts = scene.meshes[obj.obj_id].vertices @ obj.rotation.T + obj.translation
        uv, _ = q.project_points(pts, np.asarray(K), np.eye(4))
        uv = np.asarray(uv)
        expected = np.array([uv[:, 0].min(), uv[:, 1].min(), uv[:, 0].max(), uv[:, 1].max()])
        # A point splat of 3 x 3 pixels: within two pixels of the projected extremes.
        np.testing.assert_allclose(obj.visible_box, expected, atol=2.5)
        assert obj.visible_fraction == pytest.approx(1.0)


def test_an_object_behind_another_is_hidden(tmp_path):
    frame = data.load_bop_scene(_scene(tmp_path, GT)).frames[1]
    front, back = frame.objects
    assert front.visible_fraction == pytest.approx(1.0)
    assert back.visible_fraction == 0.0 and np.all(np.isnan(back.visible_box))


def test_scene_gt_info_is_used_when_present(tmp_path):
    info = {
        "3": [{"bbox_visib": [10, 20, 30, 40], "visib_fract": 0.5}, {"bbox_visib": [-1, -1, 0, 0], "visib_fract": 0.0}],
        "7": [{"bbox_visib": [1, 2, 3, 4], "visib_fract": 1.0}, {"bbox_visib": [5, 6, 7, 8], "visib_fract": 0.25}],
    }
    frame = data.load_bop_scene(_scene(tmp_path, GT, info)).frames[0]
    # BOP's [x, y, w, h] are pixel indices (x + w the last pixel): edge to edge, centres at whole numbers
    np.testing.assert_allclose(frame.objects[0].visible_box, [9.5, 19.5, 40.5, 60.5])
    assert frame.objects[0].visible_fraction == 0.5
    assert np.all(np.isnan(frame.objects[1].visible_box))


def test_binary_and_ascii_ply_agree(tmp_path):
    pts = _box_points([5.0, 6.0, 7.0], 1.0)
    _write_ply(tmp_path / "a.ply", pts)
    _write_ply(tmp_path / "b.ply", pts, binary=True)
    a, b = data.load_ply(tmp_path / "a.ply"), data.load_ply(tmp_path / "b.ply")
    np.testing.assert_allclose(a.vertices, b.vertices, atol=1e-6)
    np.testing.assert_allclose(a.radii, [0.005, 0.006, 0.007], atol=1e-9)
    assert a.colors is not None and int(a.colors[0, 0]) == 200


@pytest.mark.parametrize(
    ("damage", "words"),
    [
        (lambda s: (s / "scene_gt.json").unlink(), ["scene_gt.json"]),
        (lambda s: (s / "scene_gt.json").write_text("{ nope"), ["scene_gt.json", "JSON"]),
        (
            lambda s: (s / "scene_gt.json").write_text(
                json.dumps({"3": [{"obj_id": 1, "cam_R_m2c": [1, 0, 0], "cam_t_m2c": [0, 0, 1]}]})
            ),
            ["scene_gt.json", "3[0].cam_R_m2c"],
        ),
        (lambda s: (s / "models" / "obj_000005.ply").unlink(), ["object 5", "obj_000005.ply"]),
        (lambda s: (s / "models" / "obj_000001.ply").write_bytes(b"ply\nformat ascii 1.0\n"), ["obj_000001.ply"]),
        (lambda s: (s / "camera.json").unlink(), ["camera.json"]),
    ],
    ids=["no-gt", "bad-json", "bad-rotation", "no-mesh", "bad-ply", "no-camera"],
)
def test_bad_files_are_named(tmp_path, damage, words):
    scene = _scene(tmp_path, GT)
    damage(scene)
    with pytest.raises(ValueError) as info:
        data.load_bop_scene(scene)
    for word in words:
        assert word in str(info.value)


def test_real_lmo_scene_when_present():
    root = pathlib.Path(os.environ.get("JAXSEM_DATA_DIR", "/nonexistent")) / "lmo" / "test" / "000002"
    if not (root / "scene_gt.json").is_file():
        pytest.skip("LM-O absent (set JAXSEM_DATA_DIR to the folder of `jaxsem data fetch lmo`)")
    scene = data.load_bop_scene(root)
    tune, test = scene.split(600)
    # The fixed split: 97 frames / 756 poses to tune on, 103 / 761 held out.
    assert (len(tune), sum(len(f.objects) for f in tune)) == (97, 756)
    assert (len(test), sum(len(f.objects) for f in test)) == (103, 761)
    names = {o.class_name for f in scene.frames for o in f.objects}
    assert names == {"ape", "can", "cat", "driller", "duck", "eggbox", "glue", "holepuncher"}


# Every field checked at the boundary (issue 45 items 4-5): (file, its content, words the error names).
CAM = {"fx": 500.0, "fy": 500.0, "cx": 160.0, "cy": 120.0, "width": 320, "height": 240}
POSE = {"cam_R_m2c": EYE, "cam_t_m2c": [0.0, 0.0, 500.0]}
BAD_FIELDS = {
    "fx-zero": ("camera.json", json.dumps({**CAM, "fx": 0}), ["camera.json", "fx", "positive"]),
    "fy-negative": ("camera.json", json.dumps({**CAM, "fy": -500.0}), ["camera.json", "fy", "positive"]),
    "fx-nan": ("camera.json", json.dumps({**CAM, "fx": float("nan")}), ["camera.json", "fx", "finite"]),
    "cx-text": ("camera.json", json.dumps({**CAM, "cx": "160"}), ["camera.json", "cx"]),
    "width-zero": ("camera.json", json.dumps({**CAM, "width": 0}), ["camera.json", "width"]),
    "height-fraction": ("camera.json", json.dumps({**CAM, "height": 240.5}), ["camera.json", "height"]),
    "size-over-budget": (
        "camera.json",
        json.dumps({**CAM, "width": 100000, "height": 100000}),
        ["camera.json", "100000 x 100000", "max_pixels"],
    ),
    "gt-frame-number": ("scene_gt.json", '{"3": 5}', ["scene_gt.json", "3:", "list of objects"]),
    "gt-list": ("scene_gt.json", "[1, 2]", ["scene_gt.json", "object", "list"]),
    "gt-entry-list": ("scene_gt.json", '{"3": [[1, 2]]}', ["scene_gt.json", "3[0]", "object"]),
    "obj-id-text": ("scene_gt.json", json.dumps({"3": [{"obj_id": "abc", **POSE}]}), ["3[0].obj_id", "'abc'"]),
    "obj-id-negative": ("scene_gt.json", json.dumps({"3": [{"obj_id": -1, **POSE}]}), ["3[0].obj_id", "-1"]),
    "gt-not-utf8": ("scene_gt.json", b'{"3": "\xff"}', ["scene_gt.json", "UTF-8"]),
    "info-rows-numbers": ("scene_gt_info.json", '{"3": [1, 2], "7": [1, 2]}', ["scene_gt_info.json", "3[0]"]),
    "info-fraction-text": (
        "scene_gt_info.json",
        json.dumps({k: [{"bbox_visib": [1, 1, 5, 5], "visib_fract": "most"}] * 2 for k in ("3", "7")}),
        ["scene_gt_info.json", "3[0].visib_fract"],
    ),
    "info-fraction-over-one": (
        "scene_gt_info.json",
        json.dumps({k: [{"bbox_visib": [1, 1, 5, 5], "visib_fract": 1.5}] * 2 for k in ("3", "7")}),
        ["scene_gt_info.json", "3[0].visib_fract", "[0, 1]"],
    ),
    "per-frame-camera-list": ("scene_camera.json", "[1]", ["scene_camera.json", "object"]),
    "per-frame-k-zero-focal": (
        "scene_camera.json",
        json.dumps({k: {"cam_K": [0, 0, 160, 0, 500, 120, 0, 0, 1]} for k in ("3", "7")}),
        ["scene_camera.json", "3.cam_K", "positive"],
    ),
    "per-frame-k-bottom-row": (
        "scene_camera.json",
        json.dumps({k: {"cam_K": [500, 0, 160, 0, 500, 120, 0, 0, 0]} for k in ("3", "7")}),
        ["scene_camera.json", "3.cam_K", "[0, 0, 1]"],
    ),
    "ply-count-text": (
        "models/obj_000001.ply",
        "ply\nformat ascii 1.0\nelement vertex many\nend_header\n",
        ["obj_000001.ply", "element vertex many"],
    ),
}


@pytest.mark.parametrize("case", sorted(BAD_FIELDS))
def test_bad_fields_are_refused_naming_the_file_and_entry(tmp_path, case):
    name, content, words = BAD_FIELDS[case]
    scene = _scene(tmp_path, GT)
    target = scene / name
    target.write_bytes(content) if isinstance(content, bytes) else target.write_text(content)
    with pytest.raises(ValueError) as info:
        data.load_bop_scene(scene)
    for word in words:
        assert word in str(info.value), str(info.value)


def test_the_pixel_budget_is_an_argument(tmp_path):
    scene = _scene(tmp_path, GT)
    with pytest.raises(
        ValueError, match=r"camera.json: declares a 320 x 240 = 76,800 pixel image, more than max_pixels"
    ):
        data.load_bop_scene(scene, max_pixels=320 * 240 - 1)
    assert len(data.load_bop_scene(scene, max_pixels=320 * 240).frames) == 2


# ----------------------------------------------------------------------------------------------
# The reader's output passes the library's own checks: boxes in the core's pixel convention,
# rotations projected to proper rotations, the README's real-data snippet on a scene of its own.


def test_visible_box_runs_edge_to_edge_of_the_nearest_pixels():
    # One vertex at u = 100.3, v = 50.6 (K above, z = 1): nearest pixel centres 100 and 51, a 3 x 3
    # splat covers columns 99..101 and rows 50..52, whose outer edges are 98.5..101.5, 49.5..52.5.
    mesh = data.Mesh(np.array([[(100.3 - 160.0) / 500.0, (50.6 - 120.0) / 500.0, 0.0]]))
    boxes, fractions = data.visible_boxes([(mesh, np.eye(3), np.array([0.0, 0.0, 1.0]))], np.asarray(K), (320, 240))
    np.testing.assert_allclose(boxes[0], [98.5, 49.5, 101.5, 52.5])
    # At the right edge the last column is 319, so the box ends at 319.5 = W - 0.5.
    mesh = data.Mesh(np.array([[(319.2 - 160.0) / 500.0, 0.0, 0.0]]))
    boxes, _ = data.visible_boxes([(mesh, np.eye(3), np.array([0.0, 0.0, 1.0]))], np.asarray(K), (320, 240))
    assert boxes[0][2] == 319.5


def _rounded_rotation(seed, digits=3):
    """A rotation written with ``digits`` decimals, as BOP files are: a little off orthonormal."""
    a = np.random.default_rng(seed).normal(size=(3, 3))
    Q, R = np.linalg.qr(a)
    Q = Q * np.sign(np.diag(R))
    Q = Q if np.linalg.det(Q) > 0 else -Q
    return np.round(Q, digits) + np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.002]])


def test_rotations_are_the_nearest_proper_rotation_of_the_file(tmp_path):
    written = _rounded_rotation(0)
    assert np.abs(written.T @ written - np.eye(3)).max() > 1e-3  # over the core's tolerance as written
    gt = {"3": [{"obj_id": 1, "cam_R_m2c": written.ravel().tolist(), "cam_t_m2c": [0.0, 0.0, 500.0]}]}
    obj = data.load_bop_scene(_scene(tmp_path, gt)).frames[0].objects[0]
    np.testing.assert_allclose(obj.rotation.T @ obj.rotation, np.eye(3), atol=1e-12)
    assert np.linalg.det(obj.rotation) == pytest.approx(1.0)
    # the polar factor of the written matrix (independent: scipy-free, from the matrix square root)
    w, V = np.linalg.eigh(written.T @ written)
    polar = written @ V @ np.diag(w**-0.5) @ V.T
    np.testing.assert_allclose(obj.rotation, polar, atol=1e-9)
    q.dual_quadric(obj.rotation, obj.center, obj.radii)  # the core takes it (it checks rotations)


@pytest.mark.parametrize("matrix", [-np.eye(3), 2 * np.eye(3), np.zeros((3, 3))], ids=["reflection", "scaled", "zeros"])
def test_a_matrix_that_is_no_rotation_is_refused_naming_the_entry(tmp_path, matrix):
    gt = {"3": [{"obj_id": 1, "cam_R_m2c": matrix.ravel().tolist(), "cam_t_m2c": [0.0, 0.0, 500.0]}]}
    with pytest.raises(ValueError, match=r"scene_gt.json: 3\[0\].cam_R_m2c: expected a rotation"):
        data.load_bop_scene(_scene(tmp_path, gt))


def _readme_bop_lines():
    """The README's real-BOP-scene lines (from its "A real BOP scene" comment to the next command)."""
    readme = pathlib.Path(__file__).resolve().parents[2] / "README.md"
    lines = readme.read_text().splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("# A real BOP scene"))
    stop = next(i for i in range(start + 1, len(lines)) if lines[i].startswith("# jaxsem volumon eval"))
    stretches = [line for line in lines if line.startswith("stretches = slam.find_stretches(")]
    assert len(stretches) == 1
    return lines[start:stop] + stretches


def test_readme_real_data_snippet_runs_on_a_tiny_scene(tmp_path):
    import jax.numpy as jnp
    from PIL import Image

    from jaxsem import slam, volumon

    # A 640 x 480 LM-O-like scene: one object cut by the right edge of the image, one inside,
    # rotations written with three decimals.
    scene = tmp_path / "data" / "lmo" / "test" / "000002"
    (scene / "models").mkdir(parents=True)
    (scene / "rgb").mkdir()
    _write_ply(scene / "models" / "obj_000001.ply", _box_points([30.0, 20.0, 10.0]))
    _write_ply(scene / "models" / "obj_000005.ply", _box_points([15.0, 15.0, 15.0]))
    cam = {"fx": 572.4, "fy": 573.6, "cx": 325.3, "cy": 242.0, "width": 640, "height": 480, "depth_scale": 1.0}
    (scene / "camera.json").write_text(json.dumps(cam))
    gt = {
        str(f): [
            {"obj_id": 1, "cam_R_m2c": _rounded_rotation(f).ravel().tolist(), "cam_t_m2c": [290.0, 0.0, 600.0]},
            {"obj_id": 5, "cam_R_m2c": _rounded_rotation(f + 50).ravel().tolist(), "cam_t_m2c": [0.0, 0.0, 700.0]},
        ]
        for f in (3, 4)
    }
    (scene / "scene_gt.json").write_text(json.dumps(gt))
    for f in (3, 4):
        Image.fromarray(np.full((480, 640, 3), 90, np.uint8)).save(scene / "rgb" / f"{f:06d}.png")
    code = "\n".join(_readme_bop_lines()).replace("data/lmo/test/000002", str(scene))
    namespace = {"data": data, "slam": slam, "volumon": volumon, "q": q, "jnp": jnp, "np": np}
    exec(compile(code, "README.md", "exec"), namespace)
    seen = namespace["seen"]
    assert len(seen) == 2 and seen[0].visible_box[2] == 640 - 0.5  # the cut object reaches the edge
    assert namespace["local"].shape[0] == 2 and bool(namespace["valid"])
