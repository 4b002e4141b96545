"""Data structures of ROSHAN object SLAM: problems, estimates and frames (the solver settings
live in ``_solver_config.py``).

Everything is an equinox module (a pytree) padded to a fixed capacity with boolean masks, so the
shapes are static: a problem with fewer poses / boxes / objects than its capacity compiles once,
and many problems of the same padded size can be stacked and ``vmap``-ed.

Index conventions:

- poses ``t`` in ``[0, T)``, boxes ``m`` in ``[0, M)``, objects ``j`` in ``[0, J)``;
- ``box_pose[m]`` / ``box_object[m]`` say which pose saw box ``m`` and which object it is;
- ``object_class[j]`` indexes the problem's class table ``problem.classes`` (a
  :class:`jaxsem.classes.ClassTable`; ``None`` is the built-in :data:`jaxsem.classes.DEFAULT_TABLE`,
  whose names are :data:`jaxsem.factors.CLASS_NAMES`);
- ``odometry[t]`` (optional) is the measured motion from pose ``t`` to pose ``t + 1``;
- padded entries have ``mask == False``; their index fields must still be in range (use 0).

Build problems from numpy with :func:`make_problem` (validates and raises ``ValueError``); the
simulator and the front end may construct the modules directly when they know the data is sane.
"""

from __future__ import annotations

import warnings
from typing import Any, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.core import Tracer

from .. import classes as _classes
from ..quadrics import Camera, EllipsoidView

__all__ = [
    "Capacity",
    "Frame",
    "SlamEstimate",
    "SlamProblem",
    "compact_boxes",
    "make_frame",
    "make_problem",
    "stack_problems",
]


class SlamProblem(eqx.Module):
    """Measurements of one map, padded to capacity (T poses, M boxes, J objects).

    Attributes:
      K: (3, 3) pinhole intrinsics ``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]``.
      image_size: (2,) ``[width, height]`` in pixels (for the border-edge classification).
      pose_prior: (T, 4, 4) ``camera_T_world`` from odometry / VIO (the pose-prior factor mean).
      pose_mask: (T,) bool, True for real poses.
      box: (M, 4) measured boxes ``[u_min, v_min, u_max, v_max]`` in pixels.
      box_pose: (M,) int32 pose index of each box.
      box_object: (M,) int32 object index of each box (ground-truth or front-end association).
      box_mask: (M,) bool, True for real boxes.
      texture_depth: (M,) metres, texture-plane depth measured with box ``m`` (eq. 4.11).
      texture_mask: (M,) bool, True where a texture-plane measurement exists.
      object_class: (J,) int32 index into the class table ``classes``.
      object_mask: (J,) bool, True for real objects.
      classes: static :class:`jaxsem.classes.ClassTable` the problem was built with (``None``:
        the built-in :data:`jaxsem.classes.DEFAULT_TABLE`). The solvers take each object's shape
        prior from it (unless ``SolverConfig.shape_prior_mean`` / ``shape_prior_sigma`` override
        the arrays), so a problem keeps the table it was built with.
      odometry: optional (T, 4, 4) relative motions: ``odometry[t]`` is the measured pose of
        camera ``t + 1`` in the frame of camera ``t`` (``camera_t_T_camera_t+1``, as
        :func:`jaxsem.quadrics.relative_pose`), the mean of the between factor
        :func:`jaxsem.factors.between_residual`; ``None`` (the default): no odometry factors.
      odometry_mask: (T,) bool, True where ``odometry[t]`` is measured (never for the last
        pose, nor where pose ``t`` or ``t + 1`` is masked out); given with ``odometry``.
      pose_prior_weight: optional (T, 2) multipliers of each pose's whitened pose-prior rows,
        ``[translation, rotation]``: pose ``t``'s prior sigmas are the noise model's divided by
        them, 0 = no prior on that pose. For integrated odometry, whose error grows along the
        path (a prior on the first pose and looser ones further on, or none: the between factors
        then carry the chain). ``None`` (the default): every real pose at the noise model's
        sigmas.
      box_cut: optional (M, 4) bool, per edge ``[u_min, v_min, u_max, v_max]`` of each box: True
        where an occluder may have cut that edge (e.g. :func:`overlapped_edges`: the edge lies
        inside another box of the same frame). ``SolverConfig.box_outward_scale`` then reads only
        those edges one-sided and the others symmetrically; ``None`` (the default): every edge
        may have been cut.
    """

    K: jnp.ndarray
    image_size: jnp.ndarray
    pose_prior: jnp.ndarray
    pose_mask: jnp.ndarray
    box: jnp.ndarray
    box_pose: jnp.ndarray
    box_object: jnp.ndarray
    box_mask: jnp.ndarray
    texture_depth: jnp.ndarray
    texture_mask: jnp.ndarray
    object_class: jnp.ndarray
    object_mask: jnp.ndarray
    classes: _classes.ClassTable | None = eqx.field(static=True, default=None)
    odometry: jnp.ndarray | None = None
    odometry_mask: jnp.ndarray | None = None
    pose_prior_weight: jnp.ndarray | None = None
    box_cut: jnp.ndarray | None = None

    @property
    def num_poses(self) -> int:
        return self.pose_prior.shape[-3]

    @property
    def num_boxes(self) -> int:
        return self.box.shape[-2]

    @property
    def num_objects(self) -> int:
        return self.object_class.shape[-1]


