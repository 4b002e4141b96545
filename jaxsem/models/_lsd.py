"""The LSD network: a learned sampling distribution over a robot-centred map (thesis 3.2.4).

Figures 3-2 and 3-4 of the thesis, in flax linen:

- **inputs**: a robot-centred partial occupancy crop (``UNKNOWN=-1 / FREE=0 / OCCUPIED=1``, as
  :mod:`jaxsem.planning` stores it) and a semantic crop (class ids, ``0`` = nothing seen), both
  ``(..., H, W)`` integers, plus a context vector ``(..., C)`` (relative goal direction and
  clipped distance, goal-outdoors flag). The two integer maps are one-hot encoded inside the
  network (3 occupancy channels + ``num_semantic_classes - 1`` object channels): the class ids
  are categories, not intensities.
- **encoder** ``phi_enc``: strided 3x3 convolutions (``features``), each halving the map, to a
  latent ``(H / 2^L, W / 2^L, features[-1])``.
- **decoder** ``phi_dec``: transposed convolutions back to ``(H, W)``, giving the *general*
  un-normalised log-distribution ``phi_gen`` (eq. 3.9). With ``skip=True`` (default) the decoder
  also sees the encoder's feature maps at each scale (U-Net style): expert paths are a few cells
  wide and a coarse latent alone blurs them. This is our choice; the thesis does not say.
- **context branch** ``phi_cs``: latent concatenated with the context (tiled over the latent's
  cells, as in "concatenate the output of the encoding CNN with Upsilon"), convolutions, then
  transposed convolutions to an ``(H, W)`` log-modifier.
- **product** (eq. 3.10): ``phi_gen o phi_cs`` is a sum in log space; **softmax** over all cells
  (eq. 3.11). Dropout (``dropout_rate``) on the latent and in both decoders.

:func:`lsd_nll` is the loss of eq. 3.8, scaled: the mean over a sample's expert path cells of
``-log p(cell)`` (dividing by the path length keeps long and short paths on one scale), averaged
over the samples that have any path cell in the crop.

The defaults are CPU-sized (a forward pass of one 160 x 160 map is cheap on a CPU); the sizes
are fields of :class:`LSDConfig`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any, NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

#: Partial-occupancy codes the network expects (same as :mod:`jaxsem.planning`).
_UNKNOWN, _FREE, _OCCUPIED = -1, 0, 1


@dataclasses.dataclass(frozen=True)
class LSDConfig:
    """Sizes of the LSD network (hashable; changing one is a new network).

    map_size: side of the square robot-centred crop in cells (160 in the thesis); must be
        divisible by ``2 ** len(features)``.
    num_semantic_classes: semantic ids are ``0 .. num_semantic_classes - 1`` (0 = nothing).
    context_dim: length of the context vector.
    features: encoder channels, one strided conv per entry.
    context_features: channels of the context branch at the latent scale.
    skip: U-Net skip connections in the general decoder.
    dropout_rate: dropout on the latent and inside both decoders (training only).
    log_range: bound (nats) on the spread of the output log-probabilities: the logits pass
        through ``(R / 2) tanh(x / (R / 2))``, so over one window ``max p / min p <= e^R``.
        ``None``: unbounded (saved networks without the bound). Why: the planner sets every cell
        outside the window to the window's *minimum* (thesis 3.2.5), an extreme-value statistic;
        an unbounded network trained on path likelihood pushes single cells (walls, the off-map
        padding) to vanishing probabilities and the outside then gets almost no samples. With
        the bound the outside keeps a share of the samples even where the network is fully
        confident (``benchmarks/RESULTS.md``, "Other: devices and design measurements"; the LSD
        model card).
    upsample: 'resize' (the default and the shipped model's: nearest-neighbour doubling, then a
        3 x 3 convolution) or 'transpose' (2 x 2 transposed convolutions, stride 2: the networks
        trained before the shipped one; saved configs without this field load as 'transpose',
        :func:`jaxsem.lsd.load_model`). The transposed
        convolutions are where the stripes of the distribution images come from: each output
        cell takes one of four kernel weights by its position parity, so every upsampling stage
        stamps a period-2 pattern and the context branch, four stages from the 10 x 10 latent
        with no skip connections, shows 2-, 4-, 8- and 16-cell blocks (Odena et al., 2016,
        "Deconvolution and checkerboard artifacts"). Resize + convolution has no parity
        dependence; a constant input gives a constant output (tested).
    """

    map_size: int = 160
    num_semantic_classes: int = 5
    context_dim: int = 4
    features: tuple = (8, 16, 32, 32)
    context_features: int = 32
    skip: bool = True
    dropout_rate: float = 0.1
    log_range: float | None = None
    upsample: str = "resize"

    def __post_init__(self):
        feats = tuple(int(f) for f in self.features)
        object.__setattr__(self, "features", feats)
        if not feats or min(feats) < 1:
            raise ValueError(f"features: expected a non-empty tuple of positive ints, got {feats}")
        if self.map_size < 1 or self.map_size % (2 ** len(feats)):
            raise ValueError(
                f"map_size: expected a positive multiple of 2**len(features) = {2 ** len(feats)}, got {self.map_size}"
            )
        if self.context_dim < 1:
            raise ValueError(f"context_dim: expected >= 1, got {self.context_dim}")
        if self.num_semantic_classes < 2:
            raise ValueError(f"num_semantic_classes: expected >= 2, got {self.num_semantic_classes}")
        if not 0.0 <= self.dropout_rate < 1.0:
            raise ValueError(f"dropout_rate: expected in [0, 1), got {self.dropout_rate}")
        if self.upsample not in ("transpose", "resize"):
            raise ValueError(f"upsample: expected 'transpose' or 'resize', got {self.upsample!r}")
        if self.log_range is not None and not float(self.log_range) > 0:
            raise ValueError(f"log_range: expected None or > 0 nats, got {self.log_range}")


class LSDOutput(NamedTuple):
    """Network outputs, each ``(..., H, W)``.

    log_prob: normalised log-probability of each cell (eq. 3.11; ``logsumexp`` over cells = 0).
    general: un-normalised general log-distribution ``phi_gen`` (eq. 3.9).
    modifier: context log-modifier ``phi_cs`` (eq. 3.10), zeros when ``use_context=False``.
    """

    log_prob: jax.Array
    general: jax.Array
    modifier: jax.Array


def check_lsd_inputs(config: LSDConfig, occupancy, semantic, context) -> tuple:
    """Shape / dtype checks of the network inputs (static, so they also run under ``jit``).

    Returns the common batch shape. ``ValueError`` names the argument, its shape or dtype and
    what was expected.
    """
    k = config.map_size
    for name, m in (("occupancy", occupancy), ("semantic", semantic)):
        shape = tuple(np.shape(m))
        if len(shape) < 2 or shape[-2:] != (k, k):
            raise ValueError(f"{name}: expected shape (..., {k}, {k}), got shape {shape}")
        dt = jnp.asarray(m).dtype if not hasattr(m, "dtype") else m.dtype
        if not (jnp.issubdtype(dt, jnp.integer)):
            raise ValueError(f"{name}: expected an integer dtype (int8 class codes), got dtype {dt}")
    cshape = tuple(np.shape(context))
    if len(cshape) < 1 or cshape[-1] != config.context_dim:
        raise ValueError(f"context: expected shape (..., {config.context_dim}), got shape {cshape}")
    cdt = context.dtype if hasattr(context, "dtype") else jnp.asarray(context).dtype
    if not jnp.issubdtype(cdt, jnp.floating):
        raise ValueError(f"context: expected a floating dtype, got dtype {cdt}")
    try:
        return tuple(np.broadcast_shapes(np.shape(occupancy)[:-2], np.shape(semantic)[:-2], cshape[:-1]))
    except ValueError:
        raise ValueError(
            f"batch shapes do not broadcast: occupancy {tuple(np.shape(occupancy))}, semantic "
            f"{tuple(np.shape(semantic))}, context {cshape}"
        ) from None


def encode_maps(occupancy, semantic, num_semantic_classes: int, dtype) -> jax.Array:
    """One-hot input encoding ``(..., H, W, 3 + num_semantic_classes - 1)`` in ``dtype``.

    Channels: unknown, free, occupied, then one per semantic class ``1 .. n - 1``.
    """
    occupancy = jnp.asarray(occupancy)
    semantic = jnp.asarray(semantic)
    occ = jnp.stack([occupancy == _UNKNOWN, occupancy == _FREE, occupancy == _OCCUPIED], -1)
    sem = semantic[..., None] == jnp.arange(1, num_semantic_classes, dtype=semantic.dtype)
    return jnp.concatenate([occ, sem], -1).astype(dtype)


def _up_layer(features: int, kind: str, name: str):
    """A 2 x 2 stride-2 transposed convolution, or (``kind='resize'``) the 3 x 3 convolution that
    follows a nearest-neighbour doubling (:func:`_upsample`); same parameter names either way."""
    if kind == "transpose":
        return nn.ConvTranspose(features, (2, 2), strides=(2, 2), name=name)
    return nn.Conv(features, (3, 3), name=name)


def _upsample(layer, x, kind: str):
    if kind == "resize":  # no parity-dependent weights: no checkerboard / stripes
        x = jnp.repeat(jnp.repeat(x, 2, axis=-3), 2, axis=-2)
    return layer(x)


class LSDNet(nn.Module):
    """The LSD network (module docstring). ``config``: :class:`LSDConfig`. The compute dtype
    follows the context's floating dtype (and the parameters': :func:`init_lsd` ``dtype``)."""

    config: LSDConfig = LSDConfig()

    if TYPE_CHECKING:  # for type checkers only; flax supplies both at run time

        def __hash__(self) -> int:  # flax's field-based hash (the cached step builders key on it)
            ...

        def apply(self, *args: Any, **kwargs: Any) -> Any:  # the output, or (output, variables) by `mutable`
            ...

    def setup(self):
        c = self.config
        self.enc = [nn.Conv(f, (3, 3), strides=(2, 2), name=f"enc_{i}") for i, f in enumerate(c.features)]
        self.enc_mix = nn.Conv(c.features[-1], (3, 3), name="enc_mix")
        up = list(c.features[:-1][::-1]) + [max(4, c.features[0] // 2)]
        self.dec = [_up_layer(f, c.upsample, f"dec_{i}") for i, f in enumerate(up)]
        self.dec_out = nn.Conv(1, (3, 3), name="dec_out")
        self.ctx_in = nn.Dense(c.context_features, name="cs_context")
        self.ctx_mix = [nn.Conv(c.context_features, (3, 3), name=f"cs_mix_{i}") for i in range(2)]
        cs_up = [max(4, f // 2) for f in up]
        self.ctx_up = [_up_layer(f, c.upsample, f"cs_up_{i}") for i, f in enumerate(cs_up)]
        self.ctx_out = nn.Conv(1, (3, 3), name="cs_out")
        self.drop = nn.Dropout(c.dropout_rate)

    def __call__(
        self,
        occupancy,
        semantic,
        context,
        *,
        deterministic: bool = True,
        use_context: bool = True,
    ) -> LSDOutput:
        """occupancy, semantic: (..., H, W) int; context: (..., C) float -> :class:`LSDOutput`.

        ``deterministic=False`` turns dropout on (needs a ``'dropout'`` rng). ``use_context=False``
        is stage one of the training: the distribution is ``softmax(phi_gen)``.
        """
        c = self.config
        batch = check_lsd_inputs(c, occupancy, semantic, context)
        context = jnp.asarray(context)
        dtype = context.dtype
        k = c.map_size
        x = encode_maps(occupancy, semantic, c.num_semantic_classes, dtype)
        x = jnp.broadcast_to(x, batch + x.shape[-3:]).reshape((-1,) + x.shape[-3:])
        ctx = jnp.broadcast_to(context, batch + context.shape[-1:]).reshape(-1, context.shape[-1])

        skips = []
        for conv in self.enc:
            skips.append(x)
            x = nn.relu(conv(x))
        latent = nn.relu(self.enc_mix(x))
        latent = self.drop(latent, deterministic=deterministic)

        h = latent
        for i, deconv in enumerate(self.dec):
            h = nn.relu(_upsample(deconv, h, c.upsample))
            if c.skip:
                h = jnp.concatenate([h, skips[-1 - i]], -1)
            if i == 0:
                h = self.drop(h, deterministic=deterministic)
        general = self.dec_out(h)[..., 0]

        if use_context:
            z = nn.relu(self.ctx_in(ctx))  # (B, F)
            z = jnp.broadcast_to(z[:, None, None, :], latent.shape[:3] + z.shape[-1:])
            g = jnp.concatenate([latent, z], -1)
            for conv in self.ctx_mix:
                g = nn.relu(conv(g))
            g = self.drop(g, deterministic=deterministic)
            for deconv in self.ctx_up:
                g = nn.relu(_upsample(deconv, g, c.upsample))
            modifier = self.ctx_out(g)[..., 0]
        else:
            modifier = jnp.zeros_like(general)

        logits = general + modifier
        if c.log_range is not None:
            half = 0.5 * float(c.log_range)
            logits = half * jnp.tanh(logits / half)
        logits = logits.reshape(batch + (k, k))
        flat = logits.reshape(batch + (k * k,))
        log_prob = jax.nn.log_softmax(flat, axis=-1).reshape(batch + (k, k))
        return LSDOutput(log_prob, general.reshape(batch + (k, k)), modifier.reshape(batch + (k, k)))


def init_lsd(key, config: LSDConfig = LSDConfig(), dtype=jnp.float32):
    """Initialises ``(model, params)``; ``params`` in ``dtype``, the context branch included."""
    model = LSDNet(config)
    k = config.map_size
    occ = jnp.zeros((1, k, k), jnp.int8)
    ctx = jnp.zeros((1, config.context_dim), dtype)
    # One compiled program, as VoluMon's init: eagerly every initialiser op compiles on its own
    # (the same values, bit for bit, in about two thirds of the time).
    params = jax.jit(lambda k: model.init(k, occ, occ, ctx, use_context=True)["params"])(key)
    params = jax.tree_util.tree_map(lambda p: p.astype(dtype), params)
    return model, params


#: Top-level parameter names of each part (for freezing and inspection).
CONTEXT_BRANCH_PREFIX = "cs_"


def is_context_param(path: str) -> bool:
    """True for the context branch's parameters (``phi_cs``), given the top-level name."""
    return path.startswith(CONTEXT_BRANCH_PREFIX)


