r"""Geometry core: ellipsoids as dual and primal quadrics, and what a camera sees of them.

The one public entry point of the geometry core: ``from jaxsem import quadrics``. The code lives in
the private package :mod:`jaxsem._geometry`, one module per job, which a reader can check against
the equations of the thesis (chapter 4.2, 4.3.1-4.3.3 and 5.2; ``docs/equations.md`` maps every
equation to its function). Neither imports anything else of jaxsem but ``jaxsem._checks``.

Where the code lives (``jaxsem/_geometry/``):

- ``_common.py``: argument checks, ``safe_sqrt`` / ``safe_div`` / ``safe_norm``.
- ``types.py``: the ``Ellipsoid`` and ``Camera`` pytrees, whose methods call the functions below.
- ``conics.py``: ``dual_quadric``, ``primal_quadric``, ``camera_matrix``, ``project_dual_conic``,
  ``conic_bbox``, ``cylinder_bbox``, ``conic_outline``, ``camera_frame``, ``texture_plane_depth``,
  ``camera_depth``, ``half_extent``.
- ``bbox.py``: ``project_bbox``, the fused closed-form box with its custom JVP, and
  ``project_bbox_jacobian``, its Jacobians with respect to the object and the camera in closed form.
- ``boxes.py``: ``box_area``, ``box_iou``: image boxes compared (one definition for every part).
- ``ground.py``: ``ground_conic``, ``ground_bounds``, ``rasterize_footprint`` (top-down view).
- ``rotations.py``: quaternion conversions (``wxyz`` / ``xyzw`` in the name), ``random_rotation``,
  ``look_at``, ``nearest_rotation``, ``so3_exp``, ``skew``, ``yaw_rotation``, ``ray_rotation``, ``allocentric_rotation``.
- ``poses.py``: ``rigid_transform``, ``transform_points``, ``invert_pose``, ``project_points``,
  ``back_project``, ``single_view_ellipsoid``, ``depth_from_box_size``, ``relative_pose``,
  ``cuboid_corners``, ``stereo_right_T_left``.
- ``grid.py``: the ``Grid`` pytree (origin, resolution, static shape), ``world_to_cell``,
  ``cell_to_world``, ``cell_in_grid``, ``box_to_cells`` (every map of the planner and the object maps).
- ``shapes.py``: ``algebraic_distance``, ``ray_entry_range``, ``ray_cast_local``, ``surface_points``, ``shape_bbox``,
  ``shape_distance`` and the ``SHAPE_*`` ids.

Conventions (the only ones in jaxsem):

- An ellipsoid is ``rotation`` (..., 3, 3) object-to-world, ``center`` (..., 3) in the world and
  ``radii`` (..., 3), the semi-axis lengths in metres. Chapter 5's "size d" is ``2 * radii``.
- Dual quadric (eq. 4.1-4.3): ``Q* = Z diag(r0^2, r1^2, r2^2, -1) Z^T`` with ``Z = [[R, t], [0, 1]]``.
- Primal quadric (eq. 5.5): ``Q = [[A, -A t], [-t^T A, t^T A t - 1]]``, ``A = R diag(1/r^2) R^T``;
  ``x^T Q x < 0`` inside, ``= 0`` on the surface, ``> 0`` outside.
- A camera is ``K`` (..., 3, 3) and ``camera_T_world`` (..., 4, 4), which maps world points into the
  camera frame (OpenCV axes: x right, y down, z forward). ``P = K [I | 0] camera_T_world`` and the
  projected dual conic is ``C* = P Q* P^T`` (eq. 4.9).
- Image boxes are ``[u_min, v_min, u_max, v_max]`` in continuous pixel coordinates (eq. 4.10),
  OpenCV's, as ``K`` is: pixel (row ``i``, column ``j``) has its centre at ``(u, v) = (j, i)``,
  so a ``W x H`` image covers ``[-0.5, W - 0.5] x [-0.5, H - 0.5]`` and the box of pixels
  ``j0..j1`` runs from ``j0 - 0.5`` to ``j1 + 0.5`` (``u_max <= W - 0.5``, below the width).
  Every box jaxsem makes (BOP visible boxes, rendered segmentations, detections) and every check
  it runs (:func:`jaxsem.volumon.prepare_inputs`) uses it.
- Rotations read from files are projected with :func:`nearest_rotation` (files keep a few digits).

Every public function broadcasts leading batch axes numpy-style, works under ``jit``, ``vmap`` and
``grad`` in float32 and float64, and never returns NaN values or NaN gradients for finite inputs.
Where the closed form has no real answer (camera inside or on the ellipsoid, ellipsoid behind or
straddling the image plane, a conic that is not an ellipse) a ``valid`` mask is returned next to
a finite value. Wrong trailing shapes raise ``ValueError`` naming the argument; non-finite
concrete inputs where they would poison everything (``K``, poses) raise too.

Host code (dataset writers, the OpenCV front end) calls the same functions with ``xp=numpy``
where the option exists: the same formulas, evaluated by numpy in float64 without a jax dispatch
per call (which costs milliseconds in a per-object Python loop). The default is ``jax.numpy``.
"""

from __future__ import annotations

