"""Data association for a detector's output: per-frame detections (box, class, score and, from a
detect-and-lift network, a camera-frame ellipsoid) become tracks with ids, across the posed frames
of a sequence, with no ground truth anywhere.

Each frame's detections are matched one to one to the tracks of the same class by box overlap
(against the track's last box, seen in one of the two previous frames, and against the box of
the track's world ellipsoid projected by the frame's odometry pose) or, for lifted detections,
by how closely the new viewing ray meets the track's earlier rays (:func:`_ray_agreement`),
whichever agrees most; greedily, best pair first, down to ``min_iou``. A detection left over
starts a track. A track's ellipsoid has the mean semi-axes of its detections' lifted
ellipsoids, the first one's orientation, and a centre triangulated from the viewing rays through
the lifted centres (the point nearest to every ray, held towards the lifts' mean by a weak
prior): a single-view lift errs mostly along its ray, in depth, which the rays of other
viewpoints pin down. Tracks seen fewer than ``min_views`` times are dropped (a stray detection
cannot start a landmark). The rays keep an object across frames far apart in viewpoint, where
its boxes no longer overlap; the last box keeps it when a detector gives no ellipsoid.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np

from jaxsem import quadrics as q
from jaxsem.slam._sequence_types import Sequence

#: Tracks are projected in padded blocks of this many (one compiled program per block count).
_BLOCK = 16
#: Weight of the lifts' mean centre against the viewing rays in a track's centre: the rays
#: decide along directions they span by more than about asin(sqrt(0.05)) = 13 degrees.
_RAY_PRIOR = 0.05
#: A track's last box is compared while it was seen in one of this many previous frames.
_RECENT = 2


def _across_ray(lift):
    """The projector onto the plane across a lift's viewing ray (camera centre through its
    centre) and the ray's origin: ``P @ (x - origin)`` is how far ``x`` lies beside the ray."""
    _, c, _, origin = lift
    d = c - origin
    d = d / max(float(np.linalg.norm(d)), 1e-9)
    return np.eye(3) - np.outer(d, d), origin


def _triangulate(lifts):
    """The point nearest to the rays from each camera centre through each lifted centre, held
    towards the lifted centres' mean with weight ``_RAY_PRIOR`` (a 3 x 3 solve; always regular)."""
    A = _RAY_PRIOR * np.eye(3)
    b = _RAY_PRIOR * np.mean([x[1] for x in lifts], axis=0)
    for lift in lifts:
        P, origin = _across_ray(lift)
        A += P
        b += P @ origin
    return np.linalg.solve(A, b)


@functools.lru_cache(maxsize=1)
def _project():
    return jax.jit(q.project_bbox)


