"""The textured-object FAT writer (jaxsem.volumon.data.write_object_dataset), on a procedural mesh.

Runs without robosuite: the fixture is a box mesh with UVs and a checker texture written to a
temporary folder. The robosuite tests skip when the ``objects`` extra is not installed.
"""

from __future__ import annotations

import json
import pathlib

import cv2
import numpy as np
import pytest

from jaxsem import classes, quadrics as Q
from jaxsem.data import FatSequence, cuboid_corners, load_fat_annotations
from jaxsem.volumon.data import (
    MeshAsset,
    ObjectAssets,
    ObjectAssetsMissingError,
    robosuite_assets,
    volumon_eval_batch,
    write_object_dataset,
)

# the fixture's box: extents and the offset of its centre from the mesh file's origin
DIMS = np.array([0.12, 0.08, 0.05])
OFFSET = np.array([0.01, -0.02, 0.015])
SIZE = (128, 96)


def _box_obj(path: pathlib.Path, dims, offset) -> pathlib.Path:
    """An OBJ box (24 vertices with UVs, 12 triangles) with its centre at ``offset``."""
    half = np.asarray(dims) / 2
    lines, faces = [], []
    for axis in range(3):
        for sign in (-1.0, 1.0):
            u, v = [a for a in range(3) if a != axis]
            quad = []
            for su, sv in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
                p = np.zeros(3)
                p[axis], p[u], p[v] = sign * half[axis], su * half[u], sv * half[v]
                lines.append("v {:.6f} {:.6f} {:.6f}".format(*(p + offset)))
                lines.append(f"vt {(su + 1) / 2:.1f} {(sv + 1) / 2:.1f}")
                quad.append(len(lines) // 2)
            if (sign > 0) != (axis == 1):  # outward normals (counter-clockwise seen from outside)
                quad = quad[::-1]
            a, b, c, d = quad
            faces += [f"f {a}/{a} {c}/{c} {b}/{b}", f"f {a}/{a} {d}/{d} {c}/{c}"]
    path.write_text("\n".join(lines + faces) + "\n")
    return path


def _checker_png(path: pathlib.Path) -> pathlib.Path:
    cells = (np.indices((8, 8)).sum(0) % 2).astype(np.uint8)
    img = np.kron(cells, np.ones((16, 16), np.uint8))[..., None] * np.array([40, 200, 230], np.uint8)
    cv2.imwrite(str(path), img + 20)
    return path


@pytest.fixture(scope="module")
def assets(tmp_path_factory):
    d = tmp_path_factory.mktemp("mesh")
    mesh = MeshAsset(
        "cracker_box",
        _box_obj(d / "box.obj", DIMS, OFFSET),
        texture_file=_checker_png(d / "checker.png"),
        volumon_class="cracker_box",
    )
    return ObjectAssets((mesh,), source="test fixture")


def _write(out, assets, seed=3, scenes=1, frames=3):
    return write_object_dataset(
        out,
        scenes,
        seed=seed,
        split="test",
        assets=assets,
        frames_per_scene=frames,
        image_size=SIZE,
        image_format="png",
        num_distractors=2,
        progress=False,
    )


@pytest.fixture(scope="module")
def scene(assets, tmp_path_factory):
    return _write(tmp_path_factory.mktemp("objects"), assets)[0]


def test_rendered_box_matches_projected_cuboid(scene):
    """The object's pixels in the segmentation span the box of its projected ground-truth cuboid."""
    seq = FatSequence(scene, load_right_image=True)
    assert len(seq) == 3
    for ann in load_fat_annotations(scene):
        assert ann.class_names == ("cracker_box",)
        stem = ann.path.name.split(".")[0]
        for side, offset, boxes in (("left", 0.0, ann.boxes_left), ("right", -ann.baseline, ann.boxes_right)):
            seg = cv2.imread(str(scene / f"{stem}.{side}.seg.png"), cv2.IMREAD_UNCHANGED)
            ys, xs = np.nonzero(seg == 12 * (classes.index("cracker_box") + 1))
            assert len(xs) > 20
            centre = ann.center[0] + np.array([offset, 0.0, 0.0])
            corners = Q.cuboid_corners(ann.rotation[0], centre, ann.dimensions[0] / 2, xp=np)
            uv = Q.project_points(corners, ann.K, np.eye(4), xp=np)[0]
            projected = np.concatenate([uv.min(0), uv.max(0)])
            # pixel i covers [i - 0.5, i + 0.5]: the mask's outer edges, against the exact box
            mask_box = np.array([xs.min() - 0.5, ys.min() - 0.5, xs.max() + 0.5, ys.max() + 0.5])
            np.testing.assert_allclose(mask_box, projected, atol=1.5)
            np.testing.assert_allclose(boxes[0], projected, atol=1e-6)  # a box mesh: vertex box = cuboid box


def test_round_trip_through_the_fat_loader(scene):
    """Pose and extents read back by load_fat_annotations rebuild the file's cuboid within 1 mm."""
    anns = load_fat_annotations(scene)
    for ann in anns:
        raw = json.loads(ann.path.read_text())["objects"][0]
        corners = cuboid_corners(ann.rotation[0], ann.center[0], ann.dimensions[0])
        np.testing.assert_allclose(corners, np.asarray(raw["cuboid"]) * 0.01, atol=1e-3)
        np.testing.assert_allclose(ann.dimensions[0], DIMS, atol=1e-5)  # read from the compiled mesh
        assert raw["mesh_class"] == "cracker_box" and ann.has_right.all()
    frame = FatSequence(scene)[0]
    assert frame.depth.shape == SIZE[::-1] and frame.depth[frame.seg == 0].min() > 0.1
    batch = volumon_eval_batch(scene.parent, input_size=32, global_padding=0.2, num_points=16)
    assert len(batch["local"]) == 3


def test_same_seed_same_files(assets, scene, tmp_path):
    again = _write(tmp_path / "a", assets)[0]
    files = sorted(p.name for p in scene.iterdir())
    assert files == sorted(p.name for p in again.iterdir())
    for name in files:
        assert (scene / name).read_bytes() == (again / name).read_bytes(), name
    other = _write(tmp_path / "b", assets, seed=4, frames=1)[0]
    assert (other / "000000.left.json").read_text() != (scene / "000000.left.json").read_text()
    assert not list((tmp_path / "a" / "test").glob("*.partial"))


def test_missing_robosuite_names_the_extra(tmp_path, monkeypatch):
    with pytest.raises(ObjectAssetsMissingError, match=r"jaxsem\[objects\]"):
        robosuite_assets(tmp_path)
    import importlib.util

    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None)
    with pytest.raises(ObjectAssetsMissingError, match=r"robosuite package is not installed.*jaxsem\[objects\]"):
        robosuite_assets()
    from jaxsem.volumon.data import make_objects

    with pytest.raises(ObjectAssetsMissingError, match=r"jaxsem\[objects\]"):
        make_objects.main(["--out", str(tmp_path / "out"), "--scenes", "1"])


