"""VoluMon R-CNN (thesis 5.7): one network that detects objects and lifts each to an ellipsoid.

A two-stage detector in the style of Faster R-CNN with the VoluMon head of figure 5-8:

- **backbone**: MobileNetV2 cut at stride 16 (its first 13 inverted residual blocks), the
  thesis' choice, or a plain stride-16 CNN (``backbone="plain_cnn"``: pairs of full 3 x 3
  convolutions, the CPU preset: XLA's CPU depthwise convolutions make MobileNetV2 several times
  slower to train there, as for VoluMon's ``small_cnn``);
- **region proposals**: a 3 x 3 conv over the features, objectness and box deltas for
  ``len(anchor_sizes) x len(aspect_ratios)`` anchors per cell; the top ``pre_nms`` by score go
  through fixed-shape non-maximum suppression (:func:`jaxsem.models.nms`) to ``proposals`` boxes;
- **RoI features**: bilinear RoI pooling (:func:`jaxsem.models.roi_align`) of each proposal into
  ``roi_size x roi_size`` cells, two fully connected layers;
- **heads** on the RoI feature: class logits (background + N classes), class-agnostic box deltas,
  and the ``N x 10`` VoluMon free parameters (with the RoI's box features, as the VoluMon network
  reads its box), which :func:`reconstruct` turns into an ellipsoid given the detected box and the
  intrinsics (eq. 5.17). Outside training the VoluMon head reads by default the features
  pooled a second time at each RoI's refined box, the box it is reconstructed in
  (``RCNNConfig.lift_at``).

The free parameters of a detection are the row of its class (*VoluMon R-CNN Multi-Class*) or the
expectation under the predicted class probabilities (eq. 5.18, *Multi-Class Expectation*):
``RCNNConfig.param_rule``.

Every shape is static: ``proposals`` RoIs and ``max_detections`` detections per image, the
padding masked. Images come in at ``input_size``; boxes are in that image's pixels and the
intrinsics are scaled to it by the caller (:func:`jaxsem.volumon.rcnn_inputs`).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import TYPE_CHECKING, Any, NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import optax

from .._checks import check_fields
from ..quadrics import Ellipsoid, box_iou
from ._detect import nms, roi_align
from ._mobilenet import ConvBN, InvertedResidual, block_layout, make_divisible
from ._volumon import (
    ROTATION_INITS,
    ReconstructionConfig,
    VoluMonConfig,
    VoluMonNet,
    _head_bias_init,
    box_features,
    expected_params,
    reconstruct,
    select_class_params,
)

PARAM_RULES = ("class", "expectation")
LIFT_AT = ("refined", "proposal")
LIFT_FEATURES = ("shared", "own", "stage", "backbone", "volumon")
_OWN_LIFT_FEATURES = ("own", "stage", "backbone")  # the lift's own RoI layers over pooled features
#: The "volumon" lift's crops: pixels per side, its encoders' first width and its heads' layers, as
#: the shipped LM-O VoluMon network's (``input_size`` 48, ``small_cnn`` of width 24, ``hidden`` 128).
VOLUMON_LIFT_INPUT = 48
VOLUMON_LIFT_WIDTH = 24
VOLUMON_LIFT_HIDDEN = (128,)
_VOLUMON_LIFT_PADDING = 0.1  # the global crop's box padding, as VoluMon's ``global_padding``
BACKBONES = ("mobilenet_v2", "plain_cnn")
_LIFT8_SCALE = 0.02  # lift_stride8's branch output multiplier (see VoluMonRCNN)
_STRIDE16_BLOCKS = 13  # MobileNetV2's first 13 inverted residual blocks end at stride 16
_STRIDE8_BLOCKS = 6  # ... and the first 6 at stride 8
_MAX_LOG_SCALE = math.log(1000.0 / 16)


@dataclasses.dataclass(frozen=True)
class RCNNConfig:
    """Sizes and rules of :class:`VoluMonRCNN` (a CPU-sized default).

    Attributes:
      num_classes: N object classes (class 0 of the logits is the background).
      input_size: ``(W, H)`` of the network's image; multiples of 16.
      backbone: "mobilenet_v2" or "plain_cnn" (module docstring).
      width_multiplier: MobileNetV2 width.
      cnn_width: channels of the first ``plain_cnn`` stage (then 2x, 4x, 8x).
      anchor_sizes: anchor side lengths in input pixels; aspect_ratios: height / width.
      pre_nms, proposals: proposals kept before and after the proposal NMS (``rpn_nms`` IoU).
      roi_size: RoI pooling cells per side; hidden: width of the RoI head's layers.
      max_detections: detections per image; score_threshold, det_nms: their rules.
      param_rule: "class" (the row of the true class in training, of the detected class at test)
        or "expectation" (eq. 5.18 in both).
      rotation_init: the VoluMon head's initial allocentric rotation (``ROTATION_INITS``).
      reconstruction: constants of eq. 5.7 (:class:`ReconstructionConfig`).
      lift_stride8: the VoluMon head also reads each RoI pooled from the ``plain_cnn``'s stride-8
        features (twice the cells of the stride-16 map the detector reads: a 40-pixel object is 5
        cells, not 2.5), added to its first layer through a branch that starts at zero, so a model
        trained without it starts from the very same outputs.
      lift_crop: pixels per side of an image crop the VoluMon head also reads at each RoI (0:
        none): the object's own pixels at the input's resolution, as the separate VoluMon network
        reads its crop, through three strided convolutions and a branch that starts at zero (a
        model trained without it starts from the very same outputs). A multiple of 8.
      lift_at: the box whose pooled features the VoluMon head reads outside training: "refined"
        (each RoI's box after the head's regression, pooled a second time: the box the
        ellipsoid is reconstructed in, as Mask R-CNN's mask head reads the detected boxes) or
        "proposal" (the RoI itself, as in training).
      lift_features: the RoI features the VoluMon head reads: "shared" (the box and class heads'
        two layers over the pooled RoI) or "own" (two layers of its own over the same pooled
        RoI, ``volumon_roi0`` and ``volumon_roi1``), so the lift's features can learn while the
        detector's stay; "stage" (those two layers and the backbone's last stage too, the
        stride-8 to stride-16 one, fed from the shared stride-8 features) or "backbone" (those two
        layers and a whole backbone of its own, fed from the image): the lift's own layers are
        named ``volumon_`` and the detector's layer's name, and the lift pools its RoIs from a
        stride-16 map of its own. A network adopted from one without them starts them as copies
        of the detector's (``jaxsem.volumon.rcnn.train_rcnn``), with the same outputs. "volumon":
        the separate VoluMon network (:class:`VoluMonNet`, the shipped LM-O model's sizes) inside
        this one, named ``volumon_net``: each RoI's crop of the image and the whole image with
        everything outside the RoI (padded by a tenth) blanked, both :data:`VOLUMON_LIFT_INPUT`
        pixels a side, each read by a small CNN of its own; the first branch gives the rotation,
        size and offset, the second the depth, both with the RoI's box features (the detector's RoI
        features are not read); its batch statistics are never updated. Its weights can be a
        trained separate network's (``jaxsem.volumon.rcnn.adopt_separate_lift``). It takes neither
        ``lift_crop`` nor ``lift_stride8``.
    """

    num_classes: int = 8
    input_size: tuple = (320, 240)
    backbone: str = "mobilenet_v2"
    width_multiplier: float = 0.5
    cnn_width: int = 16
    anchor_sizes: tuple = (16.0, 32.0, 64.0, 128.0)
    aspect_ratios: tuple = (0.5, 1.0, 2.0)
    pre_nms: int = 300
    proposals: int = 48
    rpn_nms: float = 0.7
    roi_size: int = 7
    hidden: int = 256
    max_detections: int = 16
    score_threshold: float = 0.05
    det_nms: float = 0.5
    param_rule: str = "class"
    rotation_init: str = "identity"
    reconstruction: ReconstructionConfig = ReconstructionConfig(
        alpha_y=0.05, eps_s=0.01, depth_mode="absolute", min_depth=0.2, max_depth=2.5
    )
    lift_stride8: bool = False
    lift_crop: int = 0
    lift_at: str = "refined"
    lift_features: str = "shared"

    def __post_init__(self):
        if int(self.num_classes) < 1:
            raise ValueError(f"num_classes: expected >= 1, got {self.num_classes}")
        w, h = (int(x) for x in self.input_size)
        if w < 32 or h < 32 or w % 16 or h % 16:
            raise ValueError(f"input_size: expected (W, H) multiples of 16, at least 32, got {self.input_size}")
        if self.backbone not in BACKBONES:
            raise ValueError(f"backbone: expected one of {BACKBONES}, got {self.backbone!r}")
        if int(self.cnn_width) < 1:
            raise ValueError(f"cnn_width: expected >= 1, got {self.cnn_width}")
        if self.lift_stride8 and self.backbone != "plain_cnn":
            raise ValueError("lift_stride8: needs backbone='plain_cnn' (its stride-8 stage)")
        if int(self.lift_crop) < 0 or int(self.lift_crop) % 8:
            raise ValueError(f"lift_crop: expected 0 or a positive multiple of 8, got {self.lift_crop}")
        if self.lift_at not in LIFT_AT:
            raise ValueError(f"lift_at: expected one of {LIFT_AT}, got {self.lift_at!r}")
        if self.lift_features not in LIFT_FEATURES:
            raise ValueError(f"lift_features: expected one of {LIFT_FEATURES}, got {self.lift_features!r}")
        if self.lift_features == "volumon" and (self.lift_crop or self.lift_stride8):
            raise ValueError(
                "lift_features: 'volumon' reads crops of its own; leave lift_crop at 0 and lift_stride8 off"
            )
        if self.param_rule not in PARAM_RULES:
            raise ValueError(f"param_rule: expected one of {PARAM_RULES}, got {self.param_rule!r}")
        if self.rotation_init not in ROTATION_INITS:
            raise ValueError(f"rotation_init: expected one of {tuple(ROTATION_INITS)}, got {self.rotation_init!r}")
        check_fields(
            self, ("pre_nms", "proposals", "roi_size", "hidden", "max_detections"), ">= 1", lambda v: int(v) >= 1
        )
        if (
            not self.anchor_sizes
            or not self.aspect_ratios
            or min(self.anchor_sizes) <= 0
            or min(self.aspect_ratios) <= 0
        ):
            raise ValueError("anchor_sizes, aspect_ratios: expected non-empty positive values")

    @property
    def feature_shape(self) -> tuple:
        w, h = (int(x) for x in self.input_size)
        return h // 16, w // 16

    @property
    def volumon_lift(self) -> VoluMonConfig:
        """The separate VoluMon network that ``lift_features="volumon"`` holds (``volumon_net``):
        the shipped LM-O model's sizes over these classes and rotation start."""
        return VoluMonConfig(
            input_size=VOLUMON_LIFT_INPUT,
            hidden=VOLUMON_LIFT_HIDDEN,
            num_classes=int(self.num_classes),
            global_padding=_VOLUMON_LIFT_PADDING,
            backbone="small_cnn",
            cnn_width=VOLUMON_LIFT_WIDTH,
            box_input=True,
            rotation_init=self.rotation_init,
        )

    @property
    def anchors_per_cell(self) -> int:
        return len(self.anchor_sizes) * len(self.aspect_ratios)