def _predicted_boxes(tracks, K, camera_T_world):
    """(T, 4) boxes of the tracks' ellipsoids in this frame and (T,) validity."""
    n = len(tracks)
    if n == 0:
        return np.zeros((0, 4)), np.zeros(0, bool)
    cap = _BLOCK * -(-n // _BLOCK)
    R = np.tile(np.eye(3), (cap, 1, 1))
    c = np.zeros((cap, 3))
    c[:, 2] = 1.0
    r = np.ones((cap, 3))
    has = np.zeros(cap, bool)
    for j, t in enumerate(tracks):
        if t["center"] is not None:
            R[j], c[j], r[j], has[j] = t["rotation"], t["center"], t["radii"], True
    box, valid = _project()(jnp.asarray(R), jnp.asarray(c), jnp.asarray(r), jnp.asarray(K), jnp.asarray(camera_T_world))
    return np.asarray(box)[:n], (np.asarray(valid) & has)[:n]


def _ray_agreement(track, lift) -> float:
    """How well a new lift's viewing ray meets a track's rays, in [0, 1]: 1 minus the largest
    distance from their common nearest point to any of the rays, over the track's mean
    semi-axis (0 beyond it, or when that point lies behind the new camera). Objects move along
    their rays as a lift misjudges depth, not across them: two views of one object agree here
    even when their lifts are far apart and their boxes no longer overlap."""
    if lift is None or not track["lifts"]:
        return 0.0
    rays = track["lifts"] + [lift]
    p = _triangulate(rays)
    worst = max(float(np.linalg.norm(P @ (p - origin))) for P, origin in map(_across_ray, rays))
    ahead = float((p - lift[3]) @ (lift[1] - lift[3]))
    scale = max(float(np.mean(track["radii"])), 1e-3)
    return max(0.0, 1.0 - worst / scale) if ahead > 0.0 else 0.0


def _lift(det, k, world_T_camera):
    """Detection ``k``'s ellipsoid in the world frame, or None (no lift, or not finite)."""
    if det.get("center") is None:
        return None
    R = np.asarray(det["rotation"][k], np.float64)
    c = np.asarray(det["center"][k], np.float64)
    r = np.asarray(det["radii"][k], np.float64)
    if not (np.all(np.isfinite(R)) and np.all(np.isfinite(c)) and np.all(np.isfinite(r)) and np.all(r > 0)):
        return None
    U, _, Vt = np.linalg.svd(world_T_camera[:3, :3] @ R)
    return U @ Vt, world_T_camera[:3, :3] @ c + world_T_camera[:3, 3], r, world_T_camera[:3, 3]


def _check(camera_T_world, detections, min_iou, min_views, min_score, merge=0.0):
    poses = np.asarray(camera_T_world, np.float64)
    if poses.ndim != 3 or poses.shape[1:] != (4, 4) or not np.all(np.isfinite(poses)):
        raise ValueError(f"camera_T_world: expected finite (T, 4, 4) poses, got shape {poses.shape}")
    if len(detections) != len(poses):
        raise ValueError(f"detections: one entry per frame expected ({len(poses)}), got {len(detections)}")
    if not 0.0 < float(min_iou) <= 1.0:
        raise ValueError(f"min_iou: expected a value in (0, 1], got {min_iou}")
    try:
        ok = bool(np.isfinite(float(merge)) and float(merge) >= 0.0)
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise ValueError(f"merge: expected a non-negative number of semi-axes, got {merge!r}")
    if int(min_views) < 1:
        raise ValueError(f"min_views: expected at least 1, got {min_views}")
    if not 0.0 <= float(min_score) <= 1.0:
        raise ValueError(f"min_score: expected a value in [0, 1], got {min_score}")
    for t, d in enumerate(detections):
        box = np.asarray(d.get("box", np.zeros((0, 4))), np.float64).reshape(-1, 4)
        if len(d.get("class_name", ())) != len(box):
            raise ValueError(f"detections[{t}]: {len(box)} boxes but {len(d.get('class_name', ()))} class names")
        if not np.all(np.isfinite(box)) or np.any(box[:, 2:] < box[:, :2]):
            raise ValueError(f"detections[{t}]: boxes must be finite [u_min, v_min, u_max, v_max]")
    return poses


def _merge_tracks(tracks: list, raw_ids: list, merge: float) -> list:
    """Joins the tracks that are one object seen twice (:func:`associate_detections`' ``merge``):
    closest pairs first, a joined track taking the frames, views and lifts of both and a centre
    triangulated from all its rays. ``tracks`` is changed in place (a joined-away track keeps 0
    views); returns ``raw_ids`` with every detection of a joined-away track under the track it
    joined."""
    frames = [set() for _ in tracks]
    for t, ids in enumerate(raw_ids):
        for j in ids[ids >= 0]:
            frames[int(j)].add(t)

    def gap(a, b):
        ta, tb = tracks[a], tracks[b]
        if ta["class"] != tb["class"] or ta["center"] is None or tb["center"] is None:
            return np.inf
        size = 0.5 * (float(np.mean(ta["radii"])) + float(np.mean(tb["radii"])))
        return float(np.linalg.norm(ta["center"] - tb["center"])) / max(size, 1e-9)

    by_class: dict = {}
    for j, tr in enumerate(tracks):
        if tr["center"] is not None:
            by_class.setdefault(tr["class"], []).append(j)
    pairs = [(gap(a, b), a, b) for js in by_class.values() for n, a in enumerate(js) for b in js[n + 1 :]]
    into = list(range(len(tracks)))

    def root(j):
        while into[j] != j:
            j = into[j]
        return j

    for _, a, b in sorted(p for p in pairs if p[0] <= merge):
        a, b = root(a), root(b)
        if a == b or frames[a] & frames[b] or gap(a, b) > merge:
            continue  # seen together in one frame (two objects), or apart once joined to others
        a, b = min(a, b), max(a, b)  # the earlier track keeps its id and its first lift
        ta, tb = tracks[a], tracks[b]
        ta["lifts"] = ta["lifts"] + tb["lifts"]
        ta["center"] = _triangulate(ta["lifts"])
        ta["radii"] = np.mean([x[2] for x in ta["lifts"]], axis=0)
        ta["views"] += tb["views"]
        tb["views"] = 0
        frames[a] |= frames[b]
        into[b] = a
    return [np.array([root(int(j)) if j >= 0 else -1 for j in ids], np.int64) for ids in raw_ids]


def associate_detections(
    K,
    camera_T_world,
    detections,
    *,
    min_iou: float = 0.3,
    min_views: int = 3,
    min_score: float = 0.5,
    merge: float = 0.0,
) -> tuple[list, dict]:
    """Track ids for a detector's per-frame output (module docstring).

    Args:
      K: (3, 3) intrinsics shared by the frames.
      camera_T_world: (T, 4, 4) the frames' poses (odometry / VIO; world to camera).
      detections: T dicts with ``box`` (D, 4) pixels, ``class_name`` (D names), optional ``score``
        (D,) and optional camera-frame ``rotation`` (D, 3, 3), ``center`` (D, 3), ``radii`` (D, 3)
        (the output of :func:`jaxsem.volumon.rcnn.detect_image`).
      min_iou: least box overlap for a detection to continue a track.
      min_views: least detections of a kept track.
      min_score: detections scored below this are ignored.
      merge: after the last frame, two tracks of one class that never share a frame and whose
        centres lie within ``merge`` times their mean semi-axis of each other are one object seen
        twice (a track broken by an occlusion or a turn), joined into one; 0 joins none.

    Returns:
      ``(ids, tracks)``: ``ids[t]`` (D_t,) int track id per detection of frame t, -1 where it was
      ignored or its track dropped; ``tracks`` {id: {"class": name, "views": count, "rotation",
      "center", "radii"}} with the world ellipsoid (None values without a lift).

    Raises:
      ValueError: poses, detections or thresholds malformed (naming the argument).
    """
    poses = _check(camera_T_world, detections, min_iou, min_views, min_score, merge)
    K = np.asarray(K, np.float64)
    tracks: list[dict] = []
    raw_ids = []
    for t, d in enumerate(detections):
        box = np.asarray(d.get("box", np.zeros((0, 4))), np.float64).reshape(-1, 4)
        names = list(d.get("class_name", ()))
        score = np.asarray(d.get("score", np.ones(len(box))), np.float64).reshape(-1)
        world_T_camera = np.linalg.inv(poses[t])
        lifts = [_lift(d, k, world_T_camera) for k in range(len(box))]
        pred, pred_ok = _predicted_boxes(tracks, K, poses[t])
        last = np.array([tr["box"] for tr in tracks]).reshape(-1, 4)
        recent = np.array([tr["frame"] >= t - _RECENT for tr in tracks], bool)
        iou = np.zeros((len(box), len(tracks)))
        if len(box) and len(tracks):
            same = np.array([[n == tr["class"] for tr in tracks] for n in names], bool)
            from_pred = np.where(pred_ok[None], np.asarray(q.box_iou(box[:, None], pred[None])), 0.0)
            from_last = np.where(recent[None], np.asarray(q.box_iou(box[:, None], last[None])), 0.0)
            from_rays = np.array(
                [[_ray_agreement(tr, x) if ok else 0.0 for tr, ok in zip(tracks, row)] for x, row in zip(lifts, same)]
            ).reshape(len(box), len(tracks))
            iou = np.where(same, np.maximum(np.maximum(from_pred, from_last), from_rays), 0.0)
        iou[score < min_score] = 0.0
        ids = np.full(len(box), -1, np.int64)
        free_d, free_t = np.ones(len(box), bool), np.ones(len(tracks), bool)
        for flat in np.argsort(-iou, axis=None, kind="stable"):
            k, j = np.unravel_index(flat, iou.shape)
            if iou[k, j] < min_iou:
                break
            if free_d[k] and free_t[j]:
                ids[k], free_d[k], free_t[j] = j, False, False
        for k in range(len(box)):
            if ids[k] < 0 and score[k] >= min_score:
                ids[k] = len(tracks)
                tracks.append({"class": names[k], "lifts": [], "rotation": None, "center": None, "radii": None})
        for k in np.flatnonzero(ids >= 0):
            tr = tracks[ids[k]]
            tr["box"], tr["frame"] = box[k], t
            if lifts[k] is not None:
                tr["lifts"].append(lifts[k])
                tr["rotation"] = tr["lifts"][0][0]
                tr["center"] = _triangulate(tr["lifts"])
                tr["radii"] = np.mean([x[2] for x in tr["lifts"]], axis=0)
            tr["views"] = tr.get("views", 0) + 1
        raw_ids.append(ids)
    if merge > 0:
        raw_ids = _merge_tracks(tracks, raw_ids, float(merge))
    kept = [j for j, tr in enumerate(tracks) if tr["views"] >= int(min_views)]
    renumber = {j: n for n, j in enumerate(kept)}
    ids_out = [np.array([renumber.get(int(j), -1) for j in ids], np.int64) for ids in raw_ids]
    out = {renumber[j]: {k: tracks[j][k] for k in ("class", "views", "rotation", "center", "radii")} for j in kept}
    return ids_out, out


def detected_sequence(seq: Sequence, detections, **kwargs) -> Sequence:
    """``seq`` (its poses, images and intrinsics) with its detections replaced by a detector's,
    associated by :func:`associate_detections` (``kwargs``): boxes, classes and track ids per
    frame, and ``initial`` the tracks' world ellipsoids where the detector lifts them. The class
    names must be in the sequence's class table. ``truth`` is dropped: the tracks are not the
    truth's objects (match them before scoring)."""
    poses = np.stack([f.camera_T_world for f in seq.frames]) if seq.frames else np.zeros((0, 4, 4))
    ids, tracks = associate_detections(seq.K, poses, detections, **kwargs)
    if seq.classes is not None:
        for tr in tracks.values():
            if tr["class"] not in seq.classes:
                raise ValueError(f"detections: class {tr['class']!r} is not in the sequence's class table")
    frames = []
    for f, d, i in zip(seq.frames, detections, ids):
        keep = i >= 0
        box = np.asarray(d.get("box", np.zeros((0, 4))), np.float64).reshape(-1, 4)[keep]
        names = [n for n, k in zip(d.get("class_name", ()), keep) if k]
        frames.append(
            dataclasses.replace(
                f,
                boxes=box,
                classes=tuple(names),
                ids=tuple(int(x) for x in i[keep]),
                texture_depth=np.full(len(box), np.nan),
            )
        )
    initial = {
        j: {"rotation": tr["rotation"], "center": tr["center"], "radii": tr["radii"]}
        for j, tr in tracks.items()
        if tr["center"] is not None
    }
    return dataclasses.replace(seq, frames=tuple(frames), initial=initial or None, truth=None)
