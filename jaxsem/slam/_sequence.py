r"""Posed detection sequences on disk, the online smoother over them, maps as JSON, and figures.

A *sequence directory* holds ``sequence.json`` (and optionally the images it names). Layout
(all lengths in metres, pixels for boxes; jaxsem conventions: OpenCV camera axes,
``camera_T_world`` maps world points into the camera frame, boxes ``[u_min, v_min, u_max,
v_max]``)::

    {
      "format": "jaxsem.roshan.sequence/1",          # optional tag
      "K": [[fx, s, cx], [0, fy, cy], [0, 0, 1]],     # 3x3 intrinsics
      "image_size": [width, height],                  # pixels
      "frames": [                                     # in time order
        {
          "camera_T_world": [[...], [...], [...], [0, 0, 0, 1]],  # 4x4 odometry / VIO pose
          "image": "images/000000.png",               # optional, relative to the directory
          "detections": [
            {"box": [u_min, v_min, u_max, v_max],     # pixels, u_max > u_min, v_max > v_min
             "class": "car",                          # a name of jaxsem.factors.CLASS_NAMES
             "id": 3,                                 # association id (int >= 0 or string)
             "texture_depth": 12.4}                   # optional: metres, or null / absent
          ]
        }
      ],
      "initial": [{"id": 3, "center": [x, y, z],        # optional initial ellipsoids (world):
                   "radii": [a, b, c],               #   an object listed here starts from these
                   "rotation": [[...], [...], [...]]}],  # values, not its first detection
      "noise": {"box_sigma": 3.0,                     # optional noise model (any subset):
                "texture_sigma": 0.3,                 #   px per box edge, m texture depth,
                "pose_translation_sigma": 0.05,       #   m per axis (pose prior),
                "pose_rotation_sigma_deg": 1.0},      #   deg per axis (pose prior)
      "truth": {                                      # optional (simulated sequences)
        "camera_T_world": [4x4 per frame],
        "objects": [{"id": 3, "class": "car", "center": [x, y, z], "radii": [a, b, c],
                     "rotation": [[...], [...], [...]]}]
      }
    }

The association ids are the front end's landmark ids (:class:`jaxsem.slam.FrontEnd`); any
non-negative int or string works: :func:`load_sequence` maps them, in order of first
appearance, to dense object slots ``0 .. J-1`` of the online smoother and keeps the original
ids for the output map. A detection's ``texture_depth`` is the texture-plane depth (thesis
4.3.3); without it the detection contributes its box only.

Functions (numpy in and out, plain data, no jit needed):

- :func:`load_sequence` / :func:`save_sequence`: read / write the layout (``ValueError`` naming
  the file and the JSON field on bad input).
- :func:`sequence_from_simulation`: a :class:`jaxsem.sim.SimulatedMap` as a :class:`Sequence`
  (pose priors as poses, ground-truth association, texture planes, truth attached).
- :func:`run_sequence`: the online smoother (:func:`jaxsem.slam.online_init` /
  :func:`jaxsem.slam.online_update`) over a sequence, frame by frame, with a callback.
- :func:`map_to_json`: an estimated map as a JSON-ready dict (per object: id, class, center,
  radii, rotation).
- :func:`draw_top_down`, :func:`draw_camera_path`, :func:`draw_overlay`: matplotlib figures
  (top-down ellipses; projected conics and boxes over an image or a blank canvas).
"""

from __future__ import annotations

import dataclasses
import json
import math
import pathlib
from collections.abc import Callable, Mapping
from typing import Any, NoReturn

import numpy as np

__all__ = [
    "SEQUENCE_FILE",
    "SequenceFrame",
    "Sequence",
    "SequenceResult",
    "load_sequence",
    "save_sequence",
    "load_image",
    "sequence_to_json",
    "default_capacity",
    "noise_model",
    "sequence_from_simulation",
    "run_sequence",
    "map_to_json",
    "truth_errors",
    "draw_top_down",
    "draw_camera_path",
    "draw_overlay",
]

SEQUENCE_FILE = "sequence.json"
FORMAT_TAG = "jaxsem.roshan.sequence/1"


# --------------------------------------------------------------------------------------------
# The sequence layout.


