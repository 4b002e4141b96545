"""A BOP scene as ROSHAN sequences: stretches where objects stay put, camera poses from the
objects, odometry as a user's would be, rendered visible boxes, and user-style shape priors.

The recording of a BOP scene (LM-O's desk) is not static: objects are picked up and put down
between frames. ROSHAN needs a world that stays put, so the scene is cut into *stretches*
(:func:`find_stretches`):

- a stretch starts at a frame with its objects' poses; its world frame is the desk's: origin at
  the centroid of the object centres, z along the normal of the plane fitted through them
  (pointing to the camera's side), x along the camera's x axis projected into that plane;
- the objects still in the stretch's first frame are its *anchors*. In every later frame the
  camera pose ``camera_T_world`` is the rigid fit (:func:`jaxsem.quadrics.fit_rigid_transform`)
  of the anchors' cuboid corners in the world to the same corners in the frame (all present
  anchors, weighted alike); anchors whose corners then miss by more than ``tol_m`` have moved and
  leave the set (the fit is redone without them). The stretch ends at the frame where fewer than
  ``min_objects`` anchors agree;
- every object's *still spells*: the runs of frames in which its world pose (from the fitted
  camera) stays within ``tol_m`` / ``tol_deg`` of the spell's first pose. An object that moves
  starts a new spell, a new object for ROSHAN (its id ``obj_id * 100 + spell``). The spell's true
  ellipsoid is the mean of its per-frame world poses (centre of the mesh extent, half extents as
  radii: :class:`jaxsem.data.BopObject`).

:func:`stretch_sequence` turns one stretch into a :class:`jaxsem.slam._sequence_types.Sequence` with the truth
attached; ROSHAN never sees an object pose:

- poses: integrated odometry (:class:`OdometryModel`): from the true first pose, each step is the
  true relative motion times an error ``exp(b_t + n_t)`` (right-multiplied, in the camera frame of
  the step's start) with a drift ``b_t = b_{t-1} + w_t`` that random-walks and white noise
  ``n_t``, seeded; the relative motions of consecutive poses are the odometry measurements;
- detections: each spell's visible box (rendered from the mesh with occlusion between the
  annotated objects, :func:`jaxsem.data.visible_boxes`) with Gaussian pixel noise per edge,
  clipped to the image; setting ``"clean"`` keeps objects at least ``clean_min_visible`` visible,
  setting ``"missed"`` keeps objects down to ``missed_min_visible`` (boxes cut by occluders) and
  drops each detection with probability ``miss_rate``;
- classes: :func:`user_class_table`, each class's nominal size off the truth by a fixed seeded
  factor in [0.8, 1.25] (one factor per class), sigma 30 % of it.
"""

from __future__ import annotations

import dataclasses
import math

import cv2
import numpy as np

from .. import classes as _classes, quadrics
from .._checks import check_fields, finite_nonnegative
from ..data import BopFrame, BopScene
from ..quadrics import EllipsoidView
from ._sequence_types import Sequence, SequenceFrame

__all__ = [
    "STRETCH_SETTINGS",
    "OdometryModel",
    "Spell",
    "Stretch",
    "find_stretches",
    "odometry_poses",
    "pose_prior_weights",
    "POSE_PRIOR_MODES",
    "stretch_sequence",
    "user_class_table",
]

_CORNERS = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], np.float64)


@dataclasses.dataclass(frozen=True)
class Spell:
    """One object's still spell inside a stretch (world frame of the stretch, metres).

    Attributes:
      id: the object's id for ROSHAN (``obj_id * 100 + spell number``, unique in the stretch).
      obj_id, class_name: the BOP object.
      frames: indices (into :attr:`Stretch.frame_ids`) of the frames the spell covers.
      rotation (3, 3), center (3,), radii (3,): the true ellipsoid (mean over the spell).
    """

    id: int
    obj_id: int
    class_name: str
    frames: tuple
    rotation: np.ndarray
    center: np.ndarray
    radii: np.ndarray

    ellipsoid = EllipsoidView()


