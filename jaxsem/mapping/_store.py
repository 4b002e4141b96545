"""Object-map store: per-frame ellipsoid estimates -> associated, fused objects -> semantic grid.

Thesis section 5.8.2 builds its object map by "a simple centroid-based distance check to greedily
associate measurements to existing objects in the database, or ... instantiate a new entry", and
lets new measurements overwrite old ones; section 5.8.3 projects each ellipsoid orthographically
onto the ground and discretises the conic "using the same discretization as the occupancy map".
This module is that system as pure functions on a fixed-capacity pytree, so a whole mapping run
jits once and ``vmap`` maps many robots / buildings at once.

Choices the thesis leaves open (written down here, defaults first):

- Association is *global* greedy: of all (detection, object) pairs of the same class whose
  centres lie within ``gate`` metres, the closest pair is matched first, then the next closest
  among the remaining detections and objects, and so on. The result does not depend on the order
  of the detections in the frame. Detections of the same frame never merge with each other.
- Fusion ``"latest"`` (the thesis) overwrites; ``"mean"`` keeps the observation-count weighted
  mean of the centres and of the shape matrices ``S = R diag(r^2) R^T`` (invariant to the
  ellipsoid's axis permutations and sign flips, so no rotation averaging is needed) and recovers
  rotation and radii by an eigendecomposition.
- Unmatched detections take the free slots in slot order; when the store is full they are dropped
  and counted in ``ObjectMap.dropped`` (a result code a jitted caller can read).
"""

from __future__ import annotations

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .. import quadrics
from .._checks import as_float_array, is_concrete, require_type
from ..quadrics import Ellipsoid, EllipsoidView, Grid

__all__ = [
    "FUSIONS",
    "Association",
    "Ellipsoids",
    "ObjectMap",
    "associate",
    "ellipsoids",
    "init",
    "semantic_grid",
    "update",
]

FUSIONS = ("latest", "mean")


class Ellipsoids(eqx.Module):
    """A padded set of class-labelled ellipsoids (one frame's estimates; batch axes may lead).

    Attributes:
      rotation: (..., M, 3, 3) object-to-world rotations.
      center: (..., M, 3) world centres (metres, z up).
      radii: (..., M, 3) semi-axis lengths (metres).
      class_id: (..., M) int32 class; for planning use the semantic ids of
        :mod:`jaxsem.planning` (``DOOR``, ``WINDOW``, ``EXIT_SIGN``), which the grid then carries.
      valid: (..., M) bool, False for padding.
    """

    rotation: jax.Array
    center: jax.Array
    radii: jax.Array
    class_id: jax.Array
    valid: jax.Array

    ellipsoid = EllipsoidView()


class ObjectMap(eqx.Module):
    """The store: N object slots (``N`` = capacity) with masks.

    Attributes:
      rotation, center, radii, class_id: as :class:`Ellipsoids`, (..., N, ...).
      valid: (..., N) bool, True for slots that hold an object.
      observations: (..., N) int32 number of detections fused into each object.
      dropped: (...) int32 number of detections dropped so far because the store was full.
    """

    rotation: jax.Array
    center: jax.Array
    radii: jax.Array
    class_id: jax.Array
    valid: jax.Array
    observations: jax.Array
    dropped: jax.Array

    ellipsoid = EllipsoidView()

    @property
    def capacity(self) -> int:
        return int(self.valid.shape[-1])

    def objects(self) -> Ellipsoids:
        """The stored objects as :class:`Ellipsoids` (same slots, ``valid`` as the mask)."""
        return Ellipsoids(self.rotation, self.center, self.radii, self.class_id, self.valid)


class Association(eqx.Module):
    """Where each detection of a frame went (see :func:`associate`).

    slot: (M,) int32 object slot in ``[0, N)``, or ``N`` when the detection is padding or was
      dropped for lack of capacity.
    matched: (M,) bool, True where the detection was associated with an existing object.
    created: (M,) bool, True where it started a new object.
    """

    slot: jax.Array
    matched: jax.Array
    created: jax.Array


