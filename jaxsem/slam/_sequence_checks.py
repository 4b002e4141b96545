"""Validation of ``sequence.json``, field by field: each failure is a ``ValueError`` naming the file
and the JSON field (``frames[3].detections[1].box: ...``).
"""

from __future__ import annotations

import math
import pathlib
from typing import NoReturn

import numpy as np

from .. import classes as _classes
from .._checks import check_box
from ._sequence_types import Sequence, SequenceFrame


def _fail(where, field, message) -> NoReturn:
    raise ValueError(f"{where}: {field}: {message}")


def _matrix(where, field, value, shape):
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        _fail(
            where,
            field,
            f"expected a {shape[0]}x{shape[1]} array of numbers, got {value!r:.80}",
        )
    if arr.shape != shape:
        _fail(where, field, f"expected shape {shape}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        _fail(where, field, f"expected finite numbers, got {arr.tolist()}")
    return arr


def _pose(where, field, value):
    T = _matrix(where, field, value, (4, 4))
    if not np.allclose(T[3], [0.0, 0.0, 0.0, 1.0], atol=1e-6):
        _fail(where, field, f"expected the last row [0, 0, 0, 1], got {T[3].tolist()}")
    R = T[:3, :3]
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-3) or np.linalg.det(R) < 0:
        _fail(
            where,
            field,
            "expected a rotation (orthonormal, det +1) in the top-left 3x3 block",
        )
    return T


def _rotation(where, field, value):
    R = _matrix(where, field, value, (3, 3))
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-3) or np.linalg.det(R) < 0:
        _fail(where, field, "expected a rotation matrix (orthonormal, det +1)")
    return R


def _vector(where, field, value, n, positive=False):
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        _fail(where, field, f"expected {n} numbers, got {value!r:.80}")
    if arr.shape != (n,) or not np.all(np.isfinite(arr)) or (positive and np.any(arr <= 0)):
        _fail(
            where,
            field,
            f"expected {n} finite{' positive' if positive else ''} numbers, got {value!r:.80}",
        )
    return arr


def _class_name(where, field, value, table=None):
    """``value`` checked against the class table (``None``: the built-in one)."""
    names = _classes.as_table(table).names
    if not isinstance(value, str):
        _fail(where, field, f"expected a class name string, got {value!r}")
    if value not in names:
        _fail(
            where,
            field,
            f"unknown class {value!r}; known classes are {list(names)}",
        )
    return value


def _assoc_id(where, field, value):
    if isinstance(value, bool) or not isinstance(value, (int, str)):
        _fail(where, field, f"expected an int >= 0 or a non-empty string, got {value!r}")
    if isinstance(value, int) and value < 0 or isinstance(value, str) and not value:
        _fail(where, field, f"expected an int >= 0 or a non-empty string, got {value!r}")
    return value


def _parse(data, where, root, table=None, require_detections=True):
    if not isinstance(data, dict):
        _fail(where, "top level", f"expected a JSON object, got {type(data).__name__}")
    if data.get("classes") is not None:
        # The sequence's own classes, added to the given table (or the built-in one).
        table = _classes.ClassTable.from_dict(data["classes"], base=_classes.as_table(table), where=f"{where}: classes")
    for key in ("K", "image_size", "frames"):
        if key not in data:
            _fail(where, key, "missing")
    K = _matrix(where, "K", data["K"], (3, 3))
    if K[0, 0] <= 0 or K[1, 1] <= 0 or not np.allclose(K[2], [0.0, 0.0, 1.0]):
        _fail(
            where,
            "K",
            f"expected [[fx, s, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0, got {K.tolist()}",
        )
    size = data["image_size"]
    if (
        not isinstance(size, (list, tuple))
        or len(size) != 2
        or not all(isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in size)
    ):
        _fail(
            where,
            "image_size",
            f"expected [width, height] as two positive ints, got {size!r}",
        )
    image_size = (int(size[0]), int(size[1]))
    if not isinstance(data["frames"], list) or not data["frames"]:
        _fail(where, "frames", "expected a non-empty list of frames")
    frames = []
    for t, fr in enumerate(data["frames"]):
        f = f"frames[{t}]"
        if not isinstance(fr, dict):
            _fail(where, f, f"expected an object, got {type(fr).__name__}")
        if "camera_T_world" not in fr:
            _fail(where, f"{f}.camera_T_world", "missing")
        pose = _pose(where, f"{f}.camera_T_world", fr["camera_T_world"])
        image = fr.get("image")
        if image is not None:
            if not isinstance(image, str) or not image:
                _fail(where, f"{f}.image", f"expected a file name, got {image!r}")
            path = (root or pathlib.Path(".")) / image
            if not path.is_file():
                _fail(where, f"{f}.image", f"image file {str(path)!r} does not exist")
        dets = fr.get("detections", [])
        if not isinstance(dets, list):
            _fail(where, f"{f}.detections", f"expected a list, got {type(dets).__name__}")
        boxes, classes, ids, depth = [], [], [], []
        for n, d in enumerate(dets):
            g = f"{f}.detections[{n}]"
            if not isinstance(d, dict):
                _fail(where, g, f"expected an object, got {type(d).__name__}")
            for key in ("box", "class", "id"):
                if key not in d:
                    _fail(where, f"{g}.{key}", "missing")
            boxes.append(check_box(where, f"{g}.box", d["box"], image_size))
            classes.append(_class_name(where, f"{g}.class", d["class"], table))
            ids.append(_assoc_id(where, f"{g}.id", d["id"]))
            tex = d.get("texture_depth")
            if tex is None:
                depth.append(np.nan)
            elif isinstance(tex, bool) or not isinstance(tex, (int, float)) or not (math.isfinite(tex) and tex > 0):
                _fail(
                    where,
                    f"{g}.texture_depth",
                    f"expected null or a finite depth > 0 (metres), got {tex!r}",
                )
            else:
                depth.append(float(tex))
        if len(set(ids)) != len(ids):
            _fail(
                where,
                f"{f}.detections",
                f"an association id appears twice in one frame: {ids}",
            )
        frames.append(
            SequenceFrame(
                camera_T_world=pose,
                boxes=np.asarray(boxes, np.float64).reshape(-1, 4),
                classes=tuple(classes),
                ids=tuple(ids),
                texture_depth=np.asarray(depth, np.float64),
                image=image,
            )
        )
    if require_detections and not any(len(fr.ids) for fr in frames):
        lacking = sum("detections" not in fr for fr in data["frames"])
        _fail(
            where,
            "frames[*].detections",
            f"no frame has any detection (nothing to map); {lacking} of {len(frames)} frames have no "
            "'detections' key" + (f", keys seen: {sorted(data['frames'][0])}" if lacking else ""),
        )
    first_class: dict = {}
    for t, fr in enumerate(frames):
        for n, (i, c) in enumerate(zip(fr.ids, fr.classes)):
            if first_class.setdefault(i, c) != c:
                _fail(
                    where,
                    f"frames[{t}].detections[{n}].class",
                    f"id {i!r} was first seen as {first_class[i]!r}, now {c!r}",
                )
    truth = None
    if data.get("truth") is not None:
        truth = _parse_truth(where, data["truth"], len(frames), table)
    noise = _parse_noise(where, data.get("noise"))
    initial = _parse_initial(where, data.get("initial"), first_class)
    return Sequence(
        K=K,
        image_size=image_size,
        frames=tuple(frames),
        root=root,
        truth=truth,
        noise=noise,
        initial=initial,
        classes=table,
    )


