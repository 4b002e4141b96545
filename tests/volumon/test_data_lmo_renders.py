"""Rendered LM-O desk scenes (jaxsem.volumon.data.render_desk_frames and friends) on procedural meshes.

The fixtures are coloured box meshes standing in for the eight LM-O objects (written as BOP PLY
files in millimetres), rendered small; nothing here needs the LM-O data. The shipped LM-O model's
tests load it from the package; its real-frame check skips when LM-O is absent.
"""

from __future__ import annotations

import dataclasses
import pathlib

import numpy as np
import pytest

from jaxsem import data, quadrics as Q, volumon
from jaxsem.data import Mesh
from jaxsem.training import ConfigMismatchError
from jaxsem.volumon import data as vdata
from jaxsem.volumon._configs import LMO_CLASS_NAMES, tiny_config  # layers: white-box
from jaxsem.volumon._train import TRAIN_KEYS, init_state  # layers: white-box
from jaxsem.volumon.data import LMO_OBJECT_IDS, DeskConfig
from jaxsem.volumon.data._bop_eval import LMO_TUNE_BELOW  # layers: white-box
from jaxsem.volumon.data._lmo_renders import concat_npz  # layers: white-box

SIZE = (128, 96)
K_SMALL = np.array([[114.5, 0.0, 64.0], [0.0, 114.7, 48.0], [0.0, 0.0, 1.0]])  # LM-O's field of view at 128 x 96
COLOURS = {1: (220, 30, 30), 5: (30, 200, 40)}


def _box_mesh(dims, colour) -> Mesh:
    """A closed box mesh (8 vertices, 12 outward triangles) with one vertex colour."""
    half = np.asarray(dims, np.float64) / 2
    v = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], np.float64) * half
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    faces = []
    for a, b, c, d in quads:
        for tri in ((a, b, c), (a, c, d)):
            p = v[list(tri)]
            n = np.cross(p[1] - p[0], p[2] - p[0])
            faces.append(tri if n @ p.mean(0) > 0 else (tri[0], tri[2], tri[1]))
    colors = np.tile(np.asarray(colour, np.uint8), (8, 1))
    return Mesh(v, colors, np.asarray(faces, np.int64))


def _write_ply(path: pathlib.Path, mesh: Mesh):
    lines = [
        "ply",
        "format ascii 1.0",
        f"element vertex {len(mesh.vertices)}",
        "property float x",
        "property float y",
        "property float z",
        "property uchar red",
        "property uchar green",
        "property uchar blue",
        f"element face {len(mesh.faces)}",
        "property list uchar int vertex_indices",
        "end_header",
    ]
    for p, c in zip(mesh.vertices * 1000.0, mesh.colors):
        lines.append(f"{p[0]:.4f} {p[1]:.4f} {p[2]:.4f} {c[0]} {c[1]} {c[2]}")
    lines += [f"3 {a} {b} {c}" for a, b, c in mesh.faces]
    path.write_text("\n".join(lines) + "\n")


@pytest.fixture(scope="module")
def two_meshes():
    return {1: _box_mesh((0.08, 0.06, 0.1), COLOURS[1]), 5: _box_mesh((0.07, 0.07, 0.12), COLOURS[5])}


@pytest.fixture(scope="module")
def frames(two_meshes):
    cfg = DeskConfig(objects=(2, 2), distractors=(0, 1), frames_per_scene=2, distance=(0.7, 0.9))
    return list(vdata.render_desk_frames(two_meshes, 3, seed=3, config=cfg, K=K_SMALL, image_size=SIZE))


def test_face_color_atlas_gives_each_triangle_its_mean_vertex_colour():
    mesh = _box_mesh((1, 1, 1), (0, 0, 0))
    colors = np.arange(24, dtype=np.uint8).reshape(8, 3) * 10
    mesh = Mesh(mesh.vertices, colors, mesh.faces)
    uv, fuv, tex = vdata.face_color_atlas(mesh)
    S = tex.shape[0]
    assert tex.shape == (4, 4, 3) and S * S >= len(mesh.faces)
    assert uv.shape == (12, 2) and fuv.shape == (12, 3) and np.all(fuv == np.arange(12)[:, None])
    texel = np.floor(uv * S).astype(int)  # (column, row) of each triangle's texel
    expect = np.round(colors[mesh.faces].astype(np.float64).mean(1))
    np.testing.assert_array_equal(tex[texel[:, 1], texel[:, 0]], expect)
    np.testing.assert_allclose((uv * S) % 1.0, 0.5)  # texel centres: no bleeding


