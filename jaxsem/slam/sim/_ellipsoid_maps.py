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

import functools

import equinox as eqx
import jax
import jax.numpy as jnp

from ...quadrics import (
    look_at,
)
from .._problem import SlamEstimate, SlamProblem

# The configuration and the map type live in _sim_config.py, the random draws in _sim_draws.py;
# this module assembles and simulates maps and turns them into the solver's structures.
from ._sim_config import (
    SimConfig,
    SimulatedMap,
    intrinsics,
)
from ._sim_draws import (
    _detect,
    _initial_landmarks,
    _measurements_pool_size,
    _objects_pool_size,
    _perturb_poses,
    _Pool,
    _random_objects,
    _up,
    camera_path,
)

__all__ = [
    "simulate",
    "simulate_batch",
    "simulate_views",
    "to_problem",
    "ground_truth",
    "initial_estimate",
]


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
        **det,  # the detector's outputs are named as the map's measurement fields
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
    return SlamEstimate(sim.camera_T_world, sim.object_rotation, sim.object_center, sim.object_radii)


def initial_estimate(sim: SimulatedMap):
    """The config's initial estimate (pose priors + ``init_*`` landmarks) as a ``SlamEstimate``."""
    return SlamEstimate(sim.pose_prior, sim.init_rotation, sim.init_center, sim.init_radii)