def lsd_nll(log_prob, path_mask) -> jax.Array:
    """Scaled negative log-likelihood of expert path cells (eq. 3.8), a scalar.

    log_prob: (..., H, W) normalised log-probabilities (:class:`LSDOutput` ``.log_prob``).
    path_mask: (..., H, W) non-negative weights of the expert path cells (bool or float; a cell
        visited twice may count twice). Per sample the loss is ``sum(mask * -log p) / sum(mask)``;
        samples with an empty mask (padding, or a path that leaves the crop at once) are left
        out of the batch mean. Returns 0 for an all-empty batch.
    """
    log_prob = jnp.asarray(log_prob)
    if log_prob.ndim < 2:
        raise ValueError(f"log_prob: expected shape (..., H, W), got shape {log_prob.shape}")
    path_mask = jnp.asarray(path_mask)
    if path_mask.shape[-2:] != log_prob.shape[-2:]:
        raise ValueError(
            f"path_mask: expected shape (..., {log_prob.shape[-2]}, {log_prob.shape[-1]}), got shape {path_mask.shape}"
        )
    w = path_mask.astype(log_prob.dtype)
    per_cell = -jnp.sum(w * log_prob, axis=(-2, -1))
    count = jnp.sum(w, axis=(-2, -1))
    has = count > 0
    # Safe division: empty samples divide by 1 and are masked out (finite gradients).
    per_sample = per_cell / jnp.where(has, count, 1.0)
    n = jnp.sum(has)
    return jnp.sum(jnp.where(has, per_sample, 0.0)) / jnp.maximum(n, 1).astype(log_prob.dtype)


