"""Stereo views of one known object, rendered with VoluMon's exact ray caster.

:func:`render_object_stereo` draws one textured object of a VoluMon class at a given
camera-frame pose, over a random background, in a calibrated stereo pair: what the training data
of :mod:`jaxsem.volumon` looks like, but with the pose chosen by the caller (e.g. a simulated map
seen along a camera path, to feed the network the objects that ROSHAN also sees). The renderer
is :func:`jaxsem.volumon._synthetic.render_sample` (exact analytic ray casting); the boxes are
the exact image boxes of the shape (:func:`jaxsem.quadrics.shape_bbox`: projected cuboid
corners, cylinder rims, or the ellipsoid's dual conic).
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .. import quadrics
from ._synthetic import CLASSES, SHAPE_IDS, render_sample

__all__ = ["StereoView", "render_object_stereo"]


class StereoView(NamedTuple):
    """A rendered stereo pair of one object.

    Attributes:
      left, right: (H, W, 3) float32 images in [0, 1] (right camera at ``+baseline`` along the
        left camera's x axis).
      depth: (H, W) left depth (m, 0 = background); mask: (H, W) bool, left object pixels.
      box_left, box_right: (4,) exact image boxes ``[u_min, v_min, u_max, v_max]`` (unclipped).
    """

    left: jax.Array
    right: jax.Array
    depth: jax.Array
    mask: jax.Array
    box_left: jax.Array
    box_right: jax.Array


@functools.partial(jax.jit, static_argnames=("height", "width", "split_test"))
def _render(noise_l, noise_r, R, t, half, shape_id, color, K, baseline, height, width, split_test):
    right_T_left = quadrics.stereo_right_T_left(baseline, K.dtype)
    R_r, t_r = quadrics.camera_frame(R, t, right_T_left)
    pose_l = {"rotation": R, "center": t, "half": half, "shape_id": shape_id, "color": color}
    pose_r = dict(pose_l, rotation=R_r, center=t_r)
    left, depth, mask = render_sample(noise_l, pose_l, K, height, width, split_test)
    right, _, _ = render_sample(noise_r, pose_r, K, height, width, split_test)
    eye = jnp.eye(4, dtype=K.dtype)
    box_l, _ = quadrics.shape_bbox(R, t, half, shape_id, K, eye)
    box_r, _ = quadrics.shape_bbox(R, t, half, shape_id, K, right_T_left)
    return StereoView(left, right, depth, mask, box_l, box_r)


def render_object_stereo(
    rotation,
    center,
    half_extents,
    class_id: int,
    K,
    baseline: float,
    height: int,
    width: int,
    seed: int,
    *,
    split_test: bool = False,
) -> StereoView:
    """One object of VoluMon class ``class_id`` at a camera-frame pose, in a stereo pair.

    Args:
      rotation: (3, 3) object-to-camera (left camera, OpenCV axes); center: (3,) camera frame (m).
      half_extents: (3,) the shape's half extents (m) along its axes (for an ellipsoid its radii;
        a cylinder's axis is object z).
      class_id: row of :data:`jaxsem.volumon._device_data.CLASSES` (its shape and base colour).
      K: (3, 3) intrinsics; baseline: stereo baseline (m, > 0); height, width: image size.
      seed: numpy seed of the light and the background (the same seed gives the same picture).
      split_test: the held-out background style (stripes in unseen colours).

    Returns:
      :class:`StereoView`. Compiles once per image size (the pose is traced).
    """
    R = np.asarray(rotation, np.float32)
    t = np.asarray(center, np.float32)
    half = np.asarray(half_extents, np.float32)
    K = np.asarray(K, np.float32)
    if R.shape != (3, 3) or not np.all(np.isfinite(R)):
        raise ValueError(f"rotation: expected a finite (3, 3) matrix, got shape {R.shape}")
    if t.shape != (3,) or not np.all(np.isfinite(t)):
        raise ValueError(f"center: expected finite (3,), got {t.tolist()}")
    if half.shape != (3,) or not np.all(np.isfinite(half)) or np.any(half <= 0):
        raise ValueError(f"half_extents: expected three positive numbers, got {half.tolist()}")
    if K.shape != (3, 3) or not np.all(np.isfinite(K)):
        raise ValueError(f"K: expected finite (3, 3) intrinsics, got shape {K.shape}")
    if not 0 <= int(class_id) < len(CLASSES):
        raise ValueError(f"class_id: expected an int in [0, {len(CLASSES)}), got {class_id!r}")
    if not (np.isfinite(baseline) and baseline > 0):
        raise ValueError(f"baseline: expected a positive number, got {baseline!r}")
    if int(height) < 1 or int(width) < 1:
        raise ValueError(f"height, width: expected positive ints, got {height}, {width}")
    _, shape, _, color = CLASSES[int(class_id)]
    rng = np.random.default_rng(int(seed))

    def noise():
        return {
            "light": rng.normal(size=3).astype(np.float32),
            "bg0": rng.uniform(size=3).astype(np.float32),
            "bg1": rng.uniform(size=3).astype(np.float32),
            "bg_noise": rng.normal(size=(int(height), int(width), 3)).astype(np.float32),
        }

    noise_l = noise()
    noise_r = dict(noise_l, bg_noise=rng.normal(size=(int(height), int(width), 3)).astype(np.float32))
    return _render(
        noise_l,
        noise_r,
        R,
        t,
        half,
        np.int32(SHAPE_IDS[shape]),
        np.asarray(color, np.float32),
        K,
        np.float32(baseline),
        int(height),
        int(width),
        bool(split_test),
    )