@dataclasses.dataclass(frozen=True)
class SequenceFrame:
    """One posed frame with its detections (N of them; numpy, not padded).

    Attributes:
      camera_T_world: (4, 4) odometry / VIO pose (the pose prior).
      boxes: (N, 4) ``[u_min, v_min, u_max, v_max]`` pixels.
      classes: (N,) class names of :data:`jaxsem.factors.CLASS_NAMES`.
      ids: (N,) association ids as written in the file (int or str).
      texture_depth: (N,) metres, NaN where the detection has none.
      image: image file name relative to the sequence directory, or None.
    """

    camera_T_world: np.ndarray
    boxes: np.ndarray
    classes: tuple
    ids: tuple
    texture_depth: np.ndarray
    image: str | None = None


@dataclasses.dataclass(frozen=True)
class Sequence:
    """A posed detection sequence (see the module docstring for its JSON layout).

    Attributes:
      K: (3, 3) intrinsics; image_size: ``(width, height)`` pixels.
      frames: tuple of :class:`SequenceFrame` in time order.
      root: directory the image names are relative to (None: no images).
      truth: optional ``{"camera_T_world": (T, 4, 4), "objects": [{"id", "class", "center" (3,),
        "radii" (3,), "rotation" (3, 3)}]}`` (numpy arrays), for evaluation.
      noise: optional noise model ``{"box_sigma", "texture_sigma", "pose_translation_sigma",
        "pose_rotation_sigma_deg"}`` (any subset; :func:`noise_model` makes it a NoiseModel).
      initial: optional ``{id: {"center" (3,), "radii" (3,), "rotation" (3, 3)}}`` (world frame,
        numpy): the initial ellipsoid of each listed object, used by :func:`run_sequence` in
        place of the single-view initialisation from its first detection.
    """

    K: np.ndarray
    image_size: tuple
    frames: tuple
    root: pathlib.Path | None = None
    truth: dict | None = None
    noise: dict | None = None
    initial: dict | None = None

    @property
    def object_ids(self) -> tuple:
        """Association ids in order of first appearance; object slot ``j`` holds ``object_ids[j]``."""
        seen: dict = {}
        for frame in self.frames:
            for i in frame.ids:
                seen.setdefault(i, None)
        return tuple(seen)

    @property
    def object_classes(self) -> tuple:
        """Class name of each object slot (from its first detection)."""
        first: dict = {}
        for frame in self.frames:
            for i, c in zip(frame.ids, frame.classes):
                first.setdefault(i, c)
        return tuple(first[i] for i in self.object_ids)

    def image_path(self, index: int) -> pathlib.Path | None:
        """Path of frame ``index``'s image, or None when the frame names none."""
        name = self.frames[index].image
        if name is None:
            return None
        return (self.root or pathlib.Path(".")) / name


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


def _class_name(where, field, value):
    from .. import factors

    if not isinstance(value, str):
        _fail(where, field, f"expected a class name string, got {value!r}")
    if value not in factors.CLASS_NAMES:
        _fail(
            where,
            field,
            f"unknown class {value!r}; known classes are {list(factors.CLASS_NAMES)}",
        )
    return value


def _assoc_id(where, field, value):
    if isinstance(value, bool) or not isinstance(value, (int, str)):
        _fail(where, field, f"expected an int >= 0 or a non-empty string, got {value!r}")
    if isinstance(value, int) and value < 0 or isinstance(value, str) and not value:
        _fail(where, field, f"expected an int >= 0 or a non-empty string, got {value!r}")
    return value


def _box(where, field, value, image_size):
    try:
        b = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        b = None
    if b is None or not (b.shape == (4,) and np.all(np.isfinite(b)) and b[2] > b[0] and b[3] > b[1]):
        _fail(
            where,
            field,
            f"expected [u_min, v_min, u_max, v_max] (4 finite numbers, u_max > u_min, "
            f"v_max > v_min), got {value!r:.80}",
        )
    W, H = image_size
    if b[2] <= 0 or b[3] <= 0 or b[0] >= W or b[1] >= H:
        _fail(where, field, f"box {b.tolist()} lies outside the {W}x{H} image")
    return b


def _parse(data, where, root):
    if not isinstance(data, dict):
        _fail(where, "top level", f"expected a JSON object, got {type(data).__name__}")
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
            boxes.append(_box(where, f"{g}.box", d["box"], image_size))
            classes.append(_class_name(where, f"{g}.class", d["class"]))
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
        truth = _parse_truth(where, data["truth"], len(frames))
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


