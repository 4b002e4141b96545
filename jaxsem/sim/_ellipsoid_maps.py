"""Random maps of ellipsoids on the ground, camera paths and noisy ROSHAN measurements.

The simulation protocol of thesis section 4.4: objects are exact ellipsoids, the camera flies an
Orbit (diverse views) or a Forward path (a straight line past the objects), a detector returns the
projected box of every visible ellipsoid with Gaussian pixel noise, the texture-plane depth of
every detected ellipsoid comes with Gaussian noise (the thesis' simulator provides "a fifth plane
measurement at every timestep"), poses come from a noisy external odometry (the pose prior) and
the data association is the ground truth.

Everything is ``jnp`` + ``jax.random`` with shapes fixed by the (static, hashable) config, so
``jax.vmap(functools.partial(simulate, config=cfg))(keys)`` produces thousands of maps at once.
Maps have a fixed object capacity ``config.num_objects``; ``object_mask`` says which slots hold an
object (placement by rejection can fail in a crowded patch), and every per-detection array has a
mask.

World: z up, the ground is z = 0; the map patch is the square ``[-patch/2, patch/2]^2`` around the
origin. Cameras use OpenCV axes and ``camera_T_world`` poses (jaxsem conventions).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import Optional

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .. import classes as _classes, factors
from ..quadrics import (
    camera_frame,
    invert_pose,
    look_at,
    project_bbox,
    safe_norm,
    single_view_ellipsoid,
    so3_exp,
    texture_plane_depth,
)

__all__ = [
    "SimConfig",
    "SimulatedMap",
    "thesis_config",
    "quadricslam_config",
    "simulate",
    "simulate_batch",
    "simulate_views",
    "camera_path",
    "random_objects",
    "detect",
    "intrinsics",
    "class_table",
    "to_problem",
    "ground_truth",
    "initial_estimate",
]

PATHS = ("orbit", "forward", "views")
INIT_MODES = ("single_view", "noisy_truth")


def class_table(names: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Mean radii and per-axis standard deviations, (C, 3) each, of the classes ``names``.

    From :mod:`jaxsem.classes` (the table ROSHAN's shape prior reads too), so simulated sizes are
    consistent with the prior. Unknown names raise ``ValueError`` listing the known ones.
    """
    return _classes.radii_table(names)


