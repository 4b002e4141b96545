"""Network inputs from an image and a box: the local patch and the masked global image (fig. 5-2).

Both are jittable and vmappable (one image per call; ``jax.vmap`` over a batch):

- :func:`crop_and_resize`: bilinear resampling of the box contents to ``S x S`` (non-uniform
  scale, as the thesis' resize);
- :func:`masked_global_image`: the whole image, everything outside the box (enlarged by
  ``padding`` times its size) set to zero, resized to ``S x S``;
- :func:`prepare_inputs`: both, with input checks at the Python boundary.

Pixel convention (OpenCV): pixel ``(row i, col j)`` has its centre at ``(u, v) = (j, i)``.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np


def _bilinear(image, u, v):
    """Sample image (H, W, C) at continuous pixel coordinates u (..), v (..); clamped at borders."""
    H, W = image.shape[0], image.shape[1]
    u = jnp.clip(u, 0.0, W - 1.0)
    v = jnp.clip(v, 0.0, H - 1.0)
    u0 = jnp.clip(jnp.floor(u), 0, W - 2).astype(jnp.int32)
    v0 = jnp.clip(jnp.floor(v), 0, H - 2).astype(jnp.int32)
    du = (u - u0.astype(u.dtype))[..., None]
    dv = (v - v0.astype(v.dtype))[..., None]
    a = image[v0, u0]
    b = image[v0, u0 + 1]
    c = image[v0 + 1, u0]
    d = image[v0 + 1, u0 + 1]
    return (a * (1 - du) + b * du) * (1 - dv) + (c * (1 - du) + d * du) * dv


def crop_and_resize(image, box, size: int):
    """Box contents (H, W, C) -> (size, size, C) by bilinear sampling at the output pixel centres."""
    image = jnp.asarray(image)
    box = jnp.asarray(box, image.dtype)
    s = (jnp.arange(size, dtype=image.dtype) + 0.5) / size
    w = box[2] - box[0]
    h = box[3] - box[1]
    u = box[0] + s * w
    v = box[1] + s * h
    uu, vv = jnp.meshgrid(u, v)
    return _bilinear(image, uu, vv)


def masked_global_image(image, box, size: int, padding: float = 0.1):
    """Whole image with everything outside the padded box zeroed, resized to (size, size, C)."""
    image = jnp.asarray(image)
    H, W = image.shape[0], image.shape[1]
    box = jnp.asarray(box, image.dtype)
    pw = padding * (box[2] - box[0])
    ph = padding * (box[3] - box[1])
    cols = jnp.arange(W, dtype=image.dtype)
    rows = jnp.arange(H, dtype=image.dtype)
    inside = ((cols >= box[0] - pw) & (cols <= box[2] + pw))[None, :] & ((rows >= box[1] - ph) & (rows <= box[3] + ph))[
        :, None
    ]
    masked = jnp.where(inside[..., None], image, 0.0)
    full = jnp.array([-0.5, -0.5, W - 0.5, H - 0.5], image.dtype)
    return crop_and_resize(masked, full, size)


def check_image_and_boxes(image, boxes, name_image="image", name_boxes="boxes"):
    """Python-boundary checks: image (H, W, 3) uint8 or float in [0, 1]; boxes (N, 4) inside it.

    Raises ValueError naming the argument, its shape/value and what was expected.
    """
    img = np.asarray(image)
    if img.ndim != 3 or img.shape[-1] != 3:
        raise ValueError(f"{name_image}: expected shape (H, W, 3), got {img.shape}")
    if img.dtype == np.uint8:
        pass
    elif np.issubdtype(img.dtype, np.floating):
        if img.size and (not np.all(np.isfinite(img)) or img.min() < 0 or img.max() > 1):
            raise ValueError(
                f"{name_image}: float images must be finite and in [0, 1], got range [{img.min()}, {img.max()}]"
            )
    else:
        raise ValueError(f"{name_image}: expected dtype uint8 or float in [0, 1], got {img.dtype}")
    b = np.asarray(boxes, np.float64)
    if b.ndim != 2 or b.shape[-1] != 4:
        raise ValueError(f"{name_boxes}: expected shape (N, 4) [u_min, v_min, u_max, v_max], got {b.shape}")
    H, W = img.shape[:2]
    for i, bb in enumerate(b):
        if not np.all(np.isfinite(bb)):
            raise ValueError(f"{name_boxes}[{i}]: expected finite values, got {bb.tolist()}")
        if not (bb[2] > bb[0] and bb[3] > bb[1]):
            raise ValueError(f"{name_boxes}[{i}]: expected u_max > u_min and v_max > v_min, got {bb.tolist()}")
        if bb[0] < -0.5 or bb[1] < -0.5 or bb[2] > W - 0.5 or bb[3] > H - 0.5:
            raise ValueError(
                f"{name_boxes}[{i}]: box {bb.tolist()} extends outside the {W}x{H} image "
                f"(expected -0.5 <= u <= {W - 0.5}, -0.5 <= v <= {H - 0.5})"
            )
    return img, b


def to_float_image(image):
    """uint8 -> float32 in [0, 1]; float images are kept (as float32)."""
    image = jnp.asarray(image)
    if image.dtype == jnp.uint8:
        return image.astype(jnp.float32) / 255.0
    return image.astype(jnp.float32)


def prepare_inputs(image, boxes, size: int | None = None, padding: float | None = None, *, config=None):
    """One image (H, W, 3) and its boxes (N, 4) -> (local (N, S, S, 3), global (N, S, S, 3)) float32.

    ``size`` and ``padding`` must be the ones the network was trained with: the explicit
    arguments, else those of ``config`` (a VoluMon config, or its ``model`` part, e.g. the third
    value of :func:`jaxsem.volumon.load_pretrained`, or any object with ``input_size`` and
    ``global_padding``). There is no fixed default here (a default of 64 once fed the 48-pixel
    shipped model crops of the wrong scale with no error): :func:`jaxsem.volumon.prepare_inputs`
    falls back to the shipped object model's values; this one raises ValueError.

    Checks the input at the Python boundary (see :func:`check_image_and_boxes`); use the jittable
    :func:`crop_and_resize` / :func:`masked_global_image` inside traced code.
    """
    check_image_and_boxes(image, boxes)
    model = getattr(config, "model", config)
    if config is not None and not hasattr(model, "input_size"):
        raise ValueError(f"config: expected a VoluMon config (or its model part), got {type(config).__name__}")
    if model is not None:
        size = model.input_size if size is None else size
        padding = model.global_padding if padding is None else padding
    if size is None or padding is None:
        raise ValueError(
            "size, padding: expected both (the network's input size and global padding) or a config, "
            f"got size={size!r}, padding={padding!r} and no config"
        )
    size, padding = int(size), float(padding)
    if size < 8:
        raise ValueError(f"size: expected an input size of at least 8 pixels, got {size}")
    return _prepare(to_float_image(image), jnp.asarray(boxes, jnp.float32), size, padding)


@functools.partial(jax.jit, static_argnums=(2, 3))
def _prepare(img, boxes, size, padding):
    local = jax.vmap(lambda bb: crop_and_resize(img, bb, size))(boxes)
    glob = jax.vmap(lambda bb: masked_global_image(img, bb, size, padding))(boxes)
    return local, glob
