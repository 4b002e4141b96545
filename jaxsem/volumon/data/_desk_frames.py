"""Whole frames for the detect-and-lift network: rendered LM-O desks and real BOP photographs as
arrays of images with every labelled object's boxes and class.

A frame dict (what :func:`jaxsem.volumon.data.render_desk_frames` yields, and what
:func:`bop_frames` makes of a real photograph) holds ``rgb`` (H, W, 3) uint8, ``K`` and
``objects``, each with ``class_name``, ``visible_box`` and, where a stereo pair was rendered,
the amodal ``box_left`` / ``box_right``; the 3D truth (``rotation``, ``center``, ``radii``) rides
along for scoring and the oracle, never for the weak losses.

:func:`frame_arrays` turns frames into fixed-shape arrays at the network's image size (images
uint8, K and boxes scaled, objects padded to ``max_objects`` with ``box_valid``);
:func:`write_desk_frames` renders and stores them in resumable chunks; :func:`frames_batch` picks
a training batch (images as float in [0, 1]); :func:`write_bop_scene` writes frames as a BOP scene
(held-out renders scored by the commands that score the real photographs).
"""

from __future__ import annotations

import dataclasses
import json
import pathlib

import cv2
import numpy as np

from ... import metrics
from ..._files import npz_shapes
from ._bop_eval import bop_split_frames, load_bop_split, read_rgb
from ._lmo_renders import (
    LMO_CLASS_NAMES,
    LMO_K,
    DeskConfig,
    concat_npz,
    load_distractor_meshes,
    load_lmo_meshes,
    mesh_listing,
    render_desk_frames,
    write_desk_chunks,
)
from ._pipeline import mask_depth_points

#: Array keys of :func:`frame_arrays` (``image`` uint8, the rest float32 / int32 / bool).
FRAME_KEYS = (
    "image", "K", "boxes", "class_id", "box_valid", "box_left", "box_right", "stereo_valid", "right_T_left",
    "visible_fraction", "gt_rotation", "gt_center", "gt_half_extents",
)  # fmt: skip

#: Optional array keys: a teacher network's ellipsoid for each label (camera frame), where the
#: frame's objects carry one (``teacher``: ``rotation``, ``center``, ``radii``); ``teacher_valid``
#: False elsewhere. Arrays without them (older render chunks) get them empty from
#: :func:`with_teacher_keys`.
TEACHER_KEYS = ("teacher_rotation", "teacher_center", "teacher_half_extents", "teacher_valid")


#: Optional array keys: up to P depth points of each label's visible surface (camera frame,
#: metres; ``point_mask`` marks the real ones), where a frame carries its rendered ``depth`` and
#: ``seg`` (:func:`jaxsem.volumon.data.render_desk_frames`): what VoluMon's primal loss reads. A
#: photograph's labels have none (``point_mask`` all False).
POINT_KEYS = ("points", "point_mask")


def with_point_keys(arrays: dict, num_points: int) -> dict:
    """``arrays`` (of :func:`frame_arrays`) with the :data:`POINT_KEYS` added, empty (``num_points``
    of them per label), where absent."""
    if all(k in arrays for k in POINT_KEYS):
        return arrays
    n, G = arrays["box_valid"].shape
    P = int(num_points)
    return {**arrays, "points": np.zeros((n, G, P, 3), np.float32), "point_mask": np.zeros((n, G, P), bool)}


def _label_points(fr: dict, obj: dict, num_points: int, rng) -> tuple[np.ndarray, np.ndarray]:
    """Up to ``num_points`` depth points (camera frame) of ``obj``'s visible pixels in a rendered
    frame, drawn without replacement; zeros and a False mask where the frame has no depth."""
    pts = np.zeros((num_points, 3), np.float32)
    mask = np.zeros(num_points, bool)
    if "depth" not in fr or "seg" not in fr or "obj_id" not in obj:
        return pts, mask
    # eroded by a pixel: the silhouette's pixels mix the object's depth with the background's
    found = mask_depth_points(fr["depth"], np.asarray(fr["seg"]) == int(obj["obj_id"]), fr["K"], erode=1)
    if len(found) > num_points:
        found = found[rng.choice(len(found), num_points, replace=False)]
    pts[: len(found)] = found
    mask[: len(found)] = True
    return pts, mask