@dataclasses.dataclass(frozen=True)
class SimConfig:
    """Everything that defines a simulated map family (static, hashable: use as a jit static arg).

    Geometry:
      path: "orbit" (circle around the map centre looking at it), "forward" (straight line along
        +x through the middle of the patch, looking along +x, as a vehicle flies) or "views"
        (used by :func:`simulate_views`).
      num_objects: object capacity of a map; min_objects: at least this many are attempted (the
        count is uniform in [min_objects, num_objects]); placement is by rejection, so a
        crowded patch may place fewer (``object_mask``).
      classes: class names of :data:`jaxsem.factors.CLASS_NAMES`; each object draws one
        uniformly (``object_class`` holds the index into ``CLASS_NAMES``, as
        :class:`jaxsem.slam.SlamProblem` does).
      size_sigma_scale: multiplies the class's per-axis size sigma when drawing radii.
      patch_size: side of the square ground patch (m) holding object centres.
      corridor_half_width: Forward only: object centres keep at least this lateral distance from
        the flight line (the camera must not fly through an object).
      object_gap: minimum clearance (m) between the bounding circles of two objects.
      yaw_range: object yaw is uniform in [-yaw_range, yaw_range] (rad) around +x (the Forward
        direction); pi means fully random.
    Camera:
      num_frames, image_width, image_height, focal (fx = fy), principal point at the centre.
      camera_height: m above ground. orbit_radius: m. orbit_target_height: the point the orbit
        camera looks at is (0, 0, this). forward_step: m per frame; the Forward line is centred
        forward_end_margin: the Forward line ends at x = patch/2 + this (it starts
        ``(num_frames - 1) * forward_step`` before), so the camera approaches every object from
        afar, as a vehicle does, and ends at the far edge of the patch.
    Detections:
      box_noise_px: sigma of the Gaussian noise on each box edge (px).
      border_margin_px: an edge within this distance of the image border is non-constraining
        (``edge_mask`` False), as ROSHAN's edge classification (section 4.3.2).
      min_box_px: detections narrower or shorter than this (after clipping) are dropped.
      min_visible_fraction: the truncation rule: a detection is dropped when less than this
        fraction of its (noisy, unclipped) box area lies inside the image.
      max_depth: objects whose centre is farther (camera z) are not detected.
      texture_noise_m, texture_noise_rel: texture-plane depth sigma = abs + rel * depth.
    Pose prior (noisy odometry):
      pose_noise_m: sigma per axis of the camera position noise; pose_noise_deg: sigma per axis
        of the camera rotation noise.
    Initial landmarks:
      init_mode: "single_view" (section 4.3.5: centre on the ray through the first box's centre
        at ``init_depth``, identity rotation, radii ``init_radii`` or the class mean when None) or
        "noisy_truth" (truth plus Gaussian noise: init_position_noise_m per axis, init_yaw_noise_deg,
        init_radii_noise_m per axis, radii kept >= 0.1 m).
    """

    path: str = "forward"
    num_objects: int = 10
    min_objects: Optional[int] = None
    classes: tuple = ("car",)
    size_sigma_scale: float = 1.0
    patch_size: float = 30.0
    corridor_half_width: float = 4.0
    object_gap: float = 0.3
    yaw_range: float = math.pi
    num_frames: int = 60
    image_width: int = 640
    image_height: int = 480
    focal: float = 525.0
    camera_height: float = 1.5
    orbit_radius: float = 25.0
    orbit_target_height: float = 0.5
    forward_step: float = 0.75
    forward_end_margin: float = 0.0
    box_noise_px: float = 3.0
    border_margin_px: float = 10.0
    min_box_px: float = 4.0
    min_visible_fraction: float = 0.5
    max_depth: float = 60.0
    texture_noise_m: float = 0.1
    texture_noise_rel: float = 0.01
    pose_noise_m: float = 0.05
    pose_noise_deg: float = 1.0
    init_mode: str = "single_view"
    init_depth: float = 10.0
    init_radii: Optional[float] = 1.0
    init_position_noise_m: float = 1.0
    init_yaw_noise_deg: float = 20.0
    init_radii_noise_m: float = 0.3
    # Views study (simulate_views): camera distance range from the object centre (m).
    view_distance_min: float = 8.0
    view_distance_max: float = 14.0

    def __post_init__(self):
        if self.path not in PATHS:
            raise ValueError(f"path: expected one of {PATHS}, got {self.path!r}")
        if self.init_mode not in INIT_MODES:
            raise ValueError(f"init_mode: expected one of {INIT_MODES}, got {self.init_mode!r}")
        for name in ("num_objects", "num_frames", "image_width", "image_height"):
            value = getattr(self, name)
            if not isinstance(value, (int, np.integer)) or value < 1:
                raise ValueError(f"{name}: expected a positive int, got {value!r}")
        if self.min_objects is not None and not 1 <= self.min_objects <= self.num_objects:
            raise ValueError(
                f"min_objects: expected an int in [1, num_objects={self.num_objects}], got {self.min_objects!r}"
            )
        if not isinstance(self.classes, tuple) or not self.classes:
            raise ValueError(f"classes: expected a non-empty tuple of names, got {self.classes!r}")
        class_table(self.classes)  # unknown names raise here, at construction
        for name in (
            "focal",
            "patch_size",
            "orbit_radius",
            "forward_step",
            "init_depth",
            "view_distance_min",
            "view_distance_max",
            "max_depth",
        ):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name}: expected a finite positive number, got {value!r}")
        for name in (
            "box_noise_px",
            "border_margin_px",
            "min_box_px",
            "texture_noise_m",
            "texture_noise_rel",
            "pose_noise_m",
            "pose_noise_deg",
            "size_sigma_scale",
            "init_position_noise_m",
            "init_yaw_noise_deg",
            "init_radii_noise_m",
            "object_gap",
            "corridor_half_width",
            "yaw_range",
        ):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name}: expected a finite number >= 0, got {value!r}")
        if not 0 <= self.min_visible_fraction <= 1:
            raise ValueError(f"min_visible_fraction: expected a value in [0, 1], got {self.min_visible_fraction!r}")
        if self.init_radii is not None and not self.init_radii > 0:
            raise ValueError(f"init_radii: expected None or a positive number, got {self.init_radii!r}")
        if self.view_distance_max < self.view_distance_min:
            raise ValueError(
                f"view_distance_max: expected >= view_distance_min={self.view_distance_min}, got "
                f"{self.view_distance_max}"
            )

    def replace(self, **changes) -> SimConfig:
        """A copy with some fields changed (validated again)."""
        return dataclasses.replace(self, **changes)

    @property
    def image_size(self) -> tuple[int, int]:
        """(width, height) in pixels."""
        return (self.image_width, self.image_height)


