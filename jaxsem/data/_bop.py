"""BOP scenes, the standard layout of 6D object pose data sets (LM-O, YCB-V, T-LESS, ...), and PLY meshes.

A BOP scene folder holds ``scene_gt.json`` (per frame id, a list of ``{"obj_id", "cam_R_m2c"
(row-major 3x3), "cam_t_m2c" (mm)}``), the intrinsics as ``scene_camera.json`` (per frame
``cam_K``, row-major) or a data-set level ``camera.json`` (``fx, fy, cx, cy, width, height``),
optionally ``scene_gt_info.json`` (per object ``bbox_visib`` ``[x, y, w, h]`` and
``visib_fract``), and the images in ``rgb/`` or ``gray/`` (``depth/`` and ``mask_visib/`` are
optional and not read here). Object meshes are ``models/obj_XXXXXX.ply`` in millimetres, inside
the scene folder or two levels up (the data set's ``models/``).

:func:`load_bop_scene` reads the labels only (no image is opened): per frame and object, the
object id and class name, its rotation object-to-camera (the proper rotation nearest to the
file's ``cam_R_m2c``, written with a few digits), its ellipsoid in the camera frame
(centre and semi-axes of the mesh's axis-aligned extent, metres: jaxsem's convention, radii =
half the full dimensions), the visible box and the visible fraction. When
``scene_gt_info.json`` is absent they are computed from the meshes: every object of the frame is
projected as points (its vertices, splatted to 3 x 3 pixels) into one depth buffer, so objects
hide each other; the visible fraction is the share of an object's own pixels it keeps in the
shared buffer, the box that of the kept pixels. A point splat, not a triangle rasteriser: boxes
agree with a rasteriser to about the splat size on meshes with ~1 px vertex spacing.
"""

from __future__ import annotations

import dataclasses
import math
import pathlib

import numpy as np

from .._files import MAX_PIXELS, check_budget, read_json
from ..quadrics import EllipsoidView, nearest_rotation

#: Linemod's object names (LM and LM-O share the ids).
LINEMOD_NAMES = {
    1: "ape",
    2: "benchvise",
    3: "bowl",
    4: "camera",
    5: "can",
    6: "cat",
    7: "cup",
    8: "driller",
    9: "duck",
    10: "eggbox",
    11: "glue",
    12: "holepuncher",
    13: "iron",
    14: "lamp",
    15: "phone",
}


@dataclasses.dataclass(frozen=True)
class Mesh:
    """A triangle mesh: vertices (N, 3) metres, colors (N, 3) uint8 or None, faces (F, 3) int or None."""

    vertices: np.ndarray
    colors: np.ndarray | None = None
    faces: np.ndarray | None = None

    @property
    def center(self) -> np.ndarray:
        """Centre of the axis-aligned extent (model frame)."""
        return 0.5 * (self.vertices.min(0) + self.vertices.max(0))

    @property
    def radii(self) -> np.ndarray:
        """Half the axis-aligned extent (model frame): the semi-axes of the object's ellipsoid."""
        return 0.5 * (self.vertices.max(0) - self.vertices.min(0))


@dataclasses.dataclass(frozen=True)
class BopObject:
    """One object in one frame (camera frame, metres).

    rotation: (3, 3) object-to-camera; translation: (3,) the model origin in the camera frame;
    center, radii: the ellipsoid (centre of the mesh's extent, half extents along the object's
    axes); visible_box: (4,) ``[u_min, v_min, u_max, v_max]`` of the visible pixels, edge to
    edge in the core's pixel convention (pixel centres at whole coordinates: inside
    ``[-0.5, W - 0.5] x [-0.5, H - 0.5]``, what :func:`jaxsem.volumon.prepare_inputs` and
    :func:`jaxsem.slam.make_problem` take), NaN when nothing is visible; visible_fraction: in [0, 1].
    """

    obj_id: int
    class_name: str
    rotation: np.ndarray
    translation: np.ndarray
    center: np.ndarray
    radii: np.ndarray
    visible_box: np.ndarray
    visible_fraction: float

    ellipsoid = EllipsoidView()