def path_cells_to_mask(cells, map_size: int, dtype=jnp.float32) -> jax.Array:
    """Index lists ``(..., L, 2)`` of (row, col), ``-1`` (or off-crop) padding -> ``(..., k, k)``
    counts of each cell (duplicates add up)."""
    cells = jnp.asarray(cells)
    if cells.ndim < 2 or cells.shape[-1] != 2:
        raise ValueError(f"cells: expected shape (..., L, 2), got shape {cells.shape}")
    batch = cells.shape[:-2]
    flat = cells.reshape((-1,) + cells.shape[-2:])
    r, c = flat[..., 0], flat[..., 1]
    ok = (r >= 0) & (r < map_size) & (c >= 0) & (c < map_size)
    idx = jnp.where(ok, r * map_size + c, map_size * map_size)

    def one(i, w):
        return jnp.zeros(map_size * map_size, dtype).at[i].add(w, mode="drop")

    out = jax.vmap(one)(idx, ok.astype(dtype))
    return out.reshape(batch + (map_size, map_size))


def lsd_distribution(model: LSDNet, params, occupancy, semantic, context, *, use_context: bool = True) -> jax.Array:
    """Probabilities ``(..., H, W)`` (sum 1 per sample) from the trained network, dropout off."""
    out = model.apply(
        {"params": params},
        occupancy,
        semantic,
        context,
        deterministic=True,
        use_context=use_context,
    )
    return jnp.exp(out.log_prob)


def param_count(params) -> int:
    """Number of scalars in a parameter tree."""
    return int(sum(np.prod(p.shape) for p in jax.tree_util.tree_leaves(params)))


def split_params(params) -> tuple:
    """``(general, context)``: the encoder + decoder parameters and the context branch's."""
    gen = {k: v for k, v in params.items() if not is_context_param(k)}
    cs = {k: v for k, v in params.items() if is_context_param(k)}
    return gen, cs


__all__: Sequence[str] = (
    "LSDConfig",
    "LSDNet",
    "LSDOutput",
    "check_lsd_inputs",
    "encode_maps",
    "init_lsd",
    "is_context_param",
    "lsd_distribution",
    "lsd_nll",
    "param_count",
    "path_cells_to_mask",
    "split_params",
)
