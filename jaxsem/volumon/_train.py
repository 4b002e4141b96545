"""Training loop: ``train_and_evaluate(config, workdir)`` (optax Adam, orbax checkpoints, tqdm).

Data: with ``config.data == "device"`` (default) each step's batch is made inside the jitted train
step from ``fold_in(train_key(seed), step)`` (:mod:`jaxsem.volumon._device_data`): no host work
per step, one compilation. ``"host"`` keeps the numpy generator indexed by ``(seed, index)``
(:func:`jaxsem.volumon.make_batch`, epoch permutations of ``num_train`` samples).

Exact resume: the train state (step, params, batch-norm statistics, Adam state, PRNG key) is
checkpointed every ``checkpoint_every`` steps; the data of step ``s`` is a pure function of
``(seed, s)``, so a run interrupted after any checkpoint and restarted with the same config
and workdir reproduces the uninterrupted run step for step. On resume ``metrics.jsonl`` is cut
back to the checkpoint's step (no duplicate rows), a "resumed from step N" line is logged, and a
config that differs from the run's ``config.json`` in anything but its length and logging
settings raises :class:`ConfigMismatchError` unless ``force=True``.

Data parallel (``mesh=``, a one-axis :func:`jaxsem.parallel.data_mesh`): the train state is
replicated on every device and each step's batch is split along its leading axis (the
device-made batch by a sharding constraint inside the jitted step, a host batch by
:func:`jaxsem.parallel.shard_batch`). The loss and the batch-norm statistics are still the
global batch's, so a step equals the single-device step up to floating-point summation order.
"""

from __future__ import annotations

import functools
import json
import pathlib
import time
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optax

from .. import parallel
from ..checkpoint import Checkpointer
from ..models import VoluMonNet, box_features, expected_params, reconstruct, select_class_params
from ..training import TrainingRun, config_json, load_run_config
from ._configs import TrainConfig, config_from_dict
from ._device_data import augmentation_numbers, device_batch, held_out_set, train_key
from ._eval import evaluate_predictions
from ._losses import volumon_loss
from ._synthetic import make_batch

TRAIN_KEYS = (
    "local",
    "global",
    "box_input",
    "box_left",
    "box_right",
    "K",
    "baseline",
    "points",
    "point_mask",
    "class_id",
    "sample_mask",
    "class_shape",
    "gt_rotation",
    "gt_center",
    "gt_half_extents",
)

#: the key a 2-D label batch sets (:meth:`jaxsem.volumon.LabelBatch.as_train_batch`): the batch
#: carries no 3-D ground truth, so a loss that needs it is refused
LABELS_2D_ONLY = "labels_2d_only"

#: config fields that may change between the chunks of one run (length, logging, evaluation)
RESUMABLE_FIELDS = ("num_steps", "checkpoint_every", "keep_checkpoints", "eval_every", "num_eval", "log_every")


# --------------------------------------------------------------------------------------------
# augmentation (thesis 5.5.2: hue/saturation jitter, random erasing)


def _hue_saturation(img, hue, sat):
    gray = jnp.mean(img, -1, keepdims=True)
    c = img - gray
    # hue: rotation of the chroma about the gray axis (Rodrigues about (1,1,1)/sqrt 3)
    k = jnp.ones(3, img.dtype) / jnp.sqrt(3.0)
    cos, sin = jnp.cos(hue), jnp.sin(hue)
    rot = c * cos + jnp.cross(k, c) * sin + k * jnp.sum(k * c, -1, keepdims=True) * (1 - cos)
    return jnp.clip(gray + sat * rot, 0.0, 1.0)


def _erase(img, rect, on, val):
    S = img.shape[0]
    wh = rect[2:] * S
    xy = rect[:2] * (S - wh)
    r = jnp.arange(S, dtype=img.dtype)
    inside = ((r >= xy[1]) & (r < xy[1] + wh[1]))[:, None] & ((r >= xy[0]) & (r < xy[0] + wh[0]))[None, :]
    return jnp.where(on & inside[..., None], val, img)


def augmentation_params(seed: int, step: int, batch_size: int, erase_prob: float = 0.5):
    """Host-drawn augmentation numbers of ``step`` (numpy: deterministic in (seed, step), and no
    threefry compile): hue (+-0.1 turn), saturation (0.7-1.3), erase rectangle, on/off, colour."""
    rng = np.random.default_rng([seed, 15485863, step])
    B = batch_size
    rect = np.concatenate([rng.uniform(size=(B, 2)), rng.uniform(0.1, 0.4, size=(B, 2))], -1)
    return {
        "hue": rng.uniform(-0.2 * np.pi, 0.2 * np.pi, B).astype(np.float32),
        "sat": rng.uniform(0.7, 1.3, B).astype(np.float32),
        "erase_rect": rect.astype(np.float32),
        "erase_on": rng.uniform(size=B) < erase_prob,
        "erase_val": rng.uniform(size=(B, 3)).astype(np.float32),
    }


