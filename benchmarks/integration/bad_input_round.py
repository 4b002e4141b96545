"""The bad-input round, run as a new user would: every command, benchmark and training script
fed broken arguments and broken files, each case a subprocess, the outcome a table.

Each case must end with no traceback, exit status 2 for bad usage or input (1 for a failure
during the work), and a last line on stderr that names the flag or the file at fault; exit 0 on
bad input is a silent acceptance. The inputs are tiny files written into a temporary folder:
BOP scenes with one broken camera / ground-truth / visibility entry, ROS / MRPT / image maps with
bad headers or values, fetch targets that are a file or cannot be written (``--from`` a local
package file, so no registry is reached), lock, config and stamp files that are garbage or not
UTF-8, and records made under other flags.

    python benchmarks/integration/bad_input_round.py --out benchmarks/integration/bad_input_round.md
    python benchmarks/integration/bad_input_round.py --only bop- --out /tmp/bop.md   # a subset

The table's columns: the case, the command line (the temporary folder written ``$TMP``, this
checkout ``$REPO``), the exit status, the last line of stderr, and the verdict (``ok``, or what
failed). A case that runs past ``--timeout`` did work on bad input (a silent acceptance that had
not finished). The inputs include one real training run (VoluMon's tiny preset, one step), whose
workdir the resume cases reuse; every case runs on the CPU.
"""

from __future__ import annotations

import argparse
import gzip
import json
import os
import pathlib
import shutil
import struct
import subprocess
import sys
import tempfile
import time
import zlib
from typing import NamedTuple

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[2]
JAXSEM = ["-m", "jaxsem.cli"]


class Case(NamedTuple):
    """One bad input: ``argv`` after ``python`` (the temporary folder written ``{d}``), what the
    last stderr line must name (any one of ``names``) and the exit status it must give."""

    id: str
    argv: tuple[str, ...]
    names: tuple[str, ...]
    expect: int = 2


def _script(path: str, *args: str) -> tuple[str, ...]:
    return (str(ROOT / path), *args)


def _jx(*args: str) -> tuple[str, ...]:
    return (*JAXSEM, *args)


# ---------------------------------------------------------------------------------------------
# Inputs


def _png(path: pathlib.Path, width: int, height: int) -> None:
    """A PNG whose header declares ``width x height`` grey pixels; its data is one tiny chunk
    (the header alone is what a bounded reader may look at)."""

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    path.write_bytes(
        b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\0" * 64)) + chunk(b"IEND", b"")
    )


def _gridmap(path: pathlib.Path, size=(20, 20), origin=(0.0, 0.0), resolution=0.1, cells=None, first=None) -> None:
    """An MRPT COccupancyGridMap2D (version 3, 8 bits per cell), optionally broken."""
    name = b"COccupancyGridMap2D"
    sx, sy = size
    head = bytes([first if first is not None else 0x80 | len(name)]) + name + bytes([3, 8])
    head += struct.pack("<II", sx, sy)
    head += struct.pack(
        "<5f", origin[0], origin[0] + sx * resolution, origin[1], origin[1] + sy * resolution, resolution
    )
    body = np.full(sx * sy, 50, np.int8).tobytes() if cells is None else cells
    path.write_bytes(head + body)


def _cube_ply(path: pathlib.Path, half: float = 30.0) -> None:
    """An ASCII PLY cube of half-size ``half`` mm (12 triangles)."""
    v = [(x, y, z) for x in (-half, half) for y in (-half, half) for z in (-half, half)]
    faces = [(0, 1, 3), (0, 3, 2), (4, 6, 7), (4, 7, 5), (0, 4, 5), (0, 5, 1)]
    faces += [(2, 3, 7), (2, 7, 6), (0, 2, 6), (0, 6, 4), (1, 5, 7), (1, 7, 3)]
    lines = ["ply", "format ascii 1.0", f"element vertex {len(v)}", "property float x", "property float y"]
    lines += ["property float z", f"element face {len(faces)}", "property list uchar int vertex_indices", "end_header"]
    lines += [f"{a} {b} {c}" for a, b, c in v] + [f"3 {a} {b} {c}" for a, b, c in faces]
    path.write_text("\n".join(lines) + "\n")


_CAMERA = {"fx": 500.0, "fy": 500.0, "cx": 160.0, "cy": 120.0, "width": 320, "height": 240}


def _bop_scene(d: pathlib.Path, name: str, *, camera=None, gt=None, info=None, camera_raw: bytes | None = None):
    """A BOP scene folder ``d/name/test/000001`` (models two levels up): three cubes in frames
    0-1, with the given camera / scene_gt / scene_gt_info (None: a good one)."""
    scene = d / name / "test" / "000001"
    scene.mkdir(parents=True)
    (d / name / "models").mkdir()
    for oid in (1, 2, 3):
        _cube_ply(d / name / "models" / f"obj_{oid:06d}.ply")
    if camera_raw is not None:
        (scene / "camera.json").write_bytes(camera_raw)
    else:
        (scene / "camera.json").write_text(json.dumps(_CAMERA if camera is None else camera))
    pose = {"cam_R_m2c": [1, 0, 0, 0, 1, 0, 0, 0, 1]}
    good = {
        str(f): [{**pose, "obj_id": o, "cam_t_m2c": [(o - 2) * 150.0, 0.0, 1000.0]} for o in (1, 2, 3)] for f in (0, 1)
    }
    (scene / "scene_gt.json").write_text(gt if isinstance(gt, str) else json.dumps(good if gt is None else gt))
    if info is not None:
        (scene / "scene_gt_info.json").write_text(info if isinstance(info, str) else json.dumps(info))
    return scene


