"""Training data made on the device: a whole VoluMon batch from one PRNG key, inside ``jit``.

:func:`device_batch` draws the scene parameters (class, size, pose, colour), the rendering noise
(light, backgrounds, pixel noise), the noisy input box, the surface-point scores and the
augmentation numbers with ``jax.random``, and renders stereo boxes, depth, masks and network
inputs with the exact ray-caster of :mod:`jaxsem.volumon._synthetic` (boxes and corners from
:mod:`jaxsem.quadrics`). Nothing runs on the host: the train step calls it with
``jax.random.fold_in(key, step)`` and compiles once. The host generator
:func:`jaxsem.volumon.make_batch` (numpy draws per sample: host-bound, so an accelerator does not
make it faster) stays for the old-against-new benchmark and for samples
indexed by ``(seed, index)``.

Keys: :func:`train_key` and :func:`eval_key` derive the training and held-out streams from a
user seed, so a held-out seed never shares a stream with any training seed; held-out batches add
stripes in unseen colours to the backgrounds (``split_test=True``), as ``make_batch(split="test")``.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from ..quadrics import back_project, quaternion_wxyz_to_rotation
from ._synthetic import CLASSES, SHAPE_IDS, SceneConfig, _batch_dict, _render_batch

_TRAIN_STREAM = 0x5EED
_EVAL_STREAM = 0xE7A1


def train_key(seed: int):
    """PRNG key of the training stream of ``seed`` (fold in the step for the batch of that step)."""
    return jax.random.fold_in(jax.random.PRNGKey(int(seed)), _TRAIN_STREAM)


def eval_key(seed: int):
    """PRNG key of the held-out stream of ``seed`` (disjoint from every :func:`train_key`)."""
    return jax.random.fold_in(jax.random.PRNGKey(int(seed)), _EVAL_STREAM)


def _class_tables(scene: SceneConfig):
    ids = np.asarray(scene.classes, np.int32)
    dims = np.asarray([CLASSES[i][2] for i in ids], np.float32)
    colors = np.asarray([CLASSES[i][3] for i in ids], np.float32)
    shapes = np.asarray([SHAPE_IDS[CLASSES[i][1]] for i in ids], np.int32)
    return ids, dims, colors, shapes


def sample_scene(key, scene: SceneConfig):
    """Scene parameters and rendering noise of one sample, drawn with ``jax.random`` (jittable).

    Returns ``(pose, noise, class_id)``: ``pose`` with ``rotation`` (3, 3) object-to-camera,
    ``center`` (3,), ``half`` (3,) half extents, ``shape_id`` (), ``color`` (3,); ``noise`` with
    ``light`` (3,), ``bg0``, ``bg1`` (3,), ``bg_noise`` (H, W, 3), ``box_noise`` (4,),
    ``point_scores`` (H * W,). The same distributions as the host generator
    (:func:`jaxsem.volumon._synthetic.sample_poses`).
    """
    ids, dims, colors, shapes = _class_tables(scene)
    f32 = jnp.float32  # the renderer's dtype (the host generator's too), with or without x64
    H, W = scene.height, scene.width
    k = jax.random.split(key, 11)
    c = jax.random.randint(k[0], (), 0, len(ids))
    jitter = jax.random.uniform(k[1], (3,), f32, minval=-1, maxval=1)
    half = 0.5 * jnp.asarray(dims)[c] * (1 + scene.size_jitter * jitter)
    q = jax.random.normal(k[2], (4,), f32)
    R = quaternion_wxyz_to_rotation(q)
    z = jax.random.uniform(k[3], (), f32, minval=scene.depth_range[0], maxval=scene.depth_range[1])
    rmax = jnp.linalg.norm(half)
    margin = scene.focal * rmax / jnp.maximum(z - rmax, 1e-3) + 2
    lo = margin
    hi_u = jnp.maximum(W - 1 - margin, margin + 1e-3)
    hi_v = jnp.maximum(H - 1 - margin, margin + 1e-3)
    uv01 = jax.random.uniform(k[4], (2,), f32)
    uv = jnp.stack([lo + uv01[0] * (hi_u - lo), lo + uv01[1] * (hi_v - lo)])
    K = jnp.asarray(scene.K())
    center = back_project(uv, z, K, jnp.eye(4, dtype=K.dtype))
    pose = {
        "rotation": R,
        "center": center,
        "half": half,
        "shape_id": jnp.asarray(shapes)[c],
        "color": jnp.asarray(colors)[c] * jax.random.uniform(k[5], (), f32, minval=0.85, maxval=1.15),
    }
    # one uniform draw per pixel and channel: unit-variance background noise (uniform, not
    # normal: threefry normals cost ~3x more on a CPU) and, from channel 0, the scores that pick
    # the surface points (they only matter on the object, where the background is not seen)
    u = jax.random.uniform(k[9], (H, W, 3), f32)
    noise = {
        "light": jax.random.normal(k[6], (3,), f32),
        "bg0": jax.random.uniform(k[7], (3,), f32),
        "bg1": jax.random.uniform(k[8], (3,), f32),
        "bg_noise": (u - 0.5) * float(np.sqrt(12.0)),
        "box_noise": jax.random.normal(k[10], (4,), f32),
        "point_scores": u[..., 0].reshape(H * W),
    }
    return pose, noise, jnp.asarray(ids)[c]


def augmentation_numbers(key, batch_size: int, erase_prob: float = 0.5):
    """The augmentation numbers of :func:`jaxsem.volumon._train.augment`, drawn with ``jax.random``."""
    k = jax.random.split(key, 6)
    B = batch_size
    rect = jnp.concatenate(
        [
            jax.random.uniform(k[0], (B, 2)),
            jax.random.uniform(k[1], (B, 2), minval=0.1, maxval=0.4),
        ],
        -1,
    )
    return {
        "hue": jax.random.uniform(k[2], (B,), minval=-0.2 * np.pi, maxval=0.2 * np.pi),
        "sat": jax.random.uniform(k[3], (B,), minval=0.7, maxval=1.3),
        "erase_rect": rect,
        "erase_on": jax.random.uniform(k[4], (B,)) < erase_prob,
        "erase_val": jax.random.uniform(k[5], (B, 3)),
    }


_DEFAULT_SCENE = SceneConfig()


def device_batch(
    key,
    batch_size: int,
    scene: SceneConfig = _DEFAULT_SCENE,
    input_size: int = 64,
    padding: float = 0.1,
    split_test: bool = False,
    noisy: bool = False,
    keep_images: bool = False,
):
    """A VoluMon batch (same keys as :func:`jaxsem.volumon.make_batch`) from one PRNG key; jittable.

    Args:
      key: PRNG key (e.g. ``jax.random.fold_in(train_key(seed), step)``).
      batch_size, scene, input_size, padding, split_test, noisy, keep_images: static settings
        (``noisy``: box noise on the network input, clean boxes as labels).

    Returns:
      dict of arrays with leading axis ``batch_size``: ``local``, ``global`` (B, S, S, 3),
      ``box_input``, ``box_left``, ``box_right`` (B, 4), ``K`` (B, 3, 3), ``baseline`` (B,),
      ``points`` (B, J, 3), ``point_mask`` (B, J), ``class_id``, ``sample_mask`` (B,), ground truth
      ``gt_rotation``, ``gt_center``, ``gt_half_extents``, ``gt_shape_id``; ``image`` if
      ``keep_images``.
    """
    keys = jax.random.split(key, batch_size)
    poses, noise, class_id = jax.vmap(lambda k: sample_scene(k, scene))(keys)
    return _batch_dict(
        _render_batch, noise, poses, class_id, scene, input_size, padding, split_test, noisy, keep_images
    )


device_batch_jit = jax.jit(
    device_batch,
    static_argnames=(
        "batch_size",
        "scene",
        "input_size",
        "padding",
        "split_test",
        "noisy",
        "keep_images",
    ),
)


@functools.lru_cache(maxsize=8)
def _eval_batches_fn(batch_size, scene, input_size, padding, noisy, keep_images):
    return jax.jit(lambda key: device_batch(key, batch_size, scene, input_size, padding, True, noisy, keep_images))


def held_out_set(
    seed: int,
    num: int,
    scene: SceneConfig,
    input_size: int = 64,
    padding: float = 0.1,
    noisy: bool = False,
    keep_images: bool = False,
    batch_size: int = 32,
):
    """``num`` held-out samples of seed ``seed`` (unseen backgrounds), as one dict of arrays.

    Deterministic in ``(seed, num, batch_size, scene)``; made in batches of ``batch_size`` with one
    compiled function.
    """
    if int(num) < 1:
        raise ValueError(f"num: expected a positive number of held-out samples, got {num}")
    fn = _eval_batches_fn(
        int(batch_size),
        scene,
        int(input_size),
        float(padding),
        bool(noisy),
        bool(keep_images),
    )
    key = eval_key(seed)
    parts = [fn(jax.random.fold_in(key, i)) for i in range(-(-int(num) // int(batch_size)))]
    return {k: jnp.concatenate([p[k] for p in parts])[: int(num)] for k in parts[0]}