@dataclasses.dataclass(frozen=True)
class Stretch:
    """A run of frames with at least ``min_objects`` objects still.

    Attributes:
      frame_ids: BOP frame ids in order; frames: the :class:`BopFrame` of each.
      camera_T_world: (T, 4, 4) true camera poses (fitted on the anchors).
      anchors: obj ids that stayed put through the whole stretch.
      spells: the still spells of every object (:class:`Spell`).
      fit_rms: (T,) RMS corner residual of each frame's camera fit (metres).
    """

    frame_ids: tuple
    frames: tuple
    camera_T_world: np.ndarray
    anchors: tuple
    spells: tuple
    fit_rms: np.ndarray


def _corners(obj, scene: BopScene) -> np.ndarray:
    """Cuboid corners (8, 3) of an object's mesh extent, in the camera frame."""
    mesh = scene.meshes[obj.obj_id]
    local = mesh.center + _CORNERS * mesh.radii
    return local @ np.asarray(obj.rotation).T + np.asarray(obj.translation)


def _support_normal(centres, normal, rotations, radii, iterations: int = 3):
    """The normal of the plane through the objects' lowest points (the surface they rest on),
    refined from ``normal``: each object's lowest point along the current normal (its support
    point), a plane fitted through those, repeated. A plane through the centres instead is
    tilted whenever the objects differ in height (a 20 cm driller beside a 5 cm duck)."""
    for _ in range(iterations):
        reach = quadrics.half_extent(rotations, radii, normal, xp=np)
        bottoms = centres - reach[:, None] * normal
        _, sv, vt = np.linalg.svd(bottoms - bottoms.mean(0))
        if sv[1] < 1e-6:  # collinear support points: keep the estimate
            break
        normal = vt[2] if vt[2] @ normal >= 0 else -vt[2]
    return normal


def _desk_frame(centres: np.ndarray, rotations=None, radii=None) -> np.ndarray:
    """``world_T_camera`` of the desk frame of objects seen in one camera: centres (N, 3), and
    optionally their rotations (N, 3, 3) and half extents (N, 3), with which world z is the
    normal of the plane they rest on (:func:`_support_normal`), as gravity would give it, rather
    than of the plane through their centres."""
    mean = centres.mean(0)
    if len(centres) >= 3:
        _, _, vt = np.linalg.svd(centres - mean)
        normal = vt[2]
    else:
        normal = np.array([0.0, -1.0, 0.0])
    if normal @ (-mean) < 0:  # towards the camera (at the origin of its frame)
        normal = -normal
    if rotations is not None and radii is not None and len(centres) >= 3:
        normal = _support_normal(centres, normal, np.asarray(rotations), np.asarray(radii))
    x = np.array([1.0, 0.0, 0.0]) - normal[0] * normal
    if np.linalg.norm(x) < 1e-6:
        x = np.array([0.0, 1.0, 0.0]) - normal[1] * normal
    x = x / np.linalg.norm(x)
    y = np.cross(normal, x)
    world_R_cam = np.stack([x, y, normal])  # rows: world axes in camera coordinates
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = world_R_cam, -world_R_cam @ mean
    return out


def _pose(R, t) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = R, t
    return out


def _angle_deg(Ra, Rb) -> float:
    c = (np.trace(Ra.T @ Rb) - 1.0) / 2.0
    return math.degrees(math.acos(min(1.0, max(-1.0, c))))


def _mean_rotation(Rs) -> np.ndarray:
    U, _, Vt = np.linalg.svd(np.sum(Rs, axis=0))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


def camera_from_anchors(world_corners: dict, frame: BopFrame, scene: BopScene, tol_m: float):
    """``(camera_T_world, kept ids, rms)`` of one frame from the anchors' corners: a rigid fit
    over every present anchor, refitted without those whose corners miss by more than ``tol_m``
    (largest first, one at a time). ``camera_T_world`` is None when fewer than three agree."""
    seen = {o.obj_id: _corners(o, scene) for o in frame.objects if o.obj_id in world_corners}
    ids = sorted(seen)
    while len(ids) >= 3:
        P = np.concatenate([world_corners[i] for i in ids])
        Q = np.concatenate([seen[i] for i in ids])
        T = quadrics.fit_rigid_transform(P, Q, xp=np)
        miss = {
            i: float(np.max(np.linalg.norm(world_corners[i] @ T[:3, :3].T + T[:3, 3] - seen[i], axis=1))) for i in ids
        }
        worst = max(ids, key=lambda i: miss[i])
        if miss[worst] <= tol_m:
            rms = float(np.sqrt(np.mean(np.sum((P @ T[:3, :3].T + T[:3, 3] - Q) ** 2, axis=1))))
            return T, tuple(ids), rms
        ids.remove(worst)
    return None, tuple(ids), math.nan