def test_rendered_frames_boxes_match_quadrics_projections_and_masks(frames, two_meshes):
    assert len(frames) == 3
    seen = 0
    for fr in frames:
        H, W = fr["seg"].shape
        assert (W, H) == SIZE and fr["rgb"].shape == (H, W, 3) and fr["rgb"].dtype == np.uint8
        assert set(np.unique(fr["seg"]).tolist()) <= {0, 1, 5}
        assert np.all(fr["depth"][fr["seg"] > 0] > 0.3)
        for o in fr["objects"]:
            mesh = two_meshes[o["obj_id"]]
            R, t = o["rotation"], o["translation"]
            np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-9)
            np.testing.assert_allclose(o["center"], R @ mesh.center + t, atol=1e-9)
            np.testing.assert_allclose(o["radii"], mesh.radii)
            uv, _ = Q.project_points(mesh.vertices @ R.T + t, K_SMALL, np.eye(4), xp=np)
            np.testing.assert_allclose(o["box_left"], np.concatenate([uv.min(0), uv.max(0)]), atol=1e-6)
            uv_r, _ = Q.project_points(mesh.vertices @ R.T + t - [0.06, 0, 0], K_SMALL, np.eye(4), xp=np)
            np.testing.assert_allclose(o["box_right"], np.concatenate([uv_r.min(0), uv_r.max(0)]), atol=1e-6)
            assert 0.0 <= o["visible_fraction"] <= 1.0 + 1e-9
            if o["visible_fraction"] > 0.2:
                seen += 1
                vb, ab = o["visible_box"], o["box_left"]
                assert np.all(vb[:2] >= ab[:2] - 1.5) and np.all(vb[2:] <= ab[2:] + 1.5)
                # the baked vertex colour shows: the red box is red, the green box green
                rgb = fr["rgb"][fr["seg"] == o["obj_id"]].astype(float).mean(0)
                main = 0 if o["obj_id"] == 1 else 1
                assert rgb[main] == rgb.max()
    assert seen >= 2


def test_detections_hold_visible_boxes_amodal_labels_and_depth_points(frames):
    det = vdata.detections_from_frames(frames, input_size=24, global_padding=0.1, num_points=16, min_visible=0.2)
    B = len(det["box_input"])
    assert B >= 2
    assert det["local"].shape == (B, 24, 24, 3) and det["local"].dtype == np.uint8
    assert det["points"].shape == (B, 16, 3) and det["point_mask"].any(1).all()
    assert set(det["class_id"].tolist()) <= {0, 1}  # ape, can rows
    assert set(det["class_shape"].tolist()) <= {1, 2}  # ape drawn as an ellipsoid, the can as a cylinder
    for b in range(B):
        pts = det["points"][b][det["point_mask"][b]]
        uv, z = Q.project_points(pts, det["K"][b], np.eye(4), xp=np)
        box = det["box_input"][b]
        assert np.all(z > 0) and np.all(uv >= box[:2] - 1) and np.all(uv <= box[2:] + 1)
        # the points lie on the object: within its mesh extent's box around the true centre
        local = (pts - det["gt_center"][b]) @ det["gt_rotation"][b]
        assert np.all(np.abs(local) <= det["gt_half_extents"][b] + 2e-3)


def test_desk_config_and_meshes_are_checked(two_meshes):
    with pytest.raises(ValueError, match="distance"):
        DeskConfig(distance=(0.1, 0.5))
    with pytest.raises(ValueError, match="objects"):
        DeskConfig(objects=(0, 3))
    with pytest.raises(ValueError, match="meshes"):
        next(vdata.render_desk_frames({2: two_meshes[1]}, 1, 0))
    with pytest.raises(ValueError, match="obj_000001.ply"):
        vdata.load_lmo_meshes("/nonexistent")


@pytest.fixture(scope="module")
def desk_dir(tmp_path_factory):
    root = tmp_path_factory.mktemp("desk")
    models = root / "models"
    models.mkdir()
    rng = np.random.default_rng(0)
    for i in LMO_OBJECT_IDS:
        _write_ply(models / f"obj_{i:06d}.ply", _box_mesh(rng.uniform(0.05, 0.12, 3), rng.integers(0, 255, 3)))
    out = root / "det"
    cfg = DeskConfig(objects=(3, 4), distractors=(0, 1), frames_per_scene=2, distance=(0.9, 1.1))
    vdata.write_desk_detections(out, 4, seed=0, models_dir=models, chunk=2, config=cfg, progress=False, previews=1)
    return out