def write_inputs(d: pathlib.Path, trained: bool = True) -> None:
    """Every file the cases read, written into ``d``; ``trained``: also the training run the
    resume cases need (a subset without them skips it)."""
    import cv2  # deferred: the round's own inputs only

    (d / "a_file").write_text("x")
    (d / "empty_dir").mkdir()
    (d / "corrupt.npz").write_bytes(b"this is not a zip file")
    (d / "model_corrupt.npz").write_bytes(b"this is not a zip file")  # no description beside it
    (d / "corrupt.json").write_text("{ not json")
    (d / "latin1.json").write_bytes(b'{"name": "caf\xe9"}')
    (d / "corrupt.png").write_bytes(b"\x89PNG\r\n\x1a\n garbage")
    cv2.imwrite(str(d / "image.png"), np.full((96, 128, 3), 127, np.uint8))
    _png(d / "huge.png", 30000, 30000)
    (d / "boxes.json").write_text("[[10, 10, 60, 50]]")
    (d / "box_nan.json").write_text("[[10, 10, NaN, 50]]")
    (d / "box_str.json").write_text('{"box": "a"}')

    # roshan sequences
    def sequence(name, frames, raw=None, **extra):
        (d / name).mkdir()
        if raw is not None:
            (d / name / "sequence.json").write_bytes(raw)
            return
        data = {"K": [[500.0, 0, 320], [0, 500, 240], [0, 0, 1]], "image_size": [640, 480], "frames": frames, **extra}
        (d / name / "sequence.json").write_text(json.dumps(data))

    det = {"box": [10, 20, 50, 60], "class": "car", "id": 0}
    eye = np.eye(4).tolist()
    sequence("seq_corrupt", [], raw=b'{"K": ')
    sequence("seq_latin1", [], raw=b'{"K": "\xe9"}')
    sequence("seq_good", [{"camera_T_world": eye, "detections": [det]}])
    sequence("seq_misspelt", [{"camera_T_world": eye, "detection": [det]}])
    sequence("seq_huge_box", [{"camera_T_world": eye, "detections": [{**det, "box": [0, 0, 1e9, 1e9]}]}])
    sequence("seq_off_image", [{"camera_T_world": eye, "detections": [{**det, "box": [700, 500, 800, 600]}]}])
    sequence("seq_nan_pose", [{"camera_T_world": [[float("nan")] * 4] * 4, "detections": [det]}])
    sequence("seq_bad_K", [{"camera_T_world": eye, "detections": [det]}], K=[[0, 0, 320], [0, 500, 240], [0, 0, 1]])
    sequence("seq_bad_image", [{"camera_T_world": eye, "detections": [det], "image": "frame0.png"}])
    (d / "seq_bad_image" / "frame0.png").write_bytes(b"\x89PNG\r\n\x1a\n garbage")
    sequence("seq_bad_noise", [{"camera_T_world": eye, "detections": [det]}], noise={"box_sigma": -1})
    # TUM folder with a garbage ground truth
    tum = d / "rgbd_dataset_freiburg1_desk"
    (tum / "rgb").mkdir(parents=True)
    (tum / "rgb.txt").write_text("1.0 rgb/1.0.png\n")
    (tum / "groundtruth.txt").write_text("1.0 a b c d e f g\n")
    (d / "dets.jsonl").write_text('{"frame": "rgb/1.0.png", "detections": []}\n')
    # classes files
    (d / "classes_neg.json").write_text(
        json.dumps({"classes": [{"name": "mug", "dimensions": [-0.1, 0.1, 0.1], "sigma": [0.01, 0.01, 0.01]}]})
    )
    # training workdirs: a lock that is garbage / not UTF-8, a config that is not JSON
    for name, lock in (("wd_lock_garbage", b"garbage\n"), ("wd_lock_latin1", b"\xff\xfe\xe9")):
        (d / name).mkdir()
        (d / name / "train.lock").write_bytes(lock)
    for name in ("wd_config_corrupt", "wd_config_latin1"):
        (d / name).mkdir()
        (d / name / "checkpoints").mkdir()
    (d / "wd_config_corrupt" / "config.json").write_text('{"num_steps": ')
    (d / "wd_config_latin1" / "config.json").write_bytes(b'{"num_steps": "\xe9"}')
    (d / "size_unknown_field.json").write_text('{"no_such_field": 1}')
    # LSD expert shards: a corrupt one; a folder stamped under other settings
    (d / "shards").mkdir()
    (d / "shards" / "expert_train_00000.npz").write_bytes(b"not a zip")
    (d / "stamped").mkdir()
    (d / "stamped" / "stamp_train.json").write_text(json.dumps({"what": "expert shards", "family": "train"}))
    (d / "stamped_latin1").mkdir()
    (d / "stamped_latin1" / "stamp_train.json").write_bytes(b"\xff\xfe")
    # BOP scenes, one broken entry each
    scenes = {
        "fx_zero": {"camera": {**_CAMERA, "fx": 0.0}},
        "fx_neg": {"camera": {**_CAMERA, "fx": -500.0}},
        "width_zero": {"camera": {**_CAMERA, "width": 0}},
        "cy_missing": {"camera": {k: v for k, v in _CAMERA.items() if k != "cy"}},
        "cam_latin1": {"camera_raw": b'{"fx": "\xe9"}'},
        "cam_list": {"camera": [500, 500, 160, 120]},
        "gt_number": {"gt": {"0": 5}},
        "gt_list": {"gt": [[{"obj_id": 1}]]},
        "gt_objid_str": {
            "gt": {"0": [{"obj_id": "abc", "cam_R_m2c": [1, 0, 0, 0, 1, 0, 0, 0, 1], "cam_t_m2c": [0, 0, 1]}]}
        },
        "gt_frame_str": {"gt": {"x": []}},
        "gt_reflection": {
            "gt": {"0": [{"obj_id": 1, "cam_R_m2c": [-1, 0, 0, 0, 1, 0, 0, 0, 1], "cam_t_m2c": [0, 0, 1000]}]}
        },
        "gt_t_short": {"gt": {"0": [{"obj_id": 1, "cam_R_m2c": [1, 0, 0, 0, 1, 0, 0, 0, 1], "cam_t_m2c": [0, 0]}]}},
        "gt_not_json": {"gt": "{ 0: [ }"},
        "info_fract": {"info": {str(f): [{"bbox_visib": [1, 1, 10, 10], "visib_fract": 2.0}] * 3 for f in (0, 1)}},
        "info_count": {"info": {str(f): [{"bbox_visib": [1, 1, 10, 10], "visib_fract": 1.0}] for f in (0, 1)}},
        "info_bbox_str": {"info": {str(f): [{"bbox_visib": "abc", "visib_fract": 1.0}] * 3 for f in (0, 1)}},
        "good": {},
    }
    for name, spec in scenes.items():
        _bop_scene(d, f"bop_{name}", **spec)
    # maps
    m = d / "maps"
    m.mkdir()
    free = np.full((100, 100), 254, np.uint8)
    free[0, :] = free[-1, :] = free[:, 0] = free[:, -1] = 0
    cv2.imwrite(str(m / "room.png"), free)
    cv2.imwrite(str(m / "room.pgm"), free)
    cv2.imwrite(str(m / "black.png"), np.zeros((40, 40), np.uint8))
    _png(m / "huge.png", 30000, 30000)
    (m / "huge.pgm").write_bytes(b"P5\n60000 60000\n255\n" + b"\0" * 64)
    (m / "truncated.pgm").write_bytes(b"P5\n100 100\n255\n" + b"\0" * 10)

    def yaml(name, text):
        (m / name).write_text(text)

    yaml("tiny_res.yaml", "image: room.pgm\nresolution: 1.0e-9\norigin: [0, 0, 0]\n")
    yaml("neg_res.yaml", "image: room.pgm\nresolution: -0.05\norigin: [0, 0, 0]\n")
    yaml("no_image.yaml", "resolution: 0.05\norigin: [0, 0, 0]\n")
    yaml("gone_image.yaml", "image: nowhere.pgm\nresolution: 0.05\norigin: [0, 0, 0]\n")
    yaml("yaw.yaml", "image: room.pgm\nresolution: 0.05\norigin: [0, 0, 0.5]\n")
    yaml("negate.yaml", "image: room.pgm\nresolution: 0.05\norigin: [0, 0, 0]\nnegate: 3\n")
    yaml(
        "thresh.yaml", "image: room.pgm\nresolution: 0.05\norigin: [0, 0, 0]\noccupied_thresh: 0.1\nfree_thresh: 0.9\n"
    )
    yaml("origin_nan.yaml", "image: room.pgm\nresolution: 0.05\norigin: [.nan, 0, 0]\n")
    yaml("garbage.yaml", "image: [room.pgm\nresolution: : :\n")
    yaml("list.yaml", "- image\n- resolution\n")
    yaml("huge_image.yaml", "image: huge.pgm\nresolution: 0.05\norigin: [0, 0, 0]\n")
    yaml("mode.yaml", "image: room.pgm\nresolution: 0.05\norigin: [0, 0, 0]\nmode: fancy\n")
    (m / "latin1.yaml").write_bytes(b"image: caf\xe9.pgm\nresolution: 0.05\n")
    _gridmap(m / "nan_origin.gridmap", origin=(float("nan"), 0.0))
    _gridmap(m / "bad_first.gridmap", first=0x01)
    _gridmap(m / "truncated.gridmap", cells=b"\x10" * 10)
    _gridmap(m / "huge.gridmap", size=(100000, 100000), cells=b"")
    _gridmap(m / "zero_res.gridmap", resolution=0.0)
    _gridmap(m / "occupied.gridmap", cells=np.full(400, -50, np.int8).tobytes())
    (m / "garbage.gridmap.gz").write_bytes(b"not gzip at all")
    with gzip.open(m / "short.gridmap.gz", "wb") as f:
        f.write(b"\x93COccupancyGridMap2D\x03")
    (m / "map.txt").write_text("not a map")
    (m / "ann_garbage.json").write_text("{ doors: ")
    (m / "ann_misspelt.json").write_text(json.dumps({"door": [[1, 1, 2, 2]]}))
    (m / "ann_nan.json").write_text('{"doors": [[1, 1, NaN, 2]]}')
    # lsd_real records: a stamp of other flags, a file of garbage, a file that is not UTF-8
    for name, text in (
        ("other_flags", json.dumps({"stamp": {"max_steps": 150, "protocol": "thesis"}}) + "\n"),
        ("garbage", "garbage\nmore garbage\n"),
    ):
        (d / "records").mkdir(exist_ok=True)
        (d / "records" / f"{name}.records.jsonl").write_text(text)
    (d / "records" / "latin1.records.jsonl").write_bytes(b'{"stamp": {"a": "\xe9"}}\n')
    # fetch targets: the data set's folder is a file; a package that is not one
    (d / "fetch_file_target").mkdir()
    (d / "fetch_file_target" / "mrpt").write_text("mine")
    (d / "garbage.whl").write_bytes(b"not a wheel")
    (d / "garbage.deb").write_bytes(b"!<arch>\ngarbage")
    # VoluMon R-CNN renders folder that is empty
    (d / "renders_empty").mkdir()
    if trained:
        _trained_workdirs(d)