def find_stretches(
    scene: BopScene,
    frames=None,
    *,
    min_objects: int = 3,
    min_frames: int = 5,
    tol_m: float = 0.02,
    tol_deg: float = 10.0,
) -> tuple[Stretch, ...]:
    """The stretches of ``frames`` (default: every frame of ``scene``, in id order) where at least
    ``min_objects`` objects stay put (module docstring), each at least ``min_frames`` long.

    tol_m: metres; an anchor whose cuboid corners miss the fit by more, or an object whose centre
    moves by more from its spell's first pose, has moved. tol_deg: the same for an object's
    rotation.

    Raises:
      ValueError: ``min_objects`` < 3, ``min_frames`` < 2 or non-positive tolerances.
    """
    if int(min_objects) < 3:
        raise ValueError(f"min_objects: a camera pose needs at least 3 objects, got {min_objects}")
    if int(min_frames) < 2:
        raise ValueError(f"min_frames: expected >= 2, got {min_frames}")
    if not (tol_m > 0 and tol_deg > 0):
        raise ValueError(f"tol_m, tol_deg: expected positive numbers, got {tol_m}, {tol_deg}")
    frames = tuple(scene.frames if frames is None else frames)
    out = []
    k = 0
    while k < len(frames):
        stretch, k_next = _grow(scene, frames, k, int(min_objects), float(tol_m), float(tol_deg))
        if stretch is not None and len(stretch.frame_ids) >= int(min_frames):
            out.append(stretch)
        k = max(k_next, k + 1)
    return tuple(out)


def _grow(scene, frames, k, min_objects, tol_m, tol_deg):
    first = frames[k]
    if len(first.objects) < min_objects:
        return None, k + 1
    world_T_cam0 = _desk_frame(
        np.stack([o.center for o in first.objects]),
        np.stack([o.rotation for o in first.objects]),
        np.stack([scene.meshes[o.obj_id].radii for o in first.objects]),
    )
    cams = [np.linalg.inv(world_T_cam0)]
    anchors = {o.obj_id: _corners(o, scene) @ world_T_cam0[:3, :3].T + world_T_cam0[:3, 3] for o in first.objects}
    rms = [0.0]
    used = [first]
    j = k + 1
    while j < len(frames):
        T, kept, err = camera_from_anchors(anchors, frames[j], scene, tol_m)
        if T is None or len(kept) < min_objects:
            break
        present = {o.obj_id for o in frames[j].objects}
        for i in list(anchors):  # present anchors outside the fit moved
            if i in present and i not in kept:
                del anchors[i]
        cams.append(T)
        rms.append(err)
        used.append(frames[j])
        j += 1
    cams = np.stack(cams)
    # still spells of every object in the stretch's world frame
    open_: dict = {}
    spells: list = []
    count: dict = {}

    def close(obj_id):
        s = open_.pop(obj_id)
        spells.append(s)

    for t, (frame, cTw) in enumerate(zip(used, cams)):
        wTc = np.linalg.inv(cTw)
        for o in frame.objects:
            R = wTc[:3, :3] @ np.asarray(o.rotation)
            c = wTc[:3, :3] @ np.asarray(o.center) + wTc[:3, 3]
            s = open_.get(o.obj_id)
            if s is not None and (np.linalg.norm(c - s["c"][0]) > tol_m or _angle_deg(R, s["R"][0]) > tol_deg):
                close(o.obj_id)
                s = None
            if s is None:
                n = count.get(o.obj_id, 0)
                count[o.obj_id] = n + 1
                s = open_[o.obj_id] = {"obj": o, "n": n, "frames": [], "R": [], "c": []}
            s["frames"].append(t)
            s["R"].append(R)
            s["c"].append(c)
    for i in list(open_):
        close(i)
    spells_out = tuple(
        Spell(
            id=int(s["obj"].obj_id * 100 + s["n"]),
            obj_id=int(s["obj"].obj_id),
            class_name=s["obj"].class_name,
            frames=tuple(s["frames"]),
            rotation=_mean_rotation(np.stack(s["R"])),
            center=np.mean(s["c"], axis=0),
            radii=np.asarray(s["obj"].radii, np.float64),
        )
        for s in sorted(spells, key=lambda s: (s["frames"][0], s["obj"].obj_id))
    )
    stretch = Stretch(
        frame_ids=tuple(f.frame_id for f in used),
        frames=tuple(used),
        camera_T_world=cams,
        anchors=tuple(sorted(anchors)),
        spells=spells_out,
        fit_rms=np.asarray(rms),
    )
    return stretch, j


