"""The shipped VoluMon model: export, load, and the one evaluation used by ``jaxsem volumon eval``.

The weights ship inside the package (``jaxsem/volumon/pretrained/<name>.npz``: the flax
variables flattened with ``/``-joined names, float32) next to ``<name>.json`` (the training
config, the step, the seed) and ``MODEL_CARD.md``. Nothing downloads at run time.
"""

from __future__ import annotations

import functools
import json
import pathlib
import time
import types
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from ..checkpoint import latest_step
from ..quadrics import Ellipsoid
from ..training import LoadedModel, read_exported, read_run_config
from . import _inputs
from ._configs import TrainConfig, config_from_dict
from ._device_data import held_out_set
from ._eval import detection_errors, evaluate_predictions, size_errors
from ._refine import optimise_from_scratch, phi_from_ellipsoid, postopt
from ._synthetic import CLASSES
from ._train import _model_and_init, load_trained, make_predict_fn

PRETRAINED_DIR = pathlib.Path(__file__).resolve().parent / "pretrained"
DEFAULT_NAME = "volumon_fast"
#: The shipped models by kind: the tabletop object model, the door model (thesis 5.8.1) and the
#: LM-O model (the eight LM-O classes, trained weakly on rendered desks).
SHIPPED = {"object": DEFAULT_NAME, "door": "volumon_door", "lmo": "volumon_lmo"}
#: The fully supervised oracle shipped beside a model (same data, same steps; a diagnostic).
ORACLES = {"lmo": "volumon_lmo_oracle"}


def _flatten(tree, prefix=""):
    out = {}
    for k, v in tree.items():
        name = f"{prefix}/{k}" if prefix else str(k)
        if isinstance(v, dict) or hasattr(v, "items"):
            out.update(_flatten(dict(v), name))
        else:
            out[name] = np.asarray(v, np.float32)
    return out


def _portable(config: dict) -> dict:
    """The config as shipped: a data folder is recorded by its last two parts, never by the
    training machine's absolute path."""
    data_dir = config.get("data_dir")
    if isinstance(data_dir, str) and pathlib.PurePath(data_dir).is_absolute():
        config = {**config, "data_dir": pathlib.PurePath(*pathlib.PurePath(data_dir).parts[-2:]).as_posix()}
    return config


def export_pretrained(
    workdir,
    out_dir=PRETRAINED_DIR,
    name: str = DEFAULT_NAME,
    step: int | None = None,
    extra: dict | None = None,
) -> pathlib.Path:
    """Write the checkpoint of a training run (``workdir``) as a shippable ``name.npz`` + ``name.json``.

    Atomic (written to temporary names, then renamed); the JSON names no absolute path of this
    machine. Returns the ``.npz`` path.
    """
    workdir = pathlib.Path(workdir)
    cfg_path = workdir / "config.json"
    config = config_from_dict(read_run_config(workdir))
    _, variables, _ = load_trained(workdir, config, step=step)

    used = latest_step(workdir / "checkpoints") if step is None else int(step)
    out_dir = pathlib.Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    flat = _flatten(jax.device_get(variables))
    tmp = out_dir / f"{name}.tmp.npz"
    np.savez_compressed(tmp, **flat)
    tmp.replace(out_dir / f"{name}.npz")
    meta = {
        "name": name,
        "step": used,
        "config": _portable(json.loads(cfg_path.read_text())),
        **(extra or {}),
    }
    tmp = out_dir / f"{name}.json.tmp"
    tmp.write_text(json.dumps(meta, indent=1))
    tmp.replace(out_dir / f"{name}.json")
    return out_dir / f"{name}.npz"


def load_pretrained(path=None, *, kind: str = "object") -> LoadedModel:
    """``(model, variables, config, meta)`` (a :class:`jaxsem.training.LoadedModel`) of a shipped model or of a training run's workdir (a
    folder with ``config.json`` and ``checkpoints/``).

    ``path`` None: the package's model of ``kind`` -- ``"object"`` (the four tabletop classes,
    ``volumon_fast``), ``"door"`` (the door model of thesis 5.8.1, ``volumon_door``) or ``"lmo"``
    (the eight LM-O classes, ``volumon_lmo``; its fully supervised oracle ``volumon_lmo_oracle``
    ships beside it, load it by path); see ``MODEL_CARD.md``. Raises ValueError naming the path when it is neither, or naming ``kind``.
    """
    if kind not in SHIPPED:
        raise ValueError(f"kind: expected one of {sorted(SHIPPED)}, got {kind!r}")
    p = PRETRAINED_DIR / f"{SHIPPED[kind]}.npz" if path is None else pathlib.Path(path)
    if p.is_dir() and (p / "config.json").exists():
        config = config_from_dict(read_run_config(p))
        model, variables, _ = load_trained(p, config)
        return LoadedModel(model, variables, config, {"name": str(p), "step": latest_step(p / "checkpoints")})
    if p.is_dir():
        p = p / f"{DEFAULT_NAME}.npz"
    meta_path = p.with_suffix(".json")
    if not p.exists() or not meta_path.exists():
        raise ValueError(
            f"model: no shipped model at {p} (expected {p.name} and {meta_path.name}), "
            "and not a training workdir with config.json"
        )
    config, variables, meta = read_exported(p, config_from_dict)
    model = _model_and_init(config.model, config.learning_rate)[0]  # the module only: nothing compiles
    return LoadedModel(model, variables, config, meta)