def ellipsoids(ellipsoid: Ellipsoid, class_id, valid=None) -> Ellipsoids:
    """Checked constructor of :class:`Ellipsoids`: class-labelled ellipsoids for the store.

    ellipsoid: a :class:`jaxsem.quadrics.Ellipsoid` of M world ellipsoids (numpy or JAX arrays:
    rotation (..., M, 3, 3), or None for axis-aligned ones; center (..., M, 3); radii (..., M, 3)),
    e.g. ``estimate.ellipsoid``; class_id (..., M) integers; valid (..., M) bool or None (all
    valid). ``ValueError`` names the field whose shape does not fit.
    """
    rotation, center, radii = require_type("ellipsoid", ellipsoid, Ellipsoid)
    center = as_float_array("ellipsoid.center", center, (3,))
    if center.ndim < 2:
        raise ValueError(f"ellipsoid.center: expected shape (..., M, 3), got {tuple(center.shape)}")
    batch = tuple(center.shape[:-1])
    radii = as_float_array("ellipsoid.radii", radii, (3,))
    if tuple(radii.shape[:-1]) != batch:
        raise ValueError(f"ellipsoid.radii: expected shape {batch + (3,)} like center, got {tuple(radii.shape)}")
    if rotation is None:
        rotation = jnp.broadcast_to(jnp.eye(3, dtype=center.dtype), batch + (3, 3))
    rotation = as_float_array("ellipsoid.rotation", rotation, (3, 3))
    if tuple(rotation.shape[:-2]) != batch:
        raise ValueError(f"ellipsoid.rotation: expected shape {batch + (3, 3)}, got {tuple(rotation.shape)}")
    class_arr = jnp.asarray(class_id)
    if not jnp.issubdtype(class_arr.dtype, jnp.integer):
        raise ValueError(f"class_id: expected integers, got dtype {class_arr.dtype}")
    if tuple(class_arr.shape) != batch:
        raise ValueError(f"class_id: expected shape {batch}, got {tuple(class_arr.shape)}")
    valid_arr = jnp.ones(batch, bool) if valid is None else jnp.asarray(valid)
    if valid_arr.dtype != jnp.bool_ or tuple(valid_arr.shape) != batch:
        raise ValueError(f"valid: expected bool of shape {batch}, got {valid_arr.dtype} {tuple(valid_arr.shape)}")
    dtype = jnp.result_type(center.dtype, radii.dtype, rotation.dtype)
    return Ellipsoids(
        rotation.astype(dtype),
        center.astype(dtype),
        radii.astype(dtype),
        class_arr.astype(jnp.int32),
        valid_arr,
    )


def init(capacity: int, dtype=None) -> ObjectMap:
    """An empty store of ``capacity`` object slots (identity rotations, unit radii, invalid)."""
    if not isinstance(capacity, (int, np.integer)) or capacity < 1:
        raise ValueError(f"capacity: expected a positive int, got {capacity!r}")
    dtype = jnp.dtype(dtype or jnp.result_type(float))
    if not jnp.issubdtype(dtype, jnp.floating):
        raise ValueError(f"dtype: expected a floating dtype, got {dtype}")
    n = int(capacity)
    return ObjectMap(
        rotation=jnp.broadcast_to(jnp.eye(3, dtype=dtype), (n, 3, 3)),
        center=jnp.zeros((n, 3), dtype),
        radii=jnp.ones((n, 3), dtype),
        class_id=jnp.zeros((n,), jnp.int32),
        valid=jnp.zeros((n,), bool),
        observations=jnp.zeros((n,), jnp.int32),
        dropped=jnp.zeros((), jnp.int32),
    )


def _check_pair(state: ObjectMap, detections: Ellipsoids):
    if not isinstance(state, ObjectMap):  # ValueError for all bad input (CONTRIBUTING.md)
        raise ValueError(f"state: expected an ObjectMap (from init), got {type(state).__name__}")
    if not isinstance(detections, Ellipsoids):
        raise ValueError(
            f"detections: expected Ellipsoids (build with jaxsem.mapping.ellipsoids), got {type(detections).__name__}"
        )
    if detections.center.ndim != 2 or state.center.ndim != 2:
        raise ValueError(
            f"detections / state: expected one frame (M, 3) and one store (N, 3) (vmap for batches), "
            f"got center shapes {tuple(detections.center.shape)} and {tuple(state.center.shape)}"
        )