# --------------------------------------------------------------------------------------------
# What a user's sequence would hold: odometry, detections, class priors.


@dataclasses.dataclass(frozen=True)
class OdometryModel:
    """Odometry error per step (module docstring): white noise ``n_t`` and a random-walk drift
    ``b_t = b_{t-1} + w_t``, both per axis of the step's tangent (rotation rad, translation m),
    right-multiplied onto each true relative motion.

    Attributes:
      noise_translation, noise_rotation_deg: sigma of ``n_t`` (metres, degrees).
      drift_translation, drift_rotation_deg: sigma of the drift increment ``w_t``.
    """

    noise_translation: float = 0.001
    noise_rotation_deg: float = 0.1
    drift_translation: float = 0.0002
    drift_rotation_deg: float = 0.02

    def __post_init__(self):
        names = [f.name for f in dataclasses.fields(self)]
        check_fields(self, names, "a finite number >= 0", finite_nonnegative, prefix="OdometryModel.")


def _exp_se3(xi) -> np.ndarray:
    """SE(3) exponential of a (6,) tangent ``[rotation (3), translation (3)]`` (small steps)."""
    R, _ = cv2.Rodrigues(np.asarray(xi[:3], np.float64).reshape(3, 1))
    return _pose(R, np.asarray(xi[3:], np.float64))


def odometry_poses(camera_T_world, model: OdometryModel, rng: np.random.Generator) -> np.ndarray:
    """(T, 4, 4) ``camera_T_world`` integrated from noisy, drifting relative motions
    (:class:`OdometryModel`), starting at the true first pose."""
    true = np.asarray(camera_T_world, np.float64)
    if true.ndim != 3 or true.shape[1:] != (4, 4):
        raise ValueError(f"camera_T_world: expected (T, 4, 4), got {true.shape}")
    sig_n = np.r_[[math.radians(model.noise_rotation_deg)] * 3, [model.noise_translation] * 3]
    sig_w = np.r_[[math.radians(model.drift_rotation_deg)] * 3, [model.drift_translation] * 3]
    out = [true[0]]
    drift = np.zeros(6)
    for t in range(1, len(true)):
        drift = drift + sig_w * rng.standard_normal(6)
        # step = pose of camera t in camera t-1's frame; world_T_c(t) = world_T_c(t-1) @ step
        step = true[t - 1] @ np.linalg.inv(true[t])
        measured = step @ _exp_se3(drift + sig_n * rng.standard_normal(6))
        out.append(np.linalg.inv(np.linalg.inv(out[-1]) @ measured))
    return np.stack(out)


POSE_PRIOR_MODES = ("all", "first", "drift")


