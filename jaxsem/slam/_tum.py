"""TUM RGB-D sequences with a 2D detector's output, read into ROSHAN's :class:`Sequence`.

The TUM RGB-D layout (also what many ScanNet / RealSense exporters write): ``rgb.txt`` (lines
``timestamp filename``), optional ``depth.txt`` (same form; not read here) and
``groundtruth.txt`` (lines ``timestamp tx ty tz qx qy qz qw``: the pose of the camera's optical
frame in the world, OpenCV axes); ``#`` starts a comment. Detections come from any 2D detector
as a JSON-lines file, one line per image::

    {"frame": "rgb/1305031102.175304.png", "detections": [
        {"box": [u_min, v_min, u_max, v_max], "class": "cup", "score": 0.93, "id": 7}, ...]}

``frame`` is the image's name as in ``rgb.txt`` (or give ``"timestamp": t`` instead); ``id`` is
the track id that associates detections of one object over time (ROSHAN's batch and online
solvers need it; a tracker such as ByteTrack gives it); ``score`` is optional. Each image is
paired with the ground-truth pose nearest in time (at most ``max_dt`` seconds away; images
without one are skipped and counted); that pose becomes the frame's pose prior, as a user's
odometry would. Texture-plane depths are left missing (NaN): ROSHAN's front end measures them
from the images.
"""

from __future__ import annotations

import json
import math
import pathlib

import numpy as np

from .._checks import check_box
from .._files import read_text
from ..quadrics import quaternion_xyzw_to_rotation
from ._sequence_checks import _assoc_id, _class_name
from ._sequence_types import Sequence, SequenceFrame

#: Intrinsics of the TUM RGB-D cameras (freiburg1, 2, 3; from the data set's web page).
TUM_INTRINSICS = {
    "freiburg1": (517.3, 516.5, 318.6, 255.3),
    "freiburg2": (520.9, 521.0, 325.1, 249.7),
    "freiburg3": (535.4, 539.2, 320.1, 247.6),
}


def _read_list(path: pathlib.Path, columns: int, numeric: int = 1) -> list[list[str]]:
    """The rows of a TUM list file (``#`` comments and blank lines skipped), each with at least
    ``columns`` fields of which the first ``numeric`` are numbers; ``ValueError`` naming the
    file, the line and the field otherwise."""
    if not path.is_file():
        raise ValueError(f"{path}: no such file (a TUM RGB-D sequence folder has rgb.txt and groundtruth.txt)")
    rows = []
    for n, line in enumerate(read_text(path, "TUM list").splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        words = line.split()
        if len(words) < columns:
            raise ValueError(f"{path}: line {n}: expected {columns} fields, got {len(words)}: {line[:80]!r}")
        for k, word in enumerate(words[:numeric]):
            try:
                float(word)
            except ValueError:
                what = "timestamp" if k == 0 else f"field {k + 1}"
                raise ValueError(f"{path}: line {n}: {what} {word[:40]!r} is not a number") from None
        rows.append(words)
    if not rows:
        raise ValueError(f"{path}: no entries")
    return rows


def _camera_T_world(where: str, values) -> np.ndarray:
    t = np.asarray(values[:3], float)
    quat = np.asarray(values[3:7], float)
    norm = float(np.linalg.norm(quat))
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(quat)) and abs(norm - 1.0) < 1e-2):
        raise ValueError(f"{where}: expected tx ty tz qx qy qz qw with a unit quaternion, got {list(values)}")
    R = np.asarray(quaternion_xyzw_to_rotation(quat / norm), float)
    out = np.eye(4)  # the inverse of world_T_camera = [R | t]
    out[:3, :3], out[:3, 3] = R.T, -R.T @ t
    return out