@dataclasses.dataclass(frozen=True)
class BopFrame:
    """One frame: id, K (3, 3), image size (W, H), image path (may not exist), objects."""

    frame_id: int
    K: np.ndarray
    image_size: tuple[int, int]
    image_path: pathlib.Path
    objects: tuple[BopObject, ...]


@dataclasses.dataclass(frozen=True)
class BopScene:
    """A scene's frames (sorted by id) and the meshes by object id."""

    path: pathlib.Path
    frames: tuple[BopFrame, ...]
    meshes: dict

    def split(self, below: int) -> tuple[tuple[BopFrame, ...], tuple[BopFrame, ...]]:
        """Frames with id below ``below`` and the rest (e.g. the LM-O tuning / test split at 600)."""
        return (
            tuple(f for f in self.frames if f.frame_id < below),
            tuple(f for f in self.frames if f.frame_id >= below),
        )


# ----------------------------------------------------------------------------------------------
# PLY


_PLY_TYPES = {
    "char": "i1",
    "int8": "i1",
    "uchar": "u1",
    "uint8": "u1",
    "short": "i2",
    "int16": "i2",
    "ushort": "u2",
    "uint16": "u2",
    "int": "i4",
    "int32": "i4",
    "uint": "u4",
    "uint32": "u4",
    "float": "f4",
    "float32": "f4",
    "double": "f8",
    "float64": "f8",
}


def load_ply(path, scale: float = 1e-3) -> Mesh:
    """A PLY mesh (ASCII or binary little-endian; vertices with optional ``red, green, blue``
    colours, triangle faces), coordinates multiplied by ``scale`` (BOP models are in mm: 1e-3).

    Raises:
      ValueError: naming the file and what is wrong (missing file, bad header, truncated data,
        non-triangle faces).
    """
    path = pathlib.Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise ValueError(f"{path}: cannot read the PLY file ({exc.strerror or exc})") from None
    end = raw.find(b"end_header")
    if not raw.startswith(b"ply") or end < 0:
        raise ValueError(f"{path}: not a PLY file (no 'ply' magic or 'end_header')")
    header = raw[:end].decode("ascii", "replace").splitlines()
    body = raw[raw.index(b"\n", end) + 1 :]
    fmt, elements = None, []
    for line in header:
        words = line.split()
        if not words:
            continue
        if words[0] == "format":
            fmt = words[1]
        elif words[0] == "element":
            if len(words) != 3 or not words[2].isdigit():
                raise ValueError(f"{path}: bad PLY header line {line!r} (expected 'element NAME COUNT')")
            elements.append([words[1], int(words[2]), []])
        elif words[0] == "property" and elements:
            elements[-1][2].append(words[1:])
    if fmt not in ("ascii", "binary_little_endian"):
        raise ValueError(f"{path}: PLY format {fmt!r} not supported (ascii or binary_little_endian)")
    data: dict = {}
    try:
        if fmt == "ascii":
            tokens = body.split()
            pos = 0
            for name, count, props in elements:
                if props and props[0][0] == "list":
                    rows = []
                    for _ in range(count):
                        n = int(tokens[pos])
                        rows.append([int(t) for t in tokens[pos + 1 : pos + 1 + n]])
                        pos += 1 + n
                    data[name] = rows
                else:
                    k = len(props)
                    arr = np.array(tokens[pos : pos + count * k], dtype=np.float64).reshape(count, k)
                    pos += count * k
                    data[name] = {p[-1]: arr[:, i] for i, p in enumerate(props)}
        else:
            offset = 0
            for name, count, props in elements:
                if props and props[0][0] == "list":
                    count_t, index_t = _PLY_TYPES[props[0][1]], _PLY_TYPES[props[0][2]]
                    dt = np.dtype([("n", count_t), ("idx", index_t, (3,))])
                    rows = np.frombuffer(body, dt, count, offset)
                    if count and np.any(rows["n"] != 3):
                        raise ValueError(f"{path}: only triangle faces are supported")
                    offset += count * dt.itemsize
                    data[name] = rows["idx"]
                else:
                    dt = np.dtype([(p[-1], "<" + _PLY_TYPES[p[0]]) for p in props])
                    rows = np.frombuffer(body, dt, count, offset)
                    offset += count * dt.itemsize
                    data[name] = {p[-1]: rows[p[-1]].astype(np.float64) for p in props}
    except (ValueError, KeyError, IndexError) as exc:
        if str(exc).startswith(f"{path}:"):
            raise
        raise ValueError(f"{path}: truncated or malformed PLY data ({exc})") from None
    vertex = data.get("vertex")
    if not isinstance(vertex, dict) or not all(k in vertex for k in "xyz"):
        raise ValueError(f"{path}: no vertex element with x, y, z")
    vertices = np.stack([vertex["x"], vertex["y"], vertex["z"]], -1) * float(scale)
    if not np.all(np.isfinite(vertices)) or len(vertices) == 0:
        raise ValueError(f"{path}: vertices must be finite and at least one")
    colors = None
    if all(k in vertex for k in ("red", "green", "blue")):
        colors = np.stack([vertex["red"], vertex["green"], vertex["blue"]], -1).astype(np.uint8)
    faces = data.get("face")
    if faces is not None:
        if isinstance(faces, list):
            if any(len(f) != 3 for f in faces):
                raise ValueError(f"{path}: only triangle faces are supported")
            faces = np.asarray(faces, np.int64).reshape(-1, 3)
        faces = np.asarray(faces, np.int64)
    return Mesh(vertices, colors, faces)


