"""Two-stage training of the LSD network (thesis 3.2.4, figure 3-4), with checkpoints and figures.

Stage one optimises the encoder and the general decoder on ``softmax(phi_gen)``; stage two
freezes them and optimises only the context branch on ``softmax(phi_gen + phi_cs)``. Both stages
run as one compiled step (:func:`make_two_stage_step`) with one optax transformation over the
whole parameter tree (:func:`two_stage_optimizer`): ``optax.partition`` gives each group
(:func:`jaxsem.models.split_params`) its stage's optimiser (:func:`stage_optimizer`: Adam, or
AdamW with ``weight_decay``), wrapped in ``optax.transforms.conditionally_mask`` so that it runs
only during its stage. An inactive optimiser's state does not move (moments, bias-correction
count and schedule count alike), so stage two starts exactly as a fresh Adam would. The step's
loss picks the stage from the same step counter with ``lax.cond``: stage two takes gradients
with respect to the context branch only (it does not backpropagate through the encoder), and the
frozen group is carried over unchanged (bit-identical).

Checkpoints (:mod:`jaxsem.checkpoint`, orbax, ``workdir/checkpoints``) hold the parameters, the
two-stage optimiser state and the step; a run restarted with the same config resumes from the
latest one and, since batches and dropout keys are functions of (seed, step), continues exactly
as an uninterrupted run would, across the stage boundary too. Checkpoints written before the
single step (one stage's optimiser state: ``train/checkpoints/lsd_*``) still load and resume:
their state is moved into the two-stage layout. Each evaluation writes
``workdir/figures/eval_<step>.png`` with the predicted distributions over a few validation maps
and appends a row to ``workdir/metrics.jsonl``. The workdir, resume and config rules are the
ones VoluMon's training shares (:class:`jaxsem.training.TrainingRun`).

Data parallel (``mesh=``, a one-axis :func:`jaxsem.parallel.data_mesh`): parameters and
optimiser state are replicated on every device and each host batch is split along its leading
axis (:func:`jaxsem.parallel.shard_batch`); the loss is still the global batch's mean, so a step
equals the single-device step up to floating-point summation order.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import pathlib
import time
from collections.abc import Callable
from typing import Any, NamedTuple, cast

import jax
import jax.numpy as jnp
import numpy as np
import optax

from .. import parallel
from .._files import check_npz
from ..checkpoint import Checkpointer, CheckpointError, latest_step
from ..models import LSDConfig, LSDNet, init_lsd, lsd_nll, split_params
from ..planning import DEFAULT_RESOLUTION
from ..training import LoadedModel, TrainingRun, config_json, load_run_config
from ._config import TrainConfig
from ._data import (
    batch_indices,
    check_expert_data,
    dihedral_augment,
    gather_batch,
    load_expert_data,
    split_by_building,
)


class TrainResult(NamedTuple):
    """What :func:`train_and_evaluate` returns.

    model: the :class:`~jaxsem.models.LSDNet`; params: trained parameters; history: one dict per
    evaluation (step, stage, train_nll, val_nll, uniform_nll, figure); resumed_from: the step the
    run started from (0 for a fresh run); workdir.
    """

    model: LSDNet
    params: dict
    history: list
    resumed_from: int
    workdir: pathlib.Path


def stage_optimizer(config: TrainConfig, stage: int) -> optax.GradientTransformation:
    """The optax optimiser training uses in ``stage`` (1: generator, 2: context head).

    Its learning rate follows ``config.lr_schedule`` over the stage's own steps. Training runs
    both inside :func:`two_stage_optimizer`; alone, it serves a loop of one stage around
    :func:`make_train_step`.
    """
    if stage not in (1, 2):
        raise ValueError(f"stage: expected 1 or 2, got {stage!r}")
    lr = config.learning_rate if stage == 1 else config.stage2_learning_rate
    steps = config.stage1_steps if stage == 1 else config.stage2_steps
    return _optimizer_for(float(lr), float(config.weight_decay), config.lr_schedule, int(steps))


#: lr_schedule='cosine' ends each stage at this fraction of its learning rate
COSINE_FLOOR = 0.1


@functools.lru_cache(maxsize=16)
def _optimizer_for(
    lr: float, weight_decay: float, schedule: str = "constant", steps: int = 0
) -> optax.GradientTransformation:
    rate: float | optax.Schedule = lr
    if schedule == "cosine":
        rate = optax.cosine_decay_schedule(lr, decay_steps=max(steps, 1), alpha=COSINE_FLOOR)
    if weight_decay > 0:
        return optax.adamw(rate, weight_decay=weight_decay)
    return optax.adam(rate)


#: the labels of :func:`two_stage_optimizer`'s two parameter groups, by stage
STAGE_LABELS = {1: "gen", 2: "cs"}


def _stage_labels(params) -> dict:
    """``{layer: 'gen' | 'cs'}``: a prefix of the parameter tree naming each layer's group."""
    gen, cs = split_params(params)
    return {**{k: STAGE_LABELS[1] for k in gen}, **{k: STAGE_LABELS[2] for k in cs}}