class SlamEstimate(eqx.Module):
    """Values of the variables (or ground truth) of one map.

    Attributes:
      camera_T_world: (T, 4, 4) camera poses (world-to-camera, OpenCV axes).
      rotation: (J, 3, 3) ellipsoid rotations, object-to-world.
      center: (J, 3) ellipsoid centres in the world.
      radii: (J, 3) semi-axis lengths in metres (always positive in a solver's output).
    """

    camera_T_world: jnp.ndarray
    rotation: jnp.ndarray
    center: jnp.ndarray
    radii: jnp.ndarray

    ellipsoid = EllipsoidView()

    def cameras(self, K) -> Camera:
        """The T cameras with intrinsics ``K`` ((3, 3) shared, or (T, 3, 3)) as one
        :class:`jaxsem.quadrics.Camera` (the core broadcasts a shared ``K``)."""
        return Camera(jnp.asarray(K), self.camera_T_world)


class Frame(eqx.Module):
    """One frame for the online smoother, with up to D detections (padded).

    Attributes:
      pose_prior: (4, 4) ``camera_T_world`` from odometry / VIO.
      box: (D, 4) detected boxes ``[u_min, v_min, u_max, v_max]`` in pixels.
      box_class: (D,) int32 class index into the smoother's class table (``online_init(..., classes=)``;
        the built-in one, :data:`jaxsem.factors.CLASS_NAMES`, by default).
      texture_depth: (D,) metres (ignored where ``texture_mask`` is False).
      texture_mask: (D,) bool.
      object_id: (D,) int32 association id of each detection, in ``[0, capacity.max_objects)``;
        an id seen for the first time creates (initialises) a new object.
      box_mask: (D,) bool, True for real detections.
      init_rotation: (D, 3, 3) object-to-world rotation of an initial ellipsoid per detection.
      init_center: (D, 3) its centre in the world; init_radii: (D, 3) its semi-axes (m, > 0).
      init_mask: (D,) bool: where True and the detection creates a new object, the object starts
        at this ellipsoid (e.g. a single-view network's estimate,
        :func:`jaxsem.mapping.volumon_initial_ellipsoids`) instead of ROSHAN's single-view
        initialisation (:func:`jaxsem.factors.single_view_init`). Ignored for objects that
        already exist. All four are optional: left out, they are identity / zeros / ones and a
        False mask (the behaviour without them), of the box's float dtype, so frames with and
        without initial ellipsoids share one compiled program. Every value must be finite.
    """

    pose_prior: jnp.ndarray
    box: jnp.ndarray
    box_class: jnp.ndarray
    texture_depth: jnp.ndarray
    texture_mask: jnp.ndarray
    object_id: jnp.ndarray
    box_mask: jnp.ndarray
    init_rotation: Any = None
    init_center: Any = None
    init_radii: Any = None
    init_mask: Any = None

    def __post_init__(self):
        # Fill the optional initial ellipsoids (host arrays: nothing compiles) and check concrete
        # values at this boundary; traced frames (inside jit / vmap) are only shape-checked.

        lead = tuple(np.shape(self.box)[:-1])
        traced = isinstance(self.box, Tracer)
        zeros = jnp.zeros if traced else np.zeros
        box_dtype = getattr(self.box, "dtype", None)
        floating = box_dtype is not None and jnp.issubdtype(box_dtype, jnp.floating)
        dtype = box_dtype if floating else jnp.result_type(float)
        if self.init_rotation is None:
            eye = jnp.eye(3, dtype=dtype) if traced else np.eye(3, dtype=dtype)
            self.init_rotation = (jnp if traced else np).broadcast_to(eye, lead + (3, 3))
        if self.init_center is None:
            self.init_center = zeros(lead + (3,), dtype)
        if self.init_radii is None:
            self.init_radii = (jnp if traced else np).ones(lead + (3,), dtype)
        if self.init_mask is None:
            self.init_mask = zeros(lead, bool)
        for name, trailing in (
            ("init_rotation", (3, 3)),
            ("init_center", (3,)),
            ("init_radii", (3,)),
            ("init_mask", ()),
        ):
            value = getattr(self, name)
            if tuple(np.shape(value)) != lead + trailing:
                raise ValueError(
                    f"{name}: expected shape {lead + trailing} (box has {lead[-1:]} rows), got {np.shape(value)}"
                )
            if isinstance(value, Tracer) or name == "init_mask":
                continue
            if not np.all(np.isfinite(np.asarray(value))):
                raise ValueError(f"{name}: must be finite (rows without an initial ellipsoid too), got NaN or inf")
        if not isinstance(self.init_radii, Tracer):
            radii = np.asarray(self.init_radii)
            mask = True if isinstance(self.init_mask, Tracer) else np.asarray(self.init_mask)
            if np.any(mask & np.any(radii <= 0, axis=-1)):
                raise ValueError("init_radii: expected semi-axes > 0 where init_mask is True")


class Capacity(NamedTuple):
    """Static sizes of an online smoother (changing any of them recompiles).

    ``max_poses`` is the sliding window of poses kept in the graph (older poses are
    marginalised by freezing them); ``max_boxes`` the number of box factors kept;
    ``max_objects`` the number of object slots (= the range of association ids);
    ``max_detections`` the padded number of detections per :class:`Frame`.
    """

    max_poses: int = 64
    max_objects: int = 32
    max_boxes: int = 512
    max_detections: int = 16


# --------------------------------------------------------------------------------------------
# Validating constructors (numpy in, equinox modules out).