def with_teacher_keys(arrays: dict) -> dict:
    """``arrays`` (of :func:`frame_arrays`) with the :data:`TEACHER_KEYS` added, empty, where absent."""
    if all(k in arrays for k in TEACHER_KEYS):
        return arrays
    n, G = arrays["box_valid"].shape
    empty = {
        "teacher_rotation": np.tile(np.eye(3, dtype=np.float32), (n, G, 1, 1)),
        "teacher_center": np.zeros((n, G, 3), np.float32),
        "teacher_half_extents": np.ones((n, G, 3), np.float32),
        "teacher_valid": np.zeros((n, G), bool),
    }
    return {**arrays, **{k: v for k, v in empty.items() if k not in arrays}}


def frame_arrays(
    frames,
    image_size: tuple,
    class_names=LMO_CLASS_NAMES,
    max_objects: int = 8,
    baseline: float = 0.06,
    min_visible: float = 0.0,
    num_points: int = 0,
) -> dict:
    """Frames as fixed-shape arrays at ``image_size`` ``(W, H)`` (keys :data:`FRAME_KEYS` and
    :data:`TEACHER_KEYS`; with ``num_points`` > 0 also :data:`POINT_KEYS`, up to that many depth
    points per label, drawn with a generator seeded by the frame's place in ``frames``).

    Objects with no visible box or below ``min_visible`` visible fraction are not labels. An
    object without ``box_right`` has no stereo label (``stereo_valid`` False). The second view
    is a stereo rig ``baseline`` metres to the right unless the frame gives its own
    ``right_T_left`` (:func:`multiview_frames`). ``ValueError``
    naming ``max_objects`` when a frame holds more labels, ``class_names`` for an unknown class."""
    W, H = (int(x) for x in image_size)
    names = list(class_names)
    G = int(max_objects)
    P = int(num_points)
    if P < 0:
        raise ValueError(f"num_points: expected >= 0, got {num_points}")
    out: dict = {k: [] for k in FRAME_KEYS + TEACHER_KEYS + (POINT_KEYS if P else ())}
    rig = np.eye(4)
    rig[0, 3] = -float(baseline)
    for fr in frames:
        rtl = np.asarray(fr.get("right_T_left", rig), np.float64)
        h0, w0 = fr["rgb"].shape[:2]
        sx, sy = W / w0, H / h0
        scale = np.array([sx, sy, sx, sy])
        objs = [
            o
            for o in fr["objects"]
            if np.all(np.isfinite(o["visible_box"])) and float(o.get("visible_fraction", 1.0)) >= min_visible
        ]
        if len(objs) > G:
            raise ValueError(f"max_objects: a frame holds {len(objs)} labelled objects, more than {G}")
        unknown = sorted({o["class_name"] for o in objs} - set(names))
        if unknown:
            raise ValueError(f"class_names: no class {unknown[0]!r} among {names}")
        n = len(objs)

        def rows(key, shape, fill=0.0, objs=objs, n=n):
            a = np.full((G, *shape), fill, np.float64)
            for i, o in enumerate(objs):
                a[i] = np.asarray(o[key], np.float64)
            return a

        out["image"].append(cv2.resize(np.asarray(fr["rgb"], np.uint8), (W, H), interpolation=cv2.INTER_AREA))
        out["K"].append(np.diag([sx, sy, 1.0]) @ np.asarray(fr["K"], np.float64))
        out["boxes"].append(rows("visible_box", (4,)) * scale)
        out["class_id"].append(np.array([names.index(o["class_name"]) for o in objs] + [0] * (G - n)))
        out["box_valid"].append(np.arange(G) < n)
        stereo = np.array([("box_right" in o) for o in objs] + [False] * (G - n))
        out["stereo_valid"].append(stereo)
        left = np.zeros((G, 4))
        right = np.zeros((G, 4))
        for i, o in enumerate(objs):
            if stereo[i]:
                left[i], right[i] = np.asarray(o["box_left"]) * scale, np.asarray(o["box_right"]) * scale
        out["box_left"].append(left)
        out["box_right"].append(right)
        out["right_T_left"].append(rtl)
        out["visible_fraction"].append(
            np.array([float(o.get("visible_fraction", 1.0)) for o in objs] + [0.0] * (G - n))
        )
        R = np.tile(np.eye(3), (G, 1, 1))
        for i, o in enumerate(objs):
            R[i] = o["rotation"]
        out["gt_rotation"].append(R)
        out["gt_center"].append(rows("center", (3,)))
        out["gt_half_extents"].append(rows("radii", (3,), 1.0))
        taught = [o.get("teacher") for o in objs]
        tR, tc, tr = np.tile(np.eye(3), (G, 1, 1)), np.zeros((G, 3)), np.ones((G, 3))
        for i, t in enumerate(taught):
            if t is not None:
                tR[i], tc[i], tr[i] = t["rotation"], t["center"], t["radii"]
        out["teacher_rotation"].append(tR)
        out["teacher_center"].append(tc)
        out["teacher_half_extents"].append(tr)
        out["teacher_valid"].append(np.array([t is not None for t in taught] + [False] * (G - n)))
        if P:
            rng = np.random.default_rng([len(out["image"]), 0x9E1])
            pts, pmask = np.zeros((G, P, 3)), np.zeros((G, P), bool)
            for i, o in enumerate(objs):
                pts[i], pmask[i] = _label_points(fr, o, P, rng)
            out["points"].append(pts)
            out["point_mask"].append(pmask)
    if not out["image"]:
        raise ValueError("frames: expected at least one frame")
    arrays = {k: np.stack(v) for k, v in out.items()}
    for k in arrays:
        if arrays[k].dtype == np.float64:
            arrays[k] = arrays[k].astype(np.float32)
    arrays["class_id"] = arrays["class_id"].astype(np.int32)
    return arrays


