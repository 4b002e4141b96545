r"""Posed detection sequences on disk: the JSON layout, reading it (validated) and writing it.

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

The association ids are the front end's landmark ids (:class:`jaxsem.slam._frontend.FrontEnd`); any
non-negative int or string works: :func:`load_sequence` maps them, in order of first
appearance, to dense object slots ``0 .. J-1`` of the online smoother and keeps the original
ids for the output map. A detection's ``texture_depth`` is the texture-plane depth (thesis
4.3.3); without it the detection contributes its box only.

Functions (numpy in and out, plain data, no jit needed):

- :func:`load_sequence` / :func:`save_sequence`: read / write the layout (``ValueError`` naming
  the file and the JSON field on bad input; the checks are in ``_sequence_checks.py``, the
  dataclasses in ``_sequence_types.py``).
- :func:`sequence_from_simulation`: a :class:`jaxsem.slam.sim.SimulatedMap` as a :class:`Sequence`
  (pose priors as poses, ground-truth association, texture planes, truth attached).

Next to it in :mod:`jaxsem.slam` (each its own module):

- ``_run_sequence.py``: :func:`run_sequence`, the online smoother (:func:`jaxsem.slam.online_init` /
  :func:`jaxsem.slam.online_update`) over a sequence, frame by frame, with a callback.
- ``_map_json.py``: :func:`map_to_json`, an estimated map as a JSON-ready dict (per object: id,
  class, center, radii, rotation), and :func:`truth_errors`.
- ``_draw.py``: :func:`draw_top_down`, :func:`draw_camera_path`, :func:`draw_overlay`: matplotlib
  figures (top-down ellipses; projected conics and boxes over an image or a blank canvas).
"""

from __future__ import annotations

import json
import math
import pathlib

import numpy as np

from .. import classes as _classes, factors
from .._files import MAX_PIXELS, read_text
from ._sequence_checks import _parse
from ._sequence_types import (
    FORMAT_TAG,
    SEQUENCE_FILE,
    Sequence,
    SequenceFrame,
)
from ._solver_config import NoiseModel

__all__ = [
    "load_sequence",
    "save_sequence",
    "load_image",
    "sequence_to_json",
    "noise_model",
    "sequence_from_simulation",
]


def noise_model(sequence: Sequence, base=None):
    """The :class:`jaxsem.slam._solver_config.NoiseModel` of ``base`` (default ``NoiseModel()``) with the
    sequence's ``"noise"`` fields applied (degrees converted to radians)."""
    base = NoiseModel() if base is None else base
    values = {name: getattr(base, name) for name in base.__dataclass_fields__}
    for key, value in (sequence.noise or {}).items():
        if key == "pose_rotation_sigma_deg":
            values["pose_rotation_sigma"] = math.radians(value)
        else:
            values[key] = value
    return NoiseModel(**values)


def load_sequence(path, *, classes=None, require_detections: bool = True) -> Sequence:
    """Reads a sequence directory (or its ``sequence.json``), validating every field.

    Layout: ``{"K": 3x3, "image_size": [width, height], "frames": [{"camera_T_world": 4x4,
    "image": optional file name relative to the directory, "detections": [{"box": [u_min,
    v_min, u_max, v_max], "class": name, "id": int >= 0 or string, "texture_depth": optional
    metres}]}], "truth": optional {"camera_T_world": [4x4 per frame], "objects": [{"id", "class",
    "center", "radii", "rotation"}]}, "classes": optional [{"name", "dimensions", "sigma",
    "shape"}]}`` (the user's own classes, :meth:`jaxsem.classes.ClassTable.to_dict` rows, added
    after the table's).

    Args:
      path: the directory holding ``sequence.json``, or the JSON file itself. Image names are
        relative to the JSON file's directory.
      classes: the :class:`jaxsem.classes.ClassTable` the class names are read in (default: the
        built-in table), extended by the file's ``"classes"``; kept as ``sequence.classes``.
      require_detections: False accepts frames with no detection at all (posed images a
        detector will read: :func:`jaxsem.slam.detected_sequence`).

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
        data = json.loads(read_text(file, "sequence file"))  # bounded; names the file when unreadable
    except json.JSONDecodeError as exc:
        raise ValueError(f"{file}: malformed JSON at line {exc.lineno} column {exc.colno}: {exc.msg}") from None
    return _parse(data, str(file), file.parent, classes, require_detections)


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
    if sequence.classes is not None:
        extra = [r for r in sequence.classes.rows if r not in _classes.DEFAULT_TABLE.rows]
        if extra:
            out["classes"] = _classes.ClassTable(tuple(extra)).to_dict()["classes"]
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


def load_image(sequence: Sequence, index: int, *, max_pixels: int = MAX_PIXELS):
    """Deprecated: ``sequence.image(index)`` (:meth:`Sequence.image`)."""
    return sequence.image(index, max_pixels=max_pixels)


def sequence_from_simulation(sim_map, image_size) -> Sequence:
    """A simulated map (:func:`jaxsem.slam.sim.simulate`, one map, no batch axis) as a :class:`Sequence`.

    Poses are the noisy odometry (``pose_prior``), detections the noisy boxes with the
    ground-truth association (id = object slot) and the texture-plane depth where the simulator
    gives one; ``truth`` holds the true poses and every object of the map. No images.

    Args:
      sim_map: a :class:`jaxsem.slam.sim.SimulatedMap` (fields ``pose_prior`` (T, 4, 4), ``boxes``
        (T, N, 4), ``box_mask`` (T, N), ``texture_depth`` / ``texture_mask`` (T, N), ``object_*``,
        ``camera_T_world``, ``K``).
      image_size: ``(width, height)``, e.g. ``config.image_size``.
    """
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