def anchors(config: RCNNConfig) -> np.ndarray:
    """The anchors (h * w * A, 4) of the feature map, cell-major, in input pixels."""
    h, w = config.feature_shape
    base = []
    for size in config.anchor_sizes:
        for ratio in config.aspect_ratios:
            bw, bh = size / math.sqrt(ratio), size * math.sqrt(ratio)
            base.append([-bw / 2, -bh / 2, bw / 2, bh / 2])
    base = np.asarray(base)
    cy, cx = np.meshgrid((np.arange(h) + 0.5) * 16, (np.arange(w) + 0.5) * 16, indexing="ij")
    shift = np.stack([cx, cy, cx, cy], -1).reshape(-1, 1, 4)
    return (shift + base[None]).reshape(-1, 4)


def encode_boxes(reference, target, weights=(1.0, 1.0, 1.0, 1.0)):
    """Faster R-CNN deltas ``(dx, dy, dw, dh)`` taking ``reference`` (..., 4) to ``target`` (..., 4)."""
    rw = jnp.maximum(reference[..., 2] - reference[..., 0], 1e-3)
    rh = jnp.maximum(reference[..., 3] - reference[..., 1], 1e-3)
    tw = jnp.maximum(target[..., 2] - target[..., 0], 1e-3)
    th = jnp.maximum(target[..., 3] - target[..., 1], 1e-3)
    dx = (0.5 * (target[..., 0] + target[..., 2]) - 0.5 * (reference[..., 0] + reference[..., 2])) / rw
    dy = (0.5 * (target[..., 1] + target[..., 3]) - 0.5 * (reference[..., 1] + reference[..., 3])) / rh
    wx, wy, ww, wh = weights
    return jnp.stack([wx * dx, wy * dy, ww * jnp.log(tw / rw), wh * jnp.log(th / rh)], -1)