def _np(name, x, shape_tail, dtype: type | np.dtype = float):
    try:
        arr = np.asarray(x, dtype=dtype)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name}: cannot be converted to a {np.dtype(dtype).name} array ({exc})") from None
    if shape_tail is not None and arr.shape[arr.ndim - len(shape_tail) :] != tuple(shape_tail):
        raise ValueError(f"{name}: expected shape (..., {', '.join(map(str, shape_tail))}), got {arr.shape}")
    return arr


def has_measurements(problem: SlamProblem) -> jnp.ndarray:
    """() bool: the problem holds at least one usable box (unmasked, of a real pose and a real
    object). A solve of a problem without one has nothing to fit and reports
    :attr:`jaxsem.slam.RESULTS.no_measurements`. Works under ``jit`` and ``vmap``."""
    T, J = problem.pose_mask.shape[-1], problem.object_mask.shape[-1]
    pose_ok = jnp.take(problem.pose_mask, jnp.clip(problem.box_pose, 0, T - 1), axis=-1)
    obj_ok = jnp.take(problem.object_mask, jnp.clip(problem.box_object, 0, J - 1), axis=-1)
    return jnp.any(problem.box_mask & pose_ok & obj_ok)


def _image_size(image_size):
    """``image_size`` as a checked (2,) float array ``[width, height] > 0``."""
    image_size = _np("image_size", image_size, (2,))
    if image_size.shape != (2,) or not np.all(image_size > 0):
        raise ValueError(f"image_size: expected [width, height] > 0, got {image_size.tolist()}")
    return image_size


def _check_boxes(name, box, mask, image_size=None):
    """Raise on non-finite, inverted or (given ``image_size``) off-image boxes among the unmasked ones."""
    bad_finite = mask & ~np.all(np.isfinite(box), axis=-1)
    if bad_finite.any():
        idx = np.flatnonzero(bad_finite)[:5].tolist()
        raise ValueError(f"{name}: non-finite box values at indices {idx} (first values {box[bad_finite][0].tolist()})")
    inverted = mask & ((box[..., 2] <= box[..., 0]) | (box[..., 3] <= box[..., 1]))
    if inverted.any():
        idx = np.flatnonzero(inverted)[:5].tolist()
        raise ValueError(
            f"{name}: inverted or empty boxes at indices {idx} (first {box[inverted][0].tolist()}); "
            "expected [u_min, v_min, u_max, v_max] with u_max > u_min and v_max > v_min"
        )
    if image_size is not None:
        # A measured box lies on the image: it overlaps it, and no edge is more than one image
        # size beyond it (a detector's boxes are clipped to the image; a box far outside is a
        # unit mistake or garbage, and would dominate the cost).
        W, H = float(image_size[0]), float(image_size[1])
        u, v = box[..., 0::2], box[..., 1::2]
        off = mask & (
            (box[..., 0] >= W) | (box[..., 2] <= 0) | (box[..., 1] >= H) | (box[..., 3] <= 0)
            | np.any((u < -W) | (u > 2 * W), -1) | np.any((v < -H) | (v > 2 * H), -1)
        )  # fmt: skip
        if off.any():
            idx = np.flatnonzero(off)[:5].tolist()
            raise ValueError(
                f"{name}: boxes at indices {idx} lie off the {W:g} x {H:g} image (first {box[off][0].tolist()}); "
                "expected pixel boxes that overlap the image"
            )