# ----------------------------------------------------------------------------------------------
# Scenes


def _read_json(path: pathlib.Path, kind: type = dict):
    """A BOP JSON file whose top level must be ``kind`` (an object keyed by frame id)."""
    data = read_json(path, "BOP JSON file")
    if not isinstance(data, kind):
        raise ValueError(f"{path}: expected a JSON {'object' if kind is dict else 'list'}, got {type(data).__name__}")
    return data


def _number(where: str, value, *, positive: bool = False) -> float:
    """A finite number (> 0 when ``positive``) read from a file; ``ValueError`` naming ``where``."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ValueError(f"{where}: expected a finite number, got {value!r:.80}")
    if positive and value <= 0:
        raise ValueError(f"{where}: expected a positive number, got {value!r}")
    return float(value)


def _whole(where: str, value, *, low: int = 0) -> int:
    """A whole number >= ``low`` read from a file (``3.0`` is accepted as 3); ``ValueError`` naming ``where``."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or value != value or value % 1 or value < low:
        raise ValueError(f"{where}: expected a whole number >= {low}, got {value!r:.80}")
    return int(value)


def _image_size(where: str, width, height, max_pixels: int) -> tuple[int, int]:
    """``(W, H)`` of a camera: positive whole numbers whose product is within ``max_pixels`` (the
    visible boxes are rendered into a W x H buffer)."""
    size = (_whole(f"{where}: width", width, low=1), _whole(f"{where}: height", height, low=1))
    if size[0] * size[1] > max_pixels:
        raise ValueError(
            f"{where}: declares a {size[0]} x {size[1]} = {size[0] * size[1]:,} pixel image, more than "
            f"max_pixels={max_pixels:,}"
        )
    return size


def _intrinsics(where: str, K: np.ndarray) -> np.ndarray:
    """``K`` checked: positive focal lengths, zero skew row and bottom row ``[0, 0, 1]``."""
    if not (K[0, 0] > 0 and K[1, 1] > 0):
        raise ValueError(f"{where}: focal lengths fx = K[0, 0] and fy = K[1, 1] must be positive, got {K.tolist()}")
    if K[1, 0] != 0 or K[2, 0] != 0 or K[2, 1] != 0 or K[2, 2] != 1:
        raise ValueError(f"{where}: expected [[fx, s, cx], [0, fy, cy], [0, 0, 1]], got {K.tolist()}")
    return K


def _matrix(where: str, value, shape) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=np.float64).reshape(shape)
    except (TypeError, ValueError):
        raise ValueError(f"{where}: expected {int(np.prod(shape))} numbers, got {value!r:.80}") from None
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{where}: must be finite, got {value!r:.80}")
    return arr