def _cars_on_a_patch(path: str) -> SimConfig:
    """What both car presets share: 10 cars on a 30 x 30 m patch, 60 frames at 640x480, f = 525,
    camera 1.5 m high (Orbit radius 25 m, Forward 0.75 m per frame), pose prior 5 cm / 1 deg,
    texture depth noise 0.1 m + 1 % of depth."""
    return SimConfig(
        path=path,
        num_objects=10,
        classes=("car",),
        patch_size=30.0,
        num_frames=60,
        image_width=640,
        image_height=480,
        focal=525.0,
        camera_height=1.5,
        orbit_radius=25.0,
        forward_step=0.75,
        pose_noise_m=0.05,
        pose_noise_deg=1.0,
        texture_noise_m=0.1,
        texture_noise_rel=0.01,
    )


def quadricslam_config(path: str = "forward", **changes) -> SimConfig:
    """The setting in which QuadricSLAM (gtsam_quadrics LM) was measured, so both compare on equal terms.

    10 car-sized ellipsoids (semi-axes about 2.4 x 0.9 x 0.75 m) on a 30 x 30 m patch, 60 frames,
    640x480, f = 525, camera 1.5 m high; Orbit radius 25 m looking at the centre; Forward a
    straight line along the objects' long axis at 0.75 m per frame (objects' yaw within +-15 deg
    of the flight direction); box noise 3 px; pose prior 5 cm / 1 deg (sigma per axis); each
    ellipsoid initialised from its first box at 10 m depth, identity rotation, radii 1 m. Texture
    depth (used by ROSHAN only) 0.1 m + 1 % of depth. Size spread is the class table's.
    """
    base = _cars_on_a_patch(path).replace(
        box_noise_px=3.0,
        init_mode="single_view",
        init_depth=10.0,
        init_radii=1.0,
        yaw_range=math.radians(15.0),
    )
    return base.replace(**changes) if changes else base


def thesis_config(path: str = "forward", **changes) -> SimConfig:
    """Our stand-in for the thesis' OpenGL simulation (section 4.4, Table 4.1).

    The thesis states Gaussian noise on boxes, initial poses and initial ellipsoids but not the
    levels; we use: 10 cars with random yaw on a 30 x 30 m patch, 60 frames at 640x480, f = 525,
    camera 1.5 m high (Orbit radius 25 m, Forward 0.75 m/frame), box noise 2 px per edge, pose
    prior 5 cm / 1 deg (sigma per axis), texture depth 0.1 m + 1 % of depth, initial ellipsoids =
    truth + N(0, 1 m) per position axis, N(0, 20 deg) yaw, N(0, 0.3 m) per radius.
    """
    base = _cars_on_a_patch(path).replace(
        box_noise_px=2.0,
        init_mode="noisy_truth",
        init_position_noise_m=1.0,
        init_yaw_noise_deg=20.0,
        init_radii_noise_m=0.3,
        yaw_range=math.pi,
    )
    return base.replace(**changes) if changes else base


class SimulatedMap(eqx.Module):
    """One simulated map (add leading batch axes under ``vmap``). N = object capacity, T = frames.

    Ground truth:
      object_rotation (N, 3, 3) object-to-world; object_center (N, 3); object_radii (N, 3);
      object_class (N,) int32 index into :data:`jaxsem.factors.CLASS_NAMES`; object_mask (N,) bool;
      camera_T_world (T, 4, 4) true poses.
    Measurements:
      K (3, 3); pose_prior (T, 4, 4) noisy odometry poses (also the initial poses);
      boxes (T, N, 4) noisy boxes clipped to the image, [u_min, v_min, u_max, v_max];
      box_mask (T, N) bool, a detection exists (ground-truth association: box [t, j] is of object
      j); edge_mask (T, N, 4) bool, edge is constraining (farther than the margin from the
      border); texture_depth (T, N) noisy texture-plane depth; texture_mask (T, N) bool;
      true_boxes (T, N, 4) noise-free unclipped boxes; texture_sigma (T, N) its noise sigma.
    Initial landmarks:
      init_rotation (N, 3, 3); init_center (N, 3); init_radii (N, 3); first_frame (N,) int32, the
      first frame with a detection (T where there is none); observed (N,) bool.
    """

    object_rotation: jax.Array
    object_center: jax.Array
    object_radii: jax.Array
    object_class: jax.Array
    object_mask: jax.Array
    camera_T_world: jax.Array
    K: jax.Array
    pose_prior: jax.Array
    boxes: jax.Array
    box_mask: jax.Array
    edge_mask: jax.Array
    texture_depth: jax.Array
    texture_sigma: jax.Array
    texture_mask: jax.Array
    true_boxes: jax.Array
    init_rotation: jax.Array
    init_center: jax.Array
    init_radii: jax.Array
    first_frame: jax.Array
    observed: jax.Array