def make_problem(
    K,
    image_size,
    pose_prior,
    box,
    box_pose,
    box_object,
    object_class,
    texture_depth=None,
    texture_mask=None,
    *,
    pose_mask=None,
    box_mask=None,
    object_mask=None,
    capacity: tuple[int, int, int] | Capacity | None = None,
    dtype=None,
    classes: _classes.ClassTable | None = None,
    odometry=None,
    odometry_mask=None,
    pose_prior_weight=None,
    box_cut=None,
) -> SlamProblem:
    """Validated :class:`SlamProblem` from numpy-like inputs, optionally padded to capacity.

    Args:
      K: (3, 3) intrinsics. image_size: (2,) ``[width, height]``.
      pose_prior: (T, 4, 4) ``camera_T_world``; box: (M, 4); box_pose, box_object: (M,) ints.
      object_class: (J,) class indices, or class names (``"car"``) resolved in ``classes``.
      texture_depth: optional (M,) metres; entries that are NaN are treated as missing.
      texture_mask: optional (M,) bool (default: where ``texture_depth`` is finite and positive).
      pose_mask, box_mask, object_mask: optional masks (default all True).
      capacity: optional sizes to pad to (>= the data sizes): a :class:`Capacity` (its
        ``max_poses``, ``max_boxes``, ``max_objects``, by name: the online smoother's sizes give
        the same batch problem), or a plain ``(poses, boxes, objects)`` tuple in that order, as
        :func:`bucket_capacity` returns (note: not :class:`Capacity`'s field order).
      dtype: float dtype of the arrays (default: jax's default float).
      classes: the :class:`jaxsem.classes.ClassTable` of ``object_class`` (default: the built-in
        :data:`jaxsem.classes.DEFAULT_TABLE`); the problem keeps it (``problem.classes``) and
        the solvers read each object's shape prior from it.
      odometry: optional (T - 1, 4, 4) relative motions between consecutive poses:
        ``odometry[t]`` is the measured pose of camera ``t + 1`` in camera ``t``'s frame
        (:func:`jaxsem.quadrics.relative_pose` of the two ``camera_T_world``), each a between
        factor with ``NoiseModel.odometry_*_sigma``. Default: none (pose priors only).
      odometry_mask: optional (T - 1,) bool, which steps are measured (default: all; a step
        touching a masked-out pose is dropped).
      pose_prior_weight: optional (T,) or (T, 2) ``[translation, rotation]`` multipliers of the
        pose priors' whitened rows (:attr:`SlamProblem.pose_prior_weight`; finite, >= 0; 0 = no
        prior on that pose). Default: none (every pose at the noise model's sigmas).
      box_cut: optional (M, 4) bool, the edges an occluder may have cut
        (:attr:`SlamProblem.box_cut`), or ``"overlapped"``: the edges that lie inside another
        real box of the same frame (:func:`overlapped_edges`). Default: none (every edge may have
        been cut).

    Raises:
      ValueError: wrong shapes, non-finite K or poses, NaN, inverted or off-image boxes (a box
        must overlap the image and no edge be more than one image size outside it), class names not
        in the table, box indices that refer to poses or objects that do not exist (or are
        masked out: "detections for frames never posed"), non-positive image size.
    """
    table = _classes.as_table(classes)
    dtype = dtype or jnp.result_type(float)
    K = _np("K", K, (3, 3))
    if K.shape != (3, 3) or not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise ValueError(f"K: expected finite (3, 3) intrinsics with fx, fy > 0, got {K.tolist()}")
    image_size = _image_size(image_size)
    pose_prior = _np("pose_prior", pose_prior, (4, 4))
    if pose_prior.ndim != 3:
        raise ValueError(f"pose_prior: expected shape (T, 4, 4), got {pose_prior.shape}")
    if not np.all(np.isfinite(pose_prior)):
        raise ValueError("pose_prior: must be finite, got NaN or inf")
    T = pose_prior.shape[0]
    box = _np("box", box, (4,))
    if box.ndim != 2:
        raise ValueError(f"box: expected shape (M, 4), got {box.shape}")
    M = box.shape[0]
    box_pose = _np("box_pose", box_pose, None, dtype=np.int64).reshape(-1)
    box_object = _np("box_object", box_object, None, dtype=np.int64).reshape(-1)
    for name, arr in (("box_pose", box_pose), ("box_object", box_object)):
        if arr.shape != (M,):
            raise ValueError(f"{name}: expected shape ({M},) to match box, got {arr.shape}")
    object_class = table.indices(object_class, "object_class")
    J = object_class.shape[0]
    pose_mask = np.ones(T, bool) if pose_mask is None else _np("pose_mask", pose_mask, None, bool).reshape(-1)
    box_mask = np.ones(M, bool) if box_mask is None else _np("box_mask", box_mask, None, bool).reshape(-1)
    object_mask = np.ones(J, bool) if object_mask is None else _np("object_mask", object_mask, None, bool).reshape(-1)
    if pose_mask.shape != (T,) or box_mask.shape != (M,) or object_mask.shape != (J,):
        raise ValueError(
            f"masks: expected pose_mask ({T},), box_mask ({M},), object_mask ({J},), got "
            f"{pose_mask.shape}, {box_mask.shape}, {object_mask.shape}"
        )
    _check_boxes("box", box, box_mask, image_size)
    bad_pose = box_mask & ((box_pose < 0) | (box_pose >= T))
    if bad_pose.any():
        raise ValueError(f"box_pose: indices must be in [0, {T}), got {box_pose[bad_pose][:5].tolist()}")
    unposed = box_mask & ~pose_mask[np.clip(box_pose, 0, T - 1)]
    if unposed.any():
        raise ValueError(
            f"box_pose: boxes {np.flatnonzero(unposed)[:5].tolist()} refer to frames that were never "
            f"posed (pose_mask False at poses {np.unique(box_pose[unposed])[:5].tolist()})"
        )
    bad_obj = box_mask & ((box_object < 0) | (box_object >= J))
    if bad_obj.any():
        raise ValueError(f"box_object: indices must be in [0, {J}), got {box_object[bad_obj][:5].tolist()}")
    unknown = box_mask & ~object_mask[np.clip(box_object, 0, J - 1)]
    if unknown.any():
        raise ValueError(f"box_object: boxes {np.flatnonzero(unknown)[:5].tolist()} refer to masked-out objects")
    if texture_depth is None:
        texture_depth = np.zeros(M)
        tex_default = np.zeros(M, bool)
    else:
        texture_depth = _np("texture_depth", texture_depth, None).reshape(-1)
        if texture_depth.shape != (M,):
            raise ValueError(f"texture_depth: expected shape ({M},), got {texture_depth.shape}")
        tex_default = np.isfinite(texture_depth) & (texture_depth > 0)
    if texture_mask is None:
        texture_mask = tex_default
    else:
        texture_mask = _np("texture_mask", texture_mask, None, bool).reshape(-1)
        bad = texture_mask & ~tex_default
        if bad.any():
            warnings.warn(
                f"texture_depth: {int(bad.sum())} measurements are non-finite or <= 0; masked out",
                stacklevel=2,
            )
            texture_mask = texture_mask & tex_default
    texture_mask = texture_mask & box_mask
    texture_depth = np.where(texture_mask, texture_depth, 0.0)
    if odometry is not None:
        odometry = _np("odometry", odometry, (4, 4))
        if odometry.shape != (max(T - 1, 0), 4, 4):
            raise ValueError(
                f"odometry: expected shape ({T - 1}, 4, 4) (one step between consecutive poses), got {odometry.shape}"
            )
        if not np.all(np.isfinite(odometry)):
            raise ValueError("odometry: must be finite, got NaN or inf")
        if odometry_mask is None:
            odometry_mask = np.ones(T - 1, bool)
        odometry_mask = _np("odometry_mask", odometry_mask, None, bool).reshape(-1)
        if odometry_mask.shape != (T - 1,):
            raise ValueError(f"odometry_mask: expected shape ({T - 1},), got {odometry_mask.shape}")
        odometry_mask = odometry_mask & pose_mask[:-1] & pose_mask[1:]
        odometry = np.concatenate([odometry, np.eye(4)[None]])
        odometry_mask = np.concatenate([odometry_mask, np.zeros(1, bool)])
    elif odometry_mask is not None:
        raise ValueError("odometry_mask: given without odometry")
    if pose_prior_weight is not None:
        w = _np("pose_prior_weight", pose_prior_weight, None)
        if w.shape == (T,):
            w = np.repeat(w[:, None], 2, axis=1)
        if w.shape != (T, 2):
            raise ValueError(f"pose_prior_weight: expected shape ({T},) or ({T}, 2), got {w.shape}")
        if not np.all(np.isfinite(w)) or np.any(w < 0):
            raise ValueError("pose_prior_weight: expected finite weights >= 0")
        pose_prior_weight = w
    if isinstance(box_cut, str):
        if box_cut != "overlapped":
            raise ValueError(f"box_cut: expected an (M, 4) bool array or 'overlapped', got {box_cut!r}")
        box_cut = overlapped_edges(box, box_pose, box_mask)
    if box_cut is not None:
        box_cut = _np("box_cut", box_cut, None, bool)
        if box_cut.shape != (M, 4):
            raise ValueError(f"box_cut: expected shape ({M}, 4) (one flag per box edge), got {box_cut.shape}")

    if capacity is None and M == 0:
        capacity = (T, 1, J)  # one masked box: the arrays keep a row to index (no measurement, no cost)
    if isinstance(capacity, Capacity):  # by name: its field order is (poses, objects, boxes, ...)
        capacity = (capacity.max_poses, capacity.max_boxes, capacity.max_objects)
    if capacity is not None:
        if len(capacity) != 3:
            raise ValueError(f"capacity: expected a Capacity or (poses, boxes, objects), got {capacity!r}")
        Tc, Mc, Jc = (int(c) for c in capacity)
        if Tc < T or Mc < M or Jc < J:
            raise ValueError(f"capacity: {capacity} is smaller than the data sizes (T, M, J) = {(T, M, J)}")
        eye = np.broadcast_to(np.eye(4), (Tc - T, 4, 4))
        pose_prior = np.concatenate([pose_prior, eye])
        pose_mask = np.concatenate([pose_mask, np.zeros(Tc - T, bool)])
        pad_box = np.broadcast_to(np.array([0.0, 0.0, 1.0, 1.0]), (Mc - M, 4))
        box = np.concatenate([box, pad_box])
        zi = np.zeros(Mc - M, np.int64)
        box_pose = np.concatenate([box_pose, zi])
        box_object = np.concatenate([box_object, zi])
        box_mask = np.concatenate([box_mask, np.zeros(Mc - M, bool)])
        texture_depth = np.concatenate([texture_depth, np.zeros(Mc - M)])
        texture_mask = np.concatenate([texture_mask, np.zeros(Mc - M, bool)])
        object_class = np.concatenate([object_class, np.zeros(Jc - J, np.int64)])
        object_mask = np.concatenate([object_mask, np.zeros(Jc - J, bool)])
        if odometry is not None and odometry_mask is not None:
            odometry = np.concatenate([odometry, np.broadcast_to(np.eye(4), (Tc - T, 4, 4))])
            odometry_mask = np.concatenate([odometry_mask, np.zeros(Tc - T, bool)])
        if pose_prior_weight is not None:
            pose_prior_weight = np.concatenate([pose_prior_weight, np.ones((Tc - T, 2))])
        if box_cut is not None:
            box_cut = np.concatenate([box_cut, np.zeros((Mc - M, 4), bool)])
    # Padded / masked boxes get a harmless finite value so nothing downstream sees NaN.
    box = np.where(box_mask[:, None], box, np.array([0.0, 0.0, 1.0, 1.0]))
    f = lambda a: jnp.asarray(a, dtype)
    i = lambda a: jnp.asarray(np.clip(a, 0, None), jnp.int32)
    return SlamProblem(
        K=f(K),
        image_size=f(image_size),
        pose_prior=f(pose_prior),
        pose_mask=jnp.asarray(pose_mask),
        box=f(box),
        box_pose=i(box_pose),
        box_object=i(box_object),
        box_mask=jnp.asarray(box_mask),
        texture_depth=f(texture_depth),
        texture_mask=jnp.asarray(texture_mask),
        object_class=i(object_class),
        object_mask=jnp.asarray(object_mask),
        classes=None if classes is None else table,
        odometry=None if odometry is None else f(odometry),
        odometry_mask=None if odometry_mask is None else jnp.asarray(odometry_mask),
        pose_prior_weight=None if pose_prior_weight is None else f(pose_prior_weight),
        box_cut=None if box_cut is None else jnp.asarray(box_cut & box_mask[:, None]),
    )