def decode_boxes(reference, deltas, weights=(1.0, 1.0, 1.0, 1.0)):
    """Inverse of :func:`encode_boxes` (the size deltas clamped, so a box never overflows)."""
    wx, wy, ww, wh = weights
    rw = reference[..., 2] - reference[..., 0]
    rh = reference[..., 3] - reference[..., 1]
    cx = 0.5 * (reference[..., 0] + reference[..., 2]) + deltas[..., 0] / wx * rw
    cy = 0.5 * (reference[..., 1] + reference[..., 3]) + deltas[..., 1] / wy * rh
    w = rw * jnp.exp(jnp.minimum(deltas[..., 2] / ww, _MAX_LOG_SCALE))
    h = rh * jnp.exp(jnp.minimum(deltas[..., 3] / wh, _MAX_LOG_SCALE))
    return jnp.stack([cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2], -1)


HEAD_WEIGHTS = (10.0, 10.0, 5.0, 5.0)


def _clip(boxes, size):
    w, h = size
    return jnp.stack(
        [
            jnp.clip(boxes[..., 0], 0, w),
            jnp.clip(boxes[..., 1], 0, h),
            jnp.clip(boxes[..., 2], 0, w),
            jnp.clip(boxes[..., 3], 0, h),
        ],
        -1,
    )