def _trained_workdirs(d: pathlib.Path) -> None:
    """A real one-step VoluMon training run (``d/wd_trained``, the tiny preset) and copies of it
    whose ``config.json`` is garbage or not UTF-8: resumable state that a rerun must check."""
    wd = d / "wd_trained"
    argv = [*JAXSEM, "volumon", "train", "--size", "tiny", "--steps", "1", "--workdir", str(wd)]
    proc = subprocess.run(
        [sys.executable, *argv, "--run-dir", str(d / "runs" / "setup")],
        cwd=d,
        env=_env(d),
        capture_output=True,
        text=True,
        check=False,
    )
    if proc.returncode != 0:
        raise RuntimeError(f"the setup run failed ({' '.join(argv)}):\n{proc.stderr[-2000:]}")
    for name, raw in (("wd_resume_corrupt", b'{"num_steps": '), ("wd_resume_latin1", b'{"seed": "\xe9"}')):
        shutil.copytree(wd, d / name)
        (d / name / "config.json").write_bytes(raw)


# ---------------------------------------------------------------------------------------------
# Cases


def cases() -> list[Case]:
    """Every case of the round (argv with ``{d}`` for the temporary folder)."""
    d = "{d}"
    o = "{d}/out"
    m = "{d}/maps"
    lsd_real = "benchmarks/lsd/lsd_real.py"
    room = ("--map", f"{m}/room.png", "--resolution", "0.1")
    small = ("--trials", "1", "--max-steps", "5", "--min-distance", "1", "--clearance", "0.1", "--no-progress")
    out = []

    def add(id_, argv, names, expect=2):
        out.append(Case(id_, tuple(argv), tuple(names), expect))

    # --- the jaxsem front door and the demo
    add("jaxsem-no-command", _jx(), ["COMMAND", "command"])
    add("jaxsem-unknown-command", _jx("sail"), ["sail"])
    add("demo-parts", _jx("demo", "--parts", "bogus", "--out", f"{o}/demo"), ["--parts", "bogus"])
    add("demo-out-file", _jx("demo", "--parts", "geometry", "--out", f"{d}/a_file"), ["a_file"])
    add("bench-unknown", _jx("bench", "no_such_benchmark", "--run-dir", f"{o}/b1"), ["no_such_benchmark"])
    add("bench-dir-missing", _jx("bench", "--list", "--dir", f"{d}/nope"), ["--dir", "nope"])
    # --- roshan
    sim = ("roshan", "--simulate", "forward", "--out")
    add("roshan-frames-zero", _jx(*sim, f"{o}/r", "--frames", "0"), ["--frames"])
    add("roshan-objects-negative", _jx(*sim, f"{o}/r", "--objects", "-1"), ["--objects"])
    add("roshan-optimize-every-zero", _jx(*sim, f"{o}/r", "--optimize-every", "0"), ["--optimize-every"])
    add("roshan-iterations-negative", _jx(*sim, f"{o}/r", "--iterations", "-2"), ["--iterations"])
    add("roshan-set-unknown-field", _jx(*sim, f"{o}/r", "--set", "no_such.field=1"), ["--set", "no_such"])
    add("roshan-set-not-a-number", _jx(*sim, f"{o}/r", "--set", "noise.box_sigma=abc"), ["--set", "box_sigma"])
    add("roshan-box-sigma-negative", _jx(*sim, f"{o}/r", "--box-sigma", "-1"), ["--box-sigma", "box_sigma"])
    add("roshan-pose-sigma-text", _jx(*sim, f"{o}/r", "--pose-sigma", "a,b"), ["--pose-sigma"])
    add("roshan-plane-fraction-nan", _jx(*sim, f"{o}/r", "--texture-plane-fraction", "nan"), ["texture_plane_fraction", "--texture-plane-fraction"])  # fmt: skip
    add("roshan-overlays-negative", _jx(*sim, f"{o}/r", "--overlays", "-1"), ["--overlays"])
    add("roshan-out-file", _jx(*sim, f"{d}/a_file"), ["a_file"])
    add("roshan-run-dir-under-file", _jx(*sim, f"{o}/r", "--run-dir", f"{d}/a_file/run"), ["--run-dir"])
    good = ("roshan", "--out", f"{o}/r", "--sequence", f"{d}/seq_good")
    add("roshan-classes-with-simulate", _jx(*sim, f"{o}/r", "--classes", f"{d}/classes_neg.json"), ["--classes"])
    add("roshan-classes-corrupt", _jx(*good, "--classes", f"{d}/corrupt.json"), ["corrupt.json"])
    add("roshan-classes-negative", _jx(*good, "--classes", f"{d}/classes_neg.json"), ["classes_neg.json"])
    add("roshan-classes-latin1", _jx(*good, "--classes", f"{d}/latin1.json"), ["latin1.json"])
    add("roshan-detector-with-simulate", _jx(*sim, f"{o}/r", "--detector", "lmo-rcnn"), ["--detector"])
    add("roshan-detector-missing", _jx(*good, "--detector", f"{d}/nope.npz"), ["--detector", "nope.npz"])
    add("roshan-detector-corrupt", _jx(*good, "--detector", f"{d}/model_corrupt.npz"), ["model_corrupt.npz"])
    add("roshan-min-score-range", _jx(*good, "--detector", "lmo-rcnn", "--min-score", "1.5"), ["--min-score"])
    add("roshan-write-sequence-file", _jx(*sim, f"{o}/r", "--frames", "3", "--write-sequence", f"{d}/a_file"), ["--write-sequence", "a_file"])  # fmt: skip
    add("roshan-write-sequence-with-sequence", _jx(*good, "--write-sequence", f"{o}/ws"), ["--write-sequence"])
    seq = ("roshan", "--out", f"{o}/r", "--sequence")
    add("roshan-sequence-missing", _jx(*seq, f"{d}/nope"), ["nope"])
    add("roshan-sequence-corrupt", _jx(*seq, f"{d}/seq_corrupt"), ["sequence.json"])
    add("roshan-sequence-latin1", _jx(*seq, f"{d}/seq_latin1"), ["sequence.json"])
    add("roshan-sequence-misspelt-key", _jx(*seq, f"{d}/seq_misspelt"), ["sequence.json"])
    add("roshan-sequence-huge-box", _jx(*seq, f"{d}/seq_huge_box"), ["sequence.json"])
    add("roshan-sequence-off-image-box", _jx(*seq, f"{d}/seq_off_image"), ["sequence.json"])
    add("roshan-sequence-nan-pose", _jx(*seq, f"{d}/seq_nan_pose"), ["sequence.json"])
    add("roshan-sequence-zero-focal", _jx(*seq, f"{d}/seq_bad_K"), ["sequence.json"])
    add("roshan-sequence-bad-image", _jx(*seq, f"{d}/seq_bad_image"), ["frame0.png"])
    add("roshan-sequence-negative-noise", _jx(*seq, f"{d}/seq_bad_noise"), ["sequence.json"])
    add("roshan-tum-no-detections", _jx("roshan", "--out", f"{o}/r", "--tum", f"{d}/rgbd_dataset_freiburg1_desk"), ["--detections"])  # fmt: skip
    add("roshan-tum-groundtruth-garbage", _jx("roshan", "--out", f"{o}/r", "--tum", f"{d}/rgbd_dataset_freiburg1_desk", "--detections", f"{d}/dets.jsonl"), ["groundtruth.txt"])  # fmt: skip
    # --- BOP scenes (roshan --bop; volumon eval / predict on a scene)
    bop = ("roshan", "--out", f"{o}/r", "--bop")

    def scene(name):
        return f"{d}/bop_{name}/test/000001"

    # each broken scene's error names its broken file, and the field for the camera's numbers
    broken_scenes = {
        "camera.json": ("fx_zero", "fx_neg", "width_zero", "cy_missing", "cam_latin1", "cam_list"),
        "scene_gt.json": (
            "gt_number",
            "gt_list",
            "gt_objid_str",
            "gt_frame_str",
            "gt_reflection",
            "gt_t_short",
            "gt_not_json",
        ),
        "scene_gt_info.json": ("info_fract", "info_count", "info_bbox_str"),
    }
    camera_fields = {"fx_zero": "fx", "fx_neg": "fx", "width_zero": "width", "cy_missing": "cy"}
    for file, names in broken_scenes.items():
        for name in names:
            field = [camera_fields[name]] if name in camera_fields else []
            add(f"bop-{name.replace('_', '-')}", _jx(*bop, scene(name)), [file, *field])
    add("bop-stretch-out-of-range", _jx(*bop, scene("good"), "--stretch", "99"), ["--stretch"])
    add("bop-eval-fx-zero", _jx("volumon", "eval", "--data", scene("fx_zero"), "--split", "all"), ["camera.json"])
    add("bop-eval-info-fract", _jx("volumon", "eval", "--data", scene("info_fract"), "--split", "all"), ["scene_gt_info.json"])  # fmt: skip
    add("bop-predict-frame-missing", _jx("volumon", "predict", "--data", scene("good"), "--frame", "99", "--out", f"{o}/vp"), ["--frame", "99"])  # fmt: skip
    add("bop-predict-gt-number", _jx("volumon", "predict", "--data", scene("gt_number"), "--frame", "0", "--out", f"{o}/vp"), ["scene_gt.json"])  # fmt: skip
    # --- volumon
    pred = ("volumon", "predict", "--out", f"{o}/vp")
    add("volumon-predict-image-missing", _jx(*pred, "--image", f"{d}/nope.png", "--boxes", f"{d}/boxes.json"), ["nope.png"])  # fmt: skip
    add("volumon-predict-image-corrupt", _jx(*pred, "--image", f"{d}/corrupt.png", "--boxes", f"{d}/boxes.json"), ["corrupt.png"])  # fmt: skip
    add("volumon-predict-image-huge", _jx(*pred, "--image", f"{d}/huge.png", "--boxes", f"{d}/boxes.json"), ["huge.png"])  # fmt: skip
    add("volumon-predict-box-nan", _jx(*pred, "--image", f"{d}/image.png", "--boxes", f"{d}/box_nan.json"), ["box_nan.json"])  # fmt: skip
    add("volumon-predict-box-string", _jx(*pred, "--image", f"{d}/image.png", "--boxes", f"{d}/box_str.json"), ["box_str.json"])  # fmt: skip
    add("volumon-predict-boxes-latin1", _jx(*pred, "--image", f"{d}/image.png", "--boxes", f"{d}/latin1.json"), ["latin1.json"])  # fmt: skip
    add("volumon-predict-K-focal", _jx(*pred, "--image", f"{d}/image.png", "--boxes", f"{d}/boxes.json", "--K", "0,1,2,3"), ["--K"])  # fmt: skip
    add("volumon-predict-class-id", _jx(*pred, "--image", f"{d}/image.png", "--boxes", f"{d}/boxes.json", "--class-id", "99"), ["--class-id"])  # fmt: skip
    add("volumon-predict-num-zero", _jx(*pred, "--split", "test", "--num", "0"), ["--num"])
    add("volumon-predict-workdir-config-corrupt", _jx(*pred, "--workdir", f"{d}/wd_config_corrupt", "--split", "test", "--num", "2"), ["config.json"])  # fmt: skip
    add("volumon-detect-image-huge", _jx("volumon", "detect", "--image", f"{d}/huge.png", "--K", "500,500,64,48", "--out", f"{o}/vd"), ["huge.png"])  # fmt: skip
    add("volumon-detect-K-focal", _jx("volumon", "detect", "--image", f"{d}/image.png", "--K", "0,500,64,48", "--out", f"{o}/vd"), ["--K"])  # fmt: skip
    add("volumon-detect-min-score", _jx("volumon", "detect", "--image", f"{d}/image.png", "--K", "500,500,64,48", "--min-score", "1.5", "--out", f"{o}/vd"), ["--min-score"])  # fmt: skip
    add("volumon-detect-model-corrupt", _jx("volumon", "detect", "--model", f"{d}/model_corrupt.npz", "--image", f"{d}/image.png", "--K", "500,500,64,48", "--out", f"{o}/vd"), ["model_corrupt.npz"])  # fmt: skip
    add("volumon-eval-num-zero", _jx("volumon", "eval", "--num", "0"), ["--num"])
    add("volumon-eval-workdir-missing", _jx("volumon", "eval", "--workdir", f"{d}/nope"), ["nope"])
    add("volumon-eval-config-latin1", _jx("volumon", "eval", "--workdir", f"{d}/wd_config_latin1", "--num", "2"), ["config.json"])  # fmt: skip
    add("volumon-eval-input-size", _jx("volumon", "eval", "--model", "lmo-rcnn", "--input-size", "17,abc"), ["--input-size"])  # fmt: skip
    add("volumon-eval-json-under-file", _jx("volumon", "eval", "--num", "2", "--json", f"{d}/a_file/eval.json"), ["--json", "a_file"])  # fmt: skip
    add("volumon-export-workdir-missing", _jx("volumon", "export", "--workdir", f"{d}/nope", "--out", f"{o}/ve"), ["nope"])  # fmt: skip
    add("volumon-export-no-checkpoint", _jx("volumon", "export", "--workdir", f"{d}/empty_dir", "--out", f"{o}/ve"), ["empty_dir"])  # fmt: skip
    tr = ("volumon", "train", "--size", "tiny", "--steps", "1", "--workdir")
    add("volumon-train-workdir-file", _jx(*tr, f"{d}/a_file"), ["a_file"])
    add("volumon-train-size-unknown", _jx("volumon", "train", "--workdir", f"{o}/vt", "--size", "enormous"), ["--size", "enormous"])  # fmt: skip
    add("volumon-train-size-corrupt", _jx("volumon", "train", "--workdir", f"{o}/vt", "--size", f"{d}/corrupt.json"), ["corrupt.json"])  # fmt: skip
    add("volumon-train-size-unknown-field", _jx("volumon", "train", "--workdir", f"{o}/vt", "--size", f"{d}/size_unknown_field.json"), ["size_unknown_field.json", "no_such_field"])  # fmt: skip
    add("volumon-train-steps-negative", _jx("volumon", "train", "--workdir", f"{o}/vt", "--steps", "-5"), ["--steps"])  # fmt: skip
    add("volumon-train-devices-zero", _jx(*tr, f"{o}/vt", "--devices", "0"), ["--devices"])
    add("volumon-train-lock-garbage", _jx(*tr, f"{d}/wd_lock_garbage"), ["train.lock"])
    add("volumon-train-lock-latin1", _jx(*tr, f"{d}/wd_lock_latin1"), ["train.lock"])
    add("volumon-train-resume-config-corrupt", _jx(*tr, f"{d}/wd_resume_corrupt"), ["config.json"])
    add("volumon-train-resume-config-latin1", _jx(*tr, f"{d}/wd_resume_latin1"), ["config.json"])
    add("volumon-train-resume-other-seed", _jx(*tr, f"{d}/wd_trained", "--seed", "7"), ["config.json", "seed"])
    add("volumon-export-step-missing", _jx("volumon", "export", "--workdir", f"{d}/wd_trained", "--step", "99", "--out", f"{o}/ve"), ["99"])  # fmt: skip
    add("volumon-predict-step-missing", _jx("volumon", "predict", "--workdir", f"{d}/wd_trained", "--step", "99", "--split", "test", "--num", "2", "--out", f"{o}/vp"), ["99"])  # fmt: skip
    add("volumon-export-config-corrupt", _jx("volumon", "export", "--workdir", f"{d}/wd_resume_corrupt", "--out", f"{o}/ve"), ["config.json"])  # fmt: skip
    add("volumon-train-data-missing", _jx(*tr, f"{o}/vt", "--data", f"{d}/nope"), ["--data", "nope"])
    add("volumon-train-init-from-corrupt", _jx(*tr, f"{o}/vt", "--init-from", f"{d}/model_corrupt.npz"), ["model_corrupt.npz"])  # fmt: skip
    # --- lsd
    add("lsd-data-buildings-zero", _jx("lsd", "data", "--out", f"{o}/ld", "--buildings", "0"), ["--buildings"])
    add("lsd-data-workers-zero", _jx("lsd", "data", "--out", f"{o}/ld", "--workers", "0"), ["--workers"])
    add("lsd-data-sample-prob-nan", _jx("lsd", "data", "--out", f"{o}/ld", "--sample-prob", "nan"), ["--sample-prob", "sample_prob"])  # fmt: skip
    add("lsd-data-out-file", _jx("lsd", "data", "--out", f"{d}/a_file", "--buildings", "1"), ["a_file"])
    add("lsd-data-stamp-other-settings", _jx("lsd", "data", "--out", f"{d}/stamped", "--buildings", "1", "--samples-per-building", "1"), ["stamp_train.json", "stamped"])  # fmt: skip
    add("lsd-data-stamp-latin1", _jx("lsd", "data", "--out", f"{d}/stamped_latin1", "--buildings", "1", "--samples-per-building", "1"), ["stamp_train.json"])  # fmt: skip
    lt = ("lsd", "train", "--config", "tiny", "--workdir")
    add("lsd-train-data-missing", _jx(*lt, f"{o}/lt", "--data", f"{d}/nope"), ["nope"])
    add("lsd-train-data-empty", _jx(*lt, f"{o}/lt", "--data", f"{d}/empty_dir"), ["empty_dir"])
    add("lsd-train-shard-corrupt", _jx(*lt, f"{o}/lt", "--data", f"{d}/shards"), ["expert_train_00000.npz"])
    add("lsd-train-config-unknown", _jx("lsd", "train", "--workdir", f"{o}/lt", "--data", f"{d}/shards", "--config", "huge"), ["--config", "huge"])  # fmt: skip
    add("lsd-train-batch-zero", _jx(*lt, f"{o}/lt", "--data", f"{d}/shards", "--batch-size", "0"), ["--batch-size"])
    add("lsd-train-lock-latin1", _jx(*lt, f"{d}/wd_lock_latin1", "--data", f"{d}/shards"), ["train.lock", "expert_train_00000.npz"])  # fmt: skip
    add("lsd-train-devices-text", _jx(*lt, f"{o}/lt", "--data", f"{d}/shards", "--devices", "many"), ["--devices"])
    add("lsd-plan-map-missing", _jx("lsd", "plan", "--map", f"{d}/nope.npz", "--out", f"{o}/p.png"), ["nope.npz"])
    add("lsd-plan-map-corrupt", _jx("lsd", "plan", "--map", f"{d}/corrupt.npz", "--out", f"{o}/p.png"), ["corrupt.npz"])  # fmt: skip
    add("lsd-plan-n-zero", _jx("lsd", "plan", "--n", "0", "--out", f"{o}/p.png"), ["--n"])
    add("lsd-plan-start-off-map", _jx("lsd", "plan", "--start", "1e9", "1e9", "--goal", "1", "1", "--out", f"{o}/p.png"), ["--start", "start"])  # fmt: skip
    add("lsd-plan-checkpoint-corrupt", _jx("lsd", "plan", "--checkpoint", f"{d}/corrupt.npz", "--out", f"{o}/p.png"), ["corrupt.npz"])  # fmt: skip
    add("lsd-plan-start-without-goal", _jx("lsd", "plan", "--start", "1", "1", "--out", f"{o}/p.png"), ["--goal"])  # fmt: skip
    add("lsd-plan-map-not-npz", _jx("lsd", "plan", "--map", f"{m}/room.png", "--start", "1", "1", "--goal", "5", "5", "--out", f"{o}/p.png"), ["room.png"])  # fmt: skip
    add("lsd-plan-uniform-mix", _jx("lsd", "plan", "--uniform-mix", "2", "--out", f"{o}/p.png"), ["--uniform-mix"])  # fmt: skip
    add("lsd-plan-out-under-file", _jx("lsd", "plan", "--out", f"{d}/a_file/p.png", "--n", "50", "--max-steps", "2"), ["--out", "a_file"])  # fmt: skip
    # --- data fetch (no registry reached: --from a local file, or refused before any download)
    add("fetch-out-is-file", _jx("data", "fetch", "maps", "--out", f"{d}/a_file", "--from", f"{d}/garbage.deb"), ["--out", "a_file"])  # fmt: skip
    add("fetch-target-is-file", _jx("data", "fetch", "maps", "--out", f"{d}/fetch_file_target", "--from", f"{d}/garbage.deb"), ["mrpt"])  # fmt: skip
    add("fetch-out-unwritable", _jx("data", "fetch", "maps", "--out", "/sys", "--from", f"{d}/garbage.deb", "--run-dir", f"{o}/f3"), ["/sys"])  # fmt: skip
    add("fetch-out-uncreatable", _jx("data", "fetch", "maps", "--out", "/sys/jaxsem_data", "--from", f"{d}/garbage.deb", "--run-dir", f"{o}/f4"), ["/sys/jaxsem_data", "--out"])  # fmt: skip
    add("fetch-from-missing", _jx("data", "fetch", "maps", "--out", f"{o}/f5", "--from", f"{d}/nope.deb"), ["--from", "nope.deb"])  # fmt: skip
    add("fetch-from-garbage-wheel", _jx("data", "fetch", "lmo", "--out", f"{o}/f6", "--from", f"{d}/garbage.whl"), ["garbage.whl"])  # fmt: skip
    add("fetch-from-garbage-deb", _jx("data", "fetch", "maps", "--out", f"{o}/f7", "--from", f"{d}/garbage.deb"), ["garbage.deb"])  # fmt: skip
    add("fetch-unknown-set", _jx("data", "fetch", "everything", "--out", f"{o}/f8"), ["everything"])
    # --- lsd_real: maps, annotations, flags, records
    # each map's error names its file; the huge image's also names the image its YAML points at
    also_named = {"huge_image.yaml": ["huge.pgm"]}
    for name in (
        "tiny_res.yaml",
        "neg_res.yaml",
        "no_image.yaml",
        "gone_image.yaml",
        "yaw.yaml",
        "negate.yaml",
        "thresh.yaml",
        "origin_nan.yaml",
        "garbage.yaml",
        "list.yaml",
        "huge_image.yaml",
        "mode.yaml",
        "latin1.yaml",
        "nan_origin.gridmap",
        "bad_first.gridmap",
        "truncated.gridmap",
        "huge.gridmap",
        "zero_res.gridmap",
        "occupied.gridmap",
        "garbage.gridmap.gz",
        "short.gridmap.gz",
        "map.txt",
    ):
        stem = name.replace(".", "-").replace("_", "-")
        add(f"map-{stem}", _script(lsd_real, "--map", f"{m}/{name}", "--json", f"{o}/lr.json", *small), [*also_named.get(name, []), name])  # fmt: skip
    for name in ("huge.png", "huge.pgm", "truncated.pgm", "black.png"):
        stem = name.replace(".", "-")
        add(f"map-{stem}", _script(lsd_real, "--map", f"{m}/{name}", "--resolution", "0.1", "--json", f"{o}/lr.json", *small), [name])  # fmt: skip
    add("map-image-no-resolution", _script(lsd_real, "--map", f"{m}/room.png", "--json", f"{o}/lr.json", *small), ["--resolution", "room.png"])  # fmt: skip
    add("map-resolution-negative", _script(lsd_real, "--map", f"{m}/room.png", "--resolution", "-1", "--json", f"{o}/lr.json", *small), ["--resolution"])  # fmt: skip
    for name in ("ann_garbage.json", "ann_misspelt.json", "ann_nan.json"):
        add(f"annotations-{name[4:-5]}", _script(lsd_real, *room, "--annotations", f"{m}/{name}", "--json", f"{o}/lr.json", *small), [name])  # fmt: skip
    add("lsd-real-trials-zero", _script(lsd_real, *room, "--json", f"{o}/lr.json", "--trials", "0"), ["--trials"])
    add("lsd-real-distances-swapped", _script(lsd_real, *room, "--json", f"{o}/lr.json", "--min-distance", "9", "--max-distance", "3"), ["--min-distance", "--max-distance"])  # fmt: skip
    add("lsd-real-clearance-nan", _script(lsd_real, *room, "--json", f"{o}/lr.json", "--clearance", "nan"), ["--clearance"])  # fmt: skip
    add("lsd-real-checkpoint-missing", _script(lsd_real, *room, "--json", f"{o}/lr.json", "--checkpoint", f"{d}/nope"), ["--checkpoint", "nope"])  # fmt: skip
    add("lsd-real-json-under-file", _script(lsd_real, *room, "--json", f"{d}/a_file/lr.json", *small), ["--json", "a_file"])  # fmt: skip
    for name in ("other_flags", "garbage", "latin1"):
        add(f"records-{name.replace('_', '-')}", _script(lsd_real, *room, "--json", f"{d}/records/{name}.json", "--sets", "II", "--protocol", "defaults", *small), [f"{name}.records.jsonl"])  # fmt: skip
    # --- training scripts
    add("train-volumon-steps-negative", _script("train/volumon.py", "--workdir", f"{o}/tv", "--steps", "-5"), ["--steps"])  # fmt: skip
    add("train-lsd-data-missing", _script("train/lsd.py", "--data", f"{d}/nope", "--workdir", f"{o}/tl"), ["nope"])
    add("train-volumon-rcnn-models-not-lmo", _script("train/volumon_rcnn.py", "--workdir", f"{o}/tr", "--models", f"{d}/bop_good/models", "--renders", f"{o}/renders"), ["obj_000001.ply"])  # fmt: skip
    add("train-volumon-rcnn-no-meshes", _script("train/volumon_rcnn.py", "--workdir", f"{o}/tr", "--renders", f"{o}/renders"), ["--models", "--lmo"])  # fmt: skip
    add("train-volumon-rcnn-input-size", _script("train/volumon_rcnn.py", "--workdir", f"{o}/tr", "--renders", f"{d}/renders_empty", "--input-size", "17,abc"), ["--input-size"])  # fmt: skip
    add("train-volumon-rcnn-steps-zero", _script("train/volumon_rcnn.py", "--workdir", f"{o}/tr", "--renders", f"{d}/renders_empty", "--steps", "0"), ["--steps"])  # fmt: skip
    add("train-export-volumon-rcnn-missing", _script("train/export_volumon_rcnn.py", "--workdir", f"{d}/nope", "--out", f"{o}/te"), ["--workdir", "nope"])  # fmt: skip
    add("train-export-volumon-missing", _script("train/export_volumon.py", "--workdir", f"{d}/nope", "--out", f"{o}/te2"), ["nope"])  # fmt: skip
    add("train-lsd-house-init-from-missing", _script("train/lsd_house_gpu.py", "--root", f"{o}/th", "--out", f"{o}/th_out", "--init-from", f"{d}/nope.npz"), ["--init-from", "nope.npz"])  # fmt: skip
    add("train-lsd-house-deadlines-swapped", _script("train/lsd_house_gpu.py", "--root", f"{o}/th", "--out", f"{o}/th_out", "--data-deadline", "600", "--deadline", "60"), ["--deadline"])  # fmt: skip
    add("train-lsd-house-workers-zero", _script("train/lsd_house_gpu.py", "--root", f"{d}/empty_dir", "--out", f"{o}/th", "--workers", "0"), ["--workers"])  # fmt: skip
    return out