def augment(aug, local, glob):
    """Per-sample hue / saturation jitter on both inputs and random erasing on the local patch
    (thesis 5.5.2). ``aug`` from :func:`augmentation_params`; local, glob: (B, S, S, 3)."""

    def one(a, lo, gl):
        lo = _hue_saturation(lo, a["hue"], a["sat"])
        keep = jnp.max(gl, -1, keepdims=True) > 0  # keep zeros zero
        gl = jnp.where(keep, _hue_saturation(gl, a["hue"], a["sat"]), jnp.zeros((), gl.dtype))
        return _erase(lo, a["erase_rect"], a["erase_on"], a["erase_val"]), gl

    return jax.vmap(one)(aug, local, glob)


# --------------------------------------------------------------------------------------------


def predict_params(
    model: VoluMonNet, variables, local, glob, class_id=None, class_mode="true", train=False, box=None, K=None
):
    """Network free parameters (B, 10) (class row or expectation) and class logits (B, N).

    ``box`` (B, 4) and ``K`` (B, 3, 3) are needed by networks with ``config.box_input``."""
    feats = None
    if model.config.box_input:
        if box is None or K is None:
            raise ValueError("box, K: this network (box_input=True) needs the input boxes and intrinsics")
        feats = box_features(box, K)
    if train:
        out, new_vars = model.apply(variables, local, glob, train=True, box_feats=feats, mutable=["batch_stats"])
    else:
        out, new_vars = model.apply(variables, local, glob, train=False, box_feats=feats), {}
    if model.config.num_classes == 1:
        phi = out.phi[..., 0, :]
    elif class_mode == "expectation" or class_id is None:
        phi = expected_params(out.phi, out.class_logits)
    else:
        phi = select_class_params(out.phi, class_id)
    return phi, out.class_logits, new_vars


@functools.lru_cache(maxsize=16)
def make_predict_fn(model: VoluMonNet, config: TrainConfig) -> Callable:
    """Jitted ``(variables, local, glob, box, K, class_id) -> (phi (B,10), Ellipsoid)`` for inference."""

    @jax.jit
    def predict(variables, local, glob, box, K, class_id=None):
        phi, logits, _ = predict_params(model, variables, local, glob, class_id, config.class_mode, box=box, K=K)
        return phi, reconstruct(phi, box, K, config.recon), logits

    return predict


#: What the network reads from a batch dict (``make_batch``, ``held_out_set``, the door and LM-O
#: batches), in :func:`make_predict_fn`'s order.
BATCH_INPUTS = ("local", "global", "box_input", "K", "class_id")


def predict_batch(model: VoluMonNet, config: TrainConfig, variables, batch) -> tuple:
    """``(phi, Ellipsoid, class_logits)`` of :func:`make_predict_fn` on a batch dict: the one
    place that knows which of a batch's arrays the network reads (:data:`BATCH_INPUTS`)."""
    missing = [k for k in BATCH_INPUTS if k not in batch]
    if missing:
        raise ValueError(f"batch: missing {missing}; expected the keys {list(BATCH_INPUTS)}")
    return make_predict_fn(model, config)(variables, *(jnp.asarray(batch[k]) for k in BATCH_INPUTS))


@functools.lru_cache(maxsize=16)
def _model_and_init(model_config, learning_rate):
    model = VoluMonNet(model_config)
    s = model_config.input_size
    x = jnp.zeros((1, s, s, 3), jnp.float32)
    init = jax.jit(lambda key: model.init(key, x, x, train=False))
    return model, init, optax.adam(learning_rate)


def init_state(config: TrainConfig):
    """Fresh train state (a dict pytree) and the model and optimiser."""
    model, init, tx = _model_and_init(config.model, config.learning_rate)
    key = jax.random.PRNGKey(config.seed)
    k_init, k_rng = jax.random.split(key)
    variables = init(k_init)
    state = {
        "step": jnp.zeros((), jnp.int32),
        "params": variables["params"],
        "batch_stats": variables["batch_stats"],
        "opt_state": tx.init(variables["params"]),
        "rng": k_rng,
    }
    return state, model, tx


