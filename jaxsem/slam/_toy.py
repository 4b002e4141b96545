"""A small numpy generator of ellipsoid maps for the solvers' tests, examples and benchmarks.

It exists so that the solvers can be tested on their own; the full simulator is
:mod:`jaxsem.slam.sim`. Objects are car-sized ellipsoids (the ``car`` class with per-object size
noise) on a ground patch; the camera follows an ``"orbit"`` (circle looking at the centre) or a
``"forward"`` path (straight line along x past the objects); boxes are projected exactly, clipped
to the image (so truncated edges sit on the border and are dropped by the edge mask), and noised.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from .. import factors as F, quadrics as Q
from ._problem import SlamEstimate, make_frame, make_problem


def _yaw(angles):
    """Rotations (N, 3, 3) about the world z axis by ``angles`` (N,) radians (host, float64)."""
    return np.asarray(Q.yaw_rotation(np.asarray(angles, np.float64)), np.float64)


def toy_map(
    seed: int = 0,
    *,
    num_objects: int = 5,
    num_frames: int = 30,
    path: str = "forward",
    box_noise: float = 2.0,
    texture_noise: float = 0.1,
    pose_noise: tuple[float, float] = (0.02, 0.005),
    size_noise: float = 0.1,
    image_size=(640, 480),
    focal: float = 525.0,
    capacity: tuple[int, int, int] | None = None,
    class_name: str = "car",
):
    """One random map and its measurements.

    Args:
      seed: numpy seed. num_objects, num_frames: sizes. path: ``"forward"`` or ``"orbit"``.
      box_noise: pixels (Gaussian per edge). texture_noise: metres.
      pose_noise: (metres, radians) Gaussian noise of the pose priors.
      size_noise: relative Gaussian noise of each object's radii around the class mean.
      capacity: optional ``(T, M, J)`` padding (see :func:`jaxsem.slam.make_problem`).

    Returns:
      ``(problem, truth)``: a :class:`SlamProblem` and the true :class:`SlamEstimate`.
    """
    rng = np.random.default_rng(seed)
    W, H = image_size
    K = np.array([[focal, 0, W / 2], [0, focal, H / 2], [0, 0, 1.0]])
    mean = np.array(F.shape_prior(class_name).mean)
    scale = mean[0] / 2.44  # patch sized to the class (cars: about 30 m)
    radii = mean * (1 + size_noise * rng.normal(size=(num_objects, 3)))
    radii = np.clip(radii, 0.3 * mean, None)
    if path == "forward":
        x = rng.uniform(5, 40, num_objects) * scale
        y = rng.choice([-1, 1], num_objects) * rng.uniform(3, 8, num_objects) * scale
    else:
        x = rng.uniform(-8, 8, num_objects) * scale
        y = rng.uniform(-8, 8, num_objects) * scale
    center = np.stack([x, y, radii[:, 2]], -1)
    rotation = _yaw(rng.uniform(-np.pi, np.pi, num_objects))
    if path == "forward":
        xs = np.linspace(-10, 35, num_frames) * scale
        eyes = np.stack([xs, np.zeros_like(xs), np.full_like(xs, 1.5 * scale)], -1)
        poses = np.asarray(Q.look_at(eyes, eyes + np.array([1.0, 0, 0])))
    elif path == "orbit":
        a = np.linspace(0, 2 * np.pi, num_frames, endpoint=False)
        eyes = np.stack([25 * np.cos(a), 25 * np.sin(a), np.full_like(a, 1.5)], -1) * scale
        poses = np.asarray(Q.look_at(eyes, np.zeros(3)))
    else:
        raise ValueError(f"path: expected 'forward' or 'orbit', got {path!r}")
    box, valid = Q.project_bbox(rotation[None], center[None], radii[None], K, poses[:, None])
    depth, _ = Q.texture_plane_depth(rotation[None], center[None], radii[None], poses[:, None])
    box, valid, depth = np.asarray(box), np.asarray(valid), np.asarray(depth)
    box = box + box_noise * rng.normal(size=box.shape)
    clipped = np.stack(
        [
            np.clip(box[..., 0], 0, W),
            np.clip(box[..., 1], 0, H),
            np.clip(box[..., 2], 0, W),
            np.clip(box[..., 3], 0, H),
        ],
        -1,
    )
    area = np.prod(np.maximum(clipped[..., 2:] - clipped[..., :2], 0), -1)
    full = np.prod(np.maximum(box[..., 2:] - box[..., :2], 1e-9), -1)
    seen = valid & (area > 100) & (area > 0.3 * full)
    t_idx, j_idx = np.nonzero(seen)
    boxes = clipped[t_idx, j_idx]
    tex = depth[t_idx, j_idx] + texture_noise * rng.normal(size=len(t_idx))
    omegas, shifts = [], []
    for _ in poses:  # the draws interleave per pose: rotation noise, then translation noise
        omegas.append(rng.normal(0.0, pose_noise[1], 3))
        shifts.append(rng.normal(0, pose_noise[0], 3))
    noise = np.asarray(Q.rigid_transform(Q.so3_exp(np.stack(omegas)), np.stack(shifts)), np.float64)
    noisy = noise @ poses
    problem = make_problem(
        K,
        [W, H],
        noisy,
        boxes,
        t_idx,
        j_idx,
        [class_name] * num_objects,
        texture_depth=tex,
        capacity=capacity,
    )
    values = [poses, rotation, center, radii]
    if capacity is not None:
        Tc, _, Jc = capacity
        values = [
            np.concatenate([poses, np.broadcast_to(np.eye(4), (Tc - num_frames, 4, 4))]),
            np.concatenate([rotation, np.broadcast_to(np.eye(3), (Jc - num_objects, 3, 3))]),
            np.concatenate([center, np.zeros((Jc - num_objects, 3))]),
            np.concatenate([radii, np.ones((Jc - num_objects, 3))]),
        ]

    dtype = problem.K.dtype
    truth = SlamEstimate(*(jnp.asarray(a, dtype) for a in values))
    return problem, truth


def frames_from_problem(problem, max_detections: int = 16):
    """Splits a :class:`SlamProblem` into per-pose :class:`Frame` s (for the online smoother);
    the association id is the object index. Returns a list of frames, one per real pose."""
    out = []
    box = np.asarray(problem.box)
    bp = np.asarray(problem.box_pose)
    bo = np.asarray(problem.box_object)
    bm = np.asarray(problem.box_mask)
    td = np.asarray(problem.texture_depth)
    tm = np.asarray(problem.texture_mask)
    cls = np.asarray(problem.object_class)
    for t in np.flatnonzero(np.asarray(problem.pose_mask)):
        sel = bm & (bp == t)
        out.append(
            make_frame(
                np.asarray(problem.pose_prior[t]),
                box[sel],
                cls[bo[sel]],
                bo[sel],
                np.where(tm[sel], td[sel], np.nan),
                max_detections=max_detections,
                dtype=problem.K.dtype,
                image_size=np.asarray(problem.image_size),
            )
        )
    return out


def few_views():
    """Three nearby views of one car: a forward-like, ill-posed setting where the shape prior matters.

    Returns ``(problem, radii)``: the :class:`SlamProblem` (exact boxes and texture-plane depths,
    640 x 480 images, f = 525 px) and the car's true semi-axis radii (3,) as a float64 numpy array.
    """
    K = np.array([[525.0, 0.0, 320.0], [0.0, 525.0, 240.0], [0.0, 0.0, 1.0]])
    R = np.asarray(Q.quaternion_to_rotation(jnp.array([np.cos(0.2), 0.0, 0.0, np.sin(0.2)])))
    c = np.array([15.0, 2.0, 0.8])
    r = np.array([2.6, 0.95, 0.8])
    eyes = np.array([[0.0, 0.0, 1.5], [1.0, 0.1, 1.5], [2.0, 0.0, 1.5]])
    poses = np.asarray(Q.look_at(eyes, eyes + np.array([1.0, 0.0, 0.0])))
    box, _ = Q.project_bbox(R, c, r, K, poses)
    depth, _ = Q.texture_plane_depth(R, c, r, poses)
    problem = make_problem(
        K, [640, 480], poses, np.asarray(box), [0, 1, 2], [0, 0, 0], ["car"], texture_depth=np.asarray(depth)
    )
    return problem, r