def _rotation(where: str, R: np.ndarray) -> np.ndarray:
    """The proper rotation nearest to ``R`` as written (BOP writes a handful of digits: LM-O's
    ``cam_R_m2c`` are up to 0.01 from orthonormal, over the core's 1e-3 rotation tolerance);
    a matrix that is no rotation written with few digits (a reflection, a scale) is refused."""
    rotation, ok = nearest_rotation(R, with_valid=True, xp=np)
    if not bool(ok):
        raise ValueError(f"{where}: expected a rotation matrix (orthonormal, det +1), got {R.round(4).tolist()}")
    return np.asarray(rotation, np.float64)


def _models_dir(scene: pathlib.Path, models_dir) -> pathlib.Path:
    if models_dir is not None:
        return pathlib.Path(models_dir)
    for cand in (scene / "models", scene.parent.parent / "models", scene.parent / "models"):
        if cand.is_dir():
            return cand
    raise ValueError(f"{scene}: no models/ folder found beside or above the scene (give models_dir=)")


def _cameras(scene: pathlib.Path, frame_ids, max_pixels: int) -> dict:
    """frame id -> (K, (W, H)), every field checked (``ValueError`` naming the file and entry)."""
    per_frame = scene / "scene_camera.json"
    shared = [scene / "camera.json", scene.parent.parent / "camera.json", scene.parent.parent / "camera_uw.json"]
    default = None
    for path in shared:
        if path.is_file():
            cam = _read_json(path)
            missing = [k for k in ("fx", "fy", "cx", "cy", "width", "height") if k not in cam]
            if missing:
                raise ValueError(f"{path}: expected fx, fy, cx, cy, width, height; missing {', '.join(missing)}")
            fx, fy = (_number(f"{path}: {k}", cam[k], positive=True) for k in ("fx", "fy"))
            cx, cy = (_number(f"{path}: {k}", cam[k]) for k in ("cx", "cy"))
            K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
            default = (K, _image_size(str(path), cam["width"], cam["height"], max_pixels))
            break
    out = {}
    if per_frame.is_file():
        cams = _read_json(per_frame)
        for fid in frame_ids:
            entry = cams.get(str(fid))
            if entry is None:
                if default is None:
                    raise ValueError(f"{per_frame}: no entry for frame {fid}")
                out[fid] = default
                continue
            if not isinstance(entry, dict):
                raise ValueError(f"{per_frame}: {fid}: expected an object with cam_K, got {entry!r:.80}")
            K = _intrinsics(
                f"{per_frame}: {fid}.cam_K", _matrix(f"{per_frame}: {fid}.cam_K", entry.get("cam_K"), (3, 3))
            )
            if default:
                size = default[1]
            else:  # no camera.json: the image is taken as centred on the principal point
                size = _image_size(
                    f"{per_frame}: {fid}.cam_K (2 cx, 2 cy)", round(2 * K[0, 2]), round(2 * K[1, 2]), max_pixels
                )
            out[fid] = (K, size)
        return out
    if default is None:
        raise ValueError(f"{scene}: no scene_camera.json nor camera.json")
    return {fid: default for fid in frame_ids}