def _parse_initial(where, initial, first_class):
    """Optional ``"initial"`` list: per object id (one that is detected), its initial ellipsoid."""
    if initial is None:
        return None
    if not isinstance(initial, list):
        _fail(where, "initial", f"expected a list of objects, got {type(initial).__name__}")
    out: dict = {}
    for j, o in enumerate(initial):
        g = f"initial[{j}]"
        if not isinstance(o, dict):
            _fail(where, g, f"expected an object, got {type(o).__name__}")
        for key in ("id", "center", "radii", "rotation"):
            if key not in o:
                _fail(where, f"{g}.{key}", "missing")
        i = _assoc_id(where, f"{g}.id", o["id"])
        if i not in first_class:
            _fail(where, f"{g}.id", f"id {i!r} is never detected (known ids: {list(first_class)[:20]})")
        if i in out:
            _fail(where, f"{g}.id", f"id {i!r} is listed twice")
        out[i] = {
            "center": _vector(where, f"{g}.center", o["center"], 3),
            "radii": _vector(where, f"{g}.radii", o["radii"], 3, positive=True),
            "rotation": _rotation(where, f"{g}.rotation", o["rotation"]),
        }
    return out or None


NOISE_FIELDS = {
    "box_sigma": "pixels per box edge",
    "texture_sigma": "metres, texture-plane depth",
    "pose_translation_sigma": "metres per axis, pose prior",
    "pose_rotation_sigma_deg": "degrees per axis, pose prior",
}


def _parse_noise(where, noise):
    """Optional ``"noise"`` object: each of :data:`NOISE_FIELDS` a finite number > 0."""
    if noise is None:
        return None
    if not isinstance(noise, dict):
        _fail(
            where,
            "noise",
            f"expected an object with fields {sorted(NOISE_FIELDS)}, got {noise!r}",
        )
    out = {}
    for key, value in noise.items():
        if key not in NOISE_FIELDS:
            _fail(
                where,
                f"noise.{key}",
                f"unknown field; expected one of {sorted(NOISE_FIELDS)}",
            )
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not (math.isfinite(value) and value > 0):
            _fail(
                where,
                f"noise.{key}",
                f"expected a finite number > 0 ({NOISE_FIELDS[key]}), got {value!r}",
            )
        out[key] = float(value)
    return out


def _parse_truth(where, tr, num_frames, table=None):
    if not isinstance(tr, dict):
        _fail(where, "truth", f"expected an object, got {type(tr).__name__}")
    out: dict = {"objects": []}
    if tr.get("camera_T_world") is not None:
        poses = tr["camera_T_world"]
        if not isinstance(poses, list) or len(poses) != num_frames:
            _fail(
                where,
                "truth.camera_T_world",
                f"expected a list of {num_frames} 4x4 poses",
            )
        out["camera_T_world"] = np.stack([_pose(where, f"truth.camera_T_world[{t}]", p) for t, p in enumerate(poses)])
    objects = tr.get("objects", [])
    if not isinstance(objects, list):
        _fail(where, "truth.objects", "expected a list")
    for j, o in enumerate(objects):
        g = f"truth.objects[{j}]"
        if not isinstance(o, dict):
            _fail(where, g, "expected an object")
        for key in ("id", "class", "center", "radii", "rotation"):
            if key not in o:
                _fail(where, f"{g}.{key}", "missing")
        out["objects"].append(
            {
                "id": _assoc_id(where, f"{g}.id", o["id"]),
                "class": _class_name(where, f"{g}.class", o["class"], table),
                "center": _vector(where, f"{g}.center", o["center"], 3),
                "radii": _vector(where, f"{g}.radii", o["radii"], 3, positive=True),
                "rotation": _rotation(where, f"{g}.rotation", o["rotation"]),
            }
        )
    return out
