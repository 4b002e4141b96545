"""VoluMon input pipeline: fixed-shape batches of detections from a FAT-layout split.

Host-side numpy/OpenCV (data loading is not traced). A *sample* is one object in one frame. Each
batch carries what the network sees (a local patch of the input box and the masked global image),
what the losses need (the clean left box, the right box, K, the stereo baseline, the class and
surface points from mask + depth) and, for evaluation only, the ground-truth pose and size.

Determinism: the order of epoch ``e`` is a permutation drawn from ``(seed, e)`` and every random
augmentation of step ``s`` from ``(seed, e, s)``, so ``batch(e, s)`` is a pure function and a
training run resumed at any step sees exactly the batches of an uninterrupted one.

Augmentations (thesis 5.5.1-5.5.2; each off when its parameter is 0):

- box noise: the *input* box (crop and global mask) has each edge moved by
  ``N(0, box_noise * box size)``; the loss keeps the clean box (``box`` vs ``input_box``);
- hue / saturation jitter: hue shifted by ``U(-hue_jitter, hue_jitter)`` of the colour circle,
  saturation scaled by ``U(1 - saturation_jitter, 1 + saturation_jitter)``, the same for the
  patch and the global image of a sample;
- random erasing (torchvision's ``RandomErasing``: probability ``erase_prob``, area fraction in
  ``erase_scale``, aspect ratio in (0.3, 3.3), value 0) on the local patch.

Documented skips, never NaN:

- objects whose clean box extends past the image are dropped when the split is loaded
  (``drop_truncated``, as the thesis filters FAT), and so are boxes smaller than
  ``min_box_size`` pixels; :func:`crop_inputs` on its own accepts any box that overlaps the image
  (the part outside is zero) and raises ``ValueError`` for one that does not;
- a right box that is missing or extends past the right image (its edge is the border, not the
  object) gets ``has_right_box`` False, with the sample kept: a dual loss must mask its right term;
- an object with an empty mask or no positive depth on it gets ``points_mask`` all False (its
  ``points`` are zeros) and ``has_points`` False: a primal loss must weigh points by the mask.
"""

from __future__ import annotations

import dataclasses
import math
import pathlib
from collections.abc import Iterator, Sequence

import cv2
import numpy as np

from ..._checks import check_fields
from ...data import FatFrame, FatSequence

__all__ = [
    "PipelineConfig",
    "VolumonDataset",
    "crop_inputs",
    "mask_depth_points",
    "find_scenes",
    "thesis_config",
    "as_volumon_batch",
    "SHAPE_IDS",
]


@dataclasses.dataclass(frozen=True)
class PipelineConfig:
    """Sizes and augmentations of the VoluMon input pipeline.

    Attributes:
      patch_size: side of the local patch (64 for the CPU config, 224 in the thesis).
      global_size: side of the masked global image (non-uniformly resized, as the thesis).
      global_margin: padding of the kept region around the input box, as a fraction of the
        box's width / height (plus ``global_margin_px`` pixels).
      n_points: surface points per sample (drawn with replacement from the object's pixels).
      erode_mask: pixels eroded from the object mask before taking points (0 = none).
      box_noise, hue_jitter, saturation_jitter, erase_prob, erase_scale: augmentations (see the
        module docstring); used only when the dataset is built with ``augment=True``.
      drop_truncated: drop objects whose box extends past the image; min_box_size: drop boxes
        narrower or shorter than this many pixels.
      image_scale: images are resized by this factor when the split is loaded (K and boxes
        scaled to match), to hold large splits such as FAT's 960 x 540 frames in memory.
      max_points_per_object: surface points kept per object at load time (a seeded random
        subset; batches draw ``n_points`` from them).
    """

    patch_size: int = 64
    global_size: int = 64
    global_margin: float = 0.1
    global_margin_px: float = 2.0
    n_points: int = 256
    erode_mask: int = 0
    box_noise: float = 0.0
    hue_jitter: float = 0.05
    saturation_jitter: float = 0.3
    erase_prob: float = 0.5
    erase_scale: tuple = (0.02, 0.2)
    drop_truncated: bool = True
    min_box_size: float = 2.0
    image_scale: float = 1.0
    max_points_per_object: int = 4096

    def __post_init__(self):
        if not 0 < self.image_scale <= 1:
            raise ValueError(f"PipelineConfig.image_scale: expected in (0, 1], got {self.image_scale}")
        counts = ("patch_size", "global_size", "n_points", "max_points_per_object")
        check_fields(self, counts, "a positive integer", lambda v: int(v) >= 1, prefix="PipelineConfig.")
        margins = ("global_margin", "global_margin_px", "box_noise", "hue_jitter", "saturation_jitter", "erode_mask")
        check_fields(self, margins, ">= 0", lambda v: v >= 0, prefix="PipelineConfig.")
        if not 0 <= self.erase_prob <= 1:
            raise ValueError(f"PipelineConfig.erase_prob: expected in [0, 1], got {self.erase_prob}")
        lo, hi = self.erase_scale
        if not 0 < lo <= hi < 1:
            raise ValueError(f"PipelineConfig.erase_scale: expected 0 < lo <= hi < 1, got {self.erase_scale}")