def load_bop_scene(
    scene_dir,
    *,
    models_dir=None,
    class_names: dict | None = None,
    frame_filter=None,
    max_pixels: int = MAX_PIXELS,
) -> BopScene:
    """Reads a BOP scene's labels (see the module docstring); no image is opened.

    class_names: object id -> name (default: Linemod's names for ids 1-15 when the path names
    ``lm`` / ``lmo`` / ``linemod``, else ``obj_XXXXXX``).
    frame_filter: optional ``frame id -> bool``; only the frames it accepts are read (their visible
    boxes rendered), e.g. ``lambda i: i < 600`` for LM-O's tuning split alone.
    max_pixels: the largest image (width x height) a camera may declare (default 8192 x 8192):
    without ``scene_gt_info.json`` the visible boxes are rendered into a buffer of that size.

    Raises:
      ValueError: naming the file and the entry (frame id, object index) and field: missing
        files, bad JSON, a value of the wrong type (a number where a list of objects belongs, an
        ``obj_id`` that is not a whole number), wrong matrix sizes, non-finite numbers, focal
        lengths that are not positive, an image size that is not positive or is over
        ``max_pixels``, a visible fraction outside [0, 1], objects without a mesh.
    """
    max_pixels = check_budget("max_pixels", max_pixels)
    scene = pathlib.Path(scene_dir)
    if not scene.is_dir():
        raise ValueError(f"scene_dir: no such folder {str(scene)!r}")
    gt_path = scene / "scene_gt.json"
    if not gt_path.is_file():
        raise ValueError(f"{scene}: no scene_gt.json (not a BOP scene folder)")
    gt = _read_json(gt_path)
    try:
        frame_ids = sorted(int(k) for k in gt)
    except ValueError:
        raise ValueError(f"{gt_path}: frame ids must be integers, got {list(gt)[:5]}") from None
    if frame_filter is not None:
        frame_ids = [fid for fid in frame_ids if frame_filter(fid)]
    # Every entry of the frames read is checked before any mesh is loaded.
    poses_of: dict[int, list] = {}
    for fid in frame_ids:
        entries = gt[_key(gt, fid)]
        if not isinstance(entries, list):
            raise ValueError(f"{gt_path}: {fid}: expected a list of objects, got {entries!r:.80}")
        poses = []
        for i, e in enumerate(entries):
            where = f"{gt_path}: {fid}[{i}]"
            if not isinstance(e, dict):
                raise ValueError(f"{where}: expected an object with obj_id, cam_R_m2c, cam_t_m2c, got {e!r:.80}")
            if "obj_id" not in e:
                raise ValueError(f"{where}.obj_id: missing")
            oid = _whole(f"{where}.obj_id", e["obj_id"])
            R = _rotation(f"{where}.cam_R_m2c", _matrix(f"{where}.cam_R_m2c", e.get("cam_R_m2c"), (3, 3)))
            t = _matrix(f"{where}.cam_t_m2c", e.get("cam_t_m2c"), (3,)) * 1e-3
            poses.append((oid, R, t))
        poses_of[fid] = poses
    info_path = scene / "scene_gt_info.json"
    info = _read_json(info_path) if info_path.is_file() else None
    if class_names is None:
        parts = {p.lower() for p in scene.resolve().parts}
        linemod = any(p in ("lm", "lmo") or "linemod" in p for p in parts) or any(
            p.startswith("lmo_") or p.startswith("lm_") for p in parts
        )
        class_names = LINEMOD_NAMES if linemod else {}
    cameras = _cameras(scene, frame_ids, max_pixels)
    models = _models_dir(scene, models_dir)
    obj_ids = sorted({oid for poses in poses_of.values() for oid, _, _ in poses})
    meshes = {}
    for oid in obj_ids:
        path = models / f"obj_{oid:06d}.ply"
        if not path.is_file():
            raise ValueError(f"{gt_path}: object {oid} has no mesh {path}")
        meshes[oid] = load_ply(path)
    image_dir = next((scene / d for d in ("rgb", "gray") if (scene / d).is_dir()), scene / "rgb")
    frames = []
    for fid in frame_ids:
        poses = poses_of[fid]
        K, size = cameras[fid]
        if info is not None:
            rows = info.get(_key(info, fid))
            if not isinstance(rows, list) or len(rows) != len(poses):
                raise ValueError(f"{info_path}: {fid}: expected a list of {len(poses)} entries like scene_gt.json")
            boxes, fracs = [], []
            for i, row in enumerate(rows):
                where = f"{info_path}: {fid}[{i}]"
                if not isinstance(row, dict):
                    raise ValueError(f"{where}: expected an object with bbox_visib, got {row!r:.80}")
                x, y, w, h = _matrix(f"{where}.bbox_visib", row.get("bbox_visib"), (4,))
                frac = _number(f"{where}.visib_fract", row.get("visib_fract", 1.0))
                if not 0 <= frac <= 1:
                    raise ValueError(f"{where}.visib_fract: expected a fraction in [0, 1], got {frac}")
                # BOP's [x, y, w, h] are pixel indices: first pixel and last minus first (the
                # BOP toolkit's calc_2d_bbox); an unseen object has negative entries.
                seen = min(x, y, w, h) >= 0 and frac > 0
                boxes.append(np.array([x - 0.5, y - 0.5, x + w + 0.5, y + h + 0.5]) if seen else np.full(4, np.nan))
                fracs.append(frac)
        else:
            boxes, fracs = visible_boxes([(meshes[o], R, t) for o, R, t in poses], K, size)
        objects = []
        for (oid, R, t), box, frac in zip(poses, boxes, fracs):
            mesh = meshes[oid]
            objects.append(
                BopObject(
                    obj_id=oid,
                    class_name=class_names.get(oid, f"obj_{oid:06d}"),
                    rotation=R,
                    translation=t,
                    center=R @ mesh.center + t,
                    radii=mesh.radii,
                    visible_box=np.asarray(box, float),
                    visible_fraction=float(frac),
                )
            )
        image = next(
            (
                image_dir / f"{fid:06d}{ext}"
                for ext in (".png", ".jpg", ".tif")
                if (image_dir / f"{fid:06d}{ext}").is_file()
            ),
            image_dir / f"{fid:06d}.png",
        )
        frames.append(BopFrame(fid, K, size, image, tuple(objects)))
    return BopScene(scene, tuple(frames), meshes)