def overlapped_edges(box, box_pose, box_mask=None, margin: float = 0.0) -> np.ndarray:
    """(M, 4) bool: which edges ``[u_min, v_min, u_max, v_max]`` of each box lie inside another
    real box of the same frame (within ``margin`` pixels), the edges an occluder in that frame
    may have cut. An edge counts when its line meets the other box's interior over some length
    (a box that merely touches a corner does not cut it). For :func:`make_problem`'s
    ``box_cut``.

    Args:
      box: (M, 4) boxes in pixels; box_pose: (M,) frame index of each; box_mask: optional (M,)
        bool, the real boxes (default all). margin: pixels the other box is grown by.
    """
    box = _np("box", box, (4,))
    if box.ndim != 2:
        raise ValueError(f"box: expected shape (M, 4), got {box.shape}")
    M = box.shape[0]
    box_pose = _np("box_pose", box_pose, None, dtype=np.int64).reshape(-1)
    if box_pose.shape != (M,):
        raise ValueError(f"box_pose: expected shape ({M},) to match box, got {box_pose.shape}")
    box_mask = np.ones(M, bool) if box_mask is None else _np("box_mask", box_mask, None, bool).reshape(-1)
    if box_mask.shape != (M,):
        raise ValueError(f"box_mask: expected shape ({M},) to match box, got {box_mask.shape}")
    out = np.zeros((M, 4), bool)
    real = np.flatnonzero(box_mask)
    for t in np.unique(box_pose[real]):
        idx = real[box_pose[real] == t]  # the boxes of one frame: a few, so pairs are cheap
        b = box[idx]
        o = b + np.array([-margin, -margin, margin, margin])  # the others, grown
        for e, (pos, lo, hi, axis) in enumerate(((0, 1, 3, 0), (1, 0, 2, 1), (2, 1, 3, 0), (3, 0, 2, 1))):
            line = b[:, pos][:, None]
            across = (o[None, :, axis] < line) & (line < o[None, :, axis + 2])
            span = np.minimum(b[:, hi][:, None], o[None, :, hi]) - np.maximum(b[:, lo][:, None], o[None, :, lo])
            hit = across & (span > 0)
            np.fill_diagonal(hit, False)
            out[idx, e] = hit.any(axis=1)
    return out


