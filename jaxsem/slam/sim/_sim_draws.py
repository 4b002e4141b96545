"""The random draws of a simulated map: objects placed by rejection, camera paths, noisy pose
priors, detections with noisy boxes and texture planes, and the initial landmarks.

All the noise of a map is carved from one Gaussian draw (:class:`_Pool`), which keeps
``simulate`` quick to compile.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ... import factors
from ..._checks import require_type
from ...quadrics import (
    Camera,
    Ellipsoid,
    camera_frame,
    invert_pose,
    look_at,
    project_bbox,
    safe_norm,
    single_view_ellipsoid,
    so3_exp,
    texture_plane_depth,
    yaw_rotation,
)
from ._sim_config import SimConfig, class_table


class _Pool:
    """One Gaussian draw carved into all the noise a map needs.

    Each ``jax.random`` call inlines a threefry hash that adds noticeably to compile time on a
    CPU; one call per map instead of a dozen keeps ``simulate`` quick to compile. Uniform
    variates are ``Phi(g)`` of standard normals (exactly uniform).
    """

    def __init__(self, key, size: int, dtype):
        self.values = jax.random.normal(key, (int(size),), dtype)
        self.used = 0

    def normal(self, shape):
        n = int(np.prod(shape))
        if self.used + n > self.values.shape[0]:
            raise RuntimeError("jaxsem.slam.sim internal error: noise pool too small")
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
    mask = jnp.arange(n, dtype=jnp.int32) < n_taken
    r = radii[source]
    center = jnp.concatenate([xy[source], r[:, 2:3]], axis=-1)
    rotation = yaw_rotation(yaw[source])
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


def detect(key, ellipsoid: Ellipsoid, object_mask, camera: Camera, config: SimConfig):
    """Noisy detections of every object in every frame, with the drop and edge rules.

    Args:
      ellipsoid: the N true world ellipsoids (:class:`jaxsem.quadrics.Ellipsoid`, fields (N, ...));
        object_mask (N,).
      camera: the T true cameras (:class:`jaxsem.quadrics.Camera`: ``K`` (3, 3),
        ``camera_T_world`` (T, 4, 4)); e.g. ``simulated_map.ellipsoid`` and ``.cameras``.

    Returns:
      dict of ``boxes`` (T, N, 4) clipped noisy boxes, ``box_mask`` (T, N), ``edge_mask``
      (T, N, 4), ``texture_depth`` (T, N), ``texture_sigma`` (T, N), ``texture_mask`` (T, N),
      ``true_boxes`` (T, N, 4).
    """
    rotation, center, radii = require_type("ellipsoid", ellipsoid, Ellipsoid)
    K, camera_T_world = require_type("camera", camera, Camera)
    n_det = camera_T_world.shape[0] * center.shape[0]
    pool = _Pool(key, 5 * n_det, jnp.result_type(center.dtype, camera_T_world.dtype))
    return _detect(pool, rotation, center, radii, object_mask, camera_T_world, K, config)


def _detect(pool: _Pool, rotation, center, radii, object_mask, camera_T_world, K, config):
    """The detections of :func:`simulate_detections`: a dict keyed by :class:`SimulatedMap`'s
    measurement fields (``boxes`` ... ``true_boxes``), so a map takes them by name."""
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
    rot = objects["rotation"] @ yaw_rotation(d_yaw)
    rad = objects["radii"] + config.init_radii_noise_m * pool.normal((n, 3))
    rad = jnp.maximum(rad, 0.1)
    return rot, ctr, rad, first, observed


def _measurements_pool_size(T, N):
    return 6 * T + 5 * T * N + 7 * N
