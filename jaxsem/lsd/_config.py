"""Training configurations for the LSD network (defaults, then variants that change a few fields).

A config is a frozen dataclass; ``dataclasses.replace(cfg, field=value)`` or
:func:`jaxsem.config.override` (dotted names, strings parsed) makes a variant; :data:`PRESETS`
names the variants this package uses.
"""

from __future__ import annotations

import dataclasses

from .._checks import check_fields
from ..config import Presets
from ..models import LSDConfig


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """Everything :func:`jaxsem.lsd.train_and_evaluate` needs besides the data and workdir.

    model: network sizes (:class:`jaxsem.models.LSDConfig`).
    stage1_steps / stage2_steps: optimiser steps of stage one (encoder + decoder, general
        distribution) and stage two (context branch only, encoder + decoder frozen).
    batch_size, learning_rate (Adam, per stage), weight_decay (decoupled, AdamW; 0 = Adam).
    lr_schedule: 'constant' (default) or 'cosine': each stage's rate falls along a half cosine
        from its learning rate to 10 % of it over that stage's steps (the schedule counts the
        stage optimiser's own steps, so a resumed run continues it exactly).
    eval_every: steps between evaluations (validation NLL + a PNG of predicted distributions);
        the end of each stage is always evaluated.
    checkpoint_every: steps between checkpoints (the last step is always saved); keep: how many.
    val_fraction: share of the samples held out for validation (split by shard file when there
        are several shards, so validation maps come from other buildings), at least one sample.
    val_every_nth_building: when > 0, validation is instead every building whose seed is a
        multiple of this, a split that stays fixed while shards are still being added (chunked
        runs that train on data as it is generated).
    num_figure_samples: validation samples drawn in each evaluation figure.
    seed: parameter init, batch order, dropout.
    dtype: parameter / compute dtype name ('float32' or 'float64').
    init_from: '' (default: a fresh initialisation) or a model (an exported ``.npz``,
        :func:`jaxsem.lsd.export_model`, or a training workdir) whose parameters start a new run
        (fine-tuning; a resumed run ignores it, so it may differ between chunks). Every parameter is copied by name; the one change of shape
        allowed is ``model.upsample`` 'transpose' to 'resize': each 2 x 2 transposed kernel
        becomes the centre tap of the 3 x 3 convolution, averaged over its four parities, so the
        new network starts as the old one without the parity-dependent weights (the stripes).
    """

    model: LSDConfig = LSDConfig()
    stage1_steps: int = 2000
    stage2_steps: int = 1000
    batch_size: int = 16
    learning_rate: float = 1e-3
    stage2_learning_rate: float = 1e-3
    weight_decay: float = 0.0
    lr_schedule: str = "constant"
    eval_every: int = 500
    checkpoint_every: int = 500
    keep: int = 2
    val_fraction: float = 0.1
    val_every_nth_building: int = 0
    num_figure_samples: int = 4
    seed: int = 0
    dtype: str = "float32"
    init_from: str = ""

    def __post_init__(self):
        check_fields(self, ("stage1_steps", "stage2_steps"), ">= 0", lambda v: v >= 0)
        check_fields(self, ("batch_size", "eval_every", "checkpoint_every", "keep"), ">= 1", lambda v: v >= 1)
        if not 0.0 <= self.val_fraction < 1.0:
            raise ValueError(f"val_fraction: expected in [0, 1), got {self.val_fraction}")
        if self.lr_schedule not in ("constant", "cosine"):
            raise ValueError(f"lr_schedule: expected 'constant' or 'cosine', got {self.lr_schedule!r}")
        if self.dtype not in ("float32", "float64"):
            raise ValueError(f"dtype: expected 'float32' or 'float64', got {self.dtype!r}")

    @property
    def total_steps(self) -> int:
        return self.stage1_steps + self.stage2_steps


#: The named presets (:class:`jaxsem.config.Presets`): each a function of the default that changes a
#: few fields; :func:`get_config` also takes a JSON file of fields over the default.
PRESETS: Presets[TrainConfig] = Presets(TrainConfig)


@PRESETS.register("cpu")
def _cpu(c: TrainConfig) -> TrainConfig:
    """CPU-sized run used by ``benchmarks/lsd/lsd_table31.py`` when it trains its own model."""
    return dataclasses.replace(c, stage1_steps=1200, stage2_steps=600, eval_every=600, checkpoint_every=600)