def make_frame(
    pose_prior,
    box,
    box_class,
    object_id,
    texture_depth=None,
    *,
    max_detections: int = 16,
    max_objects: int | None = None,
    dtype=None,
    init_rotation=None,
    init_center=None,
    init_radii=None,
    init_mask=None,
    classes: _classes.ClassTable | None = None,
    image_size=None,
) -> Frame:
    """Validated :class:`Frame` padded to ``max_detections`` from numpy-like inputs.

    Args:
      pose_prior: (4, 4) ``camera_T_world``. box: (N, 4). box_class: (N,) indices or class names.
      object_id: (N,) association ids (``>= 0``, ``< max_objects`` when given).
      texture_depth: optional (N,); NaN / non-positive entries mean "no texture plane".
      init_rotation, init_center, init_radii: optional (N, 3, 3), (N, 3), (N, 3) initial
        ellipsoids in the WORLD frame (object-to-world rotation, centre, semi-axes), all three
        or none; a new object detected here starts from its row (see :class:`Frame`).
      init_mask: optional (N,) bool, which rows hold an initial ellipsoid (default: all rows,
        when the ellipsoids are given). Rows left out may hold NaN; they are replaced.
      classes: the :class:`jaxsem.classes.ClassTable` of ``box_class`` (default: the built-in
        table); use the same table as the smoother's (:func:`jaxsem.slam.online_init`).
      image_size: optional (2,) ``[width, height]`` in pixels; given, a box that lies off the
        image raises as in :func:`make_problem` (it must overlap the image, no edge more than
        one image size outside it).

    NaN or inverted boxes are dropped with a ``warnings.warn`` (a detector glitch should not
    stop an online system); wrong shapes, unknown class names, out-of-range ids and (given
    ``image_size``) boxes off the image raise.
    """
    table = _classes.as_table(classes)
    dtype = dtype or jnp.result_type(float)
    pose_prior = _np("pose_prior", pose_prior, (4, 4))
    if pose_prior.shape != (4, 4) or not np.all(np.isfinite(pose_prior)):
        raise ValueError(f"pose_prior: expected a finite (4, 4) camera_T_world, got shape {pose_prior.shape}")
    box = _np("box", box, (4,)).reshape(-1, 4)
    N = box.shape[0]
    if N > max_detections:
        raise ValueError(f"box: {N} detections exceed max_detections={max_detections}")
    box_class = table.indices(np.asarray(box_class).reshape(-1), "box_class")
    object_id = _np("object_id", object_id, None, np.int64).reshape(-1)
    if box_class.shape != (N,) or object_id.shape != (N,):
        raise ValueError(f"box_class, object_id: expected shape ({N},), got {box_class.shape}, {object_id.shape}")
    if np.any(object_id < 0) or (max_objects is not None and np.any(object_id >= max_objects)):
        raise ValueError(f"object_id: ids must be in [0, {max_objects}), got {object_id.tolist()}")
    ok = np.all(np.isfinite(box), axis=-1) & (box[:, 2] > box[:, 0]) & (box[:, 3] > box[:, 1])
    if image_size is not None:  # the kept boxes (NaN and inverted ones are dropped below)
        _check_boxes("box", box, ok, _image_size(image_size))
    if not ok.all():
        warnings.warn(
            f"box: dropped {int((~ok).sum())} NaN or inverted detections (indices {np.flatnonzero(~ok).tolist()})",
            stacklevel=2,
        )
    if texture_depth is None:
        texture_depth = np.full(N, np.nan)
    texture_depth = _np("texture_depth", texture_depth, None).reshape(-1)
    if texture_depth.shape != (N,):
        raise ValueError(f"texture_depth: expected shape ({N},), got {texture_depth.shape}")
    tex_mask = ok & np.isfinite(texture_depth) & (texture_depth > 0)
    pad = max_detections - N
    box = np.where(ok[:, None], box, np.array([0.0, 0.0, 1.0, 1.0]))
    # Host arrays in their final dtype, then put on the device as they are: a jnp conversion
    # would run (and on the first frame compile) a small program per field.
    fdt = np.dtype(dtype)

    def put(x, dt: Any = fdt):
        return jax.device_put(np.asarray(x, dt))

    init = _frame_inits(N, init_rotation, init_center, init_radii, init_mask)
    init_mask = np.concatenate([init[3] & ok, np.zeros(pad, bool)])
    return Frame(
        pose_prior=put(pose_prior),
        box=put(np.concatenate([box, np.tile([0.0, 0.0, 1.0, 1.0], (pad, 1))])),
        box_class=put(np.concatenate([box_class, np.zeros(pad, np.int64)]), np.int32),
        texture_depth=put(np.concatenate([np.where(tex_mask, texture_depth, 0.0), np.zeros(pad)])),
        texture_mask=put(np.concatenate([tex_mask, np.zeros(pad, bool)]), bool),
        object_id=put(np.concatenate([object_id, np.zeros(pad, np.int64)]), np.int32),
        box_mask=put(np.concatenate([ok, np.zeros(pad, bool)]), bool),
        init_rotation=put(np.concatenate([init[0], np.broadcast_to(np.eye(3), (pad, 3, 3))])),
        init_center=put(np.concatenate([init[1], np.zeros((pad, 3))])),
        init_radii=put(np.concatenate([init[2], np.ones((pad, 3))])),
        init_mask=put(init_mask, bool),
    )