def thesis_config(**changes) -> PipelineConfig:
    """The thesis-sized pipeline (224 x 224 inputs); keyword arguments override fields."""
    return dataclasses.replace(PipelineConfig(patch_size=224, global_size=224), **changes)


def _check_image(image) -> np.ndarray:
    image = np.asarray(image)
    if image.dtype != np.uint8:
        raise ValueError(f"image: expected dtype uint8 (RGB 0-255), got {image.dtype} with shape {image.shape}")
    if image.ndim != 3 or image.shape[2] != 3 or image.shape[0] < 1 or image.shape[1] < 1:
        raise ValueError(f"image: expected shape (H, W, 3), got {image.shape}")
    return image


def _check_box(box, width, height, name="box") -> np.ndarray:
    box = np.asarray(box, np.float64)
    if box.shape != (4,) or not np.all(np.isfinite(box)):
        raise ValueError(f"{name}: expected 4 finite numbers [u_min, v_min, u_max, v_max], got {box.tolist()}")
    if box[2] <= box[0] or box[3] <= box[1]:
        raise ValueError(f"{name}: expected u_max > u_min and v_max > v_min, got {box.tolist()}")
    if box[2] <= -0.5 or box[0] >= width - 0.5 or box[3] <= -0.5 or box[1] >= height - 0.5:
        raise ValueError(f"{name}: {box.tolist()} lies entirely outside the {width}x{height} image")
    return box


def _crop(image: np.ndarray, box: np.ndarray, size: int) -> np.ndarray:
    """Sub-pixel crop of ``box`` (pixel-centre coordinates) of a uint8 image, resized to
    ``size`` x ``size``, float32 in [0, 1]; zero outside the image.

    Only the box's pixels (plus one for interpolation) are converted to float, so the cost does
    not grow with the image.
    """
    h, w = image.shape[:2]
    x0 = int(np.clip(math.floor(box[0]) - 1, 0, w - 1))
    y0 = int(np.clip(math.floor(box[1]) - 1, 0, h - 1))
    x1 = int(np.clip(math.ceil(box[2]) + 2, x0 + 1, w))
    y1 = int(np.clip(math.ceil(box[3]) + 2, y0 + 1, h))
    roi = image[y0:y1, x0:x1].astype(np.float32) * np.float32(1.0 / 255.0)
    sx = size / (box[2] - box[0])
    sy = size / (box[3] - box[1])
    # Output pixel centre x' = (x - u_min) * sx - 0.5 maps the box edges onto the patch edges
    # (a box spanning the whole image, [-0.5, -0.5, W - 0.5, H - 0.5], is the identity at size W);
    # x is counted from the region's corner (x0, y0). Pixels outside the image stay zero.
    M = np.array([[sx, 0.0, -(box[0] - x0) * sx - 0.5], [0.0, sy, -(box[1] - y0) * sy - 0.5]])
    return cv2.warpAffine(roi, M, (size, size), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)