def pose_prior_weights(
    poses,
    mode: str = "all",
    odometry: OdometryModel = OdometryModel(),
    prior_translation: float = 0.02,
    prior_rotation_deg: float = 1.0,
) -> np.ndarray:
    """(T, 2) ``[translation, rotation]`` weights of absolute priors on integrated odometry
    ``poses`` (T, 4, 4) ``camera_T_world``, relative to priors at ``prior_translation`` /
    ``prior_rotation_deg`` (``jaxsem.slam.make_problem(pose_prior_weight=...)``).

    - ``"all"``: every pose at the stated sigmas (ones), whatever the drift gathered so far;
    - ``"first"``: the first pose at the odometry's white noise (the user knows where they
      started), no prior on the others (the between factors carry the chain);
    - ``"drift"``: pose ``t`` at the spread :class:`OdometryModel` implies after ``t`` steps:
      per axis ``t n^2 + d^2 t (t + 1) (2 t + 1) / 6`` (white noise ``n`` plus the integral of
      the random-walk drift ``d``), plus the rotation's share carried over to the translation
      along the path (``var_rotation * distance^2 / 3``, the distance from the first camera
      position: heading errors gathered evenly along a straight path), floored at one step's
      white noise.

    Raises:
      ValueError: unknown ``mode``, ``poses`` not (T, 4, 4), non-positive prior sigmas.
    """
    poses = np.asarray(poses, np.float64)
    if poses.ndim != 3 or poses.shape[1:] != (4, 4):
        raise ValueError(f"poses: expected (T, 4, 4), got {poses.shape}")
    if mode not in POSE_PRIOR_MODES:
        raise ValueError(f"mode: expected one of {POSE_PRIOR_MODES}, got {mode!r}")
    if not (prior_translation > 0 and prior_rotation_deg > 0):
        raise ValueError(
            f"prior_translation, prior_rotation_deg: expected > 0, got {prior_translation}, {prior_rotation_deg}"
        )
    T = len(poses)
    n_t = max(odometry.noise_translation, 1e-6)
    n_r = math.radians(max(odometry.noise_rotation_deg, 1e-4))
    prior_r = math.radians(prior_rotation_deg)
    if mode == "all":
        return np.ones((T, 2))
    if mode == "first":
        out = np.zeros((T, 2))
        out[0] = [prior_translation / n_t, prior_r / n_r]
        return out
    t = np.arange(T, dtype=np.float64)
    walk = t * (t + 1) * (2 * t + 1) / 6
    var_r = n_r**2 * np.maximum(t, 1) + math.radians(odometry.drift_rotation_deg) ** 2 * walk
    centres = np.einsum("tji,tj->ti", poses[:, :3, :3], -poses[:, :3, 3])  # camera centres in the world
    dist = np.linalg.norm(centres - centres[0], axis=1)
    var_t = n_t**2 * np.maximum(t, 1) + odometry.drift_translation**2 * walk + var_r * dist**2 / 3
    return np.stack([prior_translation / np.sqrt(var_t), prior_r / np.sqrt(var_r)], axis=1)


def user_class_table(extents: dict, seed: int = 27, sigma_fraction: float = 0.3, low=0.8, high=1.25):
    """``(ClassTable, factors)``: each class of ``extents`` (name -> true full dimensions (3,),
    e.g. :func:`jaxsem.volumon.data.bop_class_extents`) registered at its dimensions times one factor per
    class drawn log-uniformly in ``[low, high]`` (seeded; classes in sorted order), with sigma
    ``sigma_fraction`` of the nominal size, as an ellipsoid class. ``factors``: name -> factor."""
    if not extents:
        raise ValueError("extents: no classes")
    if not (0 < low <= 1 <= high):
        raise ValueError(f"low, high: expected 0 < low <= 1 <= high, got {low}, {high}")
    rng = np.random.default_rng(seed)
    table = None
    factors = {}
    for name in sorted(extents):
        f = float(np.exp(rng.uniform(np.log(low), np.log(high))))
        dims = f * np.asarray(extents[name], np.float64)
        row = _classes.ObjectClass(name, "ellipsoid", tuple(dims), tuple(sigma_fraction * dims))
        table = _classes.ClassTable((row,)) if table is None else table.with_classes(_classes.ClassTable((row,)))
        factors[name] = f
    return table, factors


STRETCH_SETTINGS = ("clean", "missed")