# ---------------------------------------------------------------------------------------------
# Running


def _env(d: pathlib.Path) -> dict:
    """The environment of every case: CPU JAX, run directories under ``d/runs``, and this
    checkout's package first on the path (the round tests the code beside it)."""
    return {
        **os.environ,
        "JAX_PLATFORMS": "cpu",
        "JAXSEM_RUNS_DIR": str(d / "runs"),
        "PYTHONPATH": os.pathsep.join(p for p in (str(ROOT), os.environ.get("PYTHONPATH")) if p),
    }


def run_case(case: Case, d: pathlib.Path, timeout: float) -> dict:
    """Runs one case in a subprocess (working folder ``d``, runs under ``d/runs``); its exit
    status, last stderr line and verdict."""
    argv = [a.replace("{d}", str(d)) for a in case.argv]
    t0 = time.perf_counter()
    try:
        proc = subprocess.run(
            [sys.executable, *argv], cwd=d, env=_env(d), capture_output=True, text=True, timeout=timeout, check=False
        )
        rc, stderr, stdout = proc.returncode, proc.stderr, proc.stdout
    except subprocess.TimeoutExpired as exc:
        rc = None
        stderr = exc.stderr.decode(errors="replace") if isinstance(exc.stderr, bytes) else (exc.stderr or "")
        stdout = ""
    seconds = time.perf_counter() - t0
    lines = [line for line in stderr.splitlines() if line.strip()]
    message = lines[-1].strip() if lines else (stdout.strip().splitlines() or [""])[-1]
    problems = []
    if rc is None:
        problems.append(f"timed out after {timeout:g} s")
    if "Traceback (most recent call last)" in stderr:
        problems.append("traceback")
    if rc == 0:
        problems.append("silent acceptance (exit 0)")
    elif rc is not None and rc != case.expect:
        problems.append(f"exit {rc}, expected {case.expect}")
    named = any(name.replace("{d}", str(d)) in message for name in case.names)
    if not named:
        problems.append("names neither flag nor file")
    return {
        "id": case.id,
        "command": " ".join(argv).replace(str(d), "$TMP").replace(str(ROOT) + "/", ""),
        "exit": rc,
        "message": message.replace(str(d), "$TMP").replace(str(ROOT), "$REPO"),
        "named": named,
        "traceback": "traceback" in problems,
        "silent": rc == 0,
        "verdict": "ok" if not problems else "; ".join(problems),
        "seconds": round(seconds, 1),
    }