def intrinsics(config: SimConfig, dtype=None) -> jax.Array:
    """(3, 3) pinhole K with fx = fy = focal and the principal point at the image centre."""
    dtype = dtype or jnp.result_type(float)
    return jnp.array(
        [
            [config.focal, 0.0, config.image_width / 2.0],
            [0.0, config.focal, config.image_height / 2.0],
            [0.0, 0.0, 1.0],
        ],
        dtype,
    )


def _yaw_rotation(yaw):
    """Rotation (..., 3, 3) about world z by ``yaw`` (...) radians."""
    zero = jnp.zeros_like(yaw)
    return so3_exp(jnp.stack([zero, zero, yaw], -1))


class _Pool:
    """One Gaussian draw carved into all the noise a map needs.

    Each ``jax.random`` call inlines a threefry hash that costs about a second of compile time on
    this CPU; one call per map instead of a dozen keeps ``simulate`` quick to compile. Uniform
    variates are ``Phi(g)`` of standard normals (exactly uniform).
    """

    def __init__(self, key, size: int, dtype):
        self.values = jax.random.normal(key, (int(size),), dtype)
        self.used = 0

    def normal(self, shape):
        n = int(np.prod(shape))
        if self.used + n > self.values.shape[0]:
            raise RuntimeError("jaxsem.sim internal error: noise pool too small")
        out = self.values[self.used : self.used + n].reshape(shape)
        self.used += n
        return out

    def uniform(self, shape, lo=0.0, hi=1.0):
        u = jax.scipy.special.ndtr(self.normal(shape))
        return lo + (hi - lo) * u

    def randint(self, shape, lo, hi):
        """Integers uniform in [lo, hi) (static bounds)."""
        u = self.uniform(shape)
        return jnp.clip(jnp.floor(lo + (hi - lo) * u).astype(jnp.int32), lo, hi - 1)


def _objects_pool_size(config):
    m = 8 * config.num_objects
    return 1 + 5 * m + 3 * m


def random_objects(key, config: SimConfig, dtype=None):
    """Non-overlapping ellipsoids standing on the ground with class-consistent sizes.

    Args:
      key: PRNG key.
      config: :class:`SimConfig` (static).

    Returns:
      dict with ``rotation`` (N, 3, 3) (yaw about z), ``center`` (N, 3) (z = height semi-axis, so
      the object touches the ground), ``radii`` (N, 3), ``class_id`` (N,) int32, ``mask`` (N,).
    """
    dtype = dtype or jnp.result_type(float)
    return _random_objects(_Pool(key, _objects_pool_size(config), dtype), config, dtype)


def _random_objects(pool: _Pool, config: SimConfig, dtype):
    n = config.num_objects
    m = 8 * n  # candidates for rejection sampling
    means, sigmas = class_table(config.classes)
    means, sigmas = jnp.asarray(means, dtype), jnp.asarray(sigmas, dtype)
    lo = config.min_objects if config.min_objects is not None else n
    count = pool.randint((), lo, n + 1)
    cls = pool.randint((m,), 0, len(config.classes))
    eps = pool.normal((m, 3))
    radii = means[cls] + config.size_sigma_scale * sigmas[cls] * eps
    radii = jnp.maximum(radii, 0.5 * means[cls])  # a size several sigma off is still an object
    yaw = pool.uniform((m,), -config.yaw_range, config.yaw_range)
    half = config.patch_size / 2.0
    x = pool.uniform((m,), -half, half)
    sign = pool.uniform((m,))
    if config.path == "forward":
        # Keep the flight line (y = 0) clear: |y| in [corridor, half].
        lo_y = min(config.corridor_half_width, half)
        y = pool.uniform((m,), lo_y, half)
        y = y * jnp.where(sign < 0.5, 1.0, -1.0)
    else:
        y = pool.uniform((m,), -half, half)
    xy = jnp.stack([x, y], -1)
    reach = jnp.max(radii, axis=-1)  # bounding-circle radius in the ground plane

    def accept(carry, i):
        taken_xy, taken_reach, n_taken = carry
        dist = safe_norm(taken_xy - xy[i], axis=-1)
        clear = jnp.all(dist >= taken_reach + reach[i] + config.object_gap)
        ok = clear & (n_taken < count)
        slot = jnp.where(ok, n_taken, n)  # out-of-range index: dropped by mode="drop"
        taken_xy = taken_xy.at[slot].set(xy[i], mode="drop")
        taken_reach = taken_reach.at[slot].set(reach[i], mode="drop")
        return (taken_xy, taken_reach, n_taken + ok.astype(jnp.int32)), jnp.where(ok, slot, -1)

    # Empty slots sit far away with zero reach, so they never block a candidate.
    init = (jnp.full((n, 2), 1e6, dtype), jnp.zeros((n,), dtype), jnp.zeros((), jnp.int32))
    (_, _, n_taken), slots = jax.lax.scan(accept, init, jnp.arange(m))
    # Gather the accepted candidates into their slots (slot k <- the candidate that took it).
    slot_of_candidate = jnp.where(slots >= 0, slots, n)
    source = jnp.zeros((n,), jnp.int32).at[slot_of_candidate].set(jnp.arange(m, dtype=jnp.int32), mode="drop")
    mask = jnp.arange(n) < n_taken
    r = radii[source]
    center = jnp.concatenate([xy[source], r[:, 2:3]], axis=-1)
    rotation = _yaw_rotation(yaw[source])
    global_ids = jnp.asarray([factors.class_index(c) for c in config.classes], jnp.int32)
    return {
        "rotation": rotation,
        "center": center,
        "radii": r,
        "class_id": global_ids[cls[source]],
        "mask": mask,
    }