@functools.lru_cache(maxsize=16)
def two_stage_optimizer(config: TrainConfig) -> optax.GradientTransformation:
    """One optax transformation over the whole parameter tree for both stages.

    ``optax.partition`` labels the encoder + general decoder 'gen' and the context branch 'cs'
    (:data:`STAGE_LABELS`); each group gets its :func:`stage_optimizer`, wrapped in
    ``optax.transforms.conditionally_mask`` on the global step (< ``config.stage1_steps``: 'gen';
    after: 'cs'). An inactive group's updates are zero and its optimiser state, including Adam's
    bias-correction count and the schedule's count, stays as it was: stage two's first step is
    a fresh Adam's first step, as with a separate optimiser per stage. Both wrappers count every
    update; :func:`make_two_stage_step` reads the stage from that counter.
    """
    n1 = int(config.stage1_steps)

    def in_stage_one(step: Any, **_) -> jax.Array:
        return jnp.asarray(step) < n1

    def in_stage_two(step: Any, **_) -> jax.Array:
        return jnp.asarray(step) >= n1

    return optax.partition(
        {
            STAGE_LABELS[1]: optax.transforms.conditionally_mask(stage_optimizer(config, 1), in_stage_one),
            STAGE_LABELS[2]: optax.transforms.conditionally_mask(stage_optimizer(config, 2), in_stage_two),
        },
        _stage_labels,
    )


def _update_count(opt_state: Any) -> jax.Array:
    """Updates applied so far: the step counter of :func:`two_stage_optimizer`'s state (int32)."""
    return opt_state.inner_states[STAGE_LABELS[1]].inner_state.step


#: steps between two reads of the recent losses for the progress bar (each read waits for the
#: device to finish the step it reads)
_PROGRESS_EVERY = 25


def _stage_of(step: int, config: TrainConfig) -> int:
    """Stage that the *next* optimiser step belongs to."""
    return 1 if step < config.stage1_steps else 2


def _trainable(params, stage):
    gen, cs = split_params(params)
    return (gen, cs) if stage == 1 else (cs, gen)


def make_loss_fn(model: LSDNet, stage: int, augment: bool):
    """``loss(trainable, frozen, batch, key) -> nll``: stage 1 trains ``gen`` with the general
    distribution only, stage 2 trains ``cs`` on the full product."""

    def loss(trainable, frozen, batch, key):
        params = {**frozen, **trainable}
        k_aug, k_drop = jax.random.split(key)
        occ, sem, ctx, mask = (
            batch["occupancy"],
            batch["semantic"],
            batch["context"],
            batch["path_mask"],
        )
        if augment:
            occ, sem, ctx, mask = dihedral_augment(k_aug, occ, sem, ctx, mask)
        out = model.apply(
            {"params": params},
            occ,
            sem,
            ctx,
            deterministic=False,
            use_context=(stage == 2),
            rngs={"dropout": k_drop},
        )
        return lsd_nll(out.log_prob, mask)

    return loss


@functools.lru_cache(maxsize=16)
def make_train_step(
    model: LSDNet,
    tx: optax.GradientTransformation,
    stage: int,
    augment: bool = True,
    mesh: jax.sharding.Mesh | None = None,
):
    """A jitted ``step(params, opt_state, batch, key) -> (params, opt_state, loss)`` of one
    stage, ``tx`` an optimiser over that stage's parameters (:func:`stage_optimizer`), for a loop
    of one stage (training runs both in :func:`make_two_stage_step`). Cached per arguments, so a
    second run in the same process does not recompile.
    ``params`` and ``opt_state`` are donated: use the returned ones, not the arguments.
    With ``mesh`` the batch comes split over its devices (:func:`jaxsem.parallel.shard_batch`)
    and the parameters, optimiser state and loss come back replicated."""
    loss_fn = make_loss_fn(model, stage, augment)

    def step(params, opt_state, batch, key):
        trainable, frozen = _trainable(params, stage)
        value, grads = jax.value_and_grad(loss_fn)(trainable, frozen, batch, key)
        # optax 0.2.8's adam computes its bias correction as `decay ** count` (a Python float
        # and the int32 step count), which strict dtype promotion refuses: optax's update alone
        # runs under standard promotion.
        with jax.numpy_dtype_promotion("standard"):
            updates, opt_state = tx.update(grads, opt_state, trainable)
        trainable = cast(dict, optax.apply_updates(trainable, updates))  # same tree as its input, a dict
        return {**frozen, **trainable}, opt_state, value

    # params and opt_state are donated: the step writes the new state into their buffers (the
    # caller rebinds both to the outputs and never reads the old ones).
    if mesh is None:
        return jax.jit(step, donate_argnums=(0, 1))
    return jax.jit(step, out_shardings=parallel.replicated(mesh), donate_argnums=(0, 1))