@pytest.mark.parametrize(
    "kwargs, name",
    [
        (dict(labels="coco"), "labels"),
        (dict(split="holdout"), "split"),
        (dict(image_size=(16, 16)), "image_size"),
        (dict(depth_range=(1.0, 0.5)), "depth_range"),
        (dict(max_objects=0), "max_objects"),
        (dict(num_distractors=-1), "num_distractors"),
        (dict(image_format="bmp"), "image_format"),
        (dict(assets="robosuite"), "assets"),
    ],
)
def test_bad_arguments_are_named(assets, tmp_path, kwargs, name):
    kwargs = {"assets": assets, **kwargs}
    with pytest.raises(ValueError, match=name):
        write_object_dataset(tmp_path, 1, progress=False, **kwargs)
    assert not (tmp_path / "test").exists() and not list(tmp_path.glob("*/scene_*"))


def test_mesh_asset_checks(tmp_path):
    with pytest.raises(ObjectAssetsMissingError, match="mesh_file"):
        MeshAsset("cracker_box", tmp_path / "none.obj")
    mesh = _box_obj(tmp_path / "b.obj", DIMS, OFFSET)
    with pytest.raises(ValueError, match="volumon_class"):
        MeshAsset("cracker_box", mesh, volumon_class="ball")  # a cuboid cannot stand in for an ellipsoid
    with pytest.raises(ValueError, match="unknown class"):
        MeshAsset("toaster", mesh)


def test_robosuite_meshes_match_the_class_table():
    """The six robosuite meshes, compiled by MuJoCo, have the class table's extents (within 1 mm)."""
    try:  # not pytest.importorskip: importing robosuite pulls its simulation dependencies
        assets = robosuite_assets()
    except ObjectAssetsMissingError:
        pytest.skip("robosuite (the 'objects' extra) is not installed")
    import mujoco

    for ob in assets.objects:
        spec = mujoco.MjSpec()
        spec.add_mesh(name="m", file=str(ob.mesh_file), scale=list(ob.scale))
        spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_MESH, meshname="m")
        m = spec.compile()
        v = m.mesh_vert[: m.mesh_vertnum[0]]
        R = np.zeros(9)
        mujoco.mju_quat2Mat(R, m.geom_quat[0])
        v = v @ R.reshape(3, 3).T
        dims = v.max(0) - v.min(0)
        expected = np.asarray(classes.get(ob.class_name).dimensions)
        tol = 2e-3 if ob.class_name == "bottle" else 1e-3  # the table keeps the bottle round
        np.testing.assert_allclose(dims, expected, atol=tol, err_msg=ob.class_name)
    import importlib.metadata

    dist = importlib.metadata.distribution("robosuite")
    licence = next(f for f in dist.files or () if str(f).endswith("licenses/LICENSE"))
    assert "MIT License" in licence.read_text()


@pytest.mark.slow
def test_robosuite_scene_renders(tmp_path):
    try:
        assets = robosuite_assets()
    except ObjectAssetsMissingError:
        pytest.skip("robosuite (the 'objects' extra) is not installed")
    (scene,) = write_object_dataset(
        tmp_path, 1, seed=0, split="test", assets=assets, frames_per_scene=2, progress=False
    )
    for ann in load_fat_annotations(scene):
        assert set(ann.class_names) <= {"cracker_box", "soup_can", "ball"}
        for i in range(ann.num_objects):
            corners = cuboid_corners(ann.rotation[i], ann.center[i], ann.dimensions[i])
            raw = json.loads(ann.path.read_text())["objects"][i]
            np.testing.assert_allclose(corners, np.asarray(raw["cuboid"]) * 0.01, atol=1e-3)