def _up(dtype):
    # An explicit array: a Python tuple would become float64 under x64 and promote everything.
    return jnp.array([0.0, 0.0, 1.0], dtype)


def camera_path(config: SimConfig, dtype=None) -> jax.Array:
    """True camera poses ``camera_T_world`` (T, 4, 4) of the Orbit or Forward path.

    Orbit: T poses evenly spaced on a full circle of radius ``orbit_radius`` at
    ``camera_height``, each looking at ``(0, 0, orbit_target_height)``.
    Forward: T poses on the line y = 0, z = ``camera_height``, spaced ``forward_step`` along +x,
    ending at x = ``patch_size / 2 + forward_end_margin`` and looking along +x (level).
    """
    dtype = dtype or jnp.result_type(float)
    T = config.num_frames
    if config.path == "orbit":
        angle = jnp.arange(T, dtype=dtype) * (2.0 * jnp.pi / T)
        eye = jnp.stack(
            [
                config.orbit_radius * jnp.cos(angle),
                config.orbit_radius * jnp.sin(angle),
                jnp.full_like(angle, config.camera_height),
            ],
            -1,
        )
        target = jnp.array([0.0, 0.0, config.orbit_target_height], dtype)
        return look_at(eye, jnp.broadcast_to(target, eye.shape), _up(dtype)).astype(dtype)
    if config.path == "forward":
        length = (T - 1) * config.forward_step
        end = config.patch_size / 2.0 + config.forward_end_margin
        x = end - length + jnp.arange(T, dtype=dtype) * config.forward_step
        eye = jnp.stack([x, jnp.zeros_like(x), jnp.full_like(x, config.camera_height)], -1)
        target = eye + jnp.array([1.0, 0.0, 0.0], dtype)
        return look_at(eye, target, _up(dtype)).astype(dtype)
    raise ValueError(f"config.path: camera_path needs 'orbit' or 'forward', got {config.path!r}")


def perturb_poses(key, camera_T_world, sigma_m: float, sigma_deg: float):
    """Noisy odometry: the camera's world position gets N(0, sigma_m^2) per axis and its
    orientation a rotation with N(0, sigma_deg^2) per axis (applied in the camera frame)."""
    batch = camera_T_world.shape[:-2]
    pool = _Pool(key, 6 * int(np.prod(batch)), camera_T_world.dtype)
    return _perturb_poses(pool, camera_T_world, sigma_m, sigma_deg)


def _perturb_poses(pool: _Pool, camera_T_world, sigma_m, sigma_deg):
    batch = camera_T_world.shape[:-2]
    world_T_cam = invert_pose(camera_T_world)
    d_rot = so3_exp(jnp.deg2rad(sigma_deg) * pool.normal(batch + (3,)))
    R = world_T_cam[..., :3, :3] @ d_rot
    t = world_T_cam[..., :3, 3] + sigma_m * pool.normal(batch + (3,))
    top = jnp.concatenate([R, t[..., None]], -1)
    noisy = jnp.concatenate([top, world_T_cam[..., 3:, :]], -2)
    return invert_pose(noisy)


def detect(key, rotation, center, radii, object_mask, camera_T_world, K, config: SimConfig):
    """Noisy detections of every object in every frame, with the drop and edge rules.

    Args:
      rotation, center, radii: (N, 3, 3), (N, 3), (N, 3) true ellipsoids; object_mask (N,).
      camera_T_world: (T, 4, 4) true poses; K: (3, 3).

    Returns:
      dict of ``boxes`` (T, N, 4) clipped noisy boxes, ``box_mask`` (T, N), ``edge_mask``
      (T, N, 4), ``texture_depth`` (T, N), ``texture_sigma`` (T, N), ``texture_mask`` (T, N),
      ``true_boxes`` (T, N, 4).
    """
    n_det = camera_T_world.shape[0] * center.shape[0]
    pool = _Pool(key, 5 * n_det, jnp.result_type(center.dtype, camera_T_world.dtype))
    return _detect(pool, rotation, center, radii, object_mask, camera_T_world, K, config)