def noise_model(sequence: Sequence, base=None):
    """The :class:`jaxsem.slam.NoiseModel` of ``base`` (default ``NoiseModel()``) with the
    sequence's ``"noise"`` fields applied (degrees converted to radians)."""
    from ._problem import NoiseModel

    base = NoiseModel() if base is None else base
    values = {name: getattr(base, name) for name in base.__dataclass_fields__}
    for key, value in (sequence.noise or {}).items():
        if key == "pose_rotation_sigma_deg":
            values["pose_rotation_sigma"] = math.radians(value)
        else:
            values[key] = value
    return NoiseModel(**values)


def _parse_truth(where, tr, num_frames):
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
                "class": _class_name(where, f"{g}.class", o["class"]),
                "center": _vector(where, f"{g}.center", o["center"], 3),
                "radii": _vector(where, f"{g}.radii", o["radii"], 3, positive=True),
                "rotation": _rotation(where, f"{g}.rotation", o["rotation"]),
            }
        )
    return out


def load_sequence(path) -> Sequence:
    """Reads a sequence directory (or its ``sequence.json``), validating every field.

    Layout: ``{"K": 3x3, "image_size": [width, height], "frames": [{"camera_T_world": 4x4,
    "image": optional file name relative to the directory, "detections": [{"box": [u_min,
    v_min, u_max, v_max], "class": name, "id": int >= 0 or string, "texture_depth": optional
    metres}]}], "truth": optional {"camera_T_world": [4x4 per frame], "objects": [{"id", "class",
    "center", "radii", "rotation"}]}}``.

    Args:
      path: the directory holding ``sequence.json``, or the JSON file itself. Image names are
        relative to the JSON file's directory.

    Returns:
      :class:`Sequence`.

    Raises:
      ValueError: naming the file and the field (``frames[3].detections[1].box: ...``) for a
        missing file, malformed JSON, a missing or malformed field, an unknown class name, a bad
        box, a missing image file or an id whose class changes.
    """
    path = pathlib.Path(path)
    file = path / SEQUENCE_FILE if path.is_dir() else path
    if not file.is_file():
        raise ValueError(
            f"{file}: no such file (expected a sequence directory holding {SEQUENCE_FILE}, or the JSON file itself)"
        )
    try:
        data = json.loads(file.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"{file}: malformed JSON at line {exc.lineno} column {exc.colno}: {exc.msg}") from None
    except UnicodeDecodeError as exc:
        raise ValueError(f"{file}: not a UTF-8 text file ({exc.reason})") from None
    return _parse(data, str(file), file.parent)


def _list(x):
    return np.asarray(x, np.float64).tolist()


def sequence_to_json(sequence: Sequence) -> dict:
    """The JSON-ready dict of a :class:`Sequence` (the layout of the module docstring)."""
    frames = []
    for fr in sequence.frames:
        dets = []
        for b, c, i, d in zip(fr.boxes, fr.classes, fr.ids, fr.texture_depth):
            det = {"box": _list(b), "class": c, "id": i}
            if np.isfinite(d):
                det["texture_depth"] = float(d)
            dets.append(det)
        entry = {"camera_T_world": _list(fr.camera_T_world)}
        if fr.image is not None:
            entry["image"] = fr.image
        entry["detections"] = dets
        frames.append(entry)
    out = {
        "format": FORMAT_TAG,
        "K": _list(sequence.K),
        "image_size": list(sequence.image_size),
        "frames": frames,
    }
    if sequence.truth is not None:
        tr = {
            "objects": [
                {
                    "id": o["id"],
                    "class": o["class"],
                    "center": _list(o["center"]),
                    "radii": _list(o["radii"]),
                    "rotation": _list(o["rotation"]),
                }
                for o in sequence.truth.get("objects", [])
            ]
        }
        if "camera_T_world" in sequence.truth:
            tr["camera_T_world"] = _list(sequence.truth["camera_T_world"])
        out["truth"] = tr
    if sequence.noise:
        out["noise"] = dict(sequence.noise)
    if sequence.initial:
        out["initial"] = [
            {"id": i, "center": _list(v["center"]), "radii": _list(v["radii"]), "rotation": _list(v["rotation"])}
            for i, v in sequence.initial.items()
        ]
    return out