def make_two_stage_step(
    model: LSDNet,
    config: TrainConfig,
    augment: bool = True,
    mesh: jax.sharding.Mesh | None = None,
):
    """The training step of both stages, compiled once: a jitted
    ``step(params, opt_state, batch, key) -> (params, opt_state, loss)`` with ``opt_state``
    from ``two_stage_optimizer(config).init(params)``.

    The stage comes from the optimiser state's step counter (no host sync, no recompile at the
    boundary): ``lax.cond`` runs stage one's loss (general distribution, gradients of the
    encoder + decoder) or stage two's (full product, gradients of the context branch only), and
    the frozen group's parameters are returned unchanged. ``params`` and ``opt_state`` are
    donated: use the returned ones. With ``mesh`` the batch comes split over its devices
    (:func:`jaxsem.parallel.shard_batch`) and the state and loss come back replicated. Cached per
    (model, optimiser, stage1_steps, augment, mesh).
    """
    return _two_stage_step(model, two_stage_optimizer(config), int(config.stage1_steps), augment, mesh)


def _select(use, new: dict, old: dict) -> dict:
    return jax.tree.map(lambda a, b: jnp.where(use, a, b), new, old)


@functools.lru_cache(maxsize=16)
def _two_stage_step(model, tx, stage1_steps: int, augment: bool, mesh):
    def stage_grads(stage: int):
        loss_fn = make_loss_fn(model, stage, augment)

        def grads(params, batch, key):
            trainable, frozen = _trainable(params, stage)
            value, g = jax.value_and_grad(loss_fn)(trainable, frozen, batch, key)
            return value, {**jax.tree.map(jnp.zeros_like, frozen), **g}

        return grads

    def step(params, opt_state, batch, key):
        first = _update_count(opt_state) < stage1_steps
        value, grads = jax.lax.cond(first, stage_grads(1), stage_grads(2), params, batch, key)
        # optax 0.2.8's adam computes its bias correction as `decay ** count` (a Python float
        # and the int32 step count), which strict dtype promotion refuses: optax's update alone
        # runs under standard promotion.
        with jax.numpy_dtype_promotion("standard"):
            updates, opt_state = tx.update(grads, opt_state, params)
        moved = cast(dict, optax.apply_updates(params, updates))
        # the frozen group gets zero updates; keeping its old values makes it bit-identical (an
        # added zero would turn a -0.0 into +0.0)
        gen_new, cs_new = split_params(moved)
        gen_old, cs_old = split_params(params)
        params = {**_select(first, gen_new, gen_old), **_select(~first, cs_new, cs_old)}
        return params, opt_state, value

    # params and opt_state are donated: the step writes the new state into their buffers (the
    # caller rebinds both to the outputs and never reads the old ones).
    if mesh is None:
        return jax.jit(step, donate_argnums=(0, 1))
    return jax.jit(step, out_shardings=parallel.replicated(mesh), donate_argnums=(0, 1))


@functools.lru_cache(maxsize=16)
def make_eval_fn(model: LSDNet, stage: int):
    """Jitted ``(params, batch) -> (per-sample nll (B,), has_path (B,), log_prob (B, k, k))``
    (cached per model and stage, so repeated evaluations do not recompile)."""

    @jax.jit
    def evaluate(params, batch):
        out = model.apply(
            {"params": params},
            batch["occupancy"],
            batch["semantic"],
            batch["context"],
            deterministic=True,
            use_context=(stage == 2),
        )
        w = batch["path_mask"].astype(out.log_prob.dtype)
        count = jnp.sum(w, axis=(-2, -1))
        nll = -jnp.sum(w * out.log_prob, axis=(-2, -1)) / jnp.maximum(count, 1.0)
        return nll, count > 0, out.log_prob

    return evaluate