def test_write_desk_detections_resumes_and_batches_are_pure_functions_of_the_step(desk_dir):
    chunks = sorted(desk_dir.glob("chunk_*.npz"))
    assert [c.name for c in chunks] == ["chunk_0000.npz", "chunk_0001.npz"]
    assert (desk_dir / "preview_0.jpg").is_file()
    stamp = chunks[0].stat().st_mtime_ns
    models = desk_dir.parent / "models"
    cfg = DeskConfig(objects=(3, 4), distractors=(0, 1), frames_per_scene=2, distance=(0.9, 1.1))
    vdata.write_desk_detections(desk_dir, 4, seed=0, models_dir=models, chunk=2, config=cfg, progress=False)
    assert chunks[0].stat().st_mtime_ns == stamp  # written chunks are skipped
    with pytest.raises(ConfigMismatchError, match="config.objects"):  # not under other settings
        vdata.write_desk_detections(desk_dir, 4, seed=0, models_dir=models, chunk=2, progress=False)
    assert vdata.is_desk_detections(desk_dir) and not vdata.is_desk_detections(models)
    det = vdata.load_desk_detections(desk_dir)
    n = len(det["box_input"])
    fn, num = vdata.desk_batch_source(desk_dir, batch_size=3, seed=1)
    assert num == n
    a, b = fn(5), fn(5)
    assert set(TRAIN_KEYS) <= set(a)
    for k in a:
        np.testing.assert_array_equal(a[k], b[k])
    assert a["local"].dtype == np.float32 and a["local"].max() <= 1.0
    ev = vdata.desk_eval_batch(desk_dir, num=2)
    assert len(ev["box_input"]) == 2 and "visible_fraction" in ev
    with pytest.raises(ValueError, match="fewer than one batch"):
        vdata.desk_batch_source(desk_dir, batch_size=n + 1)


@pytest.mark.slow  # two network initialisations compile (~10 s on a busy 2-core CPU)
def test_warm_start_copies_layers_and_maps_class_rows():
    base = tiny_config()
    src_cfg = base.replace(model=base.model.__class__(**{**vars(base.model), "num_classes": 2}))
    dst_cfg = base.replace(model=base.model.__class__(**{**vars(base.model), "num_classes": 3}))
    state, _, _ = init_state(src_cfg.replace(seed=7))
    src = {"params": state["params"], "batch_stats": state["batch_stats"]}
    out = volumon.warm_start_variables(src, dst_cfg, [1, 0, 1])
    k_src = np.asarray(src["params"]["local_out"]["kernel"]).reshape(-1, 2, 9)
    k_out = np.asarray(out["params"]["local_out"]["kernel"]).reshape(-1, 3, 9)
    np.testing.assert_array_equal(k_out, k_src[:, [1, 0, 1]])
    np.testing.assert_array_equal(
        np.asarray(out["params"]["class_out"]["bias"]), np.asarray(src["params"]["class_out"]["bias"])[[1, 0, 1]]
    )
    np.testing.assert_array_equal(
        np.asarray(out["params"]["local_fc0"]["kernel"]), np.asarray(src["params"]["local_fc0"]["kernel"])
    )
    with pytest.raises(ValueError, match="class_map"):
        volumon.warm_start_variables(src, dst_cfg, [0, 1])
    with pytest.raises(ValueError, match="class_map"):
        volumon.warm_start_variables(src, dst_cfg, [0, 1, 2])


def test_lmo_preset_is_the_fast_network_with_eight_classes():
    cfg = volumon.get_config("both", "lmo")
    fast = volumon.get_config("both", "fast")
    assert cfg.model.num_classes == 8 and cfg.class_names == LMO_CLASS_NAMES == vdata.LMO_CLASS_NAMES
    assert dataclasses.replace(cfg.model, num_classes=4) == fast.model  # so the shipped object model warm-starts it
    assert volumon.get_config("oracle", "lmo").loss.alpha_O == 1.0


def test_shipped_lmo_model_loads_under_25_mb_with_its_oracle():
    model, variables, cfg, meta = volumon.load_pretrained(kind="lmo")
    assert cfg.model.num_classes == 8 and tuple(cfg.class_names) == vdata.LMO_CLASS_NAMES
    assert cfg.variant == "both" and meta["name"] == "volumon_lmo"
    d = volumon.PRETRAINED_DIR
    files = [d / f"volumon_lmo{s}" for s in (".npz", ".json", "_oracle.npz", "_oracle.json", "_curves.png")]
    assert sum(f.stat().st_size for f in files) < 25e6
    _, _, o_cfg, o_meta = volumon.load_pretrained(d / f"{volumon.ORACLES['lmo']}.npz")
    assert o_cfg.variant == "oracle" and o_meta["step"] == meta["step"]
    assert o_cfg.data_dir == cfg.data_dir  # the same renders