def load_tum_sequence(
    root,
    detections,
    *,
    K=None,
    image_size=(640, 480),
    max_dt: float = 0.02,
    min_score: float = 0.0,
    classes=None,
) -> Sequence:
    """A ROSHAN :class:`Sequence` from a TUM RGB-D folder and a detections file (module docstring).

    K: (3, 3) intrinsics (default: :data:`TUM_INTRINSICS` when the folder's name says freiburg1,
    2 or 3). max_dt: seconds between an image and its pose. min_score: detections below it are
    dropped. classes: the :class:`jaxsem.classes.ClassTable` of the detections' class names
    (default: the built-in table).

    Raises:
      ValueError: naming the file, the line and the field (bad lines, unknown classes, boxes
        outside the image, a detection without an id, no frame with a pose and a detection).
    """
    root = pathlib.Path(root)
    table = classes  # the name is reused for a frame's class list below
    detections = pathlib.Path(detections)
    if not root.is_dir():
        raise ValueError(f"root: no such folder {str(root)!r}")
    if K is None:
        cam = next((v for k, v in TUM_INTRINSICS.items() if k in root.name), None)
        if cam is None:
            raise ValueError(f"K: {root.name} does not name a TUM camera (freiburg1/2/3); pass K=")
        fx, fy, cx, cy = cam
        K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    K = np.asarray(K, float)
    if K.shape != (3, 3) or not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise ValueError(f"K: expected finite (3, 3) intrinsics with fx, fy > 0, got {K.tolist()}")
    size = (int(image_size[0]), int(image_size[1]))
    rgb = _read_list(root / "rgb.txt", 2)
    gt = _read_list(root / "groundtruth.txt", 8, numeric=8)
    gt_t = np.array([float(r[0]) for r in gt])
    order = np.argsort(gt_t)
    gt_t, gt = gt_t[order], [gt[i] for i in order]
    by_name = {r[1]: float(r[0]) for r in rgb}
    rgb_t = np.array([float(r[0]) for r in rgb])

    if not detections.is_file():
        raise ValueError(f"{detections}: no such detections file")
    frames = []
    skipped = 0
    for n, line in enumerate(read_text(detections, "detections file").splitlines(), 1):
        if not line.strip():
            continue
        where = f"{detections}: line {n}"
        try:
            entry = json.loads(line)
        except json.JSONDecodeError as exc:
            raise ValueError(f"{where}: not valid JSON ({exc.msg})") from None
        if not isinstance(entry, dict):
            raise ValueError(f"{where}: expected an object with 'frame' (or 'timestamp') and 'detections'")
        if "frame" in entry:
            if entry["frame"] not in by_name:
                raise ValueError(f"{where}: frame: {entry['frame']!r} is not in rgb.txt")
            stamp, image = by_name[entry["frame"]], str(entry["frame"])
        elif "timestamp" in entry:
            try:
                stamp = float(entry["timestamp"])
            except (TypeError, ValueError):
                raise ValueError(f"{where}: timestamp: expected a number, got {entry['timestamp']!r}") from None
            k = int(np.argmin(np.abs(rgb_t - stamp)))
            if not math.isfinite(stamp) or abs(rgb_t[k] - stamp) > max_dt:
                raise ValueError(f"{where}: timestamp: no image in rgb.txt within {max_dt} s of {stamp}")
            image = rgb[k][1]
        else:
            raise ValueError(f"{where}: frame: missing (give 'frame' or 'timestamp')")
        dets = entry.get("detections")
        if not isinstance(dets, list):
            raise ValueError(f"{where}: detections: expected a list, got {dets!r:.60}")
        k = int(np.searchsorted(gt_t, stamp))
        near = [i for i in (k - 1, k) if 0 <= i < len(gt_t)]
        best = min(near, key=lambda i: abs(gt_t[i] - stamp))
        if abs(gt_t[best] - stamp) > max_dt:
            skipped += 1
            continue
        boxes, classes, ids = [], [], []
        for i, d in enumerate(dets):
            field = f"detections[{i}]"
            if not isinstance(d, dict):
                raise ValueError(f"{where}: {field}: expected an object with box, class, id")
            score = d.get("score", 1.0)
            if isinstance(score, bool) or not isinstance(score, (int, float)) or not math.isfinite(score):
                raise ValueError(f"{where}: {field}.score: expected a finite number, got {score!r}")
            if score < min_score:
                continue
            for key in ("box", "class", "id"):
                if key not in d:
                    raise ValueError(f"{where}: {field}.{key}: missing")
            boxes.append(check_box(where, f"{field}.box", d["box"], size))
            classes.append(_class_name(where, f"{field}.class", d["class"], table))
            ids.append(_assoc_id(where, f"{field}.id", d["id"]))
        frames.append(
            (
                stamp,
                SequenceFrame(
                    camera_T_world=_camera_T_world(f"{root / 'groundtruth.txt'}: {gt[best][0]}", gt[best][1:8]),
                    boxes=np.asarray(boxes, float).reshape(-1, 4),
                    classes=tuple(classes),
                    ids=tuple(ids),
                    texture_depth=np.full(len(boxes), np.nan),
                    image=image,
                ),
            )
        )
    if not any(len(f.boxes) for _, f in frames):
        raise ValueError(
            f"{detections}: no frame with both a pose (within {max_dt} s) and a detection ({skipped} skipped)"
        )
    frames.sort(key=lambda x: x[0])
    return Sequence(K=K, image_size=size, frames=tuple(f for _, f in frames), root=root, classes=table)