def evaluate_nll(
    model: LSDNet,
    params,
    data: dict,
    idx: np.ndarray,
    stage: int = 2,
    batch_size: int = 32,
) -> float:
    """Mean per-path-cell NLL over samples ``idx`` (samples without path cells skipped)."""
    if len(idx) == 0:
        return float("nan")
    fn = make_eval_fn(model, stage)
    tot, n = 0.0, 0
    for i in range(0, len(idx), batch_size):
        sel = idx[i : i + batch_size]
        pad = batch_size - len(sel)
        b = gather_batch(data, np.concatenate([sel, np.repeat(sel[:1], pad)]))  # one compile
        nll, has, _ = fn(params, b)
        nll, has = np.asarray(nll)[: len(sel)], np.asarray(has)[: len(sel)]
        tot += float(nll[has].sum())
        n += int(has.sum())
    return tot / max(n, 1)


# ----------------------------------------------------------------------------- checkpoints


#: config fields that may change between the chunks of one run (length, logging, evaluation)
RESUMABLE_FIELDS = ("stage2_steps", "eval_every", "checkpoint_every", "keep", "num_figure_samples", "init_from")


def _state_like(model_params, config: TrainConfig):
    return {
        "params": model_params,
        "opt_state": two_stage_optimizer(config).init(model_params),
        "step": np.zeros((), np.int64),
    }


def _legacy_state_like(model_params, config: TrainConfig, step: int):
    """The layout of checkpoints written before the single two-stage step: the optimiser state
    of the stage that wrote step ``step`` only, over that stage's parameters."""
    stage = _stage_of(max(step - 1, 0), config)
    trainable, _ = _trainable(model_params, stage)
    return {
        "params": model_params,
        "opt_state": stage_optimizer(config, stage).init(trainable),
        "step": np.zeros((), np.int64),
    }


def _from_legacy(state: dict, config: TrainConfig) -> dict:
    """A legacy checkpoint's state (:func:`_legacy_state_like`) in the two-stage layout: its
    stage's optimiser state goes to that group, the other group's is fresh (stage one's is no
    longer used after the boundary; stage two's had not started), and both step counters are
    the checkpoint's step. Resuming from it continues exactly as the old two-step loop did."""
    step = int(state["step"])
    label = STAGE_LABELS[_stage_of(max(step - 1, 0), config)]
    opt_state: Any = two_stage_optimizer(config).init(state["params"])  # an optax PartitionState
    inner = opt_state.inner_states
    masked = inner[label]
    slot = masked.inner_state.inner_state
    leaves = jax.tree.leaves(state["opt_state"])
    like = jax.tree.leaves(slot)
    if len(leaves) != len(like) or any(np.shape(a) != np.shape(b) for a, b in zip(leaves, like)):
        raise CheckpointError(f"checkpoint of step {step}: its {label!r} optimiser state does not match the config")
    slot = jax.tree.unflatten(jax.tree.structure(slot), [jnp.asarray(a, b.dtype) for a, b in zip(leaves, like)])
    inner = {**inner, label: masked._replace(inner_state=masked.inner_state._replace(inner_state=slot))}
    count = jnp.asarray(step, jnp.int32)
    inner = {k: v._replace(inner_state=v.inner_state._replace(step=count)) for k, v in inner.items()}
    return {**state, "opt_state": opt_state._replace(inner_states=inner)}


def _restore(restore: Callable, params, config: TrainConfig) -> dict:
    """``restore(like)`` (a function of the step giving the target) in the two-stage layout,
    else in the legacy one, converted; a checkpoint readable in neither raises the first
    layout's :class:`~jaxsem.checkpoint.CheckpointError`."""
    try:
        return restore(lambda step: _state_like(params, config))
    except CheckpointError as exc:
        try:
            legacy = restore(lambda step: _legacy_state_like(params, config, step))
        except CheckpointError:
            raise exc from None
        return _from_legacy(legacy, config)


def config_to_dict(config: TrainConfig) -> dict:
    d = dataclasses.asdict(config)
    d["model"]["features"] = list(d["model"]["features"])
    return d


def config_from_dict(d: dict) -> TrainConfig:
    d = dict(d)
    model = dict(d.pop("model"))
    model["features"] = tuple(model["features"])
    # Configs saved before LSDConfig.upsample existed describe transposed-convolution networks
    # (the default then; 'resize' since the stripe-free shipped model).
    model.setdefault("upsample", "transpose")
    d.pop("data_dir", None)
    return TrainConfig(
        model=LSDConfig(**model),
        **{k: v for k, v in d.items() if k in {f.name for f in dataclasses.fields(TrainConfig)}},
    )