@functools.lru_cache(maxsize=1)
def shipped_model_inputs() -> types.SimpleNamespace:
    """The shipped object model's ``input_size`` and ``global_padding`` (read from its JSON)."""
    model = json.loads((PRETRAINED_DIR / f"{SHIPPED['object']}.json").read_text())["config"]["model"]
    return types.SimpleNamespace(input_size=int(model["input_size"]), global_padding=float(model["global_padding"]))


def prepare_inputs(image, boxes, size: int | None = None, padding: float | None = None, *, config=None):
    """One image (H, W, 3) and its boxes (N, 4) -> (local (N, S, S, 3), global (N, S, S, 3)) float32.

    ``size`` and ``padding`` must be the ones the network was trained with: by default they are
    read from ``config`` (a VoluMon config, or its ``model`` part, e.g. the third value of
    :func:`jaxsem.volumon.load_pretrained`), else from the shipped object model's config (input
    size 48, padding 0.1). A fixed default of 64 once fed the 48-pixel shipped model crops of the
    wrong scale with no error (depths 12 % off). Explicit arguments win.

    Checks the input at the Python boundary (see :func:`jaxsem.volumon._inputs.check_image_and_boxes`);
    use the jittable :func:`jaxsem.volumon._inputs.crop_and_resize` /
    :func:`jaxsem.volumon._inputs.masked_global_image` inside traced code.
    """
    if config is None and (size is None or padding is None):
        config = shipped_model_inputs()
    return _inputs.prepare_inputs(image, boxes, size, padding, config=config)


def mean_size_radii(config: TrainConfig) -> np.ndarray:
    """Sorted semi-axes (3,) of the *constant* baseline: the mean over the training classes' sorted radii."""
    r = np.sort(np.asarray([CLASSES[i][2] for i in config.scene.classes], np.float64) / 2, -1)
    return r.mean(0)