@PRESETS.register("scale")
def _scale(c: TrainConfig) -> TrainConfig:
    """The shipped model's base training (``scale_resize`` fine-tunes it): expert data from
    240 train buildings (``infer/make_expert_data.py --buildings 240``), bounded output range
    (``log_range=8``, see :class:`jaxsem.models.LSDConfig`), transposed-convolution upsampling
    so that ``train/checkpoints/lsd_scale`` resumes with this preset, 8,000 + 2,500 steps at
    batch 16 with a cosine rate decay per stage, checkpoints every 1,000 steps (chunked: a
    restart resumes). Validation: the buildings whose seed is a multiple of 20. A network
    without stripes from the start: ``--set model.upsample=resize``, or the ``scale_resize``
    fine-tune from it."""
    return dataclasses.replace(
        c,
        model=LSDConfig(log_range=8.0, upsample="transpose"),
        stage1_steps=8000,
        stage2_steps=2500,
        batch_size=16,
        lr_schedule="cosine",
        eval_every=1000,
        checkpoint_every=1000,
        keep=2,
        val_every_nth_building=20,
    )


@PRESETS.register("scale_resize")
def _scale_resize(c: TrainConfig) -> TrainConfig:
    """The ``scale`` run's network with resize upsampling (no stripes, ``LSDConfig.upsample``),
    fine-tuned from a ``scale`` model: pass it as ``init_from`` (``--set
    init_from=train/checkpoints/lsd_scale``); 3,000 + 1,500 steps."""
    base = _scale(c)
    return dataclasses.replace(
        base,
        model=dataclasses.replace(base.model, upsample="resize"),
        stage1_steps=3000,
        stage2_steps=1500,
    )


@PRESETS.register("house")
def _house(c: TrainConfig) -> TrainConfig:
    """The shipped network fine-tuned on expert data from the ``house`` building family mixed
    with the train family (``train/lsd_house_gpu.py``; pass the shipped model as ``init_from``):
    8,000 + 3,000 steps at batch 32, Adam 5e-4 with a cosine decay per stage, validation the
    buildings whose seed is a multiple of 20 (of either family); minutes on one GPU."""
    base = _scale_resize(c)
    return dataclasses.replace(
        base,
        stage1_steps=8000,
        stage2_steps=3000,
        batch_size=32,
        learning_rate=5e-4,
        stage2_learning_rate=5e-4,
        eval_every=1000,
        checkpoint_every=1000,
    )


@PRESETS.register("pair")
def _pair(c: TrainConfig) -> TrainConfig:
    """A 2,000 + 1,000-step run of the shipped network (``scale`` with resize upsampling) from a
    fresh initialisation, for paired comparisons on the same data: the full-map oracle against the
    partial-map network (``benchmarks/lsd/lsd_oracle.py``); about 20 minutes on one CPU core."""
    return dataclasses.replace(
        _scale_resize(c), stage1_steps=2000, stage2_steps=1000, eval_every=500, checkpoint_every=500
    )


@PRESETS.register("tiny")
def _tiny(c: TrainConfig) -> TrainConfig:
    """Seconds-long run for tests and the quick demo (a smaller network, few steps)."""
    return dataclasses.replace(
        c,
        model=LSDConfig(features=(4, 8, 8, 8), context_features=8),
        stage1_steps=30,
        stage2_steps=20,
        batch_size=4,
        learning_rate=3e-3,
        stage2_learning_rate=3e-3,
        eval_every=25,
        checkpoint_every=25,
        num_figure_samples=2,
    )


def default_config() -> TrainConfig:
    """The default (a few minutes of training on a CPU for a few thousand samples)."""
    return PRESETS["default"]


def cpu_config() -> TrainConfig:
    """The ``cpu`` preset."""
    return PRESETS["cpu"]


def scale_config() -> TrainConfig:
    """The ``scale`` preset (the shipped model's run)."""
    return PRESETS["scale"]


def tiny_config() -> TrainConfig:
    """The ``tiny`` preset."""
    return PRESETS["tiny"]


def get_config(name: str = "default") -> TrainConfig:
    """A preset by name (``PRESETS.names``: default, cpu, scale, tiny) or a JSON file of
    :class:`TrainConfig` fields over the default (:func:`jaxsem.config.load`).
    ``ValueError`` naming it otherwise."""
    return PRESETS.resolve(name)