def load_trained(workdir, config: TrainConfig | None = None, *, step: int | None = None):
    """``(model, params, config)`` of a training ``workdir``: its latest checkpoint (or ``step``),
    with ``config`` or, when None, the run's ``config.json``. ``ValueError`` if there is none.
    The same contract as :func:`jaxsem.volumon.load_trained`."""
    workdir = pathlib.Path(workdir)
    if config is None:
        config = load_run_config(workdir, config_from_dict, "an LSD TrainConfig")
    dtype = jnp.float64 if config.dtype == "float64" else jnp.float32
    model, params = init_lsd(jax.random.PRNGKey(config.seed), config.model, dtype)
    ckpt = Checkpointer(workdir / "checkpoints", max_to_keep=None)
    try:
        step = ckpt.latest_step() if step is None else step
        if step is None:
            raise ValueError(f"workdir: no checkpoint under {str(workdir / 'checkpoints')!r}")
        state = _restore(lambda like: ckpt.restore(like(step), step=step), params, config)
    finally:
        ckpt.close()
    return model, state["params"], config


# ----------------------------------------------------------------------------- figures


def save_distribution_figure(path, batch: dict, log_prob: np.ndarray, title: str = "") -> None:
    """PNG of predicted distributions over the partial maps (one column per sample).

    Row 1: the partial occupancy (white free, grey unknown, black occupied) with objects (door
    green, window blue, exit sign red) and the expert path (magenta). Row 2: log10 of the
    predicted probability over the same map, the path on top, the goal direction as an arrow.
    """
    import matplotlib  # deferred: matplotlib is slow to import and only the figures need it

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    occ, sem, ctx, mask = (np.asarray(batch[k]) for k in ("occupancy", "semantic", "context", "path_mask"))
    n = len(occ)
    fig, axes = plt.subplots(2, n, figsize=(3.2 * n, 6.4), squeeze=False)
    for i in range(n):
        k = occ[i].shape[0]
        img = np.full(occ[i].shape + (3,), 0.6)
        img[occ[i] == 0] = 1.0
        img[occ[i] == 1] = 0.0
        for cls, col in (
            (2, (0.1, 0.7, 0.1)),
            (3, (0.2, 0.4, 1.0)),
            (4, (1.0, 0.1, 0.1)),
        ):
            img[sem[i] == cls] = col
        ax = axes[0, i]
        ax.imshow(img, origin="lower", interpolation="nearest")
        pr, pc = np.nonzero(mask[i])
        ax.scatter(pc, pr, s=1, c="m")
        # float32 context printed through tolist() reads 0.47999998927 and overlaps its
        # neighbours' titles: two decimals, as text
        ctx_text = ", ".join(f"{float(v):.2f}" for v in ctx[i])
        ax.set_title(f"map + expert path\nctx [{ctx_text}]", fontsize=7)
        ax = axes[1, i]
        im = ax.imshow(np.asarray(log_prob[i]) / np.log(10.0), origin="lower", cmap="viridis")
        ax.contour(occ[i] == 1, levels=[0.5], colors="w", linewidths=0.4)
        ax.scatter(pc, pr, s=1, c="m", alpha=0.5)
        c = k / 2
        ax.arrow(c, c, 0.3 * k * ctx[i, 0], 0.3 * k * ctx[i, 1], color="r", width=0.8)
        fig.colorbar(im, ax=ax, fraction=0.046, label="log10 p")
        ax.set_title("predicted distribution", fontsize=8)
        for a in axes[:, i]:
            a.set_xticks([])
            a.set_yticks([])
    if title:
        fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


# ----------------------------------------------------------------------------- main entry


