"""The typed pytrees of the geometry core: :class:`Ellipsoid` and :class:`Camera`.

Each is a ``NamedTuple`` of arrays, so it passes through ``jit``, ``vmap``, ``grad`` and
``lax.scan`` unchanged (batch axes lead on every field), unpacks into the array functions of the
core (``project_bbox(*ellipsoid, *camera)``), and carries methods in the style of jaxlie's groups
(``ellipsoid.project_bbox(camera)``). Every method calls the core's function of the same job, so
the math stays in one place and the checks, masks and NaN guarantees are the functions'.
:class:`jaxsem.quadrics.Grid` (``grid.py``) is the third type, for maps on the world plane.

Methods (jaxsem's modules) take and return these types; the array functions stay for code that
holds the fields apart (a least-squares state, a dataset's columns).
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from ._common import _camera_args, _ellipsoid_args
from .bbox import project_bbox
from .conics import (
    camera_depth,
    camera_frame,
    camera_matrix,
    camera_valid,
    conic_outline,
    dual_quadric,
    ellipsoid_valid,
    primal_quadric,
    project_dual_conic,
    texture_plane_depth,
)
from .ground import ground_bounds, ground_conic
from .poses import back_project, cuboid_corners, invert_pose, project_points, stereo_right_T_left
from .rotations import look_at
from .shapes import SHAPE_ELLIPSOID, algebraic_distance, shape_bbox, shape_distance, surface_points


class Ellipsoid(NamedTuple):
    """An ellipsoid in jaxsem's one representation.

    Attributes:
      rotation: (..., 3, 3) object-to-world (or -camera, for VoluMon's camera-frame outputs).
      center: (..., 3) metres.
      radii: (..., 3) semi-axes in metres (chapter 5's size ``d = 2 * radii``).

    ``Ellipsoid(rotation, center, radii)`` stores what it is given (no checks, so it is free
    under ``jit`` and in ``tree_map``); :meth:`create` checks concrete input at a boundary.
    """

    rotation: Any  # jax or numpy arrays (host code keeps numpy: figures, writers)
    center: Any
    radii: Any

    @classmethod
    def create(cls, rotation, center, radii) -> Ellipsoid:
        """Checked constructor: shapes, finiteness, proper rotations, positive radii."""
        rotation, center, radii, _ = _ellipsoid_args(rotation, center, radii)
        return cls(rotation, center, radii)

    @property
    def sizes(self) -> jax.Array:
        """Full axis lengths ``d = 2 * radii`` (chapter 5's size)."""
        return 2.0 * jnp.asarray(self.radii)

    def valid(self) -> jax.Array:
        """(...) bool under ``jit``: :func:`~jaxsem.quadrics.ellipsoid_valid`."""
        return ellipsoid_valid(*self)

    def dual_quadric(self, *, with_valid: bool = False) -> Any:
        """(..., 4, 4) ``Q*`` (eq. 4.1-4.3): :func:`~jaxsem.quadrics.dual_quadric`."""
        return dual_quadric(*self, with_valid=with_valid)

    def primal_quadric(self) -> jax.Array:
        """(..., 4, 4) ``Q`` (eq. 5.5): :func:`~jaxsem.quadrics.primal_quadric`."""
        return primal_quadric(*self)

    def transform(self, a_T_b) -> Ellipsoid:
        """This ellipsoid (given in frame b) in frame a, for a rigid ``a_T_b`` (..., 4, 4)."""
        rotation, center = camera_frame(self.rotation, self.center, a_T_b)
        return Ellipsoid(rotation, center, jnp.broadcast_to(self.radii, center.shape))

    def in_camera(self, camera: Camera) -> Ellipsoid:
        """This (world-frame) ellipsoid in ``camera``'s frame (OpenCV axes)."""
        return self.transform(camera.camera_T_world)

    def project_bbox(self, camera: Camera) -> Any:
        """``(box (..., 4), valid (...))`` seen by ``camera``: :func:`~jaxsem.quadrics.project_bbox`."""
        return project_bbox(*self, *camera)

    def shape_bbox(self, camera: Camera, shape=SHAPE_ELLIPSOID) -> Any:
        """``(box (..., 4), valid (...))``: the image box of the cuboid / ellipsoid / cylinder of these radii:
        :func:`~jaxsem.quadrics.shape_bbox`."""
        return shape_bbox(*self, shape, *camera)

    def dual_conic(self, camera: Camera) -> jax.Array:
        """(..., 3, 3) projected dual conic ``C* = P Q* P^T`` (eq. 4.9)."""
        return project_dual_conic(dual_quadric(*self), *camera)

    def outline(self, camera: Camera, num_points: int = 64) -> Any:
        """``(points (..., num_points, 2) pixels on the image outline, valid (...))``:
        :func:`~jaxsem.quadrics.conic_outline`."""
        return conic_outline(self.dual_conic(camera), num_points)

    def texture_plane_depth(self, camera: Camera) -> Any:
        """``(depth, valid)``: :func:`~jaxsem.quadrics.texture_plane_depth` (eq. 4.11-4.12) seen by ``camera``."""
        return texture_plane_depth(*self, camera.camera_T_world)

    def algebraic_distance(self, points) -> jax.Array:
        """(..., N) ``x^T Q x`` of points (..., N, 3): negative inside, 0 on the surface:
        :func:`~jaxsem.quadrics.algebraic_distance`."""
        return algebraic_distance(points, *self)

    def shape_distance(self, points, shape=SHAPE_ELLIPSOID) -> jax.Array:
        """(..., N) inside-outside value of points (..., N, 3) for the shape of these radii:
        :func:`~jaxsem.quadrics.shape_distance`."""
        return shape_distance(points, *self, shape)

    def surface_points(self, key, n: int) -> jax.Array:
        """(..., n, 3) random surface points: :func:`~jaxsem.quadrics.surface_points`."""
        return surface_points(key, *self, n)

    def corners(self) -> jax.Array:
        """(..., 8, 3) corners of the oriented bounding box: :func:`~jaxsem.quadrics.cuboid_corners`."""
        return cuboid_corners(*self)

    def ground_bounds(self) -> jax.Array:
        """(..., 4) top-down ``[x_min, y_min, x_max, y_max]``: :func:`~jaxsem.quadrics.ground_bounds`."""
        return ground_bounds(*self)

    def ground_conic(self) -> jax.Array:
        """(..., 3, 3) top-down footprint conic: :func:`~jaxsem.quadrics.ground_conic`."""
        return ground_conic(*self)


class Camera(NamedTuple):
    """A pinhole camera: ``K`` (..., 3, 3) and ``camera_T_world`` (..., 4, 4), OpenCV axes.

    ``Camera(K, camera_T_world)`` stores what it is given; :meth:`create` checks.
    """

    K: Any
    camera_T_world: Any

    @classmethod
    def create(cls, K, camera_T_world) -> Camera:
        """Checked constructor: intrinsics with positive focal lengths, a rigid pose."""
        K, pose = _camera_args(K, camera_T_world)
        return cls(K, pose)

    @classmethod
    def look_at(cls, K, eye, target, up=(0.0, 0.0, 1.0)) -> Camera:
        """A camera with intrinsics ``K`` at ``eye`` looking at ``target``: :func:`~jaxsem.quadrics.look_at`."""
        return cls.create(K, look_at(eye, target, up))

    @property
    def world_T_camera(self) -> jax.Array:
        """(..., 4, 4) the inverse pose."""
        return invert_pose(self.camera_T_world)

    @property
    def position(self) -> jax.Array:
        """(..., 3) the optical centre in the world."""
        return self.world_T_camera[..., :3, 3]

    def valid(self) -> jax.Array:
        """(...) bool under ``jit``: :func:`~jaxsem.quadrics.camera_valid`."""
        return camera_valid(*self)

    def matrix(self) -> jax.Array:
        """(..., 3, 4) ``P = K [I | 0] camera_T_world``: :func:`~jaxsem.quadrics.camera_matrix`."""
        return camera_matrix(*self)

    def project(self, points, *, with_valid: bool = False) -> Any:
        """``(uv (..., 2), depth (...))`` of world points: :func:`~jaxsem.quadrics.project_points`."""
        return project_points(points, *self, with_valid=with_valid)

    def back_project(self, uv, depth) -> jax.Array:
        """(..., 3) world points at camera depth ``depth`` through pixels ``uv``:
        :func:`~jaxsem.quadrics.back_project`."""
        return back_project(uv, depth, *self)

    def depth(self, points) -> jax.Array:
        """(...) camera z of world points: :func:`~jaxsem.quadrics.camera_depth`."""
        return camera_depth(points, self.camera_T_world)

    def project_bbox(self, ellipsoid: Ellipsoid) -> Any:
        """``(box, valid)`` of ``ellipsoid``: :meth:`Ellipsoid.project_bbox`."""
        return project_bbox(*ellipsoid, *self)

    def stereo_right(self, baseline) -> Camera:
        """The right camera of a rectified stereo pair whose left camera is this one (same ``K``,
        ``baseline`` metres along the left camera's x axis): :func:`~jaxsem.quadrics.stereo_right_T_left`."""
        T = jnp.asarray(self.camera_T_world)
        right_T_left = stereo_right_T_left(baseline, dtype=T.dtype)
        return Camera(self.K, right_T_left @ T)


class EllipsoidView:
    """A read-only attribute that bundles a container's three ellipsoid fields into an
    :class:`Ellipsoid` (``estimate.ellipsoid``), so every method's results give the typed view
    without writing the property again::

        class SlamEstimate(eqx.Module):
            rotation: jax.Array
            center: jax.Array
            radii: jax.Array
            ellipsoid = EllipsoidView()
    """

    def __init__(self, rotation: str = "rotation", center: str = "center", radii: str = "radii"):
        self.fields = (rotation, center, radii)

    def __set_name__(self, owner, name):
        self.__doc__ = (
            f"``{name}``: the fields {', '.join(self.fields)} as one :class:`jaxsem.quadrics.Ellipsoid`"
            " (batch axes leading)."
        )

    def __get__(self, obj, owner=None) -> Any:
        if obj is None:
            return self
        return Ellipsoid(*(getattr(obj, f) for f in self.fields))