def _detect(pool: _Pool, rotation, center, radii, object_mask, camera_T_world, K, config):
    W, H = float(config.image_width), float(config.image_height)
    R = rotation[None]
    c = center[None]
    r = radii[None]
    P = camera_T_world[:, None]
    true_box, valid = project_bbox(R, c, r, K, P)  # (T, N, 4), (T, N)
    depth, depth_valid = texture_plane_depth(R, c, r, P)
    _, center_cam = camera_frame(R, c, P)
    noisy = true_box + config.box_noise_px * pool.normal(true_box.shape)
    lo = jnp.minimum(noisy[..., :2], noisy[..., 2:])
    hi = jnp.maximum(noisy[..., :2], noisy[..., 2:])
    noisy = jnp.concatenate([lo, hi], -1)
    limit = jnp.array([W, H, W, H], noisy.dtype)
    clipped = jnp.clip(noisy, 0.0, limit)
    area = jnp.prod(noisy[..., 2:] - noisy[..., :2], axis=-1)
    clipped_size = clipped[..., 2:] - clipped[..., :2]
    visible = jnp.prod(clipped_size, axis=-1) / jnp.maximum(area, 1e-9)
    keep = (
        valid
        & object_mask[None]
        & (center_cam[..., 2] < config.max_depth)
        & jnp.all(clipped_size >= config.min_box_px, axis=-1)
        & (visible >= config.min_visible_fraction)
    )
    margin = config.border_margin_px
    edge_mask = (
        jnp.stack(
            [
                clipped[..., 0] > margin,
                clipped[..., 1] > margin,
                clipped[..., 2] < W - margin,
                clipped[..., 3] < H - margin,
            ],
            -1,
        )
        & keep[..., None]
    )
    tex_sigma = config.texture_noise_m + config.texture_noise_rel * jnp.abs(depth)
    tex = depth + tex_sigma * pool.normal(depth.shape)
    tex_mask = keep & depth_valid & (tex > 0)
    # Keep dropped entries finite and harmless: a unit box at the image centre.
    dummy = jnp.array([W / 2 - 1, H / 2 - 1, W / 2 + 1, H / 2 + 1], clipped.dtype)
    boxes = jnp.where(keep[..., None], clipped, dummy)
    return {
        "boxes": boxes,
        "box_mask": keep,
        "edge_mask": edge_mask,
        "texture_depth": jnp.where(tex_mask, tex, 1.0),
        "texture_sigma": tex_sigma,
        "texture_mask": tex_mask,
        "true_boxes": true_box,
    }


def _initial_landmarks(pool: _Pool, objects, det, pose_prior, K, config: SimConfig):
    T = pose_prior.shape[0]
    mask = det["box_mask"]  # (T, N)
    observed = jnp.any(mask, axis=0)
    first = jnp.where(observed, jnp.argmax(mask, axis=0), T).astype(jnp.int32)
    dtype = objects["center"].dtype
    if config.init_mode == "single_view":
        idx = jnp.minimum(first, T - 1)
        n_idx = jnp.arange(mask.shape[1])
        box = det["boxes"][idx, n_idx]
        pose = pose_prior[idx]
        if config.init_radii is None:
            table, _ = factors.shape_prior_table(dtype)
            radii = table[objects["class_id"]]
        else:
            radii = jnp.full(objects["radii"].shape, config.init_radii, dtype)
        depth = jnp.full(first.shape, config.init_depth, dtype)
        rot, ctr, rad = single_view_ellipsoid(box, K, pose, depth, radii)
        # Unobserved slots keep the truth (they are masked out of every problem anyway).
        rot = jnp.where(observed[:, None, None], rot, objects["rotation"])
        ctr = jnp.where(observed[:, None], ctr, objects["center"])
        rad = jnp.where(observed[:, None], rad, objects["radii"])
        return rot, ctr, rad, first, observed
    n = objects["center"].shape[0]
    ctr = objects["center"] + config.init_position_noise_m * pool.normal((n, 3))
    d_yaw = jnp.deg2rad(config.init_yaw_noise_deg) * pool.normal((n,))
    rot = objects["rotation"] @ _yaw_rotation(d_yaw)
    rad = objects["radii"] + config.init_radii_noise_m * pool.normal((n, 3))
    rad = jnp.maximum(rad, 0.1)
    return rot, ctr, rad, first, observed


def _measurements_pool_size(T, N):
    return 6 * T + 5 * T * N + 7 * N