def train_and_evaluate(
    config: TrainConfig,
    workdir,
    data=None,
    progress: bool = True,
    stop_at: int | None = None,
    *,
    force: bool = False,
    log: Callable[[str], None] | None = None,
    mesh: jax.sharding.Mesh | None = None,
) -> TrainResult:
    """Trains the LSD network in two stages; checkpoints, metrics and figures go to ``workdir``.

    config: :class:`TrainConfig`; workdir: folder (created); an existing checkpoint there is
    resumed (the scaffold of :class:`jaxsem.training.TrainingRun`: a "resumed from step N" line,
    ``metrics.jsonl`` cut back to the checkpoint, :class:`jaxsem.training.ConfigMismatchError`
    when the config differs in more than :data:`RESUMABLE_FIELDS` unless ``force``). data: a
    dict of arrays in the expert-shard schema, or shard paths / a folder of ``expert_*.npz``;
    default: ``workdir / 'data'``. progress: tqdm bar. stop_at: end this run (with a
    checkpoint) at that step, for chunked runs; a later call resumes. log: called with the
    resume line and each evaluation's line. mesh: train data-parallel over this one-axis mesh
    (:func:`jaxsem.parallel.data_mesh` or :func:`jaxsem.parallel.devices_mesh`): parameters and
    optimiser state replicated, each batch split over the devices; ``config.batch_size`` must be
    a multiple of the device count (else ``ValueError`` naming ``batch_size``); None (default):
    one device, as before. Returns a :class:`TrainResult` whose ``history`` is
    the evaluation rows of ``metrics.jsonl`` (earlier chunks included).
    """
    if not isinstance(config, TrainConfig):
        raise ValueError(f"config: expected a jaxsem.lsd.TrainConfig, got {type(config).__name__}")
    parallel.check_batch_size(config.batch_size, mesh)
    workdir = pathlib.Path(workdir)
    # first: a second run on the same workdir is refused before any work (the workdir's lock)
    run = TrainingRun(
        workdir,
        config_json(config_to_dict(config)),
        keep=config.keep,
        resumable=RESUMABLE_FIELDS,
        force=force,
        normalise=lambda old: config_to_dict(config_from_dict(old)),
        log=log,
    )
    with run:
        return _train(config, workdir, run, data, progress, stop_at, log, mesh)


def _train(config, workdir, run, data, progress, stop_at, log, mesh) -> TrainResult:
    if data is None:
        data = workdir / "data"
    if not isinstance(data, dict):
        data = load_expert_data(data)
    check_expert_data(data, config.model.map_size, config.model.context_dim)

    dtype = jnp.float64 if config.dtype == "float64" else jnp.float32
    key = jax.random.PRNGKey(config.seed)
    model, params = init_lsd(key, config.model, dtype)
    # Dropout / augmentation keys use the 'rbg' generator: threefry dropout masks made the
    # train step's compile slower (benchmarks/RESULTS.md, "Other: devices and design measurements").
    drop_key = jax.random.key(config.seed, impl="rbg")
    train_idx, val_idx = split_by_building(data, config.val_fraction, config.seed, config.val_every_nth_building)
    fig_idx = val_idx[: config.num_figure_samples] if len(val_idx) else train_idx[: config.num_figure_samples]

    tx = two_stage_optimizer(config)
    opt_state = None
    if run.latest_step is not None:
        state = _restore(run.restore, params, config)
        params, opt_state = state["params"], state["opt_state"]
    elif config.init_from:
        if not pathlib.Path(config.init_from).exists():
            raise ValueError(f"init_from: no such model file or training workdir {config.init_from!r}")
        params = warm_start_params(params, load_model(config.init_from)[1], "init_from")
    start = run.start
    run.begin()
    # the step donates params and opt_state: train on buffers of our own, never on arrays a
    # caller or a cache (a loaded model, a warm start's source) may still hold
    params = jax.tree.map(jnp.copy, params)
    opt_state = tx.init(params) if opt_state is None else jax.tree.map(jnp.copy, opt_state)
    rep = None if mesh is None else parallel.replicated(mesh)
    if rep is not None:
        params, opt_state = jax.device_put((params, opt_state), rep)

    uniform_nll = float(np.log(config.model.map_size**2))
    figures = workdir / "figures"
    figures.mkdir(exist_ok=True)
    step = start
    train_step = make_two_stage_step(model, config, augment=True, mesh=mesh)
    # The last losses stay on the device: reading one back every step would wait for that step to
    # finish (a host sync per step); they are read in bulk for the progress bar and the metrics.
    recent: list = []

    def recent_mean() -> float:
        return float(np.mean(np.asarray(jax.device_get(recent), np.float64))) if recent else float("nan")

    def evaluate(stage_now: int) -> dict:
        val_nll = evaluate_nll(model, params, data, val_idx, stage_now) if len(val_idx) else float("nan")
        b = gather_batch(data, fig_idx)
        _, _, lp = make_eval_fn(model, stage_now)(params, b)
        fig = figures / f"eval_{step:06d}.png"
        save_distribution_figure(
            fig,
            b,
            np.asarray(lp),
            f"step {step} (stage {stage_now}): val NLL {val_nll:.3f} (uniform {uniform_nll:.3f})",
        )
        rec = {
            "step": step,
            "stage": stage_now,
            "train_nll": recent_mean(),
            "val_nll": val_nll,
            "uniform_nll": uniform_nll,
            "figure": str(fig),
            "time": time.time(),
        }
        run.log_metrics(rec)
        return rec

    last = config.total_steps if stop_at is None else min(int(stop_at), config.total_steps)
    for step in run.steps(start, last, total=config.total_steps, desc="lsd train", progress=progress):
        stage = _stage_of(step, config)  # for the logs; the step reads its own counter
        batch = gather_batch(data, batch_indices(train_idx, config.batch_size, step, config.seed))
        if mesh is not None:
            batch = parallel.shard_batch(batch, mesh)
        skey = jax.random.fold_in(drop_key, step)
        params, opt_state, loss = train_step(params, opt_state, batch, skey)
        step += 1
        recent.append(loss)
        recent = recent[-50:]
        if step % _PROGRESS_EVERY == 0:
            run.postfix({"stage": stage, "nll": recent_mean()})
        end_of_stage = step == config.stage1_steps or step == config.total_steps
        if step % config.eval_every == 0 or end_of_stage:
            rec = evaluate(stage)
            run.write(
                f"step {step} stage {stage}: train NLL {rec['train_nll']:.3f}, "
                f"val NLL {rec['val_nll']:.3f} (uniform {uniform_nll:.3f})"
            )
        if step % config.checkpoint_every == 0 or end_of_stage or step == last:
            run.save(step, {"params": params, "opt_state": opt_state, "step": np.asarray(step, np.int64)})
        if step == config.stage1_steps:
            recent = []  # stage two's losses are of another distribution
    history = run.metrics()
    return TrainResult(model, params, history, start, workdir)