def stretch_sequence(
    stretch: Stretch,
    classes,
    *,
    setting: str = "clean",
    seed: int = 0,
    box_sigma: float = 2.0,
    odometry: OdometryModel = OdometryModel(),
    clean_min_visible: float = 0.5,
    missed_min_visible: float = 0.15,
    miss_rate: float = 0.2,
    min_box_pixels: float = 8.0,
    min_views: int = 3,
    prior_translation: float = 0.02,
    prior_rotation_deg: float = 1.0,
):
    """One stretch as a :class:`jaxsem.slam._sequence_types.Sequence` (module docstring) with ``truth`` (the true
    poses and every spell's ellipsoid) and ``noise`` (box sigma; the pose priors, which are the
    integrated odometry, at ``prior_translation`` / ``prior_rotation_deg``; each odometry step at
    its white noise and the drift it can gather over the stretch, added in quadrature).

    Frames keep their images (``root`` is the scene folder, ``image`` the relative path).
    Returns ``(sequence, odometry)``: ``odometry`` (T - 1, 4, 4), the measured relative motions
    (``jaxsem.slam.make_problem(odometry=...)``); they are also the relative motions of
    consecutive poses of the sequence.

    Raises:
      ValueError: unknown ``setting``, a class of the stretch missing from ``classes``.
    """
    if setting not in STRETCH_SETTINGS:
        raise ValueError(f"setting: expected one of {STRETCH_SETTINGS}, got {setting!r}")
    for s in stretch.spells:
        if s.class_name not in classes:
            raise ValueError(f"classes: no class {s.class_name!r} (object {s.obj_id}) in the table")
    rng = np.random.default_rng(seed)
    poses = odometry_poses(stretch.camera_T_world, odometry, rng)
    min_visible = clean_min_visible if setting == "clean" else missed_min_visible
    spell_at = {(s.obj_id, t): s for s in stretch.spells for t in s.frames}
    frames = []
    root = None
    for t, frame in enumerate(stretch.frames):
        W, H = frame.image_size
        root = frame.image_path.parent.parent
        boxes, names, ids = [], [], []
        for o in frame.objects:
            s = spell_at.get((o.obj_id, t))
            b = np.asarray(o.visible_box, np.float64)
            if s is None or not np.all(np.isfinite(b)) or o.visible_fraction < min_visible:
                continue
            if setting == "missed" and rng.uniform() < miss_rate:
                continue
            b = b + box_sigma * rng.standard_normal(4)
            b = np.clip(b, -0.5, [W - 0.5, H - 0.5, W - 0.5, H - 0.5])  # the image, pixel centres at whole numbers
            if b[2] - b[0] < min_box_pixels or b[3] - b[1] < min_box_pixels:
                continue
            boxes.append(b)
            names.append(s.class_name)
            ids.append(s.id)
        frames.append(
            SequenceFrame(
                camera_T_world=poses[t],
                boxes=np.asarray(boxes, np.float64).reshape(-1, 4),
                classes=tuple(names),
                ids=tuple(ids),
                texture_depth=np.full(len(boxes), np.nan),
                image=str(frame.image_path.relative_to(root)),
            )
        )
    views: dict = {}
    for f in frames:
        for i in f.ids:
            views[i] = views.get(i, 0) + 1
    seen = {i for i, n in views.items() if n >= int(min_views)}
    frames = [
        dataclasses.replace(
            f,
            boxes=f.boxes[keep].reshape(-1, 4),
            classes=tuple(c for c, k in zip(f.classes, keep) if k),
            ids=tuple(i for i, k in zip(f.ids, keep) if k),
            texture_depth=f.texture_depth[keep],
        )
        for f in frames
        for keep in [np.array([i in seen for i in f.ids], bool)]
    ]
    truth = {
        "camera_T_world": np.asarray(stretch.camera_T_world, np.float64),
        "objects": [
            {"id": s.id, "class": s.class_name, "center": s.center, "radii": s.radii, "rotation": s.rotation}
            for s in stretch.spells
            if s.id in seen
        ],
    }
    # pose priors are the integrated odometry: loose (its drift), the odometry steps tight
    steps = max(len(poses) - 1, 1)
    noise = {
        "box_sigma": float(box_sigma),
        "pose_translation_sigma": float(max(prior_translation, 1e-4)),
        "pose_rotation_sigma_deg": float(max(prior_rotation_deg, 1e-2)),
        "odometry_translation_sigma": float(
            max(math.hypot(odometry.noise_translation, odometry.drift_translation * math.sqrt(steps)), 1e-4)
        ),
        "odometry_rotation_sigma": float(
            max(
                math.radians(math.hypot(odometry.noise_rotation_deg, odometry.drift_rotation_deg * math.sqrt(steps))),
                1e-4,
            )
        ),
    }
    first = stretch.frames[0]
    seq = Sequence(
        K=np.asarray(first.K, np.float64),
        image_size=tuple(int(x) for x in first.image_size),
        frames=tuple(frames),
        root=root,
        truth=truth,
        noise=noise,
        classes=classes,
    )
    odo = np.asarray(quadrics.relative_pose(poses[:-1], poses[1:], xp=np)) if len(poses) > 1 else np.zeros((0, 4, 4))
    return seq, odo