def _masked_global(image: np.ndarray, box: np.ndarray, size: int, margin: float, margin_px: float) -> np.ndarray:
    """The uint8 image with everything outside the padded box zeroed, resized non-uniformly to
    ``size`` x ``size``, float32 in [0, 1]."""
    h, w = image.shape[:2]
    mx = margin * (box[2] - box[0]) + margin_px
    my = margin * (box[3] - box[1]) + margin_px
    u0, u1 = max(0, math.ceil(box[0] - mx)), min(w, math.floor(box[2] + mx) + 1)
    v0, v1 = max(0, math.ceil(box[1] - my)), min(h, math.floor(box[3] + my) + 1)
    kept = np.zeros_like(image)
    kept[v0:v1, u0:u1] = image[v0:v1, u0:u1]
    interp = cv2.INTER_AREA if size < min(h, w) else cv2.INTER_LINEAR
    # Resizing in float keeps averages exact (uint8 resizing rounds).
    return cv2.resize(kept.astype(np.float32) * np.float32(1.0 / 255.0), (size, size), interpolation=interp)


def crop_inputs(image, boxes, patch_size: int = 64, global_size: int = 64, margin: float = 0.1, margin_px: float = 2.0):
    """The two network inputs for each box of one image.

    Args:
      image: (H, W, 3) uint8 RGB.
      boxes: (n, 4) or (4,) ``[u_min, v_min, u_max, v_max]`` pixels; each must overlap the image.
      patch_size, global_size: output sides; margin, margin_px: padding of the global mask.

    Returns:
      patches (n, patch_size, patch_size, 3) and globals (n, global_size, global_size, 3),
      float32 in [0, 1]: the box crop (sub-pixel, zero outside the image) and the whole image
      with everything outside the padded box set to zero, resized non-uniformly.
    """
    image = _check_image(image)
    boxes = np.asarray(boxes, np.float64)
    single = boxes.ndim == 1
    boxes = boxes.reshape(-1, 4) if boxes.size else np.zeros((0, 4))
    h, w = image.shape[:2]
    patches = np.zeros((len(boxes), patch_size, patch_size, 3), np.float32)
    globs = np.zeros((len(boxes), global_size, global_size, 3), np.float32)
    for i, b in enumerate(boxes):
        b = _check_box(b, w, h, f"boxes[{i}]")
        patches[i] = _crop(image, b, patch_size)
        globs[i] = _masked_global(image, b, global_size, margin, margin_px)
    if single:
        return patches[0], globs[0]
    return patches, globs


def mask_depth_points(depth, mask, K, erode: int = 0) -> np.ndarray:
    """3D points (M, 3) in the camera frame of the mask's pixels that have a positive depth.

    Args:
      depth: (H, W) z-depth in metres (0 or negative = unknown); mask: (H, W) bool; K: (3, 3).
      erode: pixels to erode the mask by first (drops mixed depth at silhouettes).

    Returns:
      float32 (M, 3); M = 0 for an empty mask or no valid depth (a documented skip, no error).
    """
    depth = np.asarray(depth)
    mask = np.asarray(mask, bool)
    if depth.ndim != 2 or mask.shape != depth.shape:
        raise ValueError(f"depth, mask: expected equal (H, W) shapes, got {depth.shape} and {mask.shape}")
    if not np.issubdtype(depth.dtype, np.floating):
        raise ValueError(f"depth: expected floating metres, got dtype {depth.dtype} (scale uint16 PNGs first)")
    K = np.asarray(K, np.float64)
    if erode > 0 and mask.any():
        mask = cv2.erode(mask.astype(np.uint8), np.ones((2 * erode + 1, 2 * erode + 1), np.uint8)) > 0
    ok = mask & np.isfinite(depth) & (depth > 0)
    vs, us = np.nonzero(ok)
    z = depth[vs, us].astype(np.float64)
    y = (vs - K[1, 2]) / K[1, 1]
    x = (us - K[0, 2] - K[0, 1] * y) / K[0, 0]
    return np.stack([x * z, y * z, z], axis=1).astype(np.float32)