def _key(table: dict, fid: int) -> str:
    """The key of frame ``fid`` in a file keyed by frame id (``"3"``, or ``"03"`` as written)."""
    key = str(fid)
    return key if key in table else next((k for k in table if k.strip().isdigit() and int(k) == fid), key)


def visible_boxes(objects, K, image_size, splat: int = 1):
    """``(boxes, fractions)`` of posed meshes ``[(mesh, R, t), ...]`` seen together through ``K``
    on a ``(W, H)`` image: a shared depth buffer of their vertices splatted to ``2 splat + 1``
    pixels, so nearer objects hide farther ones. A box spans the pixels an object keeps, edge to
    edge, in the core's pixel convention (:mod:`jaxsem.quadrics`: pixel centres at whole
    coordinates, so pixels ``u_first..u_last`` give ``[u_first - 0.5, ..., u_last + 0.5, ...]``
    and a box never leaves ``[-0.5, W - 0.5] x [-0.5, H - 0.5]``); NaN if none. Its fraction is
    kept pixels over the pixels it covers alone (inside the image)."""
    W, H = int(image_size[0]), int(image_size[1])
    depth = np.full(H * W, np.inf)
    owner = np.full(H * W, -1)
    own = []
    offsets = [(du, dv) for du in range(-splat, splat + 1) for dv in range(-splat, splat + 1)]
    for k, (mesh, R, t) in enumerate(objects):
        p = mesh.vertices @ np.asarray(R).T + np.asarray(t)
        z = p[:, 2]
        front = z > 1e-6
        p, z = p[front], z[front]
        # The pixel whose centre is nearest (pixel centres at whole coordinates).
        u = np.floor(K[0, 0] * p[:, 0] / z + K[0, 1] * p[:, 1] / z + K[0, 2] + 0.5).astype(np.int64)
        v = np.floor(K[1, 1] * p[:, 1] / z + K[1, 2] + 0.5).astype(np.int64)
        idx, zz = [], []
        for du, dv in offsets:
            uu, vv = u + du, v + dv
            ok = (uu >= 0) & (uu < W) & (vv >= 0) & (vv < H)
            idx.append(vv[ok] * W + uu[ok])
            zz.append(z[ok])
        idx, zz = np.concatenate(idx), np.concatenate(zz)
        # nearest depth per pixel of this object, then into the shared buffer
        order = np.lexsort((zz, idx))
        idx, zz = idx[order], zz[order]
        first = np.ones(len(idx), bool)
        first[1:] = idx[1:] != idx[:-1]
        idx, zz = idx[first], zz[first]
        own.append(idx)
        closer = zz < depth[idx]
        depth[idx[closer]] = zz[closer]
        owner[idx[closer]] = k
    boxes, fractions = [], []
    for k, idx in enumerate(own):
        kept = idx[owner[idx] == k]
        if len(kept) == 0:
            boxes.append(np.full(4, np.nan))
            fractions.append(0.0)
            continue
        vv, uu = np.divmod(kept, W)
        boxes.append(np.array([uu.min() - 0.5, vv.min() - 0.5, uu.max() + 0.5, vv.max() + 0.5], float))
        fractions.append(len(kept) / max(len(idx), 1))
    return boxes, fractions