def batch_indices(config: TrainConfig, step: int) -> np.ndarray:
    """Training-set indices of ``step``: consecutive slices of per-epoch permutations."""
    B, N = config.batch_size, config.num_train
    start = step * B
    out = []
    while len(out) < B:
        epoch, offset = divmod(start + len(out), N)
        perm = np.random.default_rng([config.seed, 104729, epoch]).permutation(N)
        out.extend(perm[offset : offset + B - len(out)].tolist())
    return np.asarray(out)


def get_train_batch(config: TrainConfig, step: int):
    batch = make_batch(
        config.seed,
        batch_indices(config, step),
        config.scene,
        config.model.input_size,
        config.model.global_padding,
        "train",
        config.noisy,
    )
    return _host_batch(config, batch, step)


def _host_batch(config: TrainConfig, batch: dict, step: int) -> dict:
    """A host-made batch (the generator's or a ``batch_fn``'s) as the host train step takes it:
    the :data:`TRAIN_KEYS` and the augmentation numbers of the step."""
    missing = [k for k in TRAIN_KEYS if k not in batch]
    if missing:
        raise ValueError(f"batch_fn: the batch of step {step} lacks {missing} (expected the keys {list(TRAIN_KEYS)})")
    if batch.get(LABELS_2D_ONLY, False) and config.loss.alpha_O > 0:
        raise ValueError(
            f"batch_fn: the batch of step {step} holds 2-D labels only (a LabelBatch), but this config's loss "
            f"needs 3-D ground truth (loss.alpha_O = {config.loss.alpha_O}: the fully supervised oracle); "
            "train a weak variant ('both', 'dual') on 2-D labels"
        )
    rows = {k: (np.shape(batch[k]) or (None,))[0] for k in TRAIN_KEYS}
    wrong = {k: n for k, n in rows.items() if n != config.batch_size}
    if wrong:
        first = next(iter(wrong))
        raise ValueError(
            f"batch_fn: the batch of step {step} has {wrong[first]} rows in {first!r}, but config.batch_size is "
            f"{config.batch_size} (every key needs that many rows: {wrong}); make batches of batch_size objects "
            "(LabelBatch.concatenate) or set config.batch_size"
        )
    out = {k: jnp.asarray(batch[k]) for k in TRAIN_KEYS}
    if config.augment:
        out["aug"] = jax.tree.map(jnp.asarray, augmentation_params(config.seed, step, config.batch_size))
    return out


def device_train_batch(config: TrainConfig, step):
    """The batch of ``step`` (traced or int) made on the device (augmentation numbers included)."""
    key = jax.random.fold_in(train_key(config.seed), step)
    b = device_batch(
        key, config.batch_size, config.scene, config.model.input_size, config.model.global_padding, False, config.noisy
    )
    out: dict[str, Any] = {k: b[k] for k in TRAIN_KEYS}
    if config.augment:
        out["aug"] = augmentation_numbers(jax.random.fold_in(key, 1), config.batch_size)
    return out


@functools.lru_cache(maxsize=16)
def make_train_step(model: VoluMonNet, tx, config: TrainConfig, mesh: jax.sharding.Mesh | None = None):
    """Jitted train step (cached per config: no recompiles across runs).

    ``config.data == "device"``: ``(state) -> (state, loss terms)``, the batch made inside from
    the state's step; ``"host"``: ``(state, batch) -> (state, loss terms)``. With ``mesh`` the
    state comes back replicated over its devices and the device-made batch is split over them
    (a host batch arrives split: :func:`jaxsem.parallel.shard_batch`).
    """
    n = config.model.num_classes

    def loss_fn(params, batch_stats, batch):
        local, glob = batch["local"], batch["global"]
        if config.augment:
            local, glob = augment(batch["aug"], local, glob)
        phi, logits, new_vars = predict_params(
            model,
            {"params": params, "batch_stats": batch_stats},
            local,
            glob,
            batch["class_id"],
            config.class_mode,
            train=True,
            box=batch["box_input"],
            K=batch["K"],
        )
        ell = reconstruct(phi, batch["box_input"], batch["K"], config.recon)
        terms = volumon_loss(ell, batch, config.loss, n, logits)
        return terms.total, (terms, new_vars["batch_stats"])

    def step_fn(state, batch):
        (_, (terms, new_bs)), grads = jax.value_and_grad(loss_fn, has_aux=True)(
            state["params"], state["batch_stats"], batch
        )
        with jax.numpy_dtype_promotion("standard"):  # optax's adam: decay ** int32 count (lsd/_train.py)
            updates, opt_state = tx.update(grads, state["opt_state"], state["params"])
        params = optax.apply_updates(state["params"], updates)
        new_state = {
            **state,
            "step": state["step"] + 1,
            "params": params,
            "batch_stats": new_bs,
            "opt_state": opt_state,
        }
        return new_state, terms._asdict()

    if mesh is None:
        if config.data == "device":
            return jax.jit(lambda state: step_fn(state, device_train_batch(config, state["step"])))
        return jax.jit(step_fn)
    rep, split = parallel.replicated(mesh), parallel.batch_sharding(mesh)

    def sharded_batch(batch):
        return jax.tree.map(lambda x: jax.lax.with_sharding_constraint(x, split), batch)

    if config.data == "device":
        return jax.jit(
            lambda state: step_fn(state, sharded_batch(device_train_batch(config, state["step"]))),
            out_shardings=rep,
        )
    return jax.jit(lambda state, batch: step_fn(state, sharded_batch(batch)), out_shardings=rep)