def find_scenes(path) -> list:
    """Scene directories (holding ``_camera_settings.json``) at or below ``path``, sorted."""
    path = pathlib.Path(path)
    if not path.is_dir():
        raise FileNotFoundError(f"dataset directory missing: {path}")
    if (path / "_camera_settings.json").is_file():
        return [path]
    return sorted(p.parent for p in path.rglob("_camera_settings.json"))


def _rescale(image, scale):
    """Resize by ``scale``; returns the image, the K update and a box map (pixel-centre coords)."""
    h, w = image.shape[:2]
    nw, nh = max(1, int(round(w * scale))), max(1, int(round(h * scale)))
    sx, sy = nw / w, nh / h
    out = cv2.resize(image, (nw, nh), interpolation=cv2.INTER_AREA)
    # Edge coordinates (x + 0.5) scale; pixel-centre coordinates follow.
    S = np.array([[sx, 0.0, 0.5 * sx - 0.5], [0.0, sy, 0.5 * sy - 0.5], [0.0, 0.0, 1.0]])

    def box_map(b):
        return np.array(
            [(b[0] + 0.5) * sx - 0.5, (b[1] + 0.5) * sy - 0.5, (b[2] + 0.5) * sx - 0.5, (b[3] + 0.5) * sy - 0.5]
        )

    return out, S, box_map


# Ground-truth shape of a class: FAT objects are cuboids; the synthetic writer records the shape.
SHAPE_IDS = {"box": 0, "ellipsoid": 1, "cylinder": 2}


def extra_of(frame: FatFrame, i: int) -> dict:
    return frame.extra[i] if i < len(frame.extra) else {}


def as_volumon_batch(batch: dict) -> dict:
    """Rename a :class:`VolumonDataset` batch to the keys of :mod:`jaxsem.volumon`'s training loop.

    ``local`` / ``global`` (network inputs), ``box_input`` (noisy input box), ``box_left`` /
    ``box_right`` (clean labels), ``K``, ``baseline``, ``points``, ``point_mask``, ``class_id``,
    ``sample_mask`` (``valid`` of an evaluation batch and ``has_right_box``: a sample whose right
    box is unusable is left out; an empty point set is already masked by ``point_mask``) and
    ground truth ``gt_rotation``, ``gt_center``, ``gt_half_extents`` (half the cuboid extents) and
    ``gt_shape_id`` (0 cuboid, 1 ellipsoid; a cylinder is scored as its bounding cuboid, 0).
    """
    sample_mask = np.asarray(batch["has_right_box"], bool)
    if "valid" in batch:
        sample_mask = sample_mask & np.asarray(batch["valid"], bool)
    shape = np.asarray(batch["shape_id"])
    return {
        "local": batch["patch"],
        "global": batch["global_image"],
        "box_input": batch["input_box"],
        "box_left": batch["box"],
        "box_right": batch["box_right"],
        "K": batch["K"],
        "baseline": batch["baseline"],
        "points": batch["points"],
        "point_mask": batch["points_mask"],
        "class_id": batch["class_id"],
        "sample_mask": sample_mask,
        "gt_rotation": batch["rotation"],
        "gt_center": batch["center"],
        "gt_half_extents": np.asarray(batch["dimensions"]) / 2,
        "gt_shape_id": np.where(shape == SHAPE_IDS["ellipsoid"], 1, 0).astype(np.int32),
    }


@dataclasses.dataclass
class _Frame:
    image: np.ndarray
    K: np.ndarray
    baseline: float