class RCNNOutput(NamedTuple):
    """What one forward pass gives (per image, batch leading).

    rpn_logits (B, A), rpn_deltas (B, A, 4): over the anchors; rois (B, R, 4) and roi_valid (B, R):
    the RoIs the heads read; class_logits (B, R, N + 1); box_deltas (B, R, 4); phi (B, R, N, 10),
    read at the RoIs in training and, by default, at their refined boxes outside it
    (``RCNNConfig.lift_at``).
    """

    rpn_logits: jax.Array
    rpn_deltas: jax.Array
    rois: jax.Array
    roi_valid: jax.Array
    class_logits: jax.Array
    box_deltas: jax.Array
    phi: jax.Array


class Detections(NamedTuple):
    """Detections per image, ``D = max_detections`` slots, batch leading.

    box (B, D, 4) in the input image's pixels; class_id (B, D) in ``[0, N)``; score (B, D) its
    probability; probabilities (B, D, N) over the object classes; ellipsoid: the camera-frame
    :class:`jaxsem.quadrics.Ellipsoid` (B, D); valid (B, D): a real detection (the rest is padding).
    """

    box: jax.Array
    class_id: jax.Array
    score: jax.Array
    probabilities: jax.Array
    ellipsoid: Ellipsoid
    valid: jax.Array