def _associate(state: ObjectMap, det: Ellipsoids, gate, class_aware: bool) -> Association:
    M, N = det.valid.shape[0], state.valid.shape[0]
    diff = jax.lax.stop_gradient(det.center[:, None, :].astype(state.center.dtype) - state.center[None, :, :])
    dist2 = jnp.sum(diff * diff, axis=-1)  # squared: no sqrt, no NaN gradient at 0
    gate = jnp.asarray(gate, dist2.dtype)
    ok = det.valid[:, None] & state.valid[None, :] & (dist2 <= gate * gate)
    if class_aware:
        ok &= det.class_id[:, None] == state.class_id[None, :]
    inf = jnp.asarray(jnp.inf, dist2.dtype)
    cost = jnp.where(ok, dist2, inf)

    def body(_, carry):
        cost, slot = carry
        flat = jnp.argmin(cost)
        m, n = (flat // N).astype(jnp.int32), (flat % N).astype(jnp.int32)
        found = jnp.isfinite(cost[m, n])
        slot = slot.at[m].set(jnp.where(found, n, slot[m]))
        cleared = cost.at[m, :].set(inf).at[:, n].set(inf)
        return jnp.where(found, cleared, cost), slot

    _, slot = jax.lax.fori_loop(0, M, body, (cost, jnp.full((M,), N, jnp.int32)))
    matched = slot < N
    # Unmatched real detections take the free slots in slot order (rank r -> r-th free slot).
    unmatched = det.valid & ~matched
    rank = jnp.cumsum(unmatched, dtype=jnp.int32) - 1
    free = ~state.valid
    free_rank = jnp.where(free, jnp.cumsum(free, dtype=jnp.int32) - 1, M)  # ranks >= M are never asked for
    slot_of_rank = jnp.full((M,), N, jnp.int32).at[free_rank].set(jnp.arange(N, dtype=jnp.int32), mode="drop")
    new_slot = jnp.where(unmatched, slot_of_rank[jnp.clip(rank, 0, M - 1)], N)
    slot = jnp.where(matched, slot, new_slot).astype(jnp.int32)
    return Association(slot=slot, matched=matched, created=unmatched & (new_slot < N))


def associate(state: ObjectMap, detections: Ellipsoids, *, gate=1.0, class_aware: bool = True):
    """Greedy, class-aware association of one frame's detections with the stored objects.

    state: :class:`ObjectMap` (N slots); detections: :class:`Ellipsoids` (M); gate: metres between
    centres (traced: may be vmapped). Returns an :class:`Association`. Jittable.
    """
    _check_pair(state, detections)
    return _associate_jit(state, detections, gate, class_aware)


@functools.partial(jax.jit, static_argnames=("class_aware",))
def _associate_jit(state, det, gate, class_aware):
    return _associate(state, det, gate, class_aware)


def _shape_matrix(rotation, radii):
    return (rotation * jnp.square(radii)[..., None, :]) @ jnp.swapaxes(rotation, -1, -2)


def _from_shape_matrix(S):
    """(..., 3, 3) symmetric positive definite -> rotation (proper), radii (ascending)."""
    dtype = S.dtype
    scale = jnp.maximum(jnp.trace(S, axis1=-2, axis2=-1), jnp.finfo(dtype).tiny)[..., None, None]
    # A tie-break far below any physical size (1e-7 of the trace in float64, 1e-5 in float32:
    # radii move by under 1e-3 relative) keeps eigh's derivative finite when two radii are
    # exactly equal (it divides by the eigenvalue gap).
    tie = jnp.diag(jnp.array([0.0, 1.0, 2.0], dtype)) * (1e-7 if dtype == jnp.float64 else 1e-5)
    w, v = jnp.linalg.eigh(S + scale * tie)
    radii = quadrics.safe_sqrt(jnp.maximum(w, 0.0))
    det = jnp.linalg.det(v)
    v = v.at[..., :, 2].multiply(jnp.where(det < 0, -1.0, 1.0)[..., None])
    return v, radii


def _update(state: ObjectMap, det: Ellipsoids, gate, class_aware: bool, fusion: str) -> ObjectMap:
    assoc = _associate(state, det, gate, class_aware)
    N = state.valid.shape[0]
    slot = assoc.slot
    write = slot < N
    idx = jnp.clip(slot, 0, N - 1)
    old_n = jnp.where(assoc.matched, state.observations[idx], 0)
    if fusion == "latest":
        rot, ctr, rad = det.rotation, det.center, det.radii
    else:
        w_old = old_n.astype(det.center.dtype)[:, None]
        w_new = 1.0 / (w_old + 1.0)
        ctr = state.center[idx] * (w_old * w_new) + det.center * w_new
        S_old = _shape_matrix(state.rotation[idx], state.radii[idx])
        S_new = _shape_matrix(det.rotation, det.radii)
        S = S_old * (w_old * w_new)[..., None] + S_new * w_new[..., None]
        rot_f, rad_f = _from_shape_matrix(S)
        # Newly created objects keep the detection exactly (no eigendecomposition round trip).
        m = assoc.matched
        rot = jnp.where(m[:, None, None], rot_f, det.rotation)
        rad = jnp.where(m[:, None], rad_f, det.radii)
        ctr = jnp.where(m[:, None], ctr, det.center)
    target = jnp.where(write, slot, N)  # N: dropped by the scatters
    dtype = state.center.dtype
    return ObjectMap(
        rotation=state.rotation.at[target].set(rot.astype(dtype), mode="drop"),
        center=state.center.at[target].set(ctr.astype(dtype), mode="drop"),
        radii=state.radii.at[target].set(rad.astype(dtype), mode="drop"),
        class_id=state.class_id.at[target].set(det.class_id, mode="drop"),
        valid=state.valid.at[target].set(True, mode="drop"),
        observations=state.observations.at[target].set(old_n + 1, mode="drop"),
        dropped=state.dropped + jnp.sum(det.valid & ~write).astype(jnp.int32),
    )


def update(
    state: ObjectMap,
    detections: Ellipsoids,
    *,
    gate=1.0,
    class_aware: bool = True,
    fusion: str = "latest",
) -> ObjectMap:
    """Adds one frame's ellipsoid estimates to the store (associate, then fuse or create).

    state: :class:`ObjectMap` from :func:`init` (N slots); detections: :class:`Ellipsoids` (M, from
    VoluMon predictions or a ROSHAN estimate, e.g. ``ellipsoids(est.ellipsoid, classes)``); gate: association distance between centres in metres (traced);
    class_aware: only same-class pairs associate; fusion: ``"latest"`` (thesis 5.8.2: the new
    estimate overwrites) or ``"mean"`` (running mean of centre and shape matrix). Returns the new
    :class:`ObjectMap`; detections that found no free slot are counted in ``dropped``.
    Jitted; ``jax.vmap(update)`` runs many stores at once (pass fixed keyword arguments with
    ``functools.partial``).
    """
    _check_pair(state, detections)
    if fusion not in FUSIONS:
        raise ValueError(f"fusion: expected one of {FUSIONS}, got {fusion!r}")
    return _update_jit(state, detections, gate, bool(class_aware), fusion)


@functools.partial(jax.jit, static_argnames=("class_aware", "fusion"))
def _update_jit(state, det, gate, class_aware, fusion):
    return _update(state, det, gate, class_aware, fusion)


def semantic_grid(objects, grid: Grid, window: int | None = 64) -> jax.Array:
    """Rasterises the objects' ground footprints into an (H, W) int8 semantic grid.

    objects: an :class:`ObjectMap` or :class:`Ellipsoids` whose ``class_id`` are the planning
    world's semantic ids; grid: the :class:`jaxsem.quadrics.Grid` to draw on (origin, resolution,
    static shape: the occupancy grid's, e.g. ``building.grid``, so the two align cell for cell;
    origin and resolution may be traced). A cell takes the class of a footprint (orthographic projection along z,
    :func:`jaxsem.quadrics.rasterize_footprint`) that contains its centre; overlaps take the
    largest id (exit sign over window over door); everything else is ``NONE`` (0). This is the
    ``semantic`` leaf of :class:`jaxsem.planning.MapState` that LSD reads.

    window: each object is drawn in a ``window x window``-cell tile around its centre cell and
    the tiles are max-scattered into the grid (static; 64 cells = 6.4 m at 0.1 m/cell, enough for
    doors, windows, signs and cars). Drawing every object over the whole grid instead
    (``window=None``, exact for any size) costs N x H x W, against N x window^2 tiled: for a
    hundred objects on a building-sized grid that is orders of magnitude more. With concrete inputs an
    object whose footprint does not fit its tile raises ``ValueError``; under ``jit`` it is
    clipped to the tile.
    """
    if isinstance(objects, ObjectMap):
        objects = objects.objects()
    if not isinstance(objects, Ellipsoids):
        raise ValueError(f"objects: expected an ObjectMap or Ellipsoids, got {type(objects).__name__}")
    grid_shape, origin, resolution = require_type("grid", grid, Grid).shape, grid.origin, grid.resolution
    if window is None:
        raster = quadrics.rasterize_footprint(
            objects.rotation,
            objects.center,
            objects.radii,
            objects.class_id,
            grid_shape,
            origin,
            resolution,
            mask=objects.valid,
        )
        return raster.astype(jnp.int8)
    if not isinstance(window, (int, np.integer)) or window < 2:
        raise ValueError(f"window: expected None or an int >= 2 (cells), got {window!r}")
    origin = as_float_array("origin", origin, (2,))
    if origin.ndim != 1:
        raise ValueError(f"origin: expected shape (2,), got {tuple(origin.shape)}")
    if is_concrete(objects.center) and is_concrete(objects.radii) and is_concrete(resolution):
        bounds = np.asarray(quadrics.ground_bounds(objects.rotation, objects.center, objects.radii))
        half = 0.5 * (bounds[..., 2:] - bounds[..., :2]) / float(resolution)
        too_big = np.asarray(objects.valid) & np.any(half + 1.0 > window // 2, axis=-1)
        if np.any(too_big):
            raise ValueError(
                f"window: {int(too_big.sum())} object(s) with footprints up to "
                f"{2 * float(half[too_big].max()) * float(resolution):.2f} m do not fit a tile of "
                f"{window} cells at {float(resolution)} m/cell; pass a larger window or None"
            )
    return _tiled(objects, grid_shape, origin, resolution, int(window))


@functools.partial(jax.jit, static_argnames=("grid_shape", "window"))
def _tiled(objects: Ellipsoids, grid_shape, origin, resolution, window):
    H, W = grid_shape
    rot = objects.rotation.reshape(-1, 3, 3)
    ctr = objects.center.reshape(-1, 3)
    rad = objects.radii.reshape(-1, 3)
    cls = objects.class_id.reshape(-1)
    valid = objects.valid.reshape(-1)
    origin = origin.astype(ctr.dtype)
    resolution = jnp.asarray(resolution).astype(ctr.dtype)
    # Tile corner: the centre cell minus half a tile (cells), so the centre sits mid-tile.
    cell = quadrics.world_to_cell(jax.lax.stop_gradient(ctr[:, :2]), origin, resolution)[:, ::-1]  # (col, row)
    corner = cell - window // 2  # (N, 2) as (col, row)
    tile_origin = origin + corner.astype(ctr.dtype) * resolution

    def one(R, c, r, k, m, o):
        return quadrics.rasterize_footprint(R, c, r, k, (window, window), o, resolution, mask=m)

    tiles = jax.vmap(one)(rot, ctr, rad, cls, valid, tile_origin)  # (N, window, window)
    offs = jnp.arange(window, dtype=jnp.int32)
    rows = corner[:, 1, None, None] + offs[None, :, None]
    cols = corner[:, 0, None, None] + offs[None, None, :]
    # Off-grid cells go to index H / W, which mode="drop" discards (negative indices would wrap).
    rows = jnp.where((rows >= 0) & (rows < H), rows, H)
    cols = jnp.where((cols >= 0) & (cols < W), cols, W)
    rows, cols = jnp.broadcast_arrays(rows, cols)
    grid = jnp.zeros((H, W), jnp.int32).at[rows, cols].max(tiles, mode="drop")
    return grid.astype(jnp.int8)