def evaluate(
    model,
    state,
    config: TrainConfig,
    num: int | None = None,
    batch_size: int = 32,
    split: str = "test",
    seed: int | None = None,
    batch: dict | None = None,
):
    """Predict held-out samples and score them (translation / ADI AUC, 3D IoU, size errors, ...).

    ``batch``: score this batch (network inputs and ground truth ``gt_*``, ``sample_mask``), e.g.
    a directory's evaluation batch; else, by ``config.data``:

    ``config.data == "device"``: ``num`` samples of :func:`jaxsem.volumon.held_out_set` with seed
    ``seed`` (default ``config.seed``; the held-out stream never meets the training stream);
    ``"host"``: indices ``0..num-1`` of the host generator's ``split``.
    """
    num = config.num_eval if num is None else num
    variables = {"params": state["params"], "batch_stats": state["batch_stats"]}
    gt_keys = ("gt_rotation", "gt_center", "gt_half_extents", "gt_shape_id", "sample_mask")

    def predicted(b) -> tuple[dict, dict]:
        """The network's ellipsoids on batch ``b`` and its truth, as numpy."""
        _, ell, _ = predict_batch(model, config, variables, b)
        return jax.tree.map(np.asarray, ell._asdict()), {k: np.asarray(b[k]) for k in gt_keys}

    if batch is not None:
        return evaluate_predictions(*predicted(batch))
    if config.data == "directory":
        raise ValueError("batch: a run on a directory is evaluated on a given batch (no held-out stream of its own)")
    if config.data == "device":
        seed = config.seed if seed is None else seed
        size, padding = config.model.input_size, config.model.global_padding
        b = held_out_set(seed, num, config.scene, size, padding, config.noisy, batch_size=batch_size)
        return evaluate_predictions(*predicted(b))
    preds, gts = [], []
    for start in range(0, num, batch_size):
        idx = np.arange(start, min(num, start + batch_size))
        b = make_batch(
            config.seed, idx, config.scene, config.model.input_size, config.model.global_padding, split, config.noisy
        )
        pred, gt = predicted(b)
        preds.append(pred)
        gts.append(gt)
    cat = lambda xs: {k: np.concatenate([x[k] for x in xs]) for k in xs[0]}
    return evaluate_predictions(cat(preds), cat(gts))