class VoluMonRCNN(nn.Module):
    """The network (module docstring). ``__call__(images, K, extra_rois=None, train=False)``:
    images (B, H, W, 3) in [0, 1] at ``config.input_size``, K (B, 3, 3) scaled to it; in training
    ``extra_rois`` (B, G, 4) with a mask (the true boxes) join the proposals. Returns
    :class:`RCNNOutput`."""

    config: RCNNConfig = RCNNConfig()

    if TYPE_CHECKING:

        def __hash__(self) -> int: ...

        def apply(self, *args: Any, **kwargs: Any) -> Any: ...

    @nn.compact
    def __call__(self, images, K, extra_rois=None, extra_valid=None, train: bool = False) -> RCNNOutput:
        cfg = self.config
        n, a = int(cfg.num_classes), cfg.anchors_per_cell
        W, H = (int(x) for x in cfg.input_size)
        if images.shape[1:] != (H, W, 3):
            raise ValueError(f"images: expected shape (B, {H}, {W}, 3) (config.input_size), got {images.shape}")
        mean = jnp.array([0.485, 0.456, 0.406], images.dtype)
        std = jnp.array([0.229, 0.224, 0.225], images.dtype)
        x = (images - mean) / std
        pixels = x  # what lift_crop reads
        # the backbone's layers in order, as (name, layer maker); from ``split`` on, its last
        # stage (stride 8 to 16)
        if cfg.backbone == "plain_cnn":
            layers = [
                (f"plain_{i}_{j}", functools.partial(ConvBN, int(c), kernel=3, stride=stride))
                for i, c in enumerate(int(cfg.cnn_width) * np.array([1, 2, 4, 8]))
                for j, stride in enumerate((2, 1))
            ]
            split = 6
        else:
            first = functools.partial(ConvBN, make_divisible(32 * cfg.width_multiplier), kernel=3, stride=2)
            layers = [("features_0", first)] + [
                (f"features_{i + 1}", functools.partial(InvertedResidual, cin, cout, s, t))
                for i, (cin, cout, s, t) in enumerate(block_layout(cfg.width_multiplier)[:_STRIDE16_BLOCKS])
            ]
            split = 1 + _STRIDE8_BLOCKS
        for name, make in layers[:split]:
            x = make(name=name)(x, train)
        fine = x  # (B, H/8, W/8, C)
        for name, make in layers[split:]:
            x = make(name=name)(x, train)
        feats = x  # (B, H/16, W/16, C)
        lift_feats = feats
        if cfg.lift_features in ("stage", "backbone"):  # the lift's own copy of the backbone's end
            start = split if cfg.lift_features == "stage" else 0
            lift_feats = fine if start else pixels
            for name, make in layers[start:]:
                lift_feats = make(name=f"volumon_{name}")(lift_feats, train)
        B = feats.shape[0]

        r = nn.relu(nn.Conv(cfg.hidden, (3, 3), padding="SAME", name="rpn_conv")(feats))
        small = nn.initializers.normal(0.01)
        rpn_logits = nn.Conv(a, (1, 1), kernel_init=small, name="rpn_cls")(r).reshape(B, -1)
        rpn_deltas = nn.Conv(4 * a, (1, 1), kernel_init=small, name="rpn_box")(r).reshape(B, -1, 4)

        anc = jnp.asarray(anchors(cfg), feats.dtype)
        boxes = _clip(decode_boxes(anc, jax.lax.stop_gradient(rpn_deltas)), (W, H))
        wh = boxes[..., 2:] - boxes[..., :2]
        score = jnp.where(jnp.all(wh >= 2.0, -1), jax.lax.stop_gradient(rpn_logits), -jnp.inf)
        k = min(int(cfg.pre_nms), anc.shape[0])
        top, top_i = jax.lax.top_k(score, k)
        top_boxes = jnp.take_along_axis(boxes, top_i[..., None], axis=1)
        keep, keep_ok = nms(top_boxes, jnp.where(jnp.isfinite(top), top, -1e30), cfg.proposals, cfg.rpn_nms, -1e29)
        rois = jnp.take_along_axis(top_boxes, keep[..., None], axis=1)
        roi_valid = keep_ok
        if extra_rois is not None:
            extra_valid = jnp.ones(extra_rois.shape[:2], bool) if extra_valid is None else extra_valid
            rois = jnp.concatenate([rois, extra_rois.astype(rois.dtype)], 1)
            roi_valid = jnp.concatenate([roi_valid, extra_valid], 1)
        rois = jax.lax.stop_gradient(rois)

        fc0 = nn.Dense(cfg.hidden, name="roi_fc0")
        fc1 = nn.Dense(cfg.hidden, name="roi_fc1")
        own = cfg.lift_features in _OWN_LIFT_FEATURES
        own0 = nn.Dense(cfg.hidden, name="volumon_roi0") if own else None
        own1 = nn.Dense(cfg.hidden, name="volumon_roi1") if own else None
        cls_out = nn.Dense(n + 1, name="cls_out")
        box_out = nn.Dense(4, kernel_init=nn.initializers.normal(0.001), name="box_out")
        lift0 = nn.Dense(cfg.hidden, name="volumon_fc0")
        lift8 = nn.Dense(cfg.hidden, kernel_init=nn.initializers.zeros, name="lift8_fc") if cfg.lift_stride8 else None
        S = int(cfg.lift_crop)
        crop_convs = [
            nn.Conv(c, (3, 3), strides=2, padding="SAME", name=f"crop_conv{i}") for i, c in enumerate((16, 32, 64))
        ]
        crop_fc = nn.Dense(cfg.hidden, kernel_init=nn.initializers.zeros, name="crop_fc") if S else None
        tiny = nn.initializers.variance_scaling(0.01, "fan_in", "truncated_normal")
        local_out = nn.Dense(
            9 * n,
            kernel_init=tiny,
            bias_init=_head_bias_init(n, "local", ROTATION_INITS[cfg.rotation_init]),
            name="phi_local",
        )
        depth_out = nn.Dense(n, kernel_init=tiny, name="phi_depth")

        def roi_feature(boxes):
            """(the detector's features, the lift's) of RoIs ``boxes``: the same unless ``own``."""
            pool = jax.vmap(lambda f, b: roi_align(f, b, (cfg.roi_size, cfg.roi_size), 1.0 / 16, 2))
            pooled = pool(feats, boxes)
            h = pooled.reshape(pooled.shape[:2] + (-1,))
            det = nn.relu(fc1(nn.relu(fc0(h))))
            if own0 is None or own1 is None:
                return det, det
            if lift_feats is not feats:
                pooled = pool(lift_feats, boxes)
                h = pooled.reshape(pooled.shape[:2] + (-1,))
            return det, nn.relu(own1(nn.relu(own0(h))))

        vol = cfg.lift_features == "volumon"
        vol_net = None
        if vol:
            vol_net = VoluMonNet(cfg.volumon_lift, name="volumon_net")

        def volumon_lift(boxes, bf):
            """The free parameters from the separate VoluMon network's two inputs (``lift_features``)."""
            S = VOLUMON_LIFT_INPUT
            assert vol_net is not None
            Bn, R = boxes.shape[:2]
            # VoluMon's inputs are the [0, 1] image (it normalises them itself), blanked to black
            crops = jax.vmap(lambda im, b: roi_align(im, b, (S, S), 1.0, 1))(images, boxes)
            whole = jnp.asarray([[0.0, 0.0, W, H]], images.dtype)
            # VoluMon's masked_global_image blanks the full image per box, then shrinks it; here the
            # image is shrunk once and each box's mask applied to the thumbnail (no full-size copy per RoI).
            thumb = jax.vmap(lambda im: roi_align(im, whole, (S, S), 1.0, 1)[0])(images)  # (B, S, S, 3)
            u = (jnp.arange(S, dtype=boxes.dtype) + 0.5) * (W / S)  # the small image's pixel centres
            v = (jnp.arange(S, dtype=boxes.dtype) + 0.5) * (H / S)
            pad = _VOLUMON_LIFT_PADDING * (boxes[..., 2:] - boxes[..., :2])
            lo, hi = boxes[..., :2] - pad, boxes[..., 2:] + pad  # (B, R, 2)
            in_u = (u >= lo[..., :1]) & (u <= hi[..., :1])  # (B, R, S)
            in_v = (v >= lo[..., 1:]) & (v <= hi[..., 1:])
            inside = in_v[..., :, None] & in_u[..., None, :]  # (B, R, S, S)
            masked = jnp.where(inside[..., None], thumb[:, None], 0.0)
            # batch statistics stay as adopted (or initialised): a lift trained beside a frozen
            # detector normalises alike in training and use
            out = vol_net(
                crops.reshape((-1, S, S, 3)),
                masked.reshape((-1, S, S, 3)),
                train=False,
                box_feats=bf.reshape((-1, bf.shape[-1])),
            )
            return out.phi.reshape((Bn, R) + out.phi.shape[1:])

        def lift(h, boxes):
            bf = box_features(boxes, K[:, None]).astype(h.dtype)
            if vol:
                return volumon_lift(boxes, bf)
            v = lift0(jnp.concatenate([h, bf], -1))
            if lift8 is not None and fine is not None:
                p8 = jax.vmap(lambda f, b: roi_align(f, b, (cfg.roi_size, cfg.roi_size), 1.0 / 8, 2))(fine, boxes)
                # Scaled down: Adam moves every weight of a wide new layer by about the step size
                # at once, which unscaled would throw the trained head far off in its first steps.
                v = v + _LIFT8_SCALE * lift8(p8.reshape(p8.shape[:2] + (-1,)))
            if crop_fc is not None:
                c = jax.vmap(lambda im, b: roi_align(im, b, (S, S), 1.0, 2))(pixels, boxes)  # (B, R, S, S, 3)
                c = c.reshape((-1, S, S, 3))
                for conv in crop_convs:
                    c = nn.relu(conv(c))
                c = c.reshape(v.shape[:-1] + (-1,))
                v = v + _LIFT8_SCALE * crop_fc(c)  # scaled as lift8's branch, for the same reason
            v = nn.relu(v)
            local = local_out(v).reshape(v.shape[:-1] + (n, 9))
            return jnp.concatenate([local, depth_out(v)[..., None]], -1)

        h, h_lift = roi_feature(rois)
        class_logits = cls_out(h)
        box_deltas = box_out(h)
        if vol and not train:
            # The volumon lift reads two image crops per RoI, more than the detector's heads cost:
            # outside training it lifts only the RoIs that :func:`detect` keeps and the caller's
            # extra RoIs; the other rows of ``phi`` are zeros.
            read = rois
            if cfg.lift_at == "refined":
                read = jax.lax.stop_gradient(_clip(decode_boxes(rois, box_deltas, HEAD_WEIGHTS), (W, H)))
            rows = _detection_rows(rois, roi_valid, class_logits, box_deltas, cfg)[0]
            if extra_rois is not None:
                R = rois.shape[1]
                extra = jnp.arange(R - extra_rois.shape[1], R, dtype=rows.dtype)
                rows = jnp.concatenate([rows, jnp.broadcast_to(extra, (B, extra.shape[0]))], 1)
            picked = jnp.take_along_axis(read, rows[..., None], axis=1)
            lifted = volumon_lift(picked, box_features(picked, K[:, None]))
            phi = jnp.zeros(rois.shape[:2] + lifted.shape[2:], lifted.dtype)
            phi = phi.at[jnp.arange(B)[:, None], rows].set(lifted)
        elif cfg.lift_at == "refined" and not train:
            # At test time the lift reads the features at the box it reconstructs in: each RoI's
            # box refined by the head, pooled again (as Mask R-CNN's mask head reads the detected
            # boxes). Training reads the RoIs themselves, which its losses reconstruct in.
            refined = jax.lax.stop_gradient(_clip(decode_boxes(rois, box_deltas, HEAD_WEIGHTS), (W, H)))
            phi = lift(roi_feature(refined)[1], refined)
        else:
            phi = lift(h_lift, rois)
        return RCNNOutput(rpn_logits, rpn_deltas, rois, roi_valid, class_logits, box_deltas, phi)