def _cell(text: str, limit: int = 240) -> str:
    text = text if len(text) <= limit else text[: limit - 3] + "..."
    return text.replace("|", "\\|").replace("`", "'")


def table(rows: list[dict]) -> str:
    """The round as Markdown: the totals, then one row per case."""
    n = len(rows)
    totals = {
        "cases": n,
        "ok": sum(r["verdict"] == "ok" for r in rows),
        "tracebacks": sum(r["traceback"] for r in rows),
        "silent acceptances": sum(r["silent"] for r in rows),
        "timed out (work run on bad input)": sum(r["exit"] is None for r in rows),
        "messages naming the flag or file": sum(r["named"] for r in rows),
        "wrong exit status": sum(r["exit"] not in (0, None) and "expected" in r["verdict"] for r in rows),
    }
    out = [
        "# The bad-input round",
        "",
        "Written by `python benchmarks/integration/bad_input_round.py` (its docstring says what each case must give).",
        "",
        " | ".join(f"{k}: {v}" for k, v in totals.items()),
        "",
        "| case | command | exit | message | verdict |",
        "|---|---|---|---|---|",
    ]
    for r in rows:
        out.append(
            f"| {r['id']} | `{_cell(r['command'], 300)}` | {r['exit']} | {_cell(r['message'])} | {_cell(r['verdict'], 80)} |"
        )
    return "\n".join(out) + "\n"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", required=True, help="the Markdown table to write")
    p.add_argument("--only", default=None, help="run the cases whose id starts with this (comma-separated)")
    p.add_argument("--timeout", type=float, default=120.0, help="seconds per case")
    p.add_argument("--keep", action="store_true", help="keep the temporary folder (its path is printed)")
    args = p.parse_args(argv)
    selected = cases()
    if args.only:
        prefixes = tuple(args.only.split(","))
        selected = [c for c in selected if c.id.startswith(prefixes)]
        if not selected:
            p.error(f"--only: no case id starts with {args.only!r}")
    tmp = tempfile.mkdtemp(prefix="jaxsem_bad_input_")
    d = pathlib.Path(tmp)
    write_inputs(d, trained=any("{d}/wd_trained" in a or "{d}/wd_resume" in a for c in selected for a in c.argv))
    rows = []
    for i, case in enumerate(selected):
        row = run_case(case, d, args.timeout)
        rows.append(row)
        print(f"[{i + 1}/{len(selected)}] {case.id}: exit {row['exit']}, {row['verdict']} ({row['seconds']} s)")
        print(f"    {row['message'][:200]}", flush=True)
    out = pathlib.Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(table(rows))
    print(f"wrote {out}" + (f"; inputs kept in {d}" if args.keep else ""))
    if not args.keep:
        shutil.rmtree(d, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