def frames_batch(arrays: dict, idx=None) -> dict:
    """The frames ``idx`` (all by default) of :func:`frame_arrays` as a training batch: images
    float32 in [0, 1]."""
    idx = slice(None) if idx is None else np.asarray(idx)
    batch = {k: arrays[k][idx] for k in FRAME_KEYS + TEACHER_KEYS + POINT_KEYS if k in arrays}
    batch["image"] = batch["image"].astype(np.float32) / 255.0
    return batch


def _jitter(img, rng):
    """``img`` with its brightness, contrast and colour balance jittered (values kept in [0, 1])."""
    gain = rng.uniform(0.75, 1.25) * rng.uniform(0.9, 1.1, size=3)
    contrast = rng.uniform(0.75, 1.25)
    mean = img.mean()
    return np.clip((img - mean) * contrast + mean * gain, 0.0, 1.0)


def jitter_batch(batch: dict, rng) -> dict:
    """A :func:`frames_batch` batch with each image's brightness, contrast and colour balance
    jittered as :func:`augment_batch` does, and nothing else changed (labels, stereo labels and
    intrinsics stay true). ``rng`` a numpy ``Generator``; the input is not changed."""
    out = dict(batch)
    out["image"] = np.stack([_jitter(img, rng) for img in batch["image"]]).astype(batch["image"].dtype)
    return out


def augment_batch(batch: dict, rng, scale_range=(0.75, 1.33), min_kept: float = 0.4) -> dict:
    """A :func:`frames_batch` batch seen by other cameras: each image zoomed by a factor drawn
    log-uniformly in ``scale_range`` about a random point (out of the frame: grey), its
    intrinsics changed to match, so the 3D labels (camera frame) stay true; boxes moved with the
    pixels and clipped to the image, a label dropped when less than ``min_kept`` of its box stays
    in view (its visible fraction scaled by what stays); brightness, contrast and colour balance
    jittered. Stereo boxes move by the same zoom and shift, unclipped: both views' cameras change
    alike, so ``right_T_left`` and the dual loss stay true. ``rng`` a numpy ``Generator``; the
    input is not changed."""
    out = {k: np.array(v) for k, v in batch.items()}
    n, H, W = out["image"].shape[:3]
    lo, hi = np.log(scale_range[0]), np.log(scale_range[1])
    for i in range(n):
        s = float(np.exp(rng.uniform(lo, hi)))
        tx = float(rng.uniform(min(0.0, W - s * W), max(0.0, W - s * W)))
        ty = float(rng.uniform(min(0.0, H - s * H), max(0.0, H - s * H)))
        M = np.array([[s, 0.0, tx], [0.0, s, ty]])
        img = cv2.warpAffine(
            out["image"][i], M, (W, H), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=(0.45,) * 3
        )
        out["image"][i] = _jitter(img, rng).astype(out["image"].dtype)
        out["K"][i] = (np.array([[s, 0.0, tx], [0.0, s, ty], [0.0, 0.0, 1.0]]) @ out["K"][i]).astype(out["K"].dtype)
        moved = out["boxes"][i] * s + np.array([tx, ty, tx, ty])
        clipped = np.clip(moved, 0.0, [W, H, W, H])
        area = lambda b: np.maximum(b[:, 2] - b[:, 0], 0.0) * np.maximum(b[:, 3] - b[:, 1], 0.0)
        kept = area(clipped) / np.maximum(area(moved), 1e-9)
        wide = np.minimum(clipped[:, 2] - clipped[:, 0], clipped[:, 3] - clipped[:, 1]) >= 4.0
        out["boxes"][i] = clipped.astype(out["boxes"].dtype)
        out["box_valid"][i] = out["box_valid"][i] & (kept >= min_kept) & wide
        out["visible_fraction"][i] = out["visible_fraction"][i] * kept
        shift = np.array([tx, ty, tx, ty])
        for key in ("box_left", "box_right") if "box_left" in out else ():
            out[key][i] = (out[key][i] * s + shift).astype(out[key].dtype)
    return out