def save_sequence(sequence: Sequence, directory) -> pathlib.Path:
    """Writes ``sequence.json`` into ``directory`` (created); returns the file's path.

    Image names are written as they are; copy the images next to it yourself.
    """
    directory = pathlib.Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    file = directory / SEQUENCE_FILE
    file.write_text(json.dumps(sequence_to_json(sequence), indent=1))
    return file


def load_image(sequence: Sequence, index: int):
    """RGB image (H, W, 3) uint8 of frame ``index``, or None when the frame names none.

    Raises ValueError naming the file when it cannot be read or its size is not ``image_size``.
    """
    path = sequence.image_path(index)
    if path is None:
        return None
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise ValueError(f"frames[{index}].image: cannot read image file {str(path)!r}")
    if (img.shape[1], img.shape[0]) != tuple(sequence.image_size):
        raise ValueError(
            f"frames[{index}].image: {str(path)!r} is {img.shape[1]}x{img.shape[0]}, expected "
            f"image_size {sequence.image_size[0]}x{sequence.image_size[1]}"
        )
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def sequence_from_simulation(sim_map, image_size) -> Sequence:
    """A simulated map (:func:`jaxsem.sim.simulate`, one map, no batch axis) as a :class:`Sequence`.

    Poses are the noisy odometry (``pose_prior``), detections the noisy boxes with the
    ground-truth association (id = object slot) and the texture-plane depth where the simulator
    gives one; ``truth`` holds the true poses and every object of the map. No images.

    Args:
      sim_map: a :class:`jaxsem.sim.SimulatedMap` (fields ``pose_prior`` (T, 4, 4), ``boxes``
        (T, N, 4), ``box_mask`` (T, N), ``texture_depth`` / ``texture_mask`` (T, N), ``object_*``,
        ``camera_T_world``, ``K``).
      image_size: ``(width, height)``, e.g. ``config.image_size``.
    """
    from .. import factors

    g = lambda name: np.asarray(getattr(sim_map, name))
    pose, boxes, mask = g("pose_prior"), g("boxes"), g("box_mask")
    if pose.ndim != 3 or boxes.ndim != 3:
        raise ValueError(f"sim_map: expected one map (pose_prior (T, 4, 4)), got pose_prior {pose.shape}")
    tex, tex_mask, cls = g("texture_depth"), g("texture_mask"), g("object_class")
    names = [factors.CLASS_NAMES[int(c)] for c in cls]
    frames = []
    for t in range(pose.shape[0]):
        js = np.flatnonzero(mask[t])
        frames.append(
            SequenceFrame(
                camera_T_world=pose[t].astype(np.float64),
                boxes=boxes[t, js].astype(np.float64).reshape(-1, 4),
                classes=tuple(names[j] for j in js),
                ids=tuple(int(j) for j in js),
                texture_depth=np.where(tex_mask[t, js], tex[t, js], np.nan).astype(np.float64),
            )
        )
    objects = [
        {
            "id": int(j),
            "class": names[j],
            "center": g("object_center")[j].astype(np.float64),
            "radii": g("object_radii")[j].astype(np.float64),
            "rotation": g("object_rotation")[j].astype(np.float64),
        }
        for j in np.flatnonzero(g("object_mask"))
    ]
    truth = {
        "camera_T_world": g("camera_T_world").astype(np.float64),
        "objects": objects,
    }
    return Sequence(
        K=g("K").astype(np.float64),
        image_size=(int(image_size[0]), int(image_size[1])),
        frames=tuple(frames),
        truth=truth,
    )


# --------------------------------------------------------------------------------------------
# The online smoother over a sequence.


@dataclasses.dataclass(frozen=True)
class SequenceResult:
    """What :func:`run_sequence` returns (numpy).

    Attributes:
      object_ids: (J,) association ids; object_classes: (J,) class names.
      rotation (J, 3, 3), center (J, 3), radii (J, 3): the estimated ellipsoids.
      camera_T_world: (T, 4, 4) estimated pose of every frame (the latest estimate it had
        before it left the smoother's window, or the final one).
      frame_seconds: (T,) wall time of each ``online_update`` (the first includes compilation).
      state: the final :class:`jaxsem.slam.OnlineState`.
    """

    object_ids: tuple
    object_classes: tuple
    rotation: np.ndarray
    center: np.ndarray
    radii: np.ndarray
    camera_T_world: np.ndarray
    frame_seconds: np.ndarray
    state: Any = None


