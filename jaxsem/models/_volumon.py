"""VoluMon (thesis chapter 5): the two-branch network of figure 5-2 and the reconstruction f (eq. 5.7).

Network ``Phi`` (:class:`VoluMonNet`):

- **local branch**: the box contents resized to ``S x S`` -> MobileNetV2 -> fully connected
  layers -> ``phi_D`` (3), ``phi_R`` (4), ``phi_UV`` (2) per class;
- **global branch**: the whole image with everything outside the (padded) box zeroed, resized to
  ``S x S`` -> its own MobileNetV2 -> fully connected layers -> ``phi_Z`` (1) per class;
- with ``num_classes > 1`` (section 5.7) the heads give ``N x 10`` free parameters and the local
  branch also gives class logits; :func:`select_class_params` picks the true class's row,
  :func:`expected_params` the expectation under the predicted probabilities (eq. 5.18).

Reconstruction ``f`` (:func:`reconstruct`, eq. 5.7), free parameters ``phi = [phi_D, phi_R,
phi_UV, phi_Z]`` (10,) and the box -> an ellipsoid in the camera frame:

- sizes (full axis lengths) ``d = alpha_y * cumsum(exp(phi_D)) + eps_s``: positive, increasing;
  ``radii = d / 2``;
- projected centroid ``(u, v) = box_min + sigmoid(phi_UV) * box_size``: always inside the box;
- depth ``t_z = b f / (alpha_delta * sigmoid(phi_Z))`` (bounded pseudo-disparity, ``t_z >= b f /
  alpha_delta``) or, with ``depth_mode="absolute"`` (section 5.8.1), ``t_z = min_depth +
  (max_depth - min_depth) * sigmoid(phi_Z)``;
- centre ``t = t_z K^-1 [u, v, 1]`` (the thesis writes this with the image centre and one focal
  length; ``K^-1`` is the same for zero skew and square pixels and also right otherwise);
- rotation: ``phi_R`` normalised is the *allocentric* quaternion ``[w, x, y, z]``; the egocentric
  (object-to-camera) rotation is ``R = R_ray R_allo``, ``R_ray`` the smallest rotation taking the
  optical axis ``e_z`` to the ray through the centroid (Kundu et al., 3D-RCNN). For an object on
  the optical axis ``R_ray = I``.

Everything is in jaxsem conventions: ``rotation`` (..., 3, 3) object-to-camera, ``center`` (..., 3)
in the left camera frame (metres), ``radii`` (..., 3) semi-axes. Lengths are metres; the
thesis' constants in centimetres (``alpha_y = 10``, ``eps_s = 3``) become 0.1 and 0.03.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, Any, NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

from .._checks import check_fields, positive
from ..quadrics import Ellipsoid, back_project, quaternion_to_rotation, ray_rotation
from ._mobilenet import MobileNetV2

NUM_FREE = 10  # phi_D (3), phi_R (4), phi_UV (2), phi_Z (1)
SLICE_D = slice(0, 3)
SLICE_R = slice(3, 7)
SLICE_UV = slice(7, 9)
SLICE_Z = slice(9, 10)


@dataclasses.dataclass(frozen=True)
class ReconstructionConfig:
    """Constants of the reconstruction f (eq. 5.7; section 5.5.1 values converted to metres).

    Attributes:
      alpha_y: size scale (m); thesis 10 cm.
      eps_s: minimum size (m); thesis 3 cm.
      depth_mode: "disparity" (thesis 5.3) or "absolute" (thesis 5.8.1).
      baseline_focal: ``b f`` (metres x pixels) of the pseudo-disparity; set to roughly the stereo
        baseline times the focal length of the training camera.
      alpha_delta: maximum pseudo-disparity (pixels); thesis 150. Minimum depth ``b f / alpha_delta``.
      min_depth, max_depth: range of the absolute depth mode (m); thesis 50 m maximum for doors.
      reference_focal: 0, or the focal length (pixels of the network's input; the geometric mean
        of ``f_x`` and ``f_y``) of the one camera the network learnt depth under. Then the depth
        the free parameters give is that camera's (a *virtual* depth) and is scaled by the
        image's focal length over this one: an object that looks the same through a focal length
        ``s`` times as long lies ``s`` times as far, so a network that reads depth from how large
        an object looks gives the right depth through another camera, or read at another input
        size. 0: the depth as given (a network that saw many focal lengths, or reads depth from
        the box over the focal length alone).
    """

    alpha_y: float = 0.1
    eps_s: float = 0.03
    depth_mode: str = "disparity"
    baseline_focal: float = 0.06 * 110.0
    alpha_delta: float = 30.0
    min_depth: float = 0.05
    max_depth: float = 5.0
    reference_focal: float = 0.0

    def __post_init__(self):
        if not (np.isfinite(self.reference_focal) and self.reference_focal >= 0):
            raise ValueError(f"reference_focal: expected 0 or a positive focal length, got {self.reference_focal!r}")
        if self.depth_mode not in ("disparity", "absolute"):
            raise ValueError(f"depth_mode: expected 'disparity' or 'absolute', got {self.depth_mode!r}")
        check_fields(
            self, ("alpha_y", "eps_s", "baseline_focal", "alpha_delta", "max_depth"), "a positive number", positive
        )
        if not 0 <= self.min_depth < self.max_depth:
            raise ValueError(
                f"min_depth, max_depth: expected 0 <= min_depth < max_depth, got {self.min_depth}, {self.max_depth}"
            )


def reconstruct(phi, box, K, config: ReconstructionConfig = ReconstructionConfig()) -> Ellipsoid:
    """Eq. 5.7: free parameters -> ellipsoid in the camera frame.

    Args:
      phi: (..., 10) free parameters ``[phi_D (3), phi_R (4), phi_UV (2), phi_Z (1)]``.
      box: (..., 4) input box ``[u_min, v_min, u_max, v_max]`` (pixels) the centroid is kept in.
      K: (..., 3, 3) intrinsics of the image.
      config: :class:`ReconstructionConfig`.

    Returns:
      :class:`Ellipsoid` (rotation (..., 3, 3) object-to-camera, center (..., 3), radii (..., 3)).
      Finite with finite gradients for any finite ``phi`` (also a zero quaternion or a
      zero-size box).
    """
    phi = jnp.asarray(phi)
    if phi.shape[-1:] != (NUM_FREE,):
        raise ValueError(f"phi: expected shape (..., {NUM_FREE}), got {tuple(phi.shape)}")
    box = jnp.asarray(box, phi.dtype)
    if box.shape[-1:] != (4,):
        raise ValueError(f"box: expected shape (..., 4) [u_min, v_min, u_max, v_max], got {tuple(box.shape)}")
    K = jnp.asarray(K, phi.dtype)
    if K.shape[-2:] != (3, 3):
        raise ValueError(f"K: expected shape (..., 3, 3), got {tuple(K.shape)}")

    # sizes: cumulative exponentials, so d0 <= d1 <= d2 (removes the axis-permutation ambiguity)
    sizes = config.alpha_y * jnp.cumsum(jnp.exp(phi[..., SLICE_D]), axis=-1) + config.eps_s
    # centroid projection, constrained to the box
    uv01 = jax.nn.sigmoid(phi[..., SLICE_UV])
    uv = box[..., :2] + uv01 * (box[..., 2:] - box[..., :2])
    # depth
    s = jax.nn.sigmoid(phi[..., 9])
    if config.depth_mode == "disparity":
        # sigmoid saturates to 0 in float32 for phi_z < -88: keep the disparity away from zero
        disparity = config.alpha_delta * jnp.maximum(s, jnp.finfo(phi.dtype).tiny ** 0.5)
        tz = config.baseline_focal / disparity
    else:
        tz = config.min_depth + (config.max_depth - config.min_depth) * s
    if config.reference_focal > 0:  # the reference camera's depth, to this camera's
        focal = jnp.sqrt(jnp.maximum(K[..., 0, 0] * K[..., 1, 1], jnp.finfo(K.dtype).tiny))
        tz = tz * focal / config.reference_focal
    # back-project (u, v) with K^-1 (camera frame): ray = [x, y, 1], the centre at depth tz on it
    ray = back_project(uv, jnp.ones_like(tz), K, jnp.eye(4, dtype=K.dtype))
    center = ray * tz[..., None]
    R_allo = quaternion_to_rotation(phi[..., SLICE_R])
    rotation = ray_rotation(ray) @ R_allo
    return Ellipsoid(rotation, center, 0.5 * sizes)


def select_class_params(phi, class_id):
    """Row of the true class: phi (..., N, 10), class_id (...) int -> (..., 10)."""
    phi = jnp.asarray(phi)
    class_id = jnp.asarray(class_id)
    idx = jnp.clip(class_id, 0, phi.shape[-2] - 1)[..., None, None]
    return jnp.take_along_axis(phi, jnp.broadcast_to(idx, class_id.shape + (1, phi.shape[-1])), axis=-2)[..., 0, :]


def expected_params(phi, class_logits):
    """Eq. 5.18: ``sum_i p_i phi_i`` with ``p = softmax(class_logits)``; (..., N, 10), (..., N) -> (..., 10)."""
    p = jax.nn.softmax(class_logits, axis=-1)
    return jnp.sum(p[..., None] * phi, axis=-2)


# allocentric quaternions [w, x, y, z] of the head's initial bias (see VoluMonConfig.rotation_init)
ROTATION_INITS = {"identity": (1.0, 0.0, 0.0, 0.0), "short_axis_along_ray": (0.5, -0.5, -0.5, -0.5)}


@dataclasses.dataclass(frozen=True)
class VoluMonConfig:
    """Network sizes. Defaults are the CPU-sized config (width 0.35, 64 x 64); the thesis uses
    ``width_multiplier=1.0, input_size=224``.

    Attributes:
      width_multiplier: MobileNetV2 width of both branches.
      input_size: side S of the square local patch and global image fed to the branches.
      hidden: widths of the fully connected layers of each head.
      num_classes: N; the heads output N x 10 free parameters (and N class logits if N > 1).
      global_padding: fraction of the box size kept around the box in the masked global image.
      backbone: "mobilenet_v2" (the thesis) or "small_cnn" (four strided 3x3 convolutions with
        batch norm: compiles in seconds; the CPU preset -- XLA's CPU depthwise convolutions make
        MobileNetV2 far slower to train on a CPU, ``benchmarks/RESULTS.md``, "Other: devices and
        design measurements").
      cnn_width: channels of the first ``small_cnn`` layer (then 2x, 4x, 4x).
      rotation_init: starting allocentric rotation of the head's bias. "identity" (object axes =
        camera axes: the longest axis d2 along the viewing ray) or "short_axis_along_ray" (object
        x, the shortest axis d0, along the ray; y, z across the image). A box (silhouette) says
        nothing about the extent along the ray, and the visible surface little: started at the
        identity, the untrained rotation hides the longest axis there, where it inflates unseen
        (the size collapse, seen as near-circle overlays); along the shortest axis the error
        of the unseen extent is bounded by the ordering d0 <= d1 <= d2 of the seen ones.
      box_input: also feed the input box, normalised by the intrinsics (:func:`box_features`), to
        both heads. The thesis' network sees the box only through the resized masked global image,
        from which a small CNN reads the box's pixel size -- hence the depth -- poorly; the
        pseudo-disparity is proportional to that size for a class of fixed size.
    """

    width_multiplier: float = 0.35
    input_size: int = 64
    hidden: tuple[int, ...] = (256, 128)
    num_classes: int = 1
    global_padding: float = 0.1
    backbone: str = "mobilenet_v2"
    cnn_width: int = 16
    box_input: bool = False
    rotation_init: str = "identity"

    def __post_init__(self):
        if self.rotation_init not in ROTATION_INITS:
            raise ValueError(f"rotation_init: expected one of {tuple(ROTATION_INITS)}, got {self.rotation_init!r}")
        if self.backbone not in ("mobilenet_v2", "small_cnn"):
            raise ValueError(f"backbone: expected 'mobilenet_v2' or 'small_cnn', got {self.backbone!r}")
        if not self.width_multiplier > 0:
            raise ValueError(f"width_multiplier: expected > 0, got {self.width_multiplier}")
        if int(self.input_size) < 32:
            raise ValueError(f"input_size: expected >= 32 pixels, got {self.input_size}")
        if int(self.num_classes) < 1:
            raise ValueError(f"num_classes: expected >= 1, got {self.num_classes}")


class SmallCNN(nn.Module):
    """Four strided 3x3 conv + batch norm + ReLU layers and global pooling (test-sized backbone)."""

    width: int = 16

    @nn.compact
    def __call__(self, x, train: bool = False):
        for i, c in enumerate((self.width, 2 * self.width, 4 * self.width, 4 * self.width)):
            x = nn.Conv(c, (3, 3), strides=(2, 2), padding=((1, 1), (1, 1)), use_bias=False, name=f"conv{i}")(x)
            x = nn.BatchNorm(use_running_average=not train, momentum=0.9, name=f"bn{i}")(x)
            x = nn.relu(x)
        return jnp.mean(x, axis=(-3, -2))


NUM_BOX_FEATURES = 6


def box_features(box, K):
    """Box normalised by the intrinsics (..., 6): the corners as ray slopes ``(u - c_x) / f_x``,
    ``(v - c_y) / f_y`` and ``log`` of the box's width and height over the focal lengths."""
    box = jnp.asarray(box)
    K = jnp.asarray(K, box.dtype)
    fx, fy, cx, cy = K[..., 0, 0], K[..., 1, 1], K[..., 0, 2], K[..., 1, 2]
    x0, y0 = (box[..., 0] - cx) / fx, (box[..., 1] - cy) / fy
    x1, y1 = (box[..., 2] - cx) / fx, (box[..., 3] - cy) / fy
    w = jnp.maximum(x1 - x0, 1e-4)
    h = jnp.maximum(y1 - y0, 1e-4)
    return jnp.stack([x0, y0, x1, y1, jnp.log(w), jnp.log(h)], -1)