from ._geometry._common import (
    safe_div as safe_div,
    safe_norm as safe_norm,
    safe_sqrt as safe_sqrt,
)
from ._geometry.bbox import (
    project_bbox as project_bbox,
    project_bbox_jacobian as project_bbox_jacobian,
    project_bbox_reference as project_bbox_reference,
)
from ._geometry.boxes import box_area as box_area, box_iou as box_iou
from ._geometry.conics import (
    camera_depth as camera_depth,
    camera_frame as camera_frame,
    camera_matrix as camera_matrix,
    camera_valid as camera_valid,
    conic_bbox as conic_bbox,
    conic_outline as conic_outline,
    cylinder_bbox as cylinder_bbox,
    dual_quadric as dual_quadric,
    ellipsoid_valid as ellipsoid_valid,
    half_extent as half_extent,
    primal_quadric as primal_quadric,
    project_dual_conic as project_dual_conic,
    texture_plane_depth as texture_plane_depth,
)
from ._geometry.grid import (
    Grid as Grid,
    box_to_cells as box_to_cells,
    cell_in_grid as cell_in_grid,
    cell_to_world as cell_to_world,
    world_to_cell as world_to_cell,
)
from ._geometry.ground import (
    ground_bounds as ground_bounds,
    ground_conic as ground_conic,
    rasterize_footprint as rasterize_footprint,
)
from ._geometry.poses import (
    CUBOID_CORNER_SIGNS as CUBOID_CORNER_SIGNS,
    back_project as back_project,
    cuboid_corners as cuboid_corners,
    depth_from_box_size as depth_from_box_size,
    fit_rigid_transform as fit_rigid_transform,
    invert_pose as invert_pose,
    project_points as project_points,
    relative_pose as relative_pose,
    rigid_transform as rigid_transform,
    single_view_ellipsoid as single_view_ellipsoid,
    stereo_right_T_left as stereo_right_T_left,
    transform_points as transform_points,
)
from ._geometry.rotations import (
    allocentric_rotation as allocentric_rotation,
    look_at as look_at,
    nearest_rotation as nearest_rotation,
    quaternion_to_rotation as quaternion_to_rotation,
    quaternion_wxyz_to_rotation as quaternion_wxyz_to_rotation,
    quaternion_xyzw_to_rotation as quaternion_xyzw_to_rotation,
    random_rotation as random_rotation,
    ray_rotation as ray_rotation,
    rotation_to_quaternion as rotation_to_quaternion,
    rotation_to_quaternion_wxyz as rotation_to_quaternion_wxyz,
    rotation_to_quaternion_xyzw as rotation_to_quaternion_xyzw,
    skew as skew,
    so3_exp as so3_exp,
    yaw_rotation as yaw_rotation,
)
from ._geometry.shapes import (
    SHAPE_CUBOID as SHAPE_CUBOID,
    SHAPE_CYLINDER as SHAPE_CYLINDER,
    SHAPE_ELLIPSOID as SHAPE_ELLIPSOID,
    SUPERQUADRIC_EPS as SUPERQUADRIC_EPS,
    algebraic_distance as algebraic_distance,
    ray_cast_local as ray_cast_local,
    ray_entry_range as ray_entry_range,
    shape_bbox as shape_bbox,
    shape_distance as shape_distance,
    surface_points as surface_points,
)
from ._geometry.types import (
    Camera as Camera,
    Ellipsoid as Ellipsoid,
    EllipsoidView as EllipsoidView,
)

# Old names (scalar-first convention), kept so that existing code keeps working; not in __all__:
# quaternion_to_rotation = quaternion_wxyz_to_rotation, rotation_to_quaternion = rotation_to_quaternion_wxyz.

__all__ = [
    "Ellipsoid",
    "Camera",
    "Grid",
    "EllipsoidView",
    "dual_quadric",
    "primal_quadric",
    "project_dual_conic",
    "camera_matrix",
    "conic_bbox",
    "cylinder_bbox",
    "conic_outline",
    "project_bbox",
    "project_bbox_jacobian",
    "project_bbox_reference",
    "texture_plane_depth",
    "algebraic_distance",
    "ray_entry_range",
    "ray_cast_local",
    "shape_bbox",
    "shape_distance",
    "stereo_right_T_left",
    "SHAPE_CUBOID",
    "SHAPE_ELLIPSOID",
    "SHAPE_CYLINDER",
    "SUPERQUADRIC_EPS",
    "ground_conic",
    "ground_bounds",
    "rasterize_footprint",
    "surface_points",
    "camera_depth",
    "camera_frame",
    "half_extent",
    "look_at",
    "nearest_rotation",
    "rigid_transform",
    "transform_points",
    "invert_pose",
    "project_points",
    "back_project",
    "single_view_ellipsoid",
    "depth_from_box_size",
    "fit_rigid_transform",
    "relative_pose",
    "cuboid_corners",
    "world_to_cell",
    "cell_to_world",
    "cell_in_grid",
    "box_to_cells",
    "CUBOID_CORNER_SIGNS",
    "so3_exp",
    "skew",
    "yaw_rotation",
    "ray_rotation",
    "allocentric_rotation",
    "quaternion_wxyz_to_rotation",
    "rotation_to_quaternion_wxyz",
    "quaternion_xyzw_to_rotation",
    "rotation_to_quaternion_xyzw",
    "random_rotation",
    "safe_sqrt",
    "safe_div",
    "safe_norm",
]