def _assemble(pool: _Pool, objects, poses, K, config: SimConfig) -> SimulatedMap:
    pose_prior = _perturb_poses(pool, poses, config.pose_noise_m, config.pose_noise_deg)
    det = _detect(
        pool,
        objects["rotation"],
        objects["center"],
        objects["radii"],
        objects["mask"],
        poses,
        K,
        config,
    )
    rot, ctr, rad, first, observed = _initial_landmarks(pool, objects, det, pose_prior, K, config)
    return SimulatedMap(
        object_rotation=objects["rotation"],
        object_center=objects["center"],
        object_radii=objects["radii"],
        object_class=objects["class_id"],
        object_mask=objects["mask"],
        camera_T_world=poses,
        K=K,
        pose_prior=pose_prior,
        boxes=det["boxes"],
        box_mask=det["box_mask"],
        edge_mask=det["edge_mask"],
        texture_depth=det["texture_depth"],
        texture_sigma=det["texture_sigma"],
        texture_mask=det["texture_mask"],
        true_boxes=det["true_boxes"],
        init_rotation=rot,
        init_center=ctr,
        init_radii=rad,
        first_frame=first,
        observed=observed & objects["mask"],
    )


def _check_key(key):
    key = jnp.asarray(key) if not isinstance(key, jax.Array) else key
    if jnp.issubdtype(key.dtype, jax.dtypes.prng_key):
        if key.ndim != 0:
            raise ValueError(f"key: expected a single PRNG key, got shape {tuple(key.shape)} (vmap over keys)")
        return key
    if key.shape != (2,) or key.dtype != jnp.uint32:
        raise ValueError(
            f"key: expected a PRNG key (jax.random.key or PRNGKey, shape (2,) uint32), got shape "
            f"{tuple(key.shape)} dtype {key.dtype} (vmap over a batch of keys)"
        )
    return key


def simulate(key, config: SimConfig = SimConfig(), dtype=None) -> SimulatedMap:
    """One random map with its camera path, noisy measurements and initial estimates.

    Args:
      key: a PRNG key (``vmap`` over a batch of keys for many maps).
      config: :class:`SimConfig` (static; presets :func:`thesis_config`,
        :func:`quadricslam_config`).
      dtype: float dtype (default: jax's default float).

    Returns:
      :class:`SimulatedMap` with N = ``config.num_objects`` object slots and T =
      ``config.num_frames`` frames.
    """
    if not isinstance(config, SimConfig):
        raise ValueError(f"config: expected a SimConfig, got {type(config).__name__}")
    if config.path == "views":
        raise ValueError("config.path: 'views' maps come from simulate_views(), not simulate()")
    key = _check_key(key)
    dtype = dtype or jnp.result_type(float)
    size = _objects_pool_size(config) + _measurements_pool_size(config.num_frames, config.num_objects)
    pool = _Pool(key, size, dtype)
    objects = _random_objects(pool, config, dtype)
    poses = camera_path(config, dtype)
    return _assemble(pool, objects, poses, intrinsics(config, dtype), config)


@functools.partial(jax.jit, static_argnames=("config", "dtype"))
def _simulate_batch(keys, config, dtype):
    return jax.vmap(lambda k: simulate(k, config, dtype))(keys)


def simulate_batch(seed: int, num_maps: int, config: SimConfig = SimConfig(), dtype=None) -> SimulatedMap:
    """``num_maps`` maps from ``seed`` (jitted ``vmap`` of :func:`simulate`); leading axis M."""
    if int(num_maps) < 1:
        raise ValueError(f"num_maps: expected a positive int, got {num_maps!r}")
    keys = jax.random.split(jax.random.key(int(seed)), int(num_maps))
    return _simulate_batch(keys, config, dtype or jnp.result_type(float))