def init_rcnn(key, config: RCNNConfig = RCNNConfig(), batch: int = 1):
    """``(model, variables)`` of :class:`VoluMonRCNN` at ``config``."""
    W, H = (int(x) for x in config.input_size)
    model = VoluMonRCNN(config)
    K = jnp.broadcast_to(jnp.array([[W, 0.0, W / 2], [0.0, W, H / 2], [0.0, 0.0, 1.0]], jnp.float32), (batch, 3, 3))
    variables = model.init(key, jnp.zeros((batch, H, W, 3), jnp.float32), K)
    return model, variables


def free_params(phi, class_logits, class_id, rule: str):
    """The 10 free parameters of RoIs: the row of ``class_id`` (rule "class") or the expectation
    under the object-class probabilities (rule "expectation", eq. 5.18).

    phi (..., N, 10); class_logits (..., N + 1) with the background first; class_id (...) in [0, N).
    """
    if rule == "expectation":
        return expected_params(phi, class_logits[..., 1:])
    return select_class_params(phi, class_id)


def _detection_rows(rois, roi_valid, class_logits, box_deltas, cfg: RCNNConfig):
    """Which RoIs become detections: ``(rows, valid, refined boxes, class, score, object-class
    probabilities)``, ``rows`` (B, max_detections) by class-aware NMS of each RoI's most probable
    object class at its refined box."""
    W, H = (int(x) for x in cfg.input_size)
    obj = jax.nn.softmax(class_logits, -1)[..., 1:]
    cls = jnp.argmax(obj, -1)
    score = jnp.max(obj, -1)
    boxes = _clip(decode_boxes(rois, box_deltas, HEAD_WEIGHTS), (W, H))
    ok = roi_valid & jnp.all(boxes[..., 2:] - boxes[..., :2] >= 1.0, -1)
    score = jnp.where(ok, score, -1.0)
    offset = (cls.astype(boxes.dtype) * 2.0 * (W + H))[..., None]  # separate the classes for one NMS
    keep, valid = nms(boxes + offset, score, cfg.max_detections, cfg.det_nms, cfg.score_threshold)
    return keep, valid, boxes, cls, score, obj