def evaluate_held_out(
    model,
    variables,
    config: TrainConfig,
    seed: int,
    num: int,
    batch_size: int = 32,
    postopt_steps: int = 0,
    repeats: int = 5,
    batch: dict | None = None,
    scratch_steps: tuple = (),
) -> dict:
    """The figures of ``jaxsem volumon eval`` on ``num`` held-out detections of seed ``seed``.

    Returns a dict: ``num``, ``median_size_rel_error``, ``size_corr``, ``median_center_error_m``,
    ``trans_auc``, ``adi_auc``, ``iou_auc`` (see below), ``iou`` (mean 3D IoU), ``network_ms_per_detection`` (median of
    ``repeats`` batched forward passes after a warm-up, divided by the batch), the same size
    figures of the constant mean-size baseline (``baseline_*``), the ground-truth ellipsoid's
    figures (``ceiling_*``: what an exact ellipsoid scores against the true cuboids and
    cylinders under these metrics), and with ``postopt_steps > 0``
    the PostOpt rows (``postopt_*``) and PostOpt started at the exact truth
    (``postopt_from_truth_*``: how far its objective moves the true centre).

    ``batch``: score these detections instead (network inputs, ``points``, ``point_mask`` and
    ground truth ``gt_*``, ``sample_mask``, e.g. :func:`jaxsem.volumon.data.volumon_eval_batch` of a FAT
    directory); ``seed`` and ``num`` are then ignored (``num`` is the batch's size).

    ``scratch_steps``: also run the optimisation-only baseline (thesis "Optimize from scratch",
    :func:`jaxsem.volumon.optimise_from_scratch`) for each of these numbers of steps on the same
    detections (``scratch{n}_*`` figures and ``scratch{n}_ms_per_detection``).

    ``iou_auc``: area under the curve "fraction of detections with 3D IoU >= tau" for tau in
    [0, 1], times 10 (so it is on the same 0-10 scale as the other AUCs; equal to 10 x mean IoU
    up to the trapezoid rule).
    """
    if batch is not None:
        b = {k: jnp.asarray(v) for k, v in batch.items()}
        num = int(b["local"].shape[0])
    else:
        if int(num) < 1:
            raise ValueError(f"num: expected a positive number of detections, got {num}")
        b = held_out_set(
            int(seed),
            int(num),
            config.scene,
            config.model.input_size,
            config.model.global_padding,
            config.noisy,
            batch_size=batch_size,
        )
    predict = make_predict_fn(model, config)
    args = (variables, b["local"], b["global"], b["box_input"], b["K"], b["class_id"])
    phi, ell, _ = jax.block_until_ready(predict(*args))
    ts = []
    for _ in range(int(repeats)):
        t = time.perf_counter()
        jax.block_until_ready(predict(*args))
        ts.append(time.perf_counter() - t)
    gt = {
        k: np.asarray(b[k])
        for k in (
            "gt_rotation",
            "gt_center",
            "gt_half_extents",
            "gt_shape_id",
            "sample_mask",
        )
    }
    pred = jax.tree.map(np.asarray, ell._asdict())
    out: dict[str, Any] = {"num": int(np.sum(gt["sample_mask"])), "seed": None if batch is not None else int(seed)}
    out.update(_summary(pred, gt, evaluate_predictions, detection_errors))
    out["network_ms_per_detection"] = 1000.0 * float(np.median(ts)) / int(num)
    keep = gt["sample_mask"].astype(bool)
    base = np.broadcast_to(mean_size_radii(config), gt["gt_half_extents"].shape)
    rel, corr = size_errors(base[keep], gt["gt_half_extents"][keep])
    out["baseline_median_size_rel_error"] = float(np.median(rel))
    out["baseline_size_corr"] = corr
    # ceiling: the exact ground-truth ellipsoid (true pose, radii = half extents) under the same metrics
    truth = {
        "rotation": gt["gt_rotation"],
        "center": gt["gt_center"],
        "radii": gt["gt_half_extents"],
    }
    out.update({f"ceiling_{k}": v for k, v in _summary(truth, gt, evaluate_predictions, detection_errors).items()})

    data = (b["box_input"], b["K"], b["points"], b["point_mask"], config.recon, config.loss)
    shape = b.get("class_shape")

    def score(prefix, ell):
        summary = _summary(jax.tree.map(np.asarray, ell._asdict()), gt, evaluate_predictions, detection_errors)
        out.update({f"{prefix}_{k}": v for k, v in summary.items()})

    def timed(prefix, fn):
        """Run ``fn`` once to compile, then time a second call (ms per detection)."""
        jax.block_until_ready(fn())
        t = time.perf_counter()
        ell = jax.block_until_ready(fn())
        out[f"{prefix}_ms_per_detection"] = 1000.0 * (time.perf_counter() - t) / int(num)
        return ell

    if postopt_steps > 0:
        steps = int(postopt_steps)
        score("postopt", timed("postopt", lambda: postopt(phi, *data, steps, shape=shape)[1]))
        # PostOpt started at the exact ground truth: how far does the objective move it?
        phi_true = phi_from_ellipsoid(
            Ellipsoid(b["gt_rotation"], b["gt_center"], b["gt_half_extents"]), b["box_input"], b["K"], config.recon
        )
        _, ell_t, _ = postopt(phi_true, *data, steps, shape=shape)
        drift = np.linalg.norm(np.asarray(ell_t.center) - gt["gt_center"], axis=-1)[keep]
        out["postopt_from_truth_median_drift_m"] = float(np.median(drift))
        out["postopt_from_truth_p90_drift_m"] = float(np.percentile(drift, 90))
        out["postopt_from_truth_within_1cm"] = float(np.mean(drift < 0.01))
        score("postopt_from_truth", ell_t)
    for n in scratch_steps:
        prefix = f"scratch{int(n)}"
        score(prefix, timed(prefix, lambda n=int(n): optimise_from_scratch(*data, n, shape=shape)[1]))
    return out


def _summary(pred, gt, evaluate_predictions, detection_errors):
    ev = evaluate_predictions(pred, gt)
    _, _, iou = detection_errors(pred, gt)
    tau = np.linspace(0.0, 1.0, 101)
    rate = (iou[None, :] >= tau[:, None]).mean(1) if iou.size else np.zeros_like(tau)
    return {
        "median_size_rel_error": ev["median_size_rel_error"],
        "size_corr": ev["size_corr"],
        "median_center_error_m": ev["median_center_error_m"],
        "trans_auc": ev["trans_auc"],
        "adi_auc": ev["adi_auc"],
        "iou_auc": float(10.0 * np.trapezoid(rate, tau)),
        "iou": ev["iou"],
    }