def train_and_evaluate(
    config: TrainConfig,
    workdir,
    *,
    stop_after: int | None = None,
    progress: bool = True,
    log: Callable[[str], None] | None = None,
    force: bool = False,
    batch_fn: Callable[[int], dict] | None = None,
    eval_batch: dict | None = None,
    mesh: jax.sharding.Mesh | None = None,
    init_variables: dict | None = None,
) -> dict[str, Any]:
    """Train VoluMon with ``config``, checkpointing into ``workdir/checkpoints``; resume if present.

    Args:
      config: :class:`TrainConfig`.
      workdir: output folder (checkpoints, ``metrics.jsonl``, ``eval.json``, ``config.json``).
      stop_after: stop after this many steps of *this* run (simulates an interruption; the last
        step is checkpointed).
      progress: tqdm bar with the loss terms.
      log: called with one line per logged step (and "resumed from step N").
      force: resume even if ``config`` differs from the run's ``config.json`` (else
        :class:`ConfigMismatchError`); the new config is written.
      batch_fn: with ``config.data == "directory"``: ``step -> batch`` (numpy arrays with the keys
        of :data:`TRAIN_KEYS`, a pure function of the step so that a resume sees the same data),
        e.g. from :class:`jaxsem.volumon.data.VolumonDataset` and :func:`jaxsem.volumon.data.as_volumon_batch`.
      eval_batch: with ``config.data == "directory"``: the batch (same keys plus ground truth
        ``gt_*``) the periodic evaluation scores; None: no evaluation.
      mesh: train data-parallel over this one-axis mesh (:func:`jaxsem.parallel.data_mesh`, or
        :func:`jaxsem.parallel.devices_mesh`): the state replicated, each batch split over the
        devices; ``config.batch_size`` must be a multiple of the device count (else
        ``ValueError`` naming ``batch_size``). None (default): one device, as before.
      init_variables: a warm start: ``params`` and ``batch_stats`` of the same network (e.g.
        :func:`warm_start_variables` of a shipped model) that a *fresh* run starts from instead
        of the random initialisation (a resumed run restores its checkpoint and ignores them).

    Returns:
      dict with ``state`` (final train state), ``model``, ``history`` (per-step loss terms of this
      run, keyed by step), ``eval`` (metrics of the final evaluation, if the run completed).
    """
    if (config.data == "directory") != (batch_fn is not None):
        raise ValueError(
            f"batch_fn: expected a batch source exactly when config.data == 'directory', got data={config.data!r} "
            f"and batch_fn={'a function' if batch_fn is not None else None}"
        )
    parallel.check_batch_size(config.batch_size, mesh)
    workdir = pathlib.Path(workdir)

    def normalise(old: dict) -> dict:  # through the dataclasses: fields added since take their defaults
        return config_json(config_from_dict(old))

    # first: a second run on the same workdir is refused before any work (the workdir's lock)
    run = TrainingRun(
        workdir,
        config_json(config),
        keep=config.keep_checkpoints,
        resumable=RESUMABLE_FIELDS,
        force=force,
        normalise=normalise,
        log=log,
    )
    result_eval = None
    history: dict[int, dict[str, float]] = {}
    with run:
        state, model, tx = init_state(config)
        if run.latest_step is not None:
            state = run.restore(state)
        elif init_variables is not None:
            state = _warm_state(state, init_variables, tx)
        start = int(state["step"])
        run.begin()
        # the step does not depend on the run-length / logging fields: one compiled step for every chunk
        step_config = config.replace(**{k: getattr(TrainConfig(), k) for k in RESUMABLE_FIELDS})
        if mesh is None:
            train_step = make_train_step(model, tx, step_config)
            host_batch = lambda batch: batch
        else:
            state = jax.device_put(state, parallel.replicated(mesh))
            train_step = make_train_step(model, tx, step_config, mesh)
            host_batch = lambda batch: parallel.shard_batch(batch, mesh)
        end = config.num_steps if stop_after is None else min(config.num_steps, start + int(stop_after))
        can_eval = config.num_eval > 0 and (config.data != "directory" or eval_batch is not None)
        t0 = time.perf_counter()
        for step in run.steps(start, end, total=config.num_steps, desc=f"volumon[{config.variant}]", progress=progress):
            if config.reset_optimizer_at is not None and step == config.reset_optimizer_at:
                state = {**state, "opt_state": tx.init(state["params"])}
                if mesh is not None:
                    state = jax.device_put(state, parallel.replicated(mesh))
            if config.data == "device":
                state, terms = train_step(state)
            elif batch_fn is not None:
                state, terms = train_step(state, host_batch(_host_batch(config, batch_fn(step), step)))
            else:
                state, terms = train_step(state, host_batch(get_train_batch(config, step)))
            if (step + 1) % config.log_every == 0 or step + 1 == end:
                terms = {k: float(v) for k, v in terms.items()}
                if not all(np.isfinite(v) for v in terms.values()):
                    raise FloatingPointError(f"non-finite loss at step {step + 1}: {terms}")
                history[step + 1] = terms
                rec = {"step": step + 1, "time_s": time.perf_counter() - t0, **terms}
                run.log_metrics(rec)
                run.postfix({k: v for k, v in terms.items() if k != "cls" or model.config.num_classes > 1})
                if log is not None:
                    log(" ".join(f"{k}={v:.4g}" for k, v in rec.items()))
            if (step + 1) % config.checkpoint_every == 0 or step + 1 == end:
                run.save(step + 1, state)
            if config.eval_every and can_eval and (step + 1) % config.eval_every == 0:
                ev = evaluate(model, state, config, batch=eval_batch)
                if step + 1 == config.num_steps:
                    result_eval = ev
                run.log_metrics({"step": step + 1, "eval": ev})
                if log is not None:
                    log(f"eval step {step + 1}: " + " ".join(f"{k}={v:.4g}" for k, v in ev.items()))
        if end == config.num_steps and can_eval:
            result_eval = result_eval or evaluate(model, state, config, batch=eval_batch)
            tmp = workdir / "eval.json.tmp"
            tmp.write_text(json.dumps(result_eval, indent=1))
            tmp.replace(workdir / "eval.json")
    return {"state": state, "model": model, "history": history, "eval": result_eval}