def _frame_inits(N: int, rotation, center, radii, mask):
    """Host (rotation (N,3,3), center (N,3), radii (N,3), mask (N,)) of :func:`make_frame`'s
    optional initial ellipsoids: validated where ``mask``, identity / zeros / ones elsewhere."""
    given = [x is not None for x in (rotation, center, radii)]
    if not any(given):
        if mask is not None:
            raise ValueError("init_mask: given without init_rotation, init_center, init_radii")
        return np.broadcast_to(np.eye(3), (N, 3, 3)), np.zeros((N, 3)), np.ones((N, 3)), np.zeros(N, bool)
    if not all(given):
        raise ValueError("init_rotation, init_center, init_radii: give all three or none")
    rotation = _np("init_rotation", rotation, (3, 3)).reshape(-1, 3, 3)
    center = _np("init_center", center, (3,)).reshape(-1, 3)
    radii = _np("init_radii", radii, (3,)).reshape(-1, 3)
    for name, arr in (("init_rotation", rotation), ("init_center", center), ("init_radii", radii)):
        if arr.shape[0] != N:
            raise ValueError(f"{name}: expected {N} rows to match box, got shape {arr.shape}")
    mask = np.ones(N, bool) if mask is None else _np("init_mask", mask, None, bool).reshape(-1)
    if mask.shape != (N,):
        raise ValueError(f"init_mask: expected shape ({N},) to match box, got {mask.shape}")
    m = mask[:, None]
    for name, arr in (("init_rotation", rotation.reshape(N, 9)), ("init_center", center), ("init_radii", radii)):
        if np.any(m & ~np.isfinite(arr)):
            raise ValueError(
                f"{name}: non-finite values in rows {np.flatnonzero(mask & ~np.all(np.isfinite(arr), -1)).tolist()}"
            )
    if np.any(mask & np.any(radii <= 0, axis=-1)):
        raise ValueError(
            f"init_radii: expected semi-axes > 0, rows {np.flatnonzero(mask & np.any(radii <= 0, -1)).tolist()}"
        )
    rotation = np.where(m[..., None], rotation, np.eye(3))
    center = np.where(m, center, 0.0)
    radii = np.where(m, radii, 1.0)
    return rotation, center, radii, mask


def bucket_capacity(num_poses: int, num_boxes: int, num_objects: int, *, minimum: int = 8):
    """Padded ``(T, M, J)`` capacity for a problem of these sizes (each at least ``minimum``).
    Problems in one bucket share one compilation of every solver (pass it as
    ``make_problem(..., capacity=...)``).

    Each size is rounded up to a power of two or three halves of one (8, 12, 16, 24, 32, 48, 64,
    ...; at most a third of the slots wasted): the Schur step's pose work grows with the cube of
    the pose slots and the linearisation's with the box slots, so a 34-pose stretch in 48 slots
    (or 165 boxes in 192) solves markedly faster than in 64 (256), for twice the buckets of
    powers of two (:func:`bucket_capacities` caps the number over many problems)."""
    sizes = (num_poses, num_boxes, num_objects)
    if any(int(n) < 0 for n in sizes):
        raise ValueError(f"bucket_capacity: sizes must be >= 0, got {sizes}")

    def up(n):
        two = max(int(minimum), 1 << max(int(n) - 1, 0).bit_length())
        three_halves = 3 * two // 4  # 3 * 2^(k - 2): between the powers two / 2 and two
        return three_halves if two >= 8 and three_halves >= max(int(n), int(minimum)) else two

    return up(num_poses), up(num_boxes), up(num_objects)