def detect(output: RCNNOutput, K, config: RCNNConfig) -> Detections:
    """Detections from one forward pass: per RoI its most probable object class, the box refined by
    the head, class-aware NMS, the ``max_detections`` best; each with its ellipsoid (eq. 5.17)."""
    cfg = config
    keep, valid, boxes, cls, score, obj = _detection_rows(
        output.rois, output.roi_valid, output.class_logits, output.box_deltas, cfg
    )
    take = lambda x: jnp.take_along_axis(x, keep.reshape(keep.shape + (1,) * (x.ndim - 2)), axis=1)
    box, cid, sc, p = take(boxes), jnp.take_along_axis(cls, keep, 1), jnp.take_along_axis(score, keep, 1), take(obj)
    phi = free_params(take(output.phi), take(output.class_logits), cid, cfg.param_rule)
    ellipsoid = reconstruct(phi, box, jnp.asarray(K)[:, None], cfg.reconstruction)
    return Detections(box, cid, jnp.where(valid, sc, 0.0), p, ellipsoid, valid)


def match(rois, roi_valid, boxes, box_valid, threshold: float):
    """Each RoI's best true box: ``(index, iou, matched)``; matched where IoU >= ``threshold``."""
    iou = box_iou(rois[..., :, None, :], boxes[..., None, :, :])
    iou = jnp.where(roi_valid[..., :, None] & box_valid[..., None, :], iou, -1.0)
    index = jnp.argmax(iou, -1)
    best = jnp.max(iou, -1)
    return index, best, best >= threshold