def _bucket(n: int, step: int) -> int:
    return max(step, -(-int(n) // step) * step)


def default_capacity(sequence: Sequence, max_poses: int = 256):
    """A :class:`jaxsem.slam.Capacity` that fits ``sequence`` (sizes rounded up to buckets so that
    similar sequences share a compilation): every frame up to ``max_poses``, every object, the
    most detections of any frame."""
    from ._problem import Capacity

    T = len(sequence.frames)
    D = max([len(f.ids) for f in sequence.frames] + [1])
    J = max(len(sequence.object_ids), 1)
    P = min(_bucket(T, 16), max_poses)
    n_boxes = sum(len(f.ids) for f in sequence.frames)
    B = _bucket(min(n_boxes, P * D), 64)
    return Capacity(
        max_poses=P,
        max_objects=_bucket(J, 8),
        max_boxes=B,
        max_detections=_bucket(D, 4),
    )


def run_sequence(
    sequence: Sequence,
    config=None,
    *,
    capacity=None,
    optimize_every: int = 5,
    iterations: int = 3,
    final_iterations: int = 20,
    window: int | None = None,
    callback: Callable[[int, Any, float], None] | None = None,
    dtype=None,
) -> SequenceResult:
    """Runs the online smoother (:func:`online_init`, then :func:`online_update` per frame).

    New association ids are initialised from their first detection (section 4.3.5), the graph is
    optimised every ``optimize_every`` frames, and after the last frame ``final_iterations``
    LM steps run over everything kept (0 skips it). Every frame and the final optimisation run
    one program (the online step); when JAX's persistent compilation cache is on, its traced
    form is kept in ``<cache dir>/jaxsem-exports`` so that later runs skip tracing
    (:mod:`jaxsem.slam._aot`).

    Args:
      sequence: :class:`Sequence`.
      config: :class:`jaxsem.slam.SolverConfig` (default: ROSHAN's defaults).
      capacity: :class:`jaxsem.slam.Capacity` (default :func:`default_capacity`); it must hold
        every object and the largest frame.
      optimize_every, iterations, window: as :func:`jaxsem.slam.online_init`.
      callback: called after every frame as ``callback(index, state, seconds)``.
      dtype: float dtype (default: jax's default float).

    Returns:
      :class:`SequenceResult`.
    """
    import time

    import jax

    from ._aot import exported
    from ._online import _online_step, empty_frame, online_init, online_step
    from ._problem import SolverConfig, make_frame

    if not isinstance(sequence, Sequence):
        raise ValueError(f"sequence: expected a Sequence (load_sequence), got {type(sequence).__name__}")
    config = SolverConfig() if config is None else config
    capacity = default_capacity(sequence) if capacity is None else capacity
    ids = sequence.object_ids
    slot = {i: j for j, i in enumerate(ids)}
    if len(ids) > capacity.max_objects:
        raise ValueError(f"capacity.max_objects: {capacity.max_objects} < {len(ids)} objects in the sequence")
    D_max = max(len(f.ids) for f in sequence.frames)
    if D_max > capacity.max_detections:
        raise ValueError(f"capacity.max_detections: {capacity.max_detections} < {D_max} detections in one frame")
    state = online_init(
        config,
        capacity,
        sequence.K,
        sequence.image_size,
        optimize_every=optimize_every,
        iterations=iterations,
        window=window,
        dtype=dtype,
    )
    T, P = len(sequence.frames), capacity.max_poses
    poses = np.zeros((T, 4, 4))
    seconds = np.zeros(T)
    # Every frame and the final optimisation go through one program (_online_step: the
    # per-frame update and online_optimize in one), traced once per code version when the
    # compilation cache is on (_aot.exported keeps the traced program beside it), else once
    # per run.
    step = None
    update, final = np.asarray(False), np.asarray(True)
    no_steps = np.asarray(0, np.int32)
    pending = dict(sequence.initial or {})
    for t, fr in enumerate(sequence.frames):
        due = [i for i in fr.ids if i in pending]
        if due:  # user-given initial ellipsoids go in just before the object's first detection
            state = _seed_objects(state, [(slot[i], fr.classes[fr.ids.index(i)], pending.pop(i)) for i in due])
        frame = make_frame(
            fr.camera_T_world,
            fr.boxes,
            list(fr.classes),
            [slot[i] for i in fr.ids],
            fr.texture_depth,
            max_detections=capacity.max_detections,
            max_objects=capacity.max_objects,
            dtype=state.problem.K.dtype,
        )
        start = time.perf_counter()
        if step is None:  # counted in the first frame's time
            step = exported("online_step", _online_step, (state, frame, update, no_steps), state)
        state = jax.block_until_ready(step(state, frame, update, no_steps))
        seconds[t] = time.perf_counter() - start
        if t + 1 >= P and t + 1 < T:  # the next frame reuses the slot of frame t + 1 - P
            poses[t + 1 - P] = np.asarray(state.estimate.camera_T_world)[(t + 1) % P]
        if callback is not None:
            callback(t, state, seconds[t])
    if final_iterations > 0:
        step = online_step if step is None else step
        state = step(state, empty_frame(state), final, np.asarray(final_iterations, np.int32))
    est = state.estimate
    pose_frame = np.asarray(state.pose_frame)
    cams = np.asarray(est.camera_T_world, np.float64)
    for s, t in enumerate(pose_frame):
        if 0 <= t < T:
            poses[t] = cams[s]
    J = len(ids)
    return SequenceResult(
        object_ids=ids,
        object_classes=sequence.object_classes,
        rotation=np.asarray(est.rotation, np.float64)[:J],
        center=np.asarray(est.center, np.float64)[:J],
        radii=np.asarray(est.radii, np.float64)[:J],
        camera_T_world=poses,
        frame_seconds=seconds,
        state=state,
    )


def _seed_objects(state, objects):
    """``state`` with objects ``(slot, class name, {"center", "radii", "rotation"})`` set as
    initialised (host-side arrays: no compile); their first detection then adds boxes only."""
    import equinox as eqx
    import jax

    from .. import factors

    pb, est = state.problem, state.estimate
    arrays = {
        "object_mask": np.array(pb.object_mask),
        "object_class": np.array(pb.object_class),
        "rotation": np.array(est.rotation),
        "center": np.array(est.center),
        "radii": np.array(est.radii),
    }
    for j, cls, v in objects:
        arrays["object_mask"][j] = True
        arrays["object_class"][j] = factors.class_index(cls)
        arrays["rotation"][j] = v["rotation"]
        arrays["center"][j] = v["center"]
        arrays["radii"][j] = v["radii"]
    put = {k: jax.device_put(a) for k, a in arrays.items()}
    return eqx.tree_at(
        lambda st: (
            st.problem.object_mask,
            st.problem.object_class,
            st.estimate.rotation,
            st.estimate.center,
            st.estimate.radii,
        ),
        state,
        (put["object_mask"], put["object_class"], put["rotation"], put["center"], put["radii"]),
    )


def map_to_json(object_ids, object_classes, rotation, center, radii, camera_T_world=None) -> dict:
    """An estimated map as a JSON-ready dict.

    Args:
      object_ids: (J,) association ids; object_classes: (J,) class names.
      rotation: (J, 3, 3) object-to-world; center: (J, 3) world; radii: (J, 3) semi-axes (m).
      camera_T_world: optional (T, 4, 4) estimated poses, written as ``"camera_T_world"``.

    Returns:
      ``{"format", "frame": "world", "units": "metres", "objects": [{"id", "class", "center",
      "radii", "rotation"}], ["camera_T_world"]}``. ``SequenceResult`` fields fit directly:
      ``map_to_json(r.object_ids, r.object_classes, r.rotation, r.center, r.radii, r.camera_T_world)``.
    """
    rotation = np.asarray(rotation, np.float64).reshape(-1, 3, 3)
    center = np.asarray(center, np.float64).reshape(-1, 3)
    radii = np.asarray(radii, np.float64).reshape(-1, 3)
    J = len(object_ids)
    if not (len(object_classes) == rotation.shape[0] == center.shape[0] == radii.shape[0] == J):
        raise ValueError(
            f"object_ids, object_classes, rotation, center, radii: expected {J} objects each, got "
            f"{len(object_classes)}, {rotation.shape[0]}, {center.shape[0]}, {radii.shape[0]}"
        )
    out = {
        "format": "jaxsem.roshan.map/1",
        "frame": "world",
        "units": "metres",
        "objects": [
            {
                "id": object_ids[j],
                "class": object_classes[j],
                "center": center[j].tolist(),
                "radii": radii[j].tolist(),
                "rotation": rotation[j].tolist(),
            }
            for j in range(J)
        ],
    }
    if camera_T_world is not None:
        out["camera_T_world"] = np.asarray(camera_T_world, np.float64).tolist()
    return out


def truth_errors(result: SequenceResult, truth: Mapping) -> dict:
    """Per-object errors of ``result`` against ``sequence.truth`` (matched by id).

    Returns:
      ``{"ids": [...], "shape": (K,), "position": (K,), "orientation": (K,) deg, "mean": {metric:
      float}}`` over the K estimated objects that have a true counterpart
      (:func:`jaxsem.metrics.ellipsoid_errors`, symmetry-aware).
    """
    import jax

    from ..metrics import ellipsoid_errors

    by_id = {o["id"]: o for o in truth.get("objects", [])}
    keep = [j for j, i in enumerate(result.object_ids) if i in by_id]
    out: dict = {"ids": [result.object_ids[j] for j in keep]}
    if not keep:
        return {
            **out,
            "shape": np.zeros(0),
            "position": np.zeros(0),
            "orientation": np.zeros(0),
            "mean": {},
        }
    tr = [by_id[result.object_ids[j]] for j in keep]
    # One jitted program (op by op, each jnp op would compile a program of its own).
    e = jax.jit(ellipsoid_errors)(
        result.rotation[keep],
        result.center[keep],
        result.radii[keep],
        np.stack([o["rotation"] for o in tr]),
        np.stack([o["center"] for o in tr]),
        np.stack([o["radii"] for o in tr]),
    )
    for k, v in e.items():
        out[k] = np.asarray(v, np.float64)
    out["mean"] = {k: float(np.mean(out[k])) for k in ("shape", "position", "orientation")}
    return out


# --------------------------------------------------------------------------------------------
# Figures (matplotlib is imported by the caller; these only draw on the axes given).


def _ground_outline(rotation, center, radii, num_points: int = 72):
    """Top-down outline (orthographic along z) of ellipsoids: (..., num_points, 2) world x, y."""
    from .. import quadrics as Q

    # numpy (xp=np): figures are host code, and eager jnp ops would each compile a program.
    R, c, r = (np.asarray(x, np.float64) for x in (rotation, center, radii))
    outline, _ = Q.conic_outline(Q.ground_conic(R, c, np.abs(r), xp=np), num_points, xp=np)
    return np.asarray(outline, np.float64)


def draw_top_down(ax, rotation, center, radii, mask=None, *, label=None, labels=None, **style):
    """Draws ellipsoids seen from above (world x right, y up) on matplotlib axes ``ax``.

    Args:
      rotation: (J, 3, 3) object-to-world; center: (J, 3); radii: (J, 3) semi-axes (m).
      mask: optional (J,) bool, which ellipsoids to draw (default all).
      label: legend label (given to the first outline only).
      labels: optional (J,) strings written at the centres.
      **style: matplotlib ``plot`` keywords (colour, linestyle, linewidth...).

    Returns:
      the list of line artists.
    """
    outline = _ground_outline(rotation, center, radii)
    center = np.asarray(center, np.float64).reshape(-1, 3)
    mask = np.ones(len(outline), bool) if mask is None else np.asarray(mask, bool).reshape(-1)
    lines = []
    for j in np.flatnonzero(mask):
        (line,) = ax.plot(
            outline[j, :, 0],
            outline[j, :, 1],
            label=label if not lines else None,
            **style,
        )
        lines.append(line)
        if labels is not None:
            ax.text(
                center[j, 0],
                center[j, 1],
                str(labels[j]),
                fontsize=7,
                ha="center",
                va="center",
                color=style.get("color", "k"),
            )
    return lines


def draw_camera_path(
    ax,
    camera_T_world,
    *,
    arrows: int = 8,
    arrow_length: float = 2.0,
    label="camera path",
    **style,
):
    """Draws camera centres (top-down) and a few viewing directions.

    Args:
      camera_T_world: (T, 4, 4) poses (world-to-camera, OpenCV axes: the viewing direction is
        the third row of the rotation).
      arrows: number of evenly spaced heading arrows; arrow_length: metres.
    """
    pose = np.asarray(camera_T_world, np.float64).reshape(-1, 4, 4)
    R = pose[:, :3, :3]
    eye = -np.einsum("tji,tj->ti", R, pose[:, :3, 3])  # -R^T t
    forward = R[:, 2, :]
    style = {"color": "k", "lw": 1.0, **style}
    (line,) = ax.plot(eye[:, 0], eye[:, 1], label=label, **style)
    if arrows > 0 and len(eye):
        for t in np.unique(np.linspace(0, len(eye) - 1, arrows).round().astype(int)):
            d = forward[t, :2]
            n = np.linalg.norm(d)
            if n > 1e-9:
                d = d / n * arrow_length
                ax.annotate(
                    "",
                    xy=(eye[t, 0] + d[0], eye[t, 1] + d[1]),
                    xytext=(eye[t, 0], eye[t, 1]),
                    arrowprops=dict(arrowstyle="->", color=style["color"], lw=0.8),
                )
    return line


def draw_overlay(
    ax,
    image,
    K,
    camera_T_world,
    image_size,
    boxes=None,
    ids=None,
    estimate=None,
    object_ids=None,
    *,
    title=None,
):
    """Detections and projected estimates over one image (or a blank canvas of the image size).

    Args:
      ax: matplotlib axes.
      image: (H, W, 3) or (H, W) array, or None for a blank grey canvas of ``image_size``.
      K: (3, 3); camera_T_world: (4, 4) the pose to project with (the estimated one).
      image_size: (width, height) pixels.
      boxes: optional (N, 4) measured boxes, drawn green; ids: their (N,) labels.
      estimate: optional ``(rotation (J, 3, 3), center (J, 3), radii (J, 3))`` ellipsoids to
        project: outline of the dual conic in blue, its box dashed.
      object_ids: optional (J,) labels of the ellipsoids; only those in ``ids`` are drawn when
        both are given (the objects detected in this frame).
    """
    from .. import quadrics as Q

    W, H = int(image_size[0]), int(image_size[1])
    if image is None:
        ax.imshow(np.full((H, W, 3), 0.92), extent=(0, W, H, 0))
    else:
        ax.imshow(
            np.asarray(image),
            extent=(0, W, H, 0),
            cmap="gray" if np.ndim(image) == 2 else None,
        )
    ax.set_xlim(0, W)
    ax.set_ylim(H, 0)
    if boxes is not None:
        boxes = np.asarray(boxes, np.float64).reshape(-1, 4)
        for i, b in enumerate(boxes):
            ax.add_patch(_rect(b, color="tab:green", lw=1.5))
            if ids is not None:
                ax.text(b[0], b[1] - 3, str(ids[i]), color="tab:green", fontsize=7)
    if estimate is not None:
        rotation, center, radii = (np.asarray(x, np.float64) for x in estimate)
        keep = np.ones(len(center), bool)
        if ids is not None and object_ids is not None:
            wanted = {str(i) for i in ids}
            keep = np.array([str(o) in wanted for o in object_ids], bool)
        if keep.any():
            # numpy (xp=np): host code, nothing compiles. The conic is a real ellipse and its
            # centre in front of the camera exactly where project_bbox calls the box valid.
            Kn = np.asarray(K, np.float64)
            pose = np.asarray(camera_T_world, np.float64)
            R, c, r = (x[keep] for x in (rotation, center, radii))
            conic = Q.project_dual_conic(Q.dual_quadric(R, c, r, xp=np), Kn, pose, xp=np)
            outline, ok_c = Q.conic_outline(conic, 96, xp=np)
            pbox, ok_b = Q.conic_bbox(conic, xp=np)
            ok_b = ok_b & (Q.camera_depth(c, pose, xp=np) > 0)
            for k in range(int(keep.sum())):
                if bool(ok_b[k]) and bool(ok_c[k]):
                    pts = np.asarray(outline[k])
                    ax.plot(pts[:, 0], pts[:, 1], color="tab:blue", lw=1.2)
                    ax.add_patch(_rect(np.asarray(pbox[k]), color="tab:blue", lw=0.8, ls="--"))
    if title:
        ax.set_title(title, fontsize=9)
    ax.set_xticks([])
    ax.set_yticks([])


def _rect(b, **style):
    import matplotlib.patches as mpatches

    return mpatches.Rectangle((b[0], b[1]), b[2] - b[0], b[3] - b[1], fill=False, **style)