def _padded_work(capacity) -> int:
    """A solve's work at a padded capacity ``(T, M, J)``, up to a constant: the Schur step's dense
    pose system (``T^3`` and the ``T^2 J`` of forming it) and the per-box linearisation."""
    T, M, J = capacity
    return T * T * (6 * T + 9 * J) + 200 * M


def bucket_capacities(sizes, max_programs: int = 2, *, minimum: int = 8) -> list[tuple[int, int, int]]:
    """Padded capacities for many problems (the stretches of a user's sequences) such that at most
    ``max_programs`` distinct capacities, hence compiled programs of each solver, serve them all.

    Each problem's own bucket is :func:`bucket_capacity`; problems ordered by their pose bucket
    are split into at most ``max_programs`` runs, each padded to the largest bucket of its run
    (element-wise), choosing the split of least total padded work (the Schur step's pose work
    grows with the cube of the pose slots, so a short stretch joins the small group rather than
    the long ones joining the big one). With ``max_programs`` at least the number of distinct
    buckets every problem keeps its own.

    Args:
      sizes: ``(num_poses, num_boxes, num_objects)`` per problem.
      max_programs: the most distinct capacities (>= 1).

    Returns:
      One ``(T, M, J)`` per problem, in the order given (pass each as ``make_problem(...,
      capacity=...)``).
    """
    if int(max_programs) < 1:
        raise ValueError(f"max_programs: expected an int >= 1, got {max_programs}")
    own = [bucket_capacity(*map(int, s), minimum=minimum) for s in sizes]
    if not own:
        return []
    distinct = sorted(set(own))
    if len(distinct) <= max_programs:
        return own
    order = sorted(range(len(own)), key=lambda i: own[i])
    n, k = len(order), int(max_programs)

    def cap(a, b) -> tuple[int, int, int]:  # the bucket of order[a:b]
        run = [own[order[i]] for i in range(a, b)]
        return max(c[0] for c in run), max(c[1] for c in run), max(c[2] for c in run)

    # best[g][b]: least work of order[:b] in g runs, and where its last run starts; the last
    # run's bucket grows as its start moves back (a running maximum: O(k n^2) in all)
    inf = float("inf")
    best = [[(inf, 0)] * (n + 1) for _ in range(k + 1)]
    best[0][0] = (0.0, 0)
    for b in range(1, n + 1):
        runs = []  # (a, work of order[a:b]) for a = b - 1 down to 0
        T = M = J = 0
        for a in range(b - 1, -1, -1):
            c = own[order[a]]
            T, M, J = max(T, c[0]), max(M, c[1]), max(J, c[2])
            runs.append((a, (b - a) * _padded_work((T, M, J))))
        for g in range(1, k + 1):
            best[g][b] = min(((best[g - 1][a][0] + w, a) for a, w in runs), default=(inf, 0))
    g = min(range(1, k + 1), key=lambda g: best[g][n][0])
    out: list[tuple[int, int, int]] = [(0, 0, 0)] * n
    b = n
    while b > 0:
        a = best[g][b][1]
        c = cap(a, b)
        for i in range(a, b):
            out[order[i]] = c
        b, g = a, g - 1
    return out


def compact_boxes(problem: SlamProblem, max_boxes: int) -> SlamProblem:
    """The same problem with its real boxes moved to the front (in their order) and only the
    first ``max_boxes`` box slots kept.

    Box factors cost the same whether a slot is real or padding, so a problem padded to many
    unused slots (e.g. ``jaxsem.slam.sim.to_problem`` keeps one slot per frame and object, dropped
    detections included) solves ``M / max_boxes`` times faster per iteration after this, with
    the same answer. Pick ``max_boxes`` from :func:`bucket_capacity` of the largest number of
    real boxes over the problems that share a compilation. Works on batched problems (leading
    axes) and under ``jit`` / ``vmap`` (``max_boxes`` static).

    Raises:
      ValueError: ``max_boxes`` below 1, or (for concrete inputs) more real boxes than
        ``max_boxes`` in some problem.
    """
    max_boxes = int(max_boxes)
    if max_boxes < 1:
        raise ValueError(f"max_boxes: expected an int >= 1, got {max_boxes}")
    mask = problem.box_mask
    if not isinstance(mask, Tracer):
        most = int(jnp.max(jnp.sum(mask, axis=-1))) if mask.size else 0
        if most > max_boxes:
            raise ValueError(f"max_boxes: {max_boxes} is below the {most} real boxes of a problem")
    names = _BOX_FIELDS + (("box_cut",) if problem.box_cut is not None else ())
    M = mask.shape[-1]
    order = jnp.argsort(~mask, axis=-1, stable=True)
    if max_boxes <= M:
        order = order[..., :max_boxes]
        take = lambda x: jnp.take_along_axis(
            x, order.reshape(order.shape + (1,) * (x.ndim - mask.ndim)), axis=mask.ndim - 1
        )
        fields = [take(getattr(problem, n)) for n in names]
    else:
        pad = max_boxes - M
        grow = lambda x: jnp.concatenate(
            [x, jnp.zeros(x.shape[: mask.ndim - 1] + (pad,) + x.shape[mask.ndim :], x.dtype)], mask.ndim - 1
        )
        fields = [grow(getattr(problem, n)) for n in names]
    return eqx.tree_at(lambda p: tuple(getattr(p, n) for n in names), problem, tuple(fields))


_BOX_FIELDS = ("box", "box_pose", "box_object", "box_mask", "texture_depth", "texture_mask")


def stack_problems(problems):
    """Stack problems of equal padded size along a new leading axis (for ``jax.vmap``)."""
    return jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), *problems)