# ----------------------------------------------------------------------------- warm start


def warm_start_params(params, source, name: str = "source"):
    """``params`` with every leaf taken from ``source`` (same layer / parameter names).

    The one change of shape allowed: a 2 x 2 transposed-convolution kernel ``(2, 2, in, out)``
    into the 3 x 3 convolution of a resize upsampling ``(3, 3, in, out)`` (``LSDConfig.upsample``
    'transpose' to 'resize'): the centre tap gets the mean of the four parity kernels, the other
    taps zero, so on a nearest-neighbour doubled input the new layer is the old one with its
    parity dependence averaged out. ``ValueError`` naming ``name`` and the parameter for a missing
    parameter or any other shape change.
    """
    flat = {
        "/".join(str(getattr(k, "key", k)) for k in path): v for path, v in jax.tree_util.tree_leaves_with_path(source)
    }

    def take(path, leaf):
        key = "/".join(str(getattr(k, "key", k)) for k in path)
        if key not in flat:
            raise ValueError(f"{name}: has no parameter {key!r} (a different network)")
        src = np.asarray(flat[key])
        if src.shape == leaf.shape:
            return jnp.asarray(src, leaf.dtype)
        if src.ndim == 4 and src.shape[:2] == (2, 2) and leaf.shape[:2] == (3, 3) and src.shape[2:] == leaf.shape[2:]:
            out = np.zeros(leaf.shape, src.dtype)
            out[1, 1] = src.mean(axis=(0, 1))
            return jnp.asarray(out, leaf.dtype)
        raise ValueError(f"{name}: parameter {key!r} has shape {src.shape}, the network expects {tuple(leaf.shape)}")

    return jax.tree_util.tree_map_with_path(take, params)


# ----------------------------------------------------------------------------- single-file export


def export_model(path, config: TrainConfig, params, *, cell_size: float = DEFAULT_RESOLUTION) -> pathlib.Path:
    """Writes the network config and parameters to one ``.npz`` file (no optimiser state).

    Keys: ``config_json`` (the :class:`TrainConfig` as JSON), ``cell_size`` (metres per cell of
    the maps it was trained on: the expert shards' ``resolution``, 0.1 m by default) and one
    ``params/<layer>/<name>`` array per parameter. Read it back with :func:`load_model_file`.
    """
    if not (np.isfinite(cell_size) and cell_size > 0):
        raise ValueError(f"cell_size: expected metres per cell > 0, got {cell_size}")
    path = pathlib.Path(path)
    flat = {}
    for layer, leaves in params.items():
        for name, arr in leaves.items():
            flat[f"params/{layer}/{name}"] = np.asarray(arr)
    np.savez_compressed(
        path, config_json=np.str_(json.dumps(config_to_dict(config))), cell_size=np.float64(cell_size), **flat
    )
    return path


def model_cell_size(path) -> float:
    """Metres per cell of the maps the model in ``path`` (an exported ``.npz``) was trained on:
    its ``cell_size`` key, or 0.1 m for a file written before the key existed (every shipped model
    was trained on the generator's 0.1 m buildings)."""
    with np.load(pathlib.Path(path)) as z:
        return float(z["cell_size"]) if "cell_size" in z.files else DEFAULT_RESOLUTION