class VoluMonOutput(NamedTuple):
    """phi: (..., N, 10) free parameters per class; class_logits: (..., N) (zeros if N == 1)."""

    phi: jax.Array
    class_logits: jax.Array


def _head_bias_init(num_classes: int, part: str, quaternion=(1.0, 0.0, 0.0, 0.0)):
    # Start from sensible ellipsoids: identity allocentric quaternion, centroid at the box centre,
    # mid-range sizes and depth. The kernels start small so the bias dominates early on.
    def init(key, shape, dtype=jnp.float32):
        if part == "local":
            row = np.zeros(9, np.float32)
            row[3:7] = quaternion  # allocentric quaternion [w, x, y, z]
            return jnp.asarray(np.tile(row, num_classes), dtype)
        return jnp.zeros(shape, dtype)

    return init


class VoluMonNet(nn.Module):
    """The two-branch VoluMon network (figure 5-2).

    ``__call__(local_patch, global_image, train, box_feats)``: both (B, S, S, 3) float images in
    [0, 1] (see :func:`jaxsem.volumon.prepare_inputs`) and, with ``config.box_input``, the
    (B, 6) :func:`box_features` -> :class:`VoluMonOutput` with ``phi`` (B, N, 10) and
    ``class_logits`` (B, N).
    """

    config: VoluMonConfig = VoluMonConfig()

    if TYPE_CHECKING:  # for type checkers only; flax supplies both at run time

        def __hash__(self) -> int:  # flax's field-based hash (the cached step builders key on it)
            ...

        def apply(self, *args: Any, **kwargs: Any) -> Any:  # the output, or (output, variables) by `mutable`
            ...

    @nn.compact
    def __call__(self, local_patch, global_image, train: bool = False, box_feats=None) -> VoluMonOutput:
        cfg = self.config
        n = cfg.num_classes
        # ImageNet normalisation, as torchvision's pretrained MobileNetV2 expects
        mean = jnp.array([0.485, 0.456, 0.406], local_patch.dtype)
        std = jnp.array([0.229, 0.224, 0.225], local_patch.dtype)
        if cfg.backbone == "mobilenet_v2":
            make = lambda name: MobileNetV2(cfg.width_multiplier, name=name)
        else:
            make = lambda name: SmallCNN(width=cfg.cnn_width, name=name)
        fl = make("local_backbone")((local_patch - mean) / std, train)
        fg = make("global_backbone")((global_image - mean) / std, train)
        small = nn.initializers.variance_scaling(0.01, "fan_in", "truncated_normal")
        if cfg.box_input:
            if box_feats is None:
                box_feats = jnp.zeros(fl.shape[:-1] + (NUM_BOX_FEATURES,), fl.dtype)
            fl = jnp.concatenate([fl, box_feats.astype(fl.dtype)], -1)
            fg = jnp.concatenate([fg, box_feats.astype(fg.dtype)], -1)
        h = fl
        for i, w in enumerate(cfg.hidden):
            h = nn.relu(nn.Dense(w, name=f"local_fc{i}")(h))
        local = nn.Dense(
            9 * n,
            kernel_init=small,
            bias_init=_head_bias_init(n, "local", ROTATION_INITS[cfg.rotation_init]),
            name="local_out",
        )(h)
        g = fg
        for i, w in enumerate(cfg.hidden):
            g = nn.relu(nn.Dense(w, name=f"global_fc{i}")(g))
        z = nn.Dense(n, kernel_init=small, bias_init=_head_bias_init(n, "global"), name="global_out")(g)
        local = local.reshape(local.shape[:-1] + (n, 9))
        phi = jnp.concatenate([local, z[..., None]], axis=-1)
        if n > 1:
            logits = nn.Dense(n, name="class_out")(h)
        else:
            logits = jnp.zeros(phi.shape[:-1], phi.dtype)
        return VoluMonOutput(phi, logits)


def init_volumon(key, config: VoluMonConfig = VoluMonConfig(), batch: int = 1):
    """Initialise :class:`VoluMonNet`; returns ``(model, variables)`` (``params``, ``batch_stats``)."""
    model = VoluMonNet(config)
    s = int(config.input_size)
    x = jnp.zeros((batch, s, s, 3), jnp.float32)
    # jitted: flax's eager init compiles every primitive separately (slow on a small CPU)
    variables = jax.jit(lambda k: model.init(k, x, x, train=False))(key)
    return model, variables
