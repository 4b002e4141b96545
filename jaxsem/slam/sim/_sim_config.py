"""The simulator's configuration (:class:`SimConfig` and its presets), the class table it draws
from, its intrinsics, and the :class:`SimulatedMap` it returns (thesis section 4.4).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Optional

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ... import classes as _classes
from ..._checks import check_fields, int_at_least
from ...quadrics import Camera, EllipsoidView

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
        check_fields(
            self, ("num_objects", "num_frames", "image_width", "image_height"), "a positive int", int_at_least(1)
        )
        if self.min_objects is not None and not 1 <= self.min_objects <= self.num_objects:
            raise ValueError(
                f"min_objects: expected an int in [1, num_objects={self.num_objects}], got {self.min_objects!r}"
            )
        if not isinstance(self.classes, tuple) or not self.classes:
            raise ValueError(f"classes: expected a non-empty tuple of names, got {self.classes!r}")
        class_table(self.classes)  # unknown names raise here, at construction
        positive_fields = (
            "focal",
            "patch_size",
            "orbit_radius",
            "forward_step",
            "init_depth",
            "view_distance_min",
            "view_distance_max",
            "max_depth",
        )
        check_fields(self, positive_fields, "a finite positive number", lambda v: math.isfinite(v) and v > 0)
        nonnegative_fields = (
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
        )
        check_fields(self, nonnegative_fields, "a finite number >= 0", lambda v: math.isfinite(v) and v >= 0)
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

    ellipsoid = EllipsoidView("object_rotation", "object_center", "object_radii")

    @property
    def cameras(self) -> Camera:
        """The T true cameras as one :class:`jaxsem.quadrics.Camera` (``K`` shared, broadcast by the core)."""
        return Camera(self.K, self.camera_T_world)


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