@pytest.mark.slow
def test_eval_command_scores_desk_renders_with_the_shipped_oracle(desk_dir, run_cli, tmp_path):
    out = tmp_path / "held.json"
    status, _, err = run_cli(["volumon", "eval", "--model", "lmo", "--data", str(desk_dir), "--json", str(out)])
    assert status == 0, err
    import json

    r = json.loads(out.read_text())
    assert r["model"] == "volumon_lmo" and r["num"] >= 1
    for part in (r, r["baseline"], r["oracle"]):
        assert np.isfinite(part["median_center_error_m"]) and "trans_auc" in part
    assert r["baseline"]["median_size_rel_error"] < 1e-6  # given the true extents
    status, _, err = run_cli(["volumon", "eval", "--model", "lmo", "--data", str(desk_dir), "--postopt", "5"])
    assert status != 0 and "--postopt" in err


@pytest.mark.slow
def test_shipped_lmo_model_beats_the_known_size_baseline_on_tuning_frames_when_present():
    import os

    root = pathlib.Path(os.environ.get("JAXSEM_DATA_DIR", "/nonexistent")) / "lmo" / "test" / "000002"
    if not (root / "scene_gt.json").is_file():
        pytest.skip("LM-O absent (set JAXSEM_DATA_DIR to the folder of `jaxsem data fetch lmo`)")
    scene = data.load_bop_scene(root, frame_filter=lambda i: i < 120)  # a handful of tuning frames only
    assert scene.frames and all(f.frame_id < LMO_TUNE_BELOW for f in scene.frames)
    model, variables, cfg, _ = volumon.load_pretrained(kind="lmo")
    b = vdata.bop_eval_batch(scene, input_size=cfg.model.input_size, global_padding=cfg.model.global_padding)
    rows, _ = volumon.class_rows(b["class_name"], cfg)
    assert np.all(rows >= 0)  # every LM-O class has its own row
    net = volumon.evaluate_scene_batch(model, variables, cfg, b, rows)
    R, c, r = volumon.known_size_ellipsoid(b["box_input"], b["K"], b["gt_half_extents"])
    base = volumon.summarise_detections({"rotation": R, "center": c, "radii": r}, b)
    assert net["num"] == base["num"] > 50
    assert net["trans_auc"] > base["trans_auc"] and net["iou_auc"] > base["iou_auc"]


def test_desk_chunk_reads_check_each_file_before_inflating(tmp_path):
    # A rendered desk-frame chunk is a file a user may copy or truncate: one whose header declares
    # more elements than the budget, one that is not a zip, and one of another kind (an array
    # missing) are each refused naming the file, before any array is inflated.
    frames = tmp_path / "frames"
    frames.mkdir()
    keys = ("image", "K", "boxes")
    np.savez(frames / "frames_0000.npz", **{k: np.zeros((2, 3), np.float32) for k in keys})
    np.savez(frames / "frames_0001.npz", **{k: np.zeros((1, 3), np.float32) for k in keys})
    files = sorted(frames.glob("*.npz"))
    assert concat_npz(files, keys)["image"].shape == (3, 3)
    with pytest.raises(ValueError, match=r"frames_0000\.npz: declares 18 array elements.*max_elements=4"):
        concat_npz(files, keys, max_elements=4)
    np.savez(frames / "frames_0002.npz", image=np.zeros((1, 3)))
    with pytest.raises(ValueError, match=r"frames_0002\.npz: .*no array 'K'"):
        concat_npz(sorted(frames.glob("*.npz")), keys)
    (frames / "frames_0002.npz").write_bytes(b"not a zip")
    with pytest.raises(ValueError, match=r"frames_0002\.npz: not a readable \.npz"):
        concat_npz(sorted(frames.glob("*.npz")), keys)
    with pytest.raises(ValueError, match=r"frames_0000\.npz: .*no array 'class_id'"):
        vdata.load_frame_chunks(frames)  # the reader the R-CNN training uses, with its keys
    np.savez(frames / "frames_0002.npz", **{k: np.zeros((1, 4), np.float32) for k in keys})
    with pytest.raises(ValueError, match=r"frames_0002\.npz: array 'image' has shape \(1, 4\)"):
        concat_npz(sorted(frames.glob("*.npz")), keys)