def _warm_state(state: dict, variables: dict, tx) -> dict:
    """``state`` with the params and batch statistics of ``variables`` (same tree and shapes) and a fresh optimiser."""
    for part in ("params", "batch_stats"):
        ref, new = jax.tree.structure(state[part]), jax.tree.structure(variables[part])
        if ref != new:
            raise ValueError(f"init_variables: its {part} tree differs from the network's ({new} vs {ref})")
        for a, b in zip(jax.tree.leaves(state[part]), jax.tree.leaves(variables[part])):
            if a.shape != b.shape:
                raise ValueError(f"init_variables: a {part} leaf has shape {b.shape}, the network's {a.shape}")
    params = jax.tree.map(lambda a, b: jnp.asarray(b, a.dtype), state["params"], variables["params"])
    stats = jax.tree.map(lambda a, b: jnp.asarray(b, a.dtype), state["batch_stats"], variables["batch_stats"])
    return {**state, "params": params, "batch_stats": stats, "opt_state": tx.init(params)}


def warm_start_variables(variables: dict, config: TrainConfig, class_map) -> dict:
    """Variables of ``config`` 's network taken from another trained network of the same
    architecture whose class head may differ (e.g. the shipped 4-class object model for the
    8-class LM-O model): every leaf is copied, except the class-head layers (``local_out``,
    ``global_out``, ``class_out``) whose class rows are copied from the source row
    ``class_map[k]`` for each new class ``k``.

    Args:
      variables: ``params`` and ``batch_stats`` of the source network (:func:`jaxsem.volumon.load_pretrained`).
      config: the new network's config; class_map: (num_classes,) source row per new class row.
    """
    class_map = np.asarray(class_map, np.int64)
    n = int(config.model.num_classes)
    if class_map.shape != (n,):
        raise ValueError(f"class_map: expected ({n},) source rows, got shape {class_map.shape}")
    target, _, _ = init_state(config)
    src = jax.tree.map(np.asarray, dict(variables["params"]))
    out = jax.tree.map(np.asarray, dict(target["params"]))
    for name in out:
        if name not in src:
            raise ValueError(f"variables: no layer {name!r} in the source network")
        if name in ("local_out", "global_out", "class_out"):
            width = 9 if name == "local_out" else 1
            for leaf in ("kernel", "bias"):
                a = np.asarray(src[name][leaf])
                m = int(a.shape[-1]) // width
                if np.any(class_map >= m) or np.any(class_map < 0):
                    raise ValueError(f"class_map: rows must be in 0..{m - 1}, got {class_map.tolist()}")
                rows = a.reshape(a.shape[:-1] + (m, width))[..., class_map, :]
                out[name][leaf] = rows.reshape(a.shape[:-1] + (n * width,))
        else:
            out[name] = src[name]
    return {"params": out, "batch_stats": jax.tree.map(np.asarray, dict(variables["batch_stats"]))}


def load_trained(workdir, config: TrainConfig | None = None, *, step: int | None = None):
    """``(model, variables, config)`` of a training ``workdir``: its latest checkpoint (or ``step``),
    with ``config`` or, when None, the run's ``config.json``. ``variables`` holds ``params`` and
    ``batch_stats`` (what ``model.apply`` takes). The same contract as :func:`jaxsem.lsd.load_trained`.
    """
    workdir = pathlib.Path(workdir)
    if config is None:
        config = load_run_config(workdir, config_from_dict, "a VoluMon TrainConfig")
    state, model, _ = init_state(config)
    ckpt = Checkpointer(workdir / "checkpoints", max_to_keep=None)
    try:
        if ckpt.latest_step() is None:
            raise ValueError(f"workdir: no checkpoint under {str(workdir / 'checkpoints')!r}")
        state = ckpt.restore(state, step)
    finally:
        ckpt.close()
    return model, {"params": state["params"], "batch_stats": state["batch_stats"]}, config
