"""A fast, exact, jittable ray-cast generator of VoluMon training samples (no files, no GPU).

Each sample is one textured object (a cuboid like the FAT cracker box, or an ellipsoid) at a
random pose in front of a stereo camera, over a random background. Ray casting is analytic (the
geometry core's :func:`jaxsem.quadrics.ray_cast_local`), so the depth, mask and surface points
are exact and the left/right boxes are the exact projections (cuboid corners / closed-form dual
conic). Samples are a pure function of ``(seed, index)``, which makes data order reproducible
for exact resumes.

Used by the training loop, tests and benchmarks when the MuJoCo dataset of :mod:`jaxsem.volumon.data`
is not wanted; its batches have the same keys as the training loop expects (see
:func:`make_batch`).

Backgrounds: ``split="train"`` uses smooth two-colour gradients plus noise; ``split="test"``
adds stripes in unseen colours (the "unseen backgrounds" held-out split).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from .. import classes as _classes
from ..quadrics import (
    back_project,
    invert_pose,
    quaternion_wxyz_to_rotation,
    ray_cast_local,
    rigid_transform,
    shape_bbox,
)
from ._inputs import crop_and_resize, masked_global_image

#: VoluMon's tabletop classes, rows of :data:`jaxsem.classes.CLASSES` (the one class table):
#: (name, shape, full dimensions (m), base colour). Indices are what ``SceneConfig.classes``
#: and the multi-class head use.
VOLUMON_CLASS_NAMES = ("cracker_box", "ball", "melon", "soup_can")
CLASSES = tuple((c.name, c.shape, tuple(c.dimensions), tuple(c.color)) for c in map(_classes.get, VOLUMON_CLASS_NAMES))
#: shape ids of the generators and losses
SHAPE_IDS = {"cuboid": 0, "ellipsoid": 1, "cylinder": 2}


@dataclasses.dataclass(frozen=True)
class SceneConfig:
    """Camera and sampling ranges of the generator.

    Attributes:
      height, width, focal: image size and focal length (pixels); principal point at the centre.
      baseline: stereo baseline (m), right camera along +x of the left.
      depth_range: centroid depth range (m).
      classes: indices into :data:`CLASSES` sampled uniformly.
      size_jitter: relative size variation per sample.
      num_points: surface points per sample (sampled from the mask).
      box_noise: std of the noisy input box (fraction of the box size) for the "Noisy" variant.
    """

    height: int = 96
    width: int = 128
    focal: float = 110.0
    baseline: float = 0.06
    depth_range: tuple[float, float] = (0.45, 1.1)
    classes: tuple[int, ...] = (0,)
    size_jitter: float = 0.05
    num_points: int = 64
    box_noise: float = 0.05

    def K(self):
        return np.array(
            [[self.focal, 0, (self.width - 1) / 2], [0, self.focal, (self.height - 1) / 2], [0, 0, 1]], np.float32
        )


_FACE_TINTS = np.array(
    [[1.0, 1.0, 1.0], [0.55, 0.55, 0.55], [1.0, 0.85, 0.35], [0.35, 0.45, 1.0], [0.3, 1.0, 0.5], [1.0, 0.4, 0.9]]
)


def render_sample(noise, pose, K, height: int, width: int, split_test: bool):
    """Render one sample; ``pose`` is a dict of traced scene parameters (see :func:`sample_poses`),
    ``noise`` a dict of host-drawn random numbers (``light`` (3,), ``bg0``, ``bg1`` (3,), ``bg_noise``
    (H, W, 3)): drawn with numpy, because threefry sampling costs seconds of XLA compile per call.

    Returns image (H, W, 3) float32 in [0, 1], depth (H, W) (0 = background), mask (H, W) bool.
    """
    R, t, half, shape_id, color = pose["rotation"], pose["center"], pose["half"], pose["shape_id"], pose["color"]
    vs, us = jnp.meshgrid(jnp.arange(height, dtype=jnp.float32), jnp.arange(width, dtype=jnp.float32), indexing="ij")
    rays = back_project(jnp.stack([us, vs], -1), 1.0, K, jnp.eye(4, dtype=K.dtype))  # camera frame, z = 1
    object_T_camera = invert_pose(rigid_transform(R, t))
    o = jnp.broadcast_to(object_T_camera[:3, 3], rays.shape)
    d = rays @ R  # R^T ray, row-vector form
    s, hit, n_obj = ray_cast_local(o, d, half, shape_id)
    depth = s  # rays have z = 1, so the ray parameter is the z-depth (0 where no hit)
    # texture: tint by the dominant local axis of the hit point (orientation is visible)
    p_local = o + s[..., None] * d
    q = p_local / half
    ax = jnp.argmax(jnp.abs(q), -1)
    sgn = (jnp.take_along_axis(q, ax[..., None], -1)[..., 0] > 0).astype(ax.dtype)
    tint = jnp.asarray(_FACE_TINTS, color.dtype)[2 * ax + sgn]
    n_cam = n_obj @ R.T
    light = noise["light"] * 0.5 + jnp.array([0.3, -0.6, -1.0], noise["light"].dtype)
    light = light / jnp.linalg.norm(light)
    shade = 0.4 + 0.6 * jnp.clip(jnp.sum(n_cam * light, -1), 0.0, 1.0)  # light: towards the camera
    obj_rgb = color * tint * shade[..., None]
    g = (us / width)[..., None]
    bg = noise["bg0"] * (1 - g) + noise["bg1"] * g + 0.08 * noise["bg_noise"]
    stripes = 0.5 + 0.5 * jnp.sin((us + 0.7 * vs) / 4.0)[..., None] * jnp.array([0.9, 0.2, 0.6], us.dtype)
    bg = jnp.where(split_test, 0.5 * bg + 0.5 * stripes, bg)
    image = jnp.clip(jnp.where(hit[..., None], obj_rgb, bg), 0.0, 1.0)
    return image.astype(jnp.float32), depth.astype(jnp.float32), hit


def sample_poses(seed: int, indices, scene: SceneConfig):
    """Host-side scene parameters of samples ``indices`` (deterministic in (seed, index))."""
    out = {k: [] for k in ("rotation", "center", "half", "shape_id", "color", "class_id")}
    K = np.asarray(scene.K(), np.float64)
    eye = np.eye(4)
    # host code in a per-sample loop: the geometry core runs on numpy here (xp=np)
    for i in np.asarray(indices).ravel():
        rng = np.random.default_rng([int(seed), int(i)])
        cls = scene.classes[rng.integers(len(scene.classes))]
        _, shape, dims, color = CLASSES[cls]
        half = 0.5 * np.asarray(dims) * (1 + scene.size_jitter * rng.uniform(-1, 1, 3))
        q = rng.normal(size=4)
        R = quaternion_wxyz_to_rotation(q, xp=np)
        z = rng.uniform(*scene.depth_range)
        rmax = np.linalg.norm(half)
        margin = scene.focal * rmax / max(z - rmax, 1e-3) + 2
        u = rng.uniform(margin, max(scene.width - 1 - margin, margin + 1e-3))
        v = rng.uniform(margin, max(scene.height - 1 - margin, margin + 1e-3))
        center = back_project(np.array([u, v]), z, K, eye, xp=np)
        out["rotation"].append(R)
        out["center"].append(center)
        out["half"].append(half)
        out["shape_id"].append(SHAPE_IDS[shape])
        out["color"].append(np.asarray(color) * rng.uniform(0.85, 1.15))
        out["class_id"].append(cls)
    return {k: np.asarray(v, np.int32 if k in ("shape_id", "class_id") else np.float32) for k, v in out.items()}


def sample_noise(seed: int, indices, scene: SceneConfig):
    """Host-drawn random numbers of the rendering (deterministic in (seed, index))."""
    H, W = scene.height, scene.width
    out = {k: [] for k in ("light", "bg0", "bg1", "bg_noise", "box_noise", "point_scores")}
    for i in np.asarray(indices).ravel():
        rng = np.random.default_rng([int(seed), int(i), 1])
        out["light"].append(rng.normal(size=3))
        out["bg0"].append(rng.uniform(size=3))
        out["bg1"].append(rng.uniform(size=3))
        out["bg_noise"].append(rng.normal(size=(H, W, 3)))
        out["box_noise"].append(rng.normal(size=4))
        out["point_scores"].append(rng.uniform(size=H * W))
    return {k: jnp.asarray(np.asarray(v, np.float32)) for k, v in out.items()}


def _true_box(pose, K, camera_T):
    box, _ = shape_bbox(pose["rotation"], pose["center"], pose["half"], pose["shape_id"], K, camera_T)
    return box


def _render_batch(
    noise, poses, K, baseline, scene: SceneConfig, input_size: int, padding: float, split_test: bool, noisy_scale
):
    H, W, J = scene.height, scene.width, scene.num_points

    def one(noise, pose):
        image, depth, mask = render_sample(noise, pose, K, H, W, split_test)
        eye = jnp.eye(4, dtype=jnp.float32)
        right = eye.at[0, 3].set(-baseline)
        box_l = _true_box(pose, K, eye)
        box_r = _true_box(pose, K, right)
        size = box_l[2:] - box_l[:2]
        box_in = box_l + noisy_scale * noise["box_noise"] * jnp.concatenate([size, size])
        box_in = jnp.concatenate([jnp.minimum(box_in[:2], box_in[2:] - 1.0), box_in[2:]])
        box_in = jnp.clip(box_in, -0.5, jnp.array([W - 0.5, H - 0.5, W - 0.5, H - 0.5], box_in.dtype))
        # surface points: J distinct mask pixels drawn uniformly (top-k of random scores; far
        # cheaper on CPU than categorical sampling), back-projected with the depth
        scores = jnp.where(mask.ravel(), noise["point_scores"], -1.0)
        any_hit = jnp.any(mask)
        _, idx = jax.lax.top_k(scores, J)
        r, c = idx // W, idx % W
        z = depth[r, c]
        pts = back_project(jnp.stack([c, r], -1).astype(K.dtype), z, K, eye)
        pmask = mask[r, c] & any_hit
        inside = (box_l[0] >= -0.5) & (box_l[1] >= -0.5) & (box_l[2] <= W - 0.5) & (box_l[3] <= H - 0.5)
        return {
            "local": crop_and_resize(image, box_in, input_size),
            "global": masked_global_image(image, box_in, input_size, padding),
            "box_input": box_in,
            "box_left": box_l,
            "box_right": box_r,
            "points": pts,
            "point_mask": pmask,
            "sample_mask": inside & any_hit,
            "image": image,
        }

    return jax.vmap(one)(noise, poses)


_render_batch_jit = jax.jit(_render_batch, static_argnames=("scene", "input_size", "padding", "split_test"))


def make_batch(
    seed: int,
    indices,
    scene: SceneConfig = SceneConfig(),
    input_size: int = 64,
    padding: float = 0.1,
    split: str = "train",
    noisy: bool = False,
    keep_images: bool = False,
):
    """A batch for the training loop / evaluation, as a dict of arrays with leading batch axis B.

    Keys: ``local``, ``global`` (B, S, S, 3) network inputs (from the noisy box when ``noisy``);
    ``box_input`` (B, 4) the box fed to f; ``box_left``, ``box_right`` (B, 4) clean labels;
    ``K`` (B, 3, 3); ``baseline`` (B,); ``points`` (B, J, 3), ``point_mask`` (B, J);
    ``class_id`` (B,); ``sample_mask`` (B,) (False: box leaves the image or object not visible,
    a documented skip); ground truth ``gt_rotation`` (B, 3, 3) object-to-camera, ``gt_center``
    (B, 3), ``gt_half_extents`` (B, 3), ``gt_shape_id`` (B,) (0 cuboid, 1 ellipsoid); and ``image``
    (B, H, W, 3) if ``keep_images``.
    """
    if split not in ("train", "test"):
        raise ValueError(f"split: expected 'train' or 'test', got {split!r}")
    indices = np.asarray(indices).ravel()
    poses = sample_poses(seed + (0 if split == "train" else 7919), indices, scene)
    noise = sample_noise(seed + (0 if split == "train" else 7919), indices, scene)
    jp = {k: jnp.asarray(v) for k, v in poses.items() if k != "class_id"}
    class_id = jnp.asarray(poses["class_id"])
    return _batch_dict(
        _render_batch_jit, noise, jp, class_id, scene, input_size, padding, split == "test", noisy, keep_images
    )


def _batch_dict(
    render, noise, poses, class_id, scene: SceneConfig, input_size, padding, split_test, noisy, keep_images: bool
) -> dict:
    """A batch's dict: ``render`` (:func:`_render_batch` or its jitted form) of the sampled
    ``noise`` and ``poses`` (their arrays), with the camera, class ids (``class_id`` (B,)) and
    ground-truth poses added, ``image`` dropped unless ``keep_images``; shared by the host
    (:func:`make_batch`) and device batches."""
    K = jnp.asarray(scene.K())
    out = dict(
        render(
            noise,
            poses,
            K,
            jnp.float32(scene.baseline),
            scene,
            int(input_size),
            float(padding),
            bool(split_test),
            jnp.float32(scene.box_noise if noisy else 0.0),
        )
    )
    if not keep_images:
        out.pop("image")
    B = class_id.shape[0]
    out["K"] = jnp.broadcast_to(K, (B, 3, 3))
    out["baseline"] = jnp.full((B,), scene.baseline, jnp.float32)
    out["class_id"] = class_id
    out["gt_rotation"] = poses["rotation"]
    out["gt_center"] = poses["center"]
    out["gt_half_extents"] = poses["half"]
    out["gt_shape_id"] = poses["shape_id"]
    out["class_shape"] = poses["shape_id"]  # the class's shape (class table), what shape-aware losses may use
    return out