def _smooth_l1(x, beta=1.0 / 9):
    ax = jnp.abs(x)
    return jnp.where(ax < beta, 0.5 * x * x / beta, ax - 0.5 * beta)


def _mean_where(values, mask):
    m = mask.astype(values.dtype)
    return jnp.sum(values * m) / jnp.maximum(jnp.sum(m), 1.0)


def _rpn_targets(anc, boxes, box_valid, pos_iou: float, neg_iou: float):
    """Per anchor: ``(positive, negative, target_box)`` against one image's true boxes (G, 4)."""
    iou = jnp.where(box_valid[None], box_iou(anc[:, None], boxes[None]), -1.0)  # (A, G)
    best = jnp.max(iou, 1)
    which = jnp.argmax(iou, 1)
    best_of_box = jnp.max(iou, 0)
    is_best = jnp.any((iou >= best_of_box[None] - 1e-6) & (iou > 0.1) & box_valid[None], 1)
    pos = (best >= pos_iou) | is_best
    neg = (best < neg_iou) & ~pos
    return pos, neg, boxes[which]


def detection_loss(
    output: RCNNOutput, boxes, class_id, box_valid, config: RCNNConfig, fg_iou=0.5, rpn_pos=0.7, rpn_neg=0.3
):
    """Faster R-CNN's terms of one forward pass against the true boxes (B, G, 4), classes (B, G)
    and mask (B, G): proposal objectness and box (anchors at IoU >= ``rpn_pos`` or each object's
    best anchor against those below ``rpn_neg``, the two halves weighted alike), RoI class (objects
    at IoU >= ``fg_iou`` against background, weighted alike) and box (on the objects' RoIs).

    Returns ``(terms, (index, foreground, true_class))``: the scalar terms and each RoI's matched
    object, whether it is one, and that object's class (for the VoluMon terms)."""
    anc = jnp.asarray(anchors(config), output.rpn_deltas.dtype)
    boxes = jnp.asarray(boxes, anc.dtype)
    pos, neg, tgt = jax.vmap(lambda b, v: _rpn_targets(anc, b, v, rpn_pos, rpn_neg))(boxes, box_valid)
    bce = optax.sigmoid_binary_cross_entropy(output.rpn_logits, pos.astype(output.rpn_logits.dtype))
    rpn_cls = 0.5 * _mean_where(bce, pos) + 0.5 * _mean_where(bce, neg)
    rpn_box = _mean_where(jnp.sum(_smooth_l1(output.rpn_deltas - encode_boxes(anc, tgt)), -1), pos)
    index, _, fg = match(output.rois, output.roi_valid, boxes, box_valid, fg_iou)
    bg = output.roi_valid & ~fg
    true_cls = jnp.take_along_axis(jnp.asarray(class_id), index, 1)
    label = jnp.where(fg, true_cls + 1, 0)
    ce = optax.softmax_cross_entropy_with_integer_labels(output.class_logits, label)
    cls_loss = 0.5 * _mean_where(ce, fg) + 0.5 * _mean_where(ce, bg)
    matched = jnp.take_along_axis(boxes, index[..., None], axis=1)
    box_target = encode_boxes(output.rois, matched, HEAD_WEIGHTS)
    box_loss = _mean_where(jnp.sum(_smooth_l1(output.box_deltas - box_target), -1), fg)
    terms = {
        "rpn_cls": rpn_cls,
        "rpn_box": rpn_box,
        "cls": cls_loss,
        "box": box_loss,
        "fg_rois": jnp.sum(fg.astype(output.rpn_logits.dtype)) / fg.shape[0],
    }
    return terms, (index, fg, true_cls)