def simulate_views(
    key, num_views, yaw_range, config: SimConfig, max_views: int | None = None, dtype=None
) -> SimulatedMap:
    """One ellipsoid seen from views drawn over a limited yaw range (thesis figure 4-5).

    The object (drawn like :func:`random_objects`, one slot) stands at the origin with a random
    yaw. View i looks at its centre from azimuth ``a_i`` relative to the object's long (x) axis,
    at a distance uniform in [view_distance_min, view_distance_max] and at ``camera_height``.
    ``a_i`` follows a Gaussian N(0, (yaw_range / 4)^2) clipped to [-yaw_range / 2, yaw_range / 2]
    (so +-2 sigma spans the range) around a random base azimuth.

    Args:
      key: PRNG key.
      num_views: number of active views (may be traced: at most ``max_views``).
      yaw_range: full width of the allowed azimuth range (rad; may be traced).
      config: :class:`SimConfig` (``path`` is ignored; camera, noise and init fields are used).
      max_views: static frame capacity T (default ``config.num_frames``); frames beyond
        ``num_views`` carry no detections.

    Returns:
      :class:`SimulatedMap` with N = 1 and T = ``max_views``.
    """
    key = _check_key(key)
    dtype = dtype or jnp.result_type(float)
    T = int(max_views if max_views is not None else config.num_frames)
    cfg = config.replace(path="views", num_objects=1, min_objects=None, num_frames=T)
    obj_cfg = cfg.replace(path="orbit")
    size = _objects_pool_size(obj_cfg) + 1 + 2 * T + _measurements_pool_size(T, 1)
    pool = _Pool(key, size, dtype)
    objects = _random_objects(pool, obj_cfg, dtype)
    objects["center"] = objects["center"].at[:, :2].set(0.0)
    objects["mask"] = jnp.ones((1,), bool)
    yaw_range = jnp.asarray(yaw_range, dtype)
    sigma = yaw_range / 4.0
    az = jnp.clip(sigma * pool.normal((T,)), -yaw_range / 2, yaw_range / 2)
    yaw0 = jnp.arctan2(objects["rotation"][0, 1, 0], objects["rotation"][0, 0, 0])
    base = pool.uniform((), -jnp.pi, jnp.pi)
    az = az + base + yaw0
    dist = pool.uniform((T,), cfg.view_distance_min, cfg.view_distance_max)
    eye = jnp.stack([dist * jnp.cos(az), dist * jnp.sin(az), jnp.full_like(az, cfg.camera_height)], -1)
    target = jnp.broadcast_to(objects["center"][0], eye.shape)
    poses = look_at(eye, target, _up(dtype)).astype(dtype)
    sim = _assemble(pool, objects, poses, intrinsics(cfg, dtype), cfg)
    active = jnp.arange(T) < num_views
    box_mask = sim.box_mask & active[:, None]
    observed = jnp.any(box_mask, axis=0) & sim.object_mask
    first = jnp.where(observed, jnp.argmax(box_mask, axis=0), T).astype(jnp.int32)
    return eqx.tree_at(
        lambda s: (s.box_mask, s.edge_mask, s.texture_mask, s.observed, s.first_frame),
        sim,
        (
            box_mask,
            sim.edge_mask & active[:, None, None],
            sim.texture_mask & active[:, None],
            observed,
            first,
        ),
    )


# --------------------------------------------------------------------------------------------
# Into the solver's structures (jaxsem.slam).


def to_problem(sim: SimulatedMap, config: SimConfig):
    """The :class:`jaxsem.slam.SlamProblem` of a simulated map (vmappable over maps).

    Boxes are flattened frame-major: box ``m = t * N + j`` is object ``j`` seen in frame ``t``
    (ground-truth association); dropped detections keep their slot with ``box_mask`` False, so
    every map of a config has the same padded size M = T * N. Objects never detected are masked
    out (``object_mask = observed``).
    """
    from ..slam import SlamProblem

    T, N = sim.box_mask.shape[-2:]
    batch = sim.box_mask.shape[:-2]
    dtype = sim.boxes.dtype
    flat = lambda x, tail=(): x.reshape(batch + (T * N,) + tail)
    box_pose = jnp.broadcast_to(jnp.repeat(jnp.arange(T, dtype=jnp.int32), N), batch + (T * N,))
    box_object = jnp.broadcast_to(jnp.tile(jnp.arange(N, dtype=jnp.int32), T), batch + (T * N,))
    image_size = jnp.broadcast_to(jnp.asarray([config.image_width, config.image_height], dtype), batch + (2,))
    return SlamProblem(
        K=sim.K,
        image_size=image_size,
        pose_prior=sim.pose_prior,
        pose_mask=jnp.ones(sim.pose_prior.shape[:-2], bool),
        box=flat(sim.boxes, (4,)),
        box_pose=box_pose,
        box_object=box_object,
        box_mask=flat(sim.box_mask),
        texture_depth=flat(sim.texture_depth),
        texture_mask=flat(sim.texture_mask),
        object_class=sim.object_class,
        object_mask=sim.observed,
    )


def ground_truth(sim: SimulatedMap):
    """The true poses and ellipsoids as a :class:`jaxsem.slam.SlamEstimate`."""
    from ..slam import SlamEstimate

    return SlamEstimate(sim.camera_T_world, sim.object_rotation, sim.object_center, sim.object_radii)


def initial_estimate(sim: SimulatedMap):
    """The config's initial estimate (pose priors + ``init_*`` landmarks) as a ``SlamEstimate``."""
    from ..slam import SlamEstimate

    return SlamEstimate(sim.pose_prior, sim.init_rotation, sim.init_center, sim.init_radii)