def bop_frames(scene_dir, split: str) -> list:
    """The photographs of one split of a BOP scene as frame dicts (visible boxes and classes; no
    stereo labels). ``split``: ``"tune"`` or ``"test"`` of :func:`load_bop_split`."""
    scene = load_bop_split(scene_dir, split)
    frames = []
    for f in bop_split_frames(scene, split):
        objects = [
            {
                "class_name": o.class_name,
                "visible_box": o.visible_box,
                "visible_fraction": o.visible_fraction,
                "rotation": o.rotation,
                "center": o.center,
                "radii": o.radii,
                "frame_id": f.frame_id,
            }
            for o in f.objects
        ]
        frames.append({"rgb": read_rgb(f.image_path), "K": f.K, "objects": objects, "frame_id": f.frame_id})
    return frames


def _camera_motion(a: dict, b: dict, tol_m: float, tol_deg: float):
    """``(b_T_a, static)``: the camera motion from frame ``a`` to frame ``b`` that the most of their
    shared objects agree on (each object's pose in both frames gives one candidate; an object agrees
    when the candidate moves its centre within ``tol_m`` and its axes within ``tol_deg``), and the
    names of the objects that stayed put under it. ``(None, ())`` when no two objects agree."""
    pa = {o["class_name"]: o for o in a["objects"]}
    pb = {o["class_name"]: o for o in b["objects"]}
    shared = sorted(set(pa) & set(pb))
    if len(shared) < 2:
        return None, ()

    def poses(table):
        T = np.tile(np.eye(4), (len(shared), 1, 1))
        T[:, :3, :3] = [np.asarray(table[k]["rotation"]) for k in shared]
        T[:, :3, 3] = [np.asarray(table[k]["center"]) for k in shared]
        return T

    Ta, Tb = poses(pa), poses(pb)
    cand = Tb @ np.linalg.inv(Ta)  # (M, 4, 4): one motion per shared object
    moved = cand[:, None] @ Ta[None]  # (M, M, 4, 4): every object moved by every candidate
    near = np.linalg.norm(moved[..., :3, 3] - Tb[None, :, :3, 3], axis=-1) <= tol_m
    turn = np.degrees(
        np.asarray(
            metrics.rotation_angle(moved[..., :3, :3], np.broadcast_to(Tb[None, :, :3, :3], moved[..., :3, :3].shape))
        )
    )
    agree = near & (turn <= tol_deg)
    best = int(np.argmax(agree.sum(1)))
    if agree[best].sum() < 2:
        return None, ()
    return cand[best], tuple(k for k, ok in zip(shared, agree[best]) if ok)


