"""VoluMon's single-view ellipsoids as ROSHAN's initial landmarks (thesis section 6.3).

The thesis' outlook: a network such as VoluMon (chapter 5) gives each new object a full 3D
estimate from one image; ROSHAN (chapter 4) then refines it online with boxes and texture planes.
:func:`volumon_initial_ellipsoids` runs a VoluMon model on one image and its boxes and returns the
ellipsoids in the WORLD frame, ready for :func:`jaxsem.slam.make_frame` 's ``init_*`` arguments
(a new object then starts there instead of at :func:`jaxsem.factors.single_view_init`).

The camera-to-world step is :func:`jaxsem.quadrics.camera_frame` with the inverse pose
(:func:`jaxsem.quadrics.invert_pose`); nothing is re-derived here.

The network is monocular at inference (stereo pairs only supervise its training, section 5.3),
and its depth comes through a pseudo-disparity with the training camera's ``b f``
(``config.recon.baseline_focal``): give it images from a camera with that focal length (the
shipped model: 128 x 96, f = 110 px; ``config.scene``), or the depth scales with the mismatch.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from .. import quadrics, volumon
from .._checks import require_type
from ..quadrics import Camera, Ellipsoid

__all__ = ["volumon_initial_ellipsoids"]


@jax.jit
def _to_world(rotation, center, radii, camera_T_world):
    """Camera-frame ellipsoids (N, ...) seen from ``camera_T_world`` (4, 4) -> world frame, with a
    validity mask; invalid rows (non-finite, behind the camera, non-positive radii) become the
    identity / origin / unit radii so that nothing downstream sees NaN."""
    dtype = camera_T_world.dtype
    rotation, center, radii = rotation.astype(dtype), center.astype(dtype), radii.astype(dtype)
    world_T_camera = quadrics.invert_pose(camera_T_world)
    R_w, c_w = quadrics.camera_frame(rotation, center, world_T_camera[None])
    finite = (
        jnp.all(jnp.isfinite(rotation), axis=(-2, -1))
        & jnp.all(jnp.isfinite(center), axis=-1)
        & jnp.all(jnp.isfinite(radii), axis=-1)
        & jnp.all(jnp.isfinite(R_w), axis=(-2, -1))
        & jnp.all(jnp.isfinite(c_w), axis=-1)
    )
    valid = finite & (center[..., 2] > 0) & jnp.all(radii > 0, axis=-1)
    eye = jnp.eye(3, dtype=dtype)
    R_w = jnp.where(valid[:, None, None], R_w, eye)
    c_w = jnp.where(valid[:, None], c_w, 0.0)
    r = jnp.where(valid[:, None], radii, 1.0)
    return R_w, c_w, r, valid


def volumon_initial_ellipsoids(model, variables, config, image, boxes, class_id, camera: Camera):
    """World-frame ellipsoids of a VoluMon model for the boxes of one image.

    Args:
      model, variables, config: a VoluMon network, its flax variables and its
        :class:`jaxsem.volumon.TrainConfig` (e.g. ``model, variables, config, _ =
        jaxsem.volumon.load_pretrained()``).
      image: (H, W, 3) uint8, or float in [0, 1] (the left image of a stereo pair; the network
        reads one image).
      boxes: (N, 4) pixel boxes ``[u_min, v_min, u_max, v_max]`` inside the image.
      class_id: (N,) ints, the network's class rows (the shipped model:
        :data:`jaxsem.volumon.VOLUMON_CLASS_NAMES` order) or one int for all boxes.
      camera: the image's :class:`jaxsem.quadrics.Camera`: ``K`` (3, 3) intrinsics (see the module
        docstring about the focal length) and ``camera_T_world`` (4, 4) (world-to-camera, OpenCV
        axes).

    Returns:
      ``(ellipsoid, valid)``: a :class:`jaxsem.quadrics.Ellipsoid` of N world ellipsoids
      (rotation (N, 3, 3) object-to-world, center (N, 3), radii (N, 3) semi-axes in metres) in
      ``camera_T_world`` 's float dtype, and valid (N,) bool. Where ``valid`` is False (a
      non-finite prediction, a centre behind the camera) the row is identity / origin / ones.

    Compiles once per number of boxes (the network and the transform are jitted). Raises
    ``ValueError`` naming the argument on bad shapes or non-finite values.
    """

    K, camera_T_world = require_type("camera", camera, Camera)
    boxes_np = np.asarray(boxes, np.float64)
    if boxes_np.ndim != 2 or boxes_np.shape[-1] != 4:
        raise ValueError(f"boxes: expected shape (N, 4), got {boxes_np.shape}")
    n = boxes_np.shape[0]
    K_np = np.asarray(K, np.float64)
    if K_np.shape != (3, 3) or not np.all(np.isfinite(K_np)) or K_np[0, 0] <= 0 or K_np[1, 1] <= 0:
        raise ValueError(f"camera.K: expected finite (3, 3) intrinsics with fx, fy > 0, got shape {K_np.shape}")
    pose = np.asarray(camera_T_world)
    if pose.shape != (4, 4) or not np.all(np.isfinite(pose)):
        raise ValueError(f"camera.camera_T_world: expected a finite (4, 4) pose, got shape {pose.shape}")
    if not np.issubdtype(pose.dtype, np.floating):
        pose = pose.astype(float)
    cls = np.broadcast_to(np.asarray(class_id), (n,)) if np.ndim(class_id) == 0 else np.asarray(class_id)
    num_classes = int(config.model.num_classes)
    if cls.shape != (n,) or not np.issubdtype(cls.dtype, np.integer) or np.any((cls < 0) | (cls >= num_classes)):
        raise ValueError(f"class_id: expected {n} ints in [0, {num_classes}), got {np.asarray(class_id).tolist()}")
    # prepare_inputs checks the image and that every box lies inside it (ValueError naming them)
    local, glob = volumon.prepare_inputs(image, boxes_np, config.model.input_size, config.model.global_padding)
    predict = volumon.make_predict_fn(model, config)
    _, ell, _ = predict(
        variables,
        local,
        glob,
        jax.device_put(boxes_np.astype(np.float32)),
        jax.device_put(np.broadcast_to(K_np.astype(np.float32), (n, 3, 3))),
        jax.device_put(cls.astype(np.int32)),
    )
    dtype = jnp.result_type(pose.dtype) if jax.config.read("jax_enable_x64") else jnp.float32
    R, c, r, valid = _to_world(ell.rotation, ell.center, ell.radii, jax.device_put(pose.astype(dtype)))
    return Ellipsoid(R, c, r), valid
