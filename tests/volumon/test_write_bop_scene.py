"""Frames written as a BOP scene (jaxsem.volumon.data.write_bop_scene) read back by the BOP reader
every command uses: poses, intrinsics, visible boxes and fractions, pixels; an existing scene is
not overwritten."""

import numpy as np
import pytest
from test_volumon_bop_eval import RADII_MM, _ellipsoid_mesh_mm, _write_ply

from jaxsem.volumon import data as vdata


def _rotation(rng):
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def _frames(rng):
    out = []
    for f in range(3):
        K = np.array([[500.0 + 40 * f, 0.0, 160.0], [0.0, 505.0 + 40 * f, 118.0 + f], [0.0, 0.0, 1.0]])
        objs = []
        for oid in (1, 5):
            x0, y0 = rng.integers(0, 200), rng.integers(0, 150)
            box = np.array([x0 - 0.5, y0 - 0.5, x0 + rng.integers(5, 60) + 0.5, y0 + rng.integers(5, 60) + 0.5])
            unseen = f == 2 and oid == 5
            objs.append(
                {
                    "obj_id": oid,
                    "rotation": _rotation(rng),
                    "translation": rng.uniform([-0.2, -0.2, 0.5], [0.2, 0.2, 1.5]),
                    "visible_box": np.full(4, np.nan) if unseen else box,
                    "visible_fraction": 0.0 if unseen else float(rng.uniform(0.1, 1.0)),
                }
            )
        out.append({"rgb": rng.integers(0, 256, (240, 320, 3), dtype=np.uint8), "K": K, "objects": objs})
    return out


def test_a_written_scene_reads_back_through_the_bop_reader(tmp_path):
    rng = np.random.default_rng(0)
    frames = _frames(rng)
    scene = tmp_path / "lmo" / "test" / "000001"
    assert vdata.write_bop_scene(frames, scene) == scene
    (tmp_path / "lmo" / "models").mkdir()  # BOP's layout: the meshes two levels up
    for oid, r in RADII_MM.items():
        _write_ply(tmp_path / "lmo" / "models" / f"obj_{oid:06d}.ply", _ellipsoid_mesh_mm(r))
    back = vdata.load_bop_split(scene, "all")
    assert [f.frame_id for f in back.frames] == [0, 1, 2]
    for fr, got in zip(frames, back.frames):
        np.testing.assert_allclose(got.K, fr["K"])
        assert tuple(got.image_size) == (320, 240)
        np.testing.assert_array_equal(vdata.read_rgb(got.image_path), fr["rgb"])
        assert [o.class_name for o in got.objects] == ["ape", "can"]
        for o, g in zip(fr["objects"], got.objects):
            np.testing.assert_allclose(g.rotation, o["rotation"], atol=1e-12)
            np.testing.assert_allclose(g.translation, o["translation"], atol=1e-12)
            np.testing.assert_allclose(g.visible_box, o["visible_box"], atol=1e-9)  # NaN where unseen, both
            assert g.visible_fraction == pytest.approx(o["visible_fraction"])
    with pytest.raises(ValueError, match="scene_dir"):
        vdata.write_bop_scene(frames[:1], scene)
    with pytest.raises(ValueError, match="size"):
        vdata.write_bop_scene([frames[0], {**frames[1], "rgb": frames[1]["rgb"][:200]}], tmp_path / "sizes")
    with pytest.raises(ValueError, match="rgb"):
        vdata.write_bop_scene([{**frames[0], "rgb": frames[0]["rgb"].astype(float)}], tmp_path / "other")