def multiview_frames(
    frames,
    baseline=(0.1, 0.5),
    min_visible: float = 0.95,
    border: float = 2.0,
    tol_m: float = 0.01,
    tol_deg: float = 3.0,
) -> list:
    """Photographs of one scene as stereo pairs for the dual loss: each frame gets a second view
    among ``frames`` (the camera moved between ``baseline`` metres), and each object seen whole in
    both (at least ``min_visible`` visible, its box at least ``border`` pixels inside both images,
    and not moved between them) gets ``box_left`` / ``box_right``, its boxes in the two views.

    The dual loss needs the whole object's box in both views; the visible box is that box when
    the object is neither hidden nor cut by the image edge. The camera motion is the one the
    scene's static objects agree on (:func:`_camera_motion`), what a user's odometry or SLAM gives;
    an object that moved is left without a stereo label. The partner is the frame that labels the
    most objects, then the one whose baseline is nearest the middle of the range. Only ``frames``
    are partners: pass one split at a time, so no label crosses a split. Returns new frame dicts
    (the input is not changed) with ``right_T_left`` (4, 4) where a partner was found and
    ``partner_id``; frames without one are returned unchanged."""
    lo, hi = (float(x) for x in baseline)
    if not 0.0 <= lo < hi:
        raise ValueError(f"baseline: expected 0 <= low < high metres, got {baseline!r}")
    frames = list(frames)

    def whole(o, shape) -> bool:
        box = np.asarray(o["visible_box"], np.float64)
        H, W = shape[:2]
        inside = box[0] >= border and box[1] >= border and box[2] <= W - border and box[3] <= H - border
        return bool(np.all(np.isfinite(box)) and inside and float(o.get("visible_fraction", 1.0)) >= min_visible)

    out = []
    for a in frames:
        best = None
        for b in frames:
            if b is a:
                continue
            motion, static = _camera_motion(a, b, tol_m, tol_deg)
            if motion is None:
                continue
            dist = float(np.linalg.norm(np.linalg.inv(motion)[:3, 3]))
            if not lo <= dist <= hi:
                continue
            in_b = {o["class_name"]: o for o in b["objects"] if whole(o, b["rgb"].shape)}
            pairs = {
                o["class_name"]: in_b[o["class_name"]]["visible_box"]
                for o in a["objects"]
                if o["class_name"] in static and o["class_name"] in in_b and whole(o, a["rgb"].shape)
            }
            key = (len(pairs), -abs(dist - (lo + hi) / 2.0))
            if pairs and (best is None or key > best[0]):
                best = (key, b, motion, pairs)
        if best is None:
            out.append(a)
            continue
        _, b, motion, pairs = best
        objects = []
        for o in a["objects"]:
            o = dict(o)
            if o["class_name"] in pairs:
                o["box_left"] = np.asarray(o["visible_box"], np.float64)
                o["box_right"] = np.asarray(pairs[o["class_name"]], np.float64)
            objects.append(o)
        out.append({**a, "objects": objects, "right_T_left": motion, "partner_id": b.get("frame_id")})
    return out


def write_desk_frames(
    out_dir,
    num_frames: int,
    seed: int,
    *,
    models_dir,
    distractor_dir=None,
    image_size: tuple = (320, 240),
    chunk: int = 50,
    max_objects: int = 8,
    config: DeskConfig = DeskConfig(),
    progress: bool = True,
    num_points: int = 0,
) -> list:
    """Render ``num_frames`` desk frames straight at ``image_size`` (the LM-O intrinsics scaled)
    and write their :func:`frame_arrays` as ``out_dir/frames_NNNN.npz`` chunks (seeds per chunk:
    an interrupted call resumes by skipping the chunks written; each is written atomically).
    ``out_dir/stamp.json`` records the arguments: a call with others into the same folder is
    refused (:func:`jaxsem.training.check_stamp`). ``num_points`` > 0 also stores that many depth
    points per label (:data:`POINT_KEYS`). Returns the chunk paths."""
    out = pathlib.Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    meshes = load_lmo_meshes(models_dir)
    distractors = load_distractor_meshes(distractor_dir) if distractor_dir is not None else []
    W, H = (int(x) for x in image_size)
    K = np.diag([W / 640.0, H / 480.0, 1.0]) @ np.asarray(LMO_K, np.float64)
    stamp = {
        "what": "desk frames",
        "num_frames": int(num_frames),
        "seed": int(seed),
        "image_size": [W, H],
        "chunk": int(chunk),
        "max_objects": int(max_objects),
        "config": dataclasses.asdict(config),
        "models": mesh_listing(models_dir),
        "distractors": mesh_listing(distractor_dir),
        **({"num_points": int(num_points)} if num_points else {}),
    }

    def chunk_arrays(c, n, tick):
        def counted():
            for fr in render_desk_frames(
                meshes, n, seed=int(seed) * 100003 + c, distractors=distractors, config=config, K=K, image_size=(W, H)
            ):
                tick()
                yield fr

        return frame_arrays(counted(), (W, H), max_objects=max_objects, num_points=num_points)

    return write_desk_chunks(
        out, "frames", num_frames, chunk, stamp, chunk_arrays, desc="desk frames", progress=progress
    )