def load_model_file(path):
    """``(model, params, config)`` from a file written by :func:`export_model`."""
    path = pathlib.Path(path)
    if not path.exists():
        raise ValueError(f"path: no such model file {str(path)!r}")
    check_npz(path)  # the declared sizes within budget before anything is inflated
    with np.load(path) as z:
        if "config_json" not in z:
            raise ValueError(f"path: {str(path)!r} is not an exported LSD model (no config_json)")
        config = config_from_dict(json.loads(str(z["config_json"])))
        params: dict = {}
        for key in z.files:
            if key.startswith("params/"):
                _, layer, name = key.split("/")
                params.setdefault(layer, {})[name] = jnp.asarray(z[key])
    model = LSDNet(config.model)
    k = config.model.map_size
    occ = jnp.zeros((1, k, k), jnp.int8)
    # eval_shape: the parameter structure without compiling an initialisation.
    like = jax.eval_shape(
        lambda: model.init(jax.random.PRNGKey(0), occ, occ, jnp.zeros((1, config.model.context_dim), jnp.float32))
    )["params"]
    if jax.tree_util.tree_structure(like) != jax.tree_util.tree_structure(params):
        raise ValueError(f"path: parameters in {str(path)!r} do not match the model config")
    return model, params, config


#: The first CPU-sized model (``train/lsd.py --config cpu``: 6 train buildings x 80 expert samples,
#: 300 + 150 steps, unbounded output). Kept for comparison; not the default.
PRETRAINED_CPU = pathlib.Path(__file__).resolve().parent / "pretrained_cpu.npz"

#: The shipped model, the default of every LSD entry point: one model for every kind of map, the
#: generated-building model fine-tuned on the house, campus and train building families in equal
#: parts (``train/lsd_house_gpu.py --family house campus``; data, steps, curves and held-out
#: results in ``MODEL_CARD.md`` next to it).
PRETRAINED = pathlib.Path(__file__).resolve().parent / "pretrained.npz"

#: The generated-building model (``train/lsd.py --config scale``: the train family's grids of
#: rooms, bounded output range; ``MODEL_CARD.md``), from which the others are fine-tuned.
PRETRAINED_GENERATED = pathlib.Path(__file__).resolve().parent / "pretrained_generated.npz"


#: The house model: the shipped model fine-tuned on the ``house`` building family mixed with the
#: train family (``train/lsd_house_gpu.py``; ``MODEL_CARD.md``, "The house model").
PRETRAINED_HOUSE = pathlib.Path(__file__).resolve().parent / "pretrained_house.npz"

#: The campus model: the shipped model fine-tuned on the ``campus`` building family (long
#: university buildings, 3-6 m corridors) mixed with the train family (``train/lsd_house_gpu.py
#: --family campus``; ``MODEL_CARD.md``, "The campus model").
PRETRAINED_CAMPUS = pathlib.Path(__file__).resolve().parent / "pretrained_campus.npz"

#: Shipped models by name (:func:`load_model`).
MODELS = {
    "default": PRETRAINED,
    "generated": PRETRAINED_GENERATED,
    "house": PRETRAINED_HOUSE,
    "campus": PRETRAINED_CAMPUS,
    "cpu": PRETRAINED_CPU,
}


def load_model(source=None) -> LoadedModel:
    """``(model, params, config, meta)`` (a :class:`jaxsem.training.LoadedModel`, the shape
    :func:`jaxsem.volumon.load_pretrained` returns too) from a training workdir, an exported
    ``.npz`` file, a shipped model's name (:data:`MODELS`: 'default', 'generated', 'house', 'campus', 'cpu'), or (None)
    the shipped model :data:`PRETRAINED` (:data:`PRETRAINED_CPU` if that file is absent).
    ``meta``: ``name`` (the file or folder), ``step`` (a workdir's checkpoint; None for a file) and
    ``cell_size`` (metres per map cell it was trained on, :func:`model_cell_size`; 0.1 m for a
    workdir): pass it on, ``LSDSampler(model, params, cell_size=meta["cell_size"])``."""
    if source is None:
        source = PRETRAINED if PRETRAINED.exists() else PRETRAINED_CPU
    if isinstance(source, str) and source in MODELS:
        source = MODELS[source]
    source = pathlib.Path(source)
    if source.suffix == ".npz":
        model, params, config = load_model_file(source)
        meta = {"name": str(source), "step": None, "cell_size": model_cell_size(source)}
        return LoadedModel(model, params, config, meta)
    model, params, config = load_trained(source)
    meta = {"name": str(source), "step": latest_step(source / "checkpoints"), "cell_size": DEFAULT_RESOLUTION}
    return LoadedModel(model, params, config, meta)