class VolumonDataset:
    """A split held in memory; yields fixed-shape VoluMon batches.

    Args:
      frames: :class:`FatFrame` objects (e.g. from :meth:`from_directory`).
      config: :class:`PipelineConfig`.
      class_names: the class list (class id = index). ``None``: sorted names found in ``frames``.
        Objects of other classes are skipped.
      augment: apply the augmentations of ``config`` (training) or not (evaluation).
      seed: seed of the epoch order and of the augmentations.

    Attributes:
      num_samples, class_names, skipped (dict reason -> count of objects dropped).

    A batch (``B`` samples) is a dict of numpy arrays: ``patch`` (B, P, P, 3) and
    ``global_image`` (B, G, G, 3) float32 in [0, 1]; ``input_box`` (B, 4) the (noisy) box the
    inputs were cut from and ``box`` (B, 4) the clean left box; ``box_right`` (B, 4) with
    ``has_right_box`` (B,); ``K`` (B, 3, 3); ``baseline`` (B,) metres (right camera at +x);
    ``image_size`` (B, 2) ``(W, H)``; ``class_id`` (B,) int32; ``points`` (B, n_points, 3) in the
    left camera frame with ``points_mask`` (B, n_points) and ``has_points`` (B,); ground truth for
    evaluation only: ``rotation`` (B, 3, 3) object-to-camera, ``center`` (B, 3), ``dimensions``
    (B, 3) full cuboid extents, ``shape_id`` (B,) (see ``SHAPE_IDS``); ``index`` (B,) sample
    numbers; and ``valid`` (B,) in evaluation batches. :func:`as_volumon_batch` renames them for
    :mod:`jaxsem.volumon`.
    """

    def __init__(
        self,
        frames: Sequence[FatFrame],
        config: PipelineConfig = PipelineConfig(),
        *,
        class_names: Sequence[str] | None = None,
        augment: bool = False,
        seed: int = 0,
    ):
        self.config = config
        self.augment = bool(augment)
        self.seed = int(seed)
        if self.seed < 0:
            raise ValueError(f"seed: expected a non-negative integer, got {seed}")
        frames = list(frames)
        if class_names is None:
            class_names = sorted({n for fr in frames for n in fr.class_names})
        self.class_names = tuple(class_names)
        ids = {n: i for i, n in enumerate(self.class_names)}
        self._frames: list[_Frame] = []
        self.skipped = {"truncated": 0, "small": 0, "unknown_class": 0}
        rows = []
        load_rng = np.random.default_rng([self.seed, 2**32 - 2])
        for fi, fr in enumerate(frames):
            image = _check_image(fr.image)
            h, w = image.shape[:2]
            if config.image_scale != 1.0:
                image, scale_K, scale_box = _rescale(image, config.image_scale)
            else:
                scale_K, scale_box = np.eye(3), (lambda b: b)
            self._frames.append(_Frame(image, scale_K @ np.asarray(fr.K, np.float64), float(fr.baseline)))
            for i, name in enumerate(fr.class_names):
                box = fr.boxes_left[i]
                if name not in ids:
                    self.skipped["unknown_class"] += 1
                    continue
                if config.drop_truncated and (box[0] < -0.5 or box[1] < -0.5 or box[2] > w - 0.5 or box[3] > h - 0.5):
                    self.skipped["truncated"] += 1
                    continue
                sbox = scale_box(box)
                if min(sbox[2] - sbox[0], sbox[3] - sbox[1]) < config.min_box_size:
                    self.skipped["small"] += 1
                    continue
                rb = fr.boxes_right[i]
                right_ok = bool(fr.has_right_box[i]) and not (
                    rb[0] < -0.5 or rb[1] < -0.5 or rb[2] > w - 0.5 or rb[3] > h - 0.5
                )
                pts = mask_depth_points(fr.depth, fr.seg == i, fr.K, config.erode_mask)
                if len(pts) > config.max_points_per_object:
                    pts = pts[np.sort(load_rng.choice(len(pts), config.max_points_per_object, replace=False))]
                rows.append(
                    dict(
                        frame=len(self._frames) - 1,
                        class_id=ids[name],
                        box=scale_box(box.copy()),
                        box_right=scale_box(fr.boxes_right[i].copy()),
                        has_right_box=right_ok,
                        points=pts,
                        rotation=fr.rotation[i].copy(),
                        center=fr.center[i].copy(),
                        dimensions=fr.dimensions[i].copy(),
                        source=f"{fr.path}#{i}",
                        shape_id=SHAPE_IDS.get(str(extra_of(fr, i).get("shape", "box")), 0),
                    )
                )
        self._rows = rows

    @classmethod
    def from_directory(cls, path, config: PipelineConfig = PipelineConfig(), *, loader_options=None, **kwargs):
        """Load every scene at or below ``path`` (a split directory or one scene)."""
        frames = []
        for scene in find_scenes(path):
            frames.extend(FatSequence(scene, **(loader_options or {})))
        return cls(frames, config, **kwargs)

    @property
    def num_samples(self) -> int:
        return len(self._rows)

    def __len__(self) -> int:
        return len(self._rows)

    def steps_per_epoch(self, batch_size: int) -> int:
        """Full batches per epoch (the incomplete last batch of an epoch is dropped)."""
        return len(self._rows) // int(batch_size)

    def epoch_order(self, epoch: int) -> np.ndarray:
        return np.random.default_rng([self.seed, int(epoch)]).permutation(len(self._rows))

    def batch(self, epoch: int, step: int, batch_size: int) -> dict:
        """Training batch ``step`` of ``epoch`` (pure function of seed, epoch, step)."""
        steps = self.steps_per_epoch(batch_size)
        if steps == 0:
            raise ValueError(f"batch_size: {batch_size} exceeds the {len(self._rows)} samples of the dataset")
        if int(epoch) < 0:
            raise ValueError(f"epoch: expected >= 0, got {epoch}")
        if not 0 <= step < steps:
            raise ValueError(f"step: expected 0 <= step < {steps} (steps per epoch), got {step}")
        idx = self.epoch_order(epoch)[step * batch_size : (step + 1) * batch_size]
        rng = np.random.default_rng([self.seed, int(epoch), int(step), 1])
        return self._make(idx, rng, self.augment)

    def batch_at(self, global_step: int, batch_size: int) -> dict:
        """Batch number ``global_step`` counted across epochs (for resuming at a step)."""
        steps = self.steps_per_epoch(batch_size)
        if steps == 0:
            raise ValueError(f"batch_size: {batch_size} exceeds the {len(self._rows)} samples of the dataset")
        return self.batch(global_step // steps, global_step % steps, batch_size)

    def epoch(self, epoch: int, batch_size: int, start_step: int = 0) -> Iterator[dict]:
        for s in range(int(start_step), self.steps_per_epoch(batch_size)):
            yield self.batch(epoch, s, batch_size)

    def eval_batches(self, batch_size: int) -> Iterator[dict]:
        """Every sample once, in order, without augmentation; the last batch is padded by
        repeating its final sample, with ``valid`` False on the padding."""
        n = len(self._rows)
        for start in range(0, n, batch_size):
            idx = np.arange(start, min(start + batch_size, n))
            valid = np.ones(batch_size, bool)
            valid[len(idx) :] = False
            idx = np.concatenate([idx, np.full(batch_size - len(idx), idx[-1])])
            rng = np.random.default_rng([self.seed, 2**32 - 1, start])  # not an epoch's stream
            out = self._make(idx, rng, False)
            out["valid"] = valid
            yield out

    # ----------------------------------------------------------------------------------------

    def _noisy_box(self, rng, box, w, h):
        c = self.config
        size = np.array([box[2] - box[0], box[3] - box[1]] * 2)
        for _ in range(10):
            noisy = box + rng.normal(size=4) * c.box_noise * size
            noisy = np.clip(noisy, -0.5, [w - 0.5, h - 0.5, w - 0.5, h - 0.5])
            if noisy[2] - noisy[0] >= 1 and noisy[3] - noisy[1] >= 1:
                return noisy
        return box.copy()

    def _colour_jitter(self, rng, images):
        c = self.config
        dh = rng.uniform(-c.hue_jitter, c.hue_jitter) * 360.0
        ds = rng.uniform(1 - c.saturation_jitter, 1 + c.saturation_jitter)
        out = []
        for im in images:
            hsv = cv2.cvtColor(im, cv2.COLOR_RGB2HSV)  # float32: H in [0, 360), S, V in [0, 1]
            h, sat, v = cv2.split(hsv)
            h = h + np.float32(dh)  # as cv2.add (a float32 sum)
            h[h >= 360.0] -= 360.0
            h[h < 0.0] += 360.0
            sat = np.minimum((sat.astype(np.float64) * ds).astype(np.float32), np.float32(1.0))  # as cv2.multiply
            rgb = cv2.cvtColor(cv2.merge([h, sat, v]), cv2.COLOR_HSV2RGB)
            out.append(np.clip(rgb, 0.0, 1.0, out=rgb))
        return out

    def _erase(self, rng, patch):
        c = self.config
        if rng.random() >= c.erase_prob:
            return patch
        p = patch.shape[0]
        for _ in range(10):
            area = rng.uniform(*c.erase_scale) * p * p
            ratio = math.exp(rng.uniform(math.log(0.3), math.log(3.3)))
            eh, ew = int(round(math.sqrt(area * ratio))), int(round(math.sqrt(area / ratio)))
            if 0 < eh < p and 0 < ew < p:
                y, x = rng.integers(0, p - eh + 1), rng.integers(0, p - ew + 1)
                patch = patch.copy()
                patch[y : y + eh, x : x + ew] = 0.0
                return patch
        return patch

    def _make(self, idx, rng, augment: bool) -> dict:
        c = self.config
        B, P, G, N = len(idx), int(c.patch_size), int(c.global_size), int(c.n_points)
        out = {
            "patch": np.zeros((B, P, P, 3), np.float32),
            "global_image": np.zeros((B, G, G, 3), np.float32),
            "input_box": np.zeros((B, 4), np.float32),
            "box": np.zeros((B, 4), np.float32),
            "box_right": np.zeros((B, 4), np.float32),
            "has_right_box": np.zeros(B, bool),
            "K": np.zeros((B, 3, 3), np.float32),
            "baseline": np.zeros(B, np.float32),
            "image_size": np.zeros((B, 2), np.float32),
            "class_id": np.zeros(B, np.int32),
            "points": np.zeros((B, N, 3), np.float32),
            "points_mask": np.zeros((B, N), bool),
            "has_points": np.zeros(B, bool),
            "rotation": np.zeros((B, 3, 3), np.float32),
            "center": np.zeros((B, 3), np.float32),
            "dimensions": np.zeros((B, 3), np.float32),
            "shape_id": np.zeros(B, np.int32),
            "index": np.asarray(idx, np.int32),
        }
        for b, i in enumerate(idx):
            row = self._rows[i]
            fr = self._frames[row["frame"]]
            h, w = fr.image.shape[:2]
            box = row["box"]
            in_box = self._noisy_box(rng, box, w, h) if augment and c.box_noise > 0 else box
            patch = _crop(fr.image, in_box, P)
            glob = _masked_global(fr.image, in_box, G, c.global_margin, c.global_margin_px)
            if augment and (c.hue_jitter > 0 or c.saturation_jitter > 0):
                patch, glob = self._colour_jitter(rng, [patch, glob])
            if augment and c.erase_prob > 0:
                patch = self._erase(rng, patch)
            pts = row["points"]
            if len(pts):
                out["points"][b] = pts[rng.integers(0, len(pts), N)]
                out["points_mask"][b] = True
                out["has_points"][b] = True
            out["patch"][b], out["global_image"][b] = patch, glob
            out["input_box"][b], out["box"][b] = in_box, box
            out["box_right"][b], out["has_right_box"][b] = row["box_right"], row["has_right_box"]
            out["K"][b], out["baseline"][b], out["image_size"][b] = fr.K, fr.baseline, (w, h)
            out["class_id"][b] = row["class_id"]
            out["rotation"][b], out["center"][b], out["dimensions"][b] = (
                row["rotation"],
                row["center"],
                row["dimensions"],
            )
            out["shape_id"][b] = row["shape_id"]
        return out