def load_frame_chunks(path) -> dict:
    """The arrays of :func:`write_desk_frames` (a folder of ``frames_NNNN.npz``), concatenated."""
    path = pathlib.Path(path)
    files = [f for f in sorted(path.glob("frames_[0-9]*.npz")) if ".tmp" not in f.name]
    if not files:
        raise ValueError(f"path: no frames_NNNN.npz chunks in {path}")
    first = npz_shapes(files[0])  # the array headers only: whether the chunks carry depth points
    points = POINT_KEYS if all(k in first for k in POINT_KEYS) else ()
    arrays = concat_npz(files, FRAME_KEYS + points)
    return with_teacher_keys(arrays)


def write_bop_scene(frames, scene_dir) -> pathlib.Path:
    """Write frame dicts (e.g. :func:`render_desk_frames`'s: ``rgb``, ``K``, ``objects`` with
    ``obj_id``, ``rotation``, ``translation`` (metres), ``visible_box``, ``visible_fraction``) as a
    BOP scene folder that :func:`jaxsem.volumon.data.load_bop_split` and every BOP command read:
    ``rgb/NNNNNN.png``, ``scene_gt.json`` (millimetres), ``scene_camera.json``,
    ``scene_gt_info.json`` (visible boxes as BOP's pixel indices; an unseen object gets -1
    entries), and ``camera.json`` (the first frame's intrinsics and the image size, which
    ``scene_camera.json`` does not hold: every frame must have that size). Frames are numbered
    from 0 in order. The meshes are not written: the scene's
    ``models/`` lies beside or above it, as in a BOP data set. Each file is written atomically; a
    folder that already holds a ``scene_gt.json`` is refused (ValueError naming ``scene_dir``), so
    no scene is overwritten. Returns the folder."""
    from ..._atomic import atomic_write_bytes, atomic_write_text

    scene = pathlib.Path(scene_dir)
    if (scene / "scene_gt.json").exists():
        raise ValueError(f"scene_dir: {scene} already holds a BOP scene (scene_gt.json)")
    gt, cameras, info = {}, {}, {}
    shared = None
    for i, fr in enumerate(frames):
        rgb = np.asarray(fr["rgb"])
        if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
            raise ValueError(f"frames: frame {i}: expected rgb (H, W, 3) uint8, got {rgb.shape} {rgb.dtype}")
        if shared is None:
            K0 = np.asarray(fr["K"], np.float64)
            shared = {"fx": float(K0[0, 0]), "fy": float(K0[1, 1]), "cx": float(K0[0, 2]), "cy": float(K0[1, 2])}
            shared |= {"width": int(rgb.shape[1]), "height": int(rgb.shape[0])}
        elif rgb.shape[:2] != (shared["height"], shared["width"]):
            raise ValueError(f"frames: frame {i} is {rgb.shape[1]} x {rgb.shape[0]}, frame 0 was another size")
        ok, png = cv2.imencode(".png", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
        if not ok:
            raise ValueError(f"frames: frame {i}: its image could not be encoded as PNG")
        atomic_write_bytes(scene / "rgb" / f"{i:06d}.png", png.tobytes(), record=False)
        objs = fr["objects"]
        gt[str(i)] = [
            {
                "obj_id": int(o["obj_id"]),
                "cam_R_m2c": np.asarray(o["rotation"], np.float64).ravel().tolist(),
                "cam_t_m2c": (1000.0 * np.asarray(o["translation"], np.float64)).tolist(),
            }
            for o in objs
        ]
        cameras[str(i)] = {"cam_K": np.asarray(fr["K"], np.float64).ravel().tolist(), "depth_scale": 1.0}
        rows = []
        for o in objs:
            b = np.asarray(o["visible_box"], np.float64)
            if np.all(np.isfinite(b)):  # the core's box edges to BOP's first pixel and last minus first
                x0, y0 = b[0] + 0.5, b[1] + 0.5
                box = [float(x0), float(y0), float(b[2] - 0.5 - x0), float(b[3] - 0.5 - y0)]
                rows.append({"bbox_visib": box, "visib_fract": float(o["visible_fraction"])})
            else:
                rows.append({"bbox_visib": [-1, -1, -1, -1], "visib_fract": 0.0})
        info[str(i)] = rows
    if shared is None:
        raise ValueError("frames: expected at least one frame")
    atomic_write_text(scene / "camera.json", json.dumps(shared), record=False)
    atomic_write_text(scene / "scene_camera.json", json.dumps(cameras), record=False)
    atomic_write_text(scene / "scene_gt_info.json", json.dumps(info), record=False)
    atomic_write_text(scene / "scene_gt.json", json.dumps(gt), record=False)  # last: it marks a whole scene
    return scene
