"""VoluMon R-CNN (thesis 5.7): training the detect-and-lift network from 2D labels only.

The network is :class:`jaxsem.models.VoluMonRCNN`; this module trains and scores it:
:class:`RCNNTrainConfig`, :class:`RCNNLossConfig`, :func:`train_rcnn`, :func:`rcnn_loss`,
:func:`make_rcnn_step`, :func:`rcnn_batch`, :func:`evaluate_detections` (and over the folds of a
cross-validation, :func:`evaluate_folds`); on the photographs of
a real scene :func:`evaluate_scene` (detection, the 3D figures of the matched detections, the
parallel design of thesis 5.3 and the known-size baseline on the same boxes).

The loss is Faster R-CNN's (proposal objectness and box, RoI class and box) plus VoluMon's weak
terms on the RoIs matched to a true object: the dual box loss on the object's stereo boxes
(eq. 5.11, where a frame has a right image) and the intra-class size consistency (eq. 5.14).
During the burn-in only the detection terms count (the thesis' 5 epochs), so the VoluMon head
starts on RoIs that already find objects.

A batch (:func:`rcnn_batch`) is a dict of arrays, batch axis leading, ``G`` true objects per
image padded with ``box_valid`` False:

- ``image`` (B, H, W, 3) float in [0, 1] at the network's ``input_size``; ``K`` (B, 3, 3) scaled to it;
- ``boxes`` (B, G, 4) the visible boxes (the detector's labels), ``class_id`` (B, G) in [0, N);
- ``box_left``, ``box_right`` (B, G, 4) amodal stereo boxes, ``stereo_valid`` (B, G), and
  ``right_T_left`` (B, 4, 4): the dual loss's labels (``stereo_valid`` False: no dual term);
- optional, never read by the weak losses: ``gt_rotation``, ``gt_center``, ``gt_half_extents``
  (B, G, ...) for the fully supervised oracle and for scoring;
- optional: ``teacher_rotation``, ``teacher_center``, ``teacher_half_extents``, ``teacher_valid``
  (B, G, ...): another network's ellipsoids for the labels (:func:`teacher_labels`), which the
  distillation term pulls the lift towards.

Distillation: the separate VoluMon network reads each object's crop at its own resolution and was
trained on rendered desks with the thesis' weak losses (boxes and depth points, no 3D label, no
photograph); on photographs it lifts better than the R-CNN's RoI features do. Its ellipsoids on
the real photographs' 2D labels (visible box and class) are targets for the R-CNN's lift there, so
the one network learns from the photographs what the weak terms teach only on renders. Nothing of
the photographs' 3D truth is read.
"""

from __future__ import annotations

__all__ = [
    "RCNNLossConfig",
    "RCNNTrainConfig",
    "SHIPPED_RCNN",
    "SHIPPED_RCNNS",
    "ADOPTED_RCNNS",
    "detect_image",
    "lift_boxes",
    "centre_errors",
    "evaluate_detections",
    "evaluate_folds",
    "evaluate_scene",
    "at_input_size",
    "configured",
    "average_models",
    "graft_lift",
    "adopt_separate_lift",
    "export_rcnn",
    "load_rcnn",
    "rcnn_config_from_dict",
    "make_rcnn_step",
    "rcnn_batch",
    "rcnn_loss",
    "teacher_labels",
    "train_rcnn",
]

import dataclasses
import functools
import json
import pathlib
import time
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optax

from .. import metrics
from .._files import read_json
from ..checkpoint import latest_step, restore_checkpoint
from ..models import RCNNConfig, RCNNOutput, VoluMonRCNN, detect, detection_loss, free_params, init_rcnn, reconstruct
from ..quadrics import box_iou
from ..training import LoadedModel, TrainingRun, config_json, read_exported
from ._losses import (
    LossConfig,
    dual_loss_per_sample,
    oracle_loss_per_sample,
    primal_loss_per_sample,
    size_variance_loss,
)
from ._pretrained import PRETRAINED_DIR, load_pretrained, prepare_inputs
from ._scene_eval import (
    class_rows,
    evaluate_scene_batch,
    known_size_ellipsoid,
    predict_by_rows,
    summarise_detections,
)
from ._train import make_predict_fn
from .data import (
    LMO_CLASS_NAMES,
    augment_batch,
    bop_class_extents,
    bop_eval_batch,
    frame_arrays,
    frames_batch,
    jitter_batch,
    load_bop_split,
    read_rgb,
)


@dataclasses.dataclass(frozen=True)
class RCNNLossConfig:
    """Weights and matching rules of the R-CNN loss.

    Attributes:
      rpn, classification, box: weights of the detection terms.
      dual, size: weights of VoluMon's dual box loss and intra-class size consistency (the
        thesis' only two terms for R-CNN).
      oracle: weight of the fully supervised 3D loss (the oracle run; 0 in a weak run).
      distill: weight of the same loss against a teacher network's ellipsoids, on the labels that
        carry one (``teacher_valid``; :func:`teacher_labels`); 0: no distillation.
      primal: weight of VoluMon's primal loss (eq. 5.12-5.13, ``volumon.primal_distance``) on the
        labels that carry depth points (``point_mask``: rendered frames stored with
        ``num_points``; photographs carry none): the separate network's "both" losses, which
        the thesis names as what its R-CNN lacked. 0: the thesis' R-CNN terms only.
      burn_in: steps with the detection terms alone.
      fg_iou: a RoI is an object's at IoU >= fg_iou; rpn_pos / rpn_neg: an anchor is positive at
        IoU >= rpn_pos (or the best anchor of an object), negative below rpn_neg.
      volumon: the VoluMon loss constants (``pixel_scale``, ``length_unit``, ``eps_v`` ...).
    """

    rpn: float = 1.0
    classification: float = 1.0
    box: float = 1.0
    dual: float = 1.0
    size: float = 1.0
    oracle: float = 0.0
    distill: float = 0.0
    primal: float = 0.0
    burn_in: int = 500
    fg_iou: float = 0.5
    rpn_pos: float = 0.7
    rpn_neg: float = 0.3
    volumon: LossConfig = LossConfig(pixel_scale=10.0, alpha_S=1.0)


def _mean_where(values, mask):
    m = mask.astype(values.dtype)
    return jnp.sum(values * m) / jnp.maximum(jnp.sum(m), 1.0)


def rcnn_loss(output: RCNNOutput, batch: dict, config: RCNNConfig, loss: RCNNLossConfig, volumon_on) -> tuple:
    """The total loss and its terms (a dict of scalars) of one forward pass on ``batch``.

    ``volumon_on`` (a scalar 0 / 1): whether the VoluMon terms count (0 during the burn-in).
    """
    terms, (index, fg, true_cls) = detection_loss(
        output, batch["boxes"], batch["class_id"], batch["box_valid"], config, loss.fg_iou, loss.rpn_pos, loss.rpn_neg
    )
    take = lambda x: jnp.take_along_axis(x, index.reshape(index.shape + (1,) * (x.ndim - 2)), axis=1)
    phi = free_params(output.phi, output.class_logits, true_cls, config.param_rule)
    K = batch["K"][:, None]
    ell = reconstruct(phi, output.rois, K, config.reconstruction)
    stereo = fg & take(batch["stereo_valid"])
    dual = dual_loss_per_sample(
        ell, take(batch["box_left"]), take(batch["box_right"]), K, batch["right_T_left"][:, None], loss.volumon
    )
    dual_loss = _mean_where(dual, stereo)
    n = int(config.num_classes)
    sizes = (2.0 * ell.radii).reshape(-1, 3)
    size_loss = size_variance_loss(sizes, true_cls.reshape(-1), n, fg.reshape(-1), loss.volumon)
    terms = {**terms, "dual": dual_loss, "size": size_loss}
    total = (
        loss.rpn * (terms["rpn_cls"] + terms["rpn_box"]) + loss.classification * terms["cls"] + loss.box * terms["box"]
    )
    volumon = loss.dual * dual_loss + loss.size * size_loss
    if loss.oracle > 0 and "gt_rotation" in batch:
        oracle = oracle_loss_per_sample(
            ell, take(batch["gt_rotation"]), take(batch["gt_center"]), take(batch["gt_half_extents"])
        )
        terms["oracle"] = _mean_where(oracle, fg)
        volumon = volumon + loss.oracle * terms["oracle"]
    if loss.distill > 0 and "teacher_valid" in batch:
        taught = fg & take(batch["teacher_valid"])
        distill = oracle_loss_per_sample(
            ell, take(batch["teacher_rotation"]), take(batch["teacher_center"]), take(batch["teacher_half_extents"])
        )
        terms["distill"] = _mean_where(distill, taught)
        volumon = volumon + loss.distill * terms["distill"]
    if loss.primal > 0 and "point_mask" in batch:
        primal, has = primal_loss_per_sample(ell, take(batch["points"]), take(batch["point_mask"]), loss.volumon)
        terms["primal"] = _mean_where(primal, fg & has)
        volumon = volumon + loss.primal * terms["primal"]
    total = total + volumon_on * volumon
    terms["total"] = total
    return total, terms


def rcnn_batch(frames, config: RCNNConfig, class_names, max_objects: int, baseline: float = 0.06) -> dict:
    """A training batch of frame dicts (rendered desks, :func:`jaxsem.volumon.data.bop_frames`) at
    the network's ``input_size`` (:func:`jaxsem.volumon.data.frame_arrays`, then float images)."""
    return frames_batch(frame_arrays(frames, config.input_size, class_names, max_objects, baseline))


def make_rcnn_step(model, config: RCNNConfig, loss: RCNNLossConfig, tx, freeze_stats: bool = False):
    """A jitted SGD step ``(params, batch_stats, opt_state, batch, step) -> (params, batch_stats,
    opt_state, terms)``; the VoluMon terms count from ``loss.burn_in`` on. ``freeze_stats``: the
    batch-norm statistics are returned as given (a frozen backbone)."""

    def loss_fn(params, batch_stats, batch, step):
        out, updates = model.apply(
            {"params": params, "batch_stats": batch_stats},
            batch["image"],
            batch["K"],
            batch["boxes"],
            batch["box_valid"],
            train=True,
            mutable=["batch_stats"],
        )
        on = (step >= loss.burn_in).astype(jnp.float32)
        total, terms = rcnn_loss(out, batch, config, loss, on)
        return total, (terms, updates["batch_stats"])

    @jax.jit
    def step_fn(params, batch_stats, opt_state, batch, step):
        (_, (terms, stats)), grads = jax.value_and_grad(loss_fn, has_aux=True)(params, batch_stats, batch, step)
        with jax.numpy_dtype_promotion("standard"):  # optax's bias correction mixes int32 and float
            updates, opt_state = tx.update(grads, opt_state, params)
        params = optax.apply_updates(params, updates)
        return params, batch_stats if freeze_stats else stats, opt_state, terms

    return step_fn


@dataclasses.dataclass(frozen=True)
class RCNNTrainConfig:
    """One R-CNN training run.

    Attributes:
      model, loss: :class:`RCNNConfig`, :class:`RCNNLossConfig`.
      batch_size: frames per step, of which ``real_per_batch`` real photographs (when given).
      learning_rate, clip: Adam's step size and the gradient's global-norm clip.
      num_steps, checkpoint_every, eval_every: the run's length and its rhythm (0: checkpoint or
        evaluate only at the end of each chunk).
      eval_frames: held-out frames scored at each evaluation.
      seed: the initialisation and the batch order (a pure function of the step).
      class_names: the names of the model's classes (ids are their indices).
      augment_real: each step's real photographs seen by other cameras
        (:func:`jaxsem.volumon.data.augment_batch`: zoom and shift with the intrinsics to match,
        colour jitter): a few dozen photos of one desk are otherwise learnt by heart.
      init_from: start from this model's weights (a training workdir or an exported ``.npz``;
        the same network) instead of a fresh initialisation; the optimiser starts afresh.
      augment_renders: the rendered frames' brightness, contrast and colour jittered as the
        photographs' are (:func:`jaxsem.volumon.data.jitter_batch`; labels kept), so the lift,
        learnt on renders alone, meets the colour changes of photographs (no zoom: see ``zoom_renders``).
      zoom_renders: above 1, each rendered frame is also seen by another camera
        (:func:`jaxsem.volumon.data.augment_batch`: zoomed by a factor log-uniform in
        ``[1 / zoom_renders, zoom_renders]``, the intrinsics and stereo labels changed to match,
        colour jittered). At the renders' one focal length an object's apparent size and its
        box over the focal length (the lift's :func:`~jaxsem.models.box_features`) say the same,
        so a lift may learn depth from either; one that learnt it from apparent size reads the
        wrong depth from a camera of another focal length. 1: no zoom.
      multiview_real: the real photographs carry dual-loss labels from a second photograph of
        the same scene (:func:`jaxsem.volumon.data.multiview_frames`), so the lift learns depth on
        real pixels too, not only on renders. The caller pairs the frames; the flag records it,
        so a resume with other data is refused.
      distill_from: the teacher whose ellipsoids label the real photographs (:func:`teacher_labels`;
        ``loss.distill`` weighs them); recorded so a resume with another teacher is refused.
      train_only: "" (every layer), "lift" or "heads". "lift": only the VoluMon head's layers
        (:data:`LIFT_LAYERS`) learn; the backbone, the proposal stage, the box and class heads
        and the batch-norm statistics stay as ``init_from`` gave them, so the detections stay
        exactly the starting network's while its lift learns (e.g. a new lift branch grown on a
        shipped detector). "heads": only the proposal stage and the box and class outputs
        (:data:`HEAD_LAYERS`) learn, so the RoI features and the lift stay ``init_from``'s while
        the detections adapt to them (e.g. a lift-tuned network's detector recovered). Training
        steps still normalise by each batch's statistics, as in every run.
      detector_lr_scale: every layer outside :data:`LIFT_LAYERS` learns at ``learning_rate``
        times this (an Adam of its own): below 1, the shared features move for the lift while
        the boxes and classes of a trained ``init_from`` drift less. 1 trains every layer alike.
    """

    model: RCNNConfig = RCNNConfig()
    loss: RCNNLossConfig = RCNNLossConfig()
    batch_size: int = 8
    real_per_batch: int = 2
    learning_rate: float = 1e-3
    clip: float = 10.0
    num_steps: int = 100_000
    checkpoint_every: int = 250
    eval_every: int = 500
    eval_frames: int = 64
    seed: int = 0
    keep: int = 2
    class_names: tuple = LMO_CLASS_NAMES
    augment_real: bool = False
    init_from: str = ""
    augment_renders: bool = False
    multiview_real: bool = False
    distill_from: str = ""
    train_only: str = ""
    detector_lr_scale: float = 1.0
    zoom_renders: float = 1.0


#: The VoluMon head's own layers (the lift): what ``RCNNTrainConfig.train_only="lift"`` trains.
LIFT_LAYERS = ("volumon_", "lift8_fc", "crop_", "phi_local", "phi_depth")
#: The detector's outputs (proposal stage, class and box heads; not the RoI features the lift
#: reads): what ``RCNNTrainConfig.train_only="heads"`` trains.
HEAD_LAYERS = ("rpn_", "cls_out", "box_out")
_TRAINED = {"lift": LIFT_LAYERS, "heads": HEAD_LAYERS}


def _optimizer(config: RCNNTrainConfig):
    """Adam behind a global-norm clip; with ``train_only`` "lift" or "heads" only the layers in
    :data:`LIFT_LAYERS` or :data:`HEAD_LAYERS` get Adam (clipped by their own norm) and every
    other layer a zero update and no optimiser state; with ``detector_lr_scale`` below 1 the other layers get an Adam of
    their own at the scaled rate, behind the one clip of the whole gradient."""
    if config.train_only:
        trained = _TRAINED[config.train_only]
        tx = optax.chain(optax.clip_by_global_norm(config.clip), optax.adam(config.learning_rate))
        # The labels name the optimiser state's branches: "lift" and "detector" as runs saved before.
        on, off = ("lift", "detector") if config.train_only == "lift" else ("heads", "frozen")
        moving = lambda params: {k: (on if k.startswith(trained) else off) for k in params}
        return optax.multi_transform({on: tx, off: optax.set_to_zero()}, moving)
    labels = lambda params: {k: ("lift" if k.startswith(LIFT_LAYERS) else "detector") for k in params}
    if config.detector_lr_scale != 1.0:
        lift, detector = optax.adam(config.learning_rate), optax.adam(config.learning_rate * config.detector_lr_scale)
        return optax.chain(
            optax.clip_by_global_norm(config.clip), optax.multi_transform({"lift": lift, "detector": detector}, labels)
        )
    return optax.chain(optax.clip_by_global_norm(config.clip), optax.adam(config.learning_rate))


def teacher_labels(frames, teacher: LoadedModel, batch: int = 256) -> list:
    """``frames`` (frame dicts: ``rgb``, ``K``, ``objects`` with ``visible_box`` and
    ``class_name``) with a teacher VoluMon network's ellipsoid for each labelled object: each
    object gains ``teacher`` (``rotation`` object-to-camera, ``center``, ``radii``; metres, the
    camera frame of ``K``), made from the 2D label alone (the visible box and the class's row of
    the teacher's class head; the class head's expectation for a class it does not have).

    ``teacher``: :func:`jaxsem.volumon.load_pretrained` (e.g. ``kind="lmo"``). Objects without a
    finite visible box are left without. The input frames are not changed."""
    predict = make_predict_fn(teacher.model, teacher.config)
    cfg = teacher.config.model
    rows_local, rows_global, rows_box, rows_K, rows_cls, where = [], [], [], [], [], []
    out = []
    for fi, fr in enumerate(frames):
        objs = [dict(o) for o in fr["objects"]]
        out.append({**fr, "objects": objs})
        labelled = [i for i, o in enumerate(objs) if np.all(np.isfinite(np.asarray(o["visible_box"], np.float64)))]
        if not labelled:
            continue
        boxes = np.array([objs[i]["visible_box"] for i in labelled], np.float64)
        local, glob = prepare_inputs(np.asarray(fr["rgb"]), boxes, config=cfg)
        rows_local.append(local)
        rows_global.append(glob)
        rows_box.append(boxes)
        rows_K.append(np.broadcast_to(np.asarray(fr["K"], np.float64), (len(labelled), 3, 3)))
        rows_cls.append([objs[i]["class_name"] for i in labelled])
        where += [(fi, i) for i in labelled]
    if not where:
        return out
    cls, _ = class_rows(np.concatenate(rows_cls), teacher.config)
    cat = lambda parts: np.concatenate(parts).astype(np.float32)
    local, glob, box, K = cat(rows_local), cat(rows_global), cat(rows_box), cat(rows_K)
    n, step = len(where), int(batch)
    pad = -n % step
    idx = np.concatenate([np.arange(n), np.full(pad, n - 1)])
    R, c, r = [], [], []
    for s in range(0, n + pad, step):
        j = idx[s : s + step]
        ell = predict_by_rows(predict, (teacher.variables, local[j], glob[j], box[j], K[j]), np.asarray(cls)[j])
        R.append(np.asarray(ell.rotation))
        c.append(np.asarray(ell.center))
        r.append(np.asarray(ell.radii))
    R, c, r = (np.concatenate(x)[:n].astype(np.float64) for x in (R, c, r))
    for k, (fi, i) in enumerate(where):
        out[fi]["objects"][i]["teacher"] = {"rotation": R[k], "center": c[k], "radii": r[k]}
    return out


def _indices(n: int, k: int, seed: int, step: int, stream: int) -> np.ndarray:
    rng = np.random.default_rng([seed, stream, step])
    return rng.choice(n, size=k, replace=n < k)


#: Box IoU at which a detection of the right class finds its object. A detection that finds only
#: an object less than ``min_visible`` visible is left out of the AP, neither right nor wrong
#: (COCO's crowd rule).
IOU_MATCH = 0.5


@jax.jit
def _pairwise_iou(a, b):
    return box_iou(a[:, None], b[None])


def _padded(boxes) -> np.ndarray:
    """``boxes`` (n, 4) as float64, padded with empty boxes to a multiple of 16 rows (the
    pairwise IoU compiles once per size class, not once per frame's count)."""
    boxes = np.asarray(boxes, np.float64).reshape(-1, 4)
    return np.concatenate([boxes, np.zeros((-len(boxes) % 16, 4))])


def _same_class_iou(box, cls, tbox, tcls) -> np.ndarray:
    if not len(box) or not len(tbox):
        return np.full((len(box), len(tbox)), -1.0)
    iou = np.asarray(_pairwise_iou(_padded(box), _padded(tbox)))[: len(box), : len(tbox)]
    return np.where(np.asarray(cls)[:, None] == np.asarray(tcls)[None], iou, -1.0)


def _greedy_match(iou: np.ndarray, score) -> dict:
    """Truth index -> detection index: detections by descending score take their best free truth
    at IoU >= 0.5 (the rule of :func:`jaxsem.metrics.average_precision`)."""
    taken: dict[int, int] = {}
    used = np.zeros(iou.shape[1], bool)
    for d in np.argsort(-np.asarray(score), kind="stable"):
        if not iou.shape[1]:
            break
        row = np.where(used, -1.0, iou[d])
        t = int(np.argmax(row))
        if row[t] >= IOU_MATCH:
            taken[t], used[t] = int(d), True
    return taken


def _not_crowd(box, cls, tbox, tcls, ibox, icls) -> np.ndarray:
    """(D,) bool: the detections that do not find only a less visible object (``ibox``, ``icls``;
    the COCO crowd rule of :data:`IOU_MATCH`)."""
    if not len(box) or not len(ibox):
        return np.ones(len(box), bool)
    hit_ign = _same_class_iou(box, cls, ibox, icls).max(1) >= IOU_MATCH
    hit_true = _same_class_iou(box, cls, tbox, tcls).max(1, initial=-1.0) >= IOU_MATCH
    return ~(hit_ign & ~hit_true)


def centre_errors(center, true_center) -> tuple[float, float, float]:
    """``(centre error, |log(|c| / |c_true|)|, ray error)`` of one estimated centre (camera frame,
    metres): the distance, how far off the distance from the camera is (a ratio, as a log), and
    the distance left once the estimate slides along its ray to the true distance."""
    c, g = np.asarray(center, np.float64), np.asarray(true_center, np.float64)
    dc, dg = max(float(np.linalg.norm(c)), 1e-9), max(float(np.linalg.norm(g)), 1e-9)
    return float(np.linalg.norm(c - g)), abs(float(np.log(dc / dg))), float(np.linalg.norm(c * (dg / dc) - g))


def evaluate_detections(
    model, variables, arrays: dict, config: RCNNConfig, batch: int = 8, min_visible: float = 0.5
) -> dict:
    """Detection AP50 (mean over classes with truth) and the 3D errors of the detections matched
    to a true object at IoU >= 0.5 (median centre error, translation AUC out of 10 at 10 cm) on
    the frames of :func:`jaxsem.volumon.data.frame_arrays`. The centre error split in two:
    ``median_depth_log_error`` (median ``|log(|c| / |c_true|)|``, the distance along the ray) and
    ``median_ray_error_m`` (the centre moved along its ray to the true distance: the direction).

    The truth is the objects at least ``min_visible`` visible; a detection of a less visible
    object (same class, IoU >= 0.5 with it and with no counted object) is neither right nor wrong
    and is left out, as the crowd regions of COCO."""
    return evaluate_folds([(model, variables, arrays)], config, batch=batch, min_visible=min_visible)


def evaluate_folds(folds, config: RCNNConfig, batch: int = 8, min_visible: float = 0.5) -> dict:
    """:func:`evaluate_detections` over the folds of a cross-validation scored as one set: each
    ``(model, variables, arrays)`` detects its own frames (the ones its run held out), and AP50
    and the matched errors are computed over all of them together, so that a recipe is judged on
    every held-out photo at once rather than on each fold's few. The folds' models share
    ``config`` (classes, input size)."""
    if not folds:
        raise ValueError("folds: expected at least one (model, variables, arrays)")
    dets, truth, centre_err, depth_err, ray_err = [], [], [], [], []
    offset = 0
    for model, variables, arrays in folds:
        fwd = jax.jit(lambda v, img, K, model=model: detect(model.apply(v, img, K), K, config))
        n = arrays["image"].shape[0]
        for s in range(0, n, batch):
            idx = np.arange(s, min(s + batch, n))
            pad = np.concatenate([idx, np.full(batch - len(idx), idx[-1])])
            b = frames_batch(arrays, pad)
            d = jax.device_get(fwd(variables, b["image"], b["K"]))
            vis = arrays["visible_fraction"][pad]
            for j, i in enumerate(idx):
                ok = np.asarray(d.valid[j])
                box, cid, score = d.box[j][ok], d.class_id[j][ok], d.score[j][ok]
                centre = np.asarray(d.ellipsoid.center[j])[ok]
                tv = b["box_valid"][j] & (vis[j] >= min_visible)
                ign = b["box_valid"][j] & ~tv
                tbox, tcls = b["boxes"][j][tv], b["class_id"][j][tv]
                keep = _not_crowd(box, cid, tbox, tcls, b["boxes"][j][ign], b["class_id"][j][ign])
                box, cid, score, centre = box[keep], cid[keep], score[keep], centre[keep]
                dets.append((np.full(len(box), offset + i), box, cid, score))
                truth.append((np.full(tv.sum(), offset + i), tbox, tcls))
                for t, k in _greedy_match(_same_class_iou(box, cid, tbox, tcls), score).items():
                    errs_k = centre_errors(centre[k], b["gt_center"][j][tv][t])
                    for out, e in zip((centre_err, depth_err, ray_err), errs_k):
                        out.append(e)
        offset += n
    cat = lambda parts, i: np.concatenate([p[i] for p in parts])
    ap, recall = metrics.average_precision(
        tuple(cat(dets, i) for i in range(4)), tuple(cat(truth, i) for i in range(3)), config.num_classes
    )
    errs = np.asarray(centre_err)
    return {
        "ap50": float(np.nanmean(ap)),
        "ap50_per_class": [None if np.isnan(a) else float(a) for a in ap],
        "recall50": float(np.nanmean(recall)),
        "num_matched": int(len(errs)),
        "median_center_error_m": float(np.median(errs)) if len(errs) else float("nan"),
        "trans_auc": float(metrics.auc_pass_rate(jnp.asarray(errs), 0.1)) if len(errs) else 0.0,
        "median_depth_log_error": float(np.median(depth_err)) if len(errs) else float("nan"),
        "median_ray_error_m": float(np.median(ray_err)) if len(errs) else float("nan"),
    }


#: Fields of :class:`RCNNTrainConfig` that may change between the chunks of one run: its length
#: and rhythm, not what it learns from or how.
RESUMABLE_FIELDS = ("num_steps", "checkpoint_every", "eval_every", "eval_frames", "keep")


def train_rcnn(
    config: RCNNTrainConfig,
    workdir,
    renders: dict,
    real: dict | None = None,
    held_out: dict | None = None,
    *,
    progress: bool = True,
    stop_at: int | None = None,
    log=None,
):
    """Train (or resume) VoluMon R-CNN in ``workdir`` with the project's training scaffold
    (:class:`jaxsem.training.TrainingRun`: config check, resumable orbax checkpoints, metrics).

    ``renders``, ``real``, ``held_out``: :func:`jaxsem.volumon.data.frame_arrays` dicts at
    ``config.model.input_size`` (the real photographs join each batch, ``real_per_batch`` of
    them; ``held_out`` is scored every ``eval_every`` steps). Returns ``(model, variables,
    metrics rows)``."""
    if not isinstance(config, RCNNTrainConfig):
        raise ValueError(f"config: expected an RCNNTrainConfig, got {type(config).__name__}")
    if len(config.class_names) != config.model.num_classes:
        raise ValueError(f"class_names: {len(config.class_names)} names for {config.model.num_classes} classes")
    W, H = (int(x) for x in config.model.input_size)
    for name, arr in (("renders", renders), ("real", real), ("held_out", held_out)):
        if arr is not None and tuple(arr["image"].shape[1:3]) != (H, W):
            raise ValueError(f"{name}: images of {arr['image'].shape[1:3]} (H, W), the model reads {(H, W)}")
    if config.train_only not in ("", *_TRAINED):
        raise ValueError(f"train_only: expected '', 'lift' or 'heads', got {config.train_only!r}")
    if not (0.0 < config.detector_lr_scale <= 1.0):
        raise ValueError(f"detector_lr_scale: expected a number in (0, 1], got {config.detector_lr_scale!r}")
    if config.train_only and config.detector_lr_scale != 1.0:
        raise ValueError("detector_lr_scale: train_only already sets which layers learn; leave the scale at 1")
    if not (config.zoom_renders >= 1.0 and np.isfinite(config.zoom_renders)):
        raise ValueError(f"zoom_renders: expected a finite factor >= 1, got {config.zoom_renders!r}")
    if config.train_only and not config.init_from:
        raise ValueError(f"train_only: {config.train_only!r} keeps trained layers, so config.init_from must name them")
    model, variables = init_rcnn(jax.random.PRNGKey(config.seed), config.model, config.batch_size)
    tx = _optimizer(config)
    state = {
        "params": variables["params"],
        "batch_stats": variables["batch_stats"],
        "opt_state": tx.init(variables["params"]),
        "step": np.asarray(0, np.int64),
    }
    run = TrainingRun(
        workdir,
        config_json(config),
        keep=config.keep,
        resumable=RESUMABLE_FIELDS,
        normalise=lambda old: config_json(rcnn_config_from_dict(old)),
        log=log,
    )
    with run:
        if run.latest_step is not None:
            state = run.restore(state)
        elif config.init_from:
            loaded = load_rcnn(config.init_from).variables
            if config.model.lift_features == "volumon":  # a lift of another design: its old layers go
                loaded = _without_missing_lift(loaded, variables)
            start = _adopt(loaded, variables)
            if start is None:
                raise ValueError(f"init_from: {config.init_from} is not the same network as config.model")
            params = _own_lift_features(start["params"], loaded["params"])
            stats = _own_lift_features(start["batch_stats"], loaded["batch_stats"])
            state = {**state, "params": params, "batch_stats": stats}
        run.begin()
        step_fn = make_rcnn_step(model, config.model, config.loss, tx, freeze_stats=bool(config.train_only))
        params, stats, opt = state["params"], state["batch_stats"], state["opt_state"]
        n_real = 0 if real is None else min(config.real_per_batch, config.batch_size - 1)
        last = config.num_steps if stop_at is None else min(int(stop_at), config.num_steps)
        recent: list = []
        step = run.start
        for step in run.steps(run.start, last, total=config.num_steps, desc="volumon rcnn", progress=progress):
            b = frames_batch(
                renders, _indices(renders["image"].shape[0], config.batch_size - n_real, config.seed, step, 0)
            )
            if config.zoom_renders > 1.0:
                zoom = float(config.zoom_renders)
                b = augment_batch(b, np.random.default_rng([config.seed, 4, step]), scale_range=(1.0 / zoom, zoom))
            elif config.augment_renders:
                b = jitter_batch(b, np.random.default_rng([config.seed, 3, step]))
            if n_real:
                assert real is not None
                r = frames_batch(real, _indices(real["image"].shape[0], n_real, config.seed, step, 1))
                if config.augment_real:
                    r = augment_batch(r, np.random.default_rng([config.seed, 2, step]))
                # a key the photographs lack (the renders' depth points) is empty for them
                blank = lambda k: np.zeros((len(r["image"]), *b[k].shape[1:]), b[k].dtype)
                b = {k: np.concatenate([b[k], r[k] if k in r else blank(k)]) for k in b}
            params, stats, opt, terms = step_fn(params, stats, opt, b, jnp.asarray(step))
            recent.append(terms)
            recent = recent[-50:]
            done = step + 1
            if done % 25 == 0:
                run.postfix({k: float(np.mean([float(t[k]) for t in recent])) for k in ("total", "cls", "dual")})
            if (config.eval_every and done % config.eval_every == 0) or done == last:
                row = {"step": done, **{k: float(np.mean([float(t[k]) for t in recent])) for k in recent[-1]}}
                if held_out is not None:
                    ev = evaluate_detections(model, {"params": params, "batch_stats": stats}, held_out, config.model)
                    row.update({f"heldout_{k}": v for k, v in ev.items()})
                run.log_metrics(row)
                run.write(f"step {done}: " + ", ".join(f"{k} {v:.3g}" for k, v in row.items() if isinstance(v, float)))
            if (config.checkpoint_every and done % config.checkpoint_every == 0) or done == last:
                run.save(
                    done, {"params": params, "batch_stats": stats, "opt_state": opt, "step": np.asarray(done, np.int64)}
                )
        return model, {"params": params, "batch_stats": stats}, run.metrics()


def _adopt(start, fresh):
    """``fresh`` (a network's initial variables, nested dicts) with every entry that ``start``
    also holds taken from ``start``; None when ``start`` is not a part of the same network (an
    entry ``fresh`` lacks, or a shape that differs). Entries only ``fresh`` holds (a branch added
    to a trained network, such as ``lift_stride8``'s) keep their initial values."""
    if not hasattr(fresh, "keys"):
        return start if getattr(start, "shape", None) == getattr(fresh, "shape", None) else None
    if not hasattr(start, "keys") or set(start) - set(fresh):
        return None
    out = {}
    for key in fresh:
        if key not in start:
            out[key] = fresh[key]
            continue
        sub = _adopt(start[key], fresh[key])
        if sub is None:
            return None
        out[key] = sub
    return out


def _without_missing_lift(start, fresh):
    """``start`` (variables) without the lift's layers that ``fresh`` lacks: a network whose lift
    is of another design (``lift_features="volumon"``) adopts the detector and the output heads."""
    return {
        c: {k: v for k, v in tree.items() if k in fresh.get(c, {}) or not k.startswith(LIFT_LAYERS)}
        for c, tree in start.items()
    }


def _doubled_layer(layer: str, layers) -> str | None:
    """The detector's layer that the lift's own ``layer`` doubles (``volumon_roi0`` -> ``roi_fc0``,
    ``volumon_plain_3_0`` -> ``plain_3_0``), if ``layers`` (a network's layer names) hold it;
    else None (a layer that is the lift's alone, or one of the detector's)."""
    name = {"volumon_roi0": "roi_fc0", "volumon_roi1": "roi_fc1"}.get(layer)
    if name is None and layer.startswith("volumon_"):
        name = layer[len("volumon_") :]
    return name if name is not None and name in layers else None


def _own_lift_features(tree, start_tree):
    """``tree`` (one collection, ``params`` or ``batch_stats``, of a network whose lift has
    layers of its own: ``lift_features`` "own", "stage" or "backbone"; nested dicts) with each of the
    lift's own layers that ``start_tree`` (the adopted network's) lacks copied from the
    detector's layer it doubles: the adopted network's outputs are the very same. ``tree``
    itself when there is nothing to copy."""
    doubles = {k: _doubled_layer(k, tree) for k in tree if k not in start_tree}
    copies = {mine: tree[theirs] for mine, theirs in doubles.items() if theirs is not None}
    return {**tree, **copies} if copies else tree


# ----------------------------------------------------------------------------- models on disk

#: The shipped LM-O detect-and-lift model's file stem in ``jaxsem/volumon/pretrained``, and the
#: name the commands and :func:`load_rcnn` know it by.
SHIPPED_RCNN = "volumon_lmo_rcnn"
SHIPPED_RCNN_NAME = "lmo-rcnn"
#: Every shipped R-CNN by name: the default (320 x 240) and the one trained at 448 x 336 (better
#: ellipsoids and boxes for the separate network, fewer detections; the model card has the trade).
SHIPPED_RCNNS = {SHIPPED_RCNN_NAME: SHIPPED_RCNN, "lmo-rcnn-448": "volumon_lmo_rcnn_448"}
#: Shipped networks put together at load time (:func:`adopt_separate_lift`), by name: (the shipped
#: R-CNN whose detector it runs, the shipped VoluMon ``kind`` it lifts with, the ``(W, H)`` it reads
#: or None for the detector's own). No file of their own: their weights are those two models'. Not
#: trained from 2D labels only (the separate LM-O network learnt from rendered depth points too; the
#: model card has it). The 320 x 240 detector is read at 384 x 288: its lift's crops gain resolution
#: for about the same detections (chosen on the tuning photos; the model card).
ADOPTED_RCNNS = {
    "lmo-rcnn-volumon": (SHIPPED_RCNN_NAME, "lmo", (384, 288)),
    "lmo-rcnn-448-volumon": ("lmo-rcnn-448", "lmo", None),
}


def _from_dict(cls, d: dict):
    """A frozen dataclass from its :func:`dataclasses.asdict` form (nested configs, tuples)."""
    kwargs = {}
    for f in dataclasses.fields(cls):
        if f.name not in d:
            continue
        v = d[f.name]
        default = f.default if f.default is not dataclasses.MISSING else None
        if dataclasses.is_dataclass(default) and isinstance(v, dict):
            v = _from_dict(type(default), v)
        elif isinstance(default, tuple) and isinstance(v, list):
            v = tuple(v)
        kwargs[f.name] = v
    return cls(**kwargs)


def rcnn_config_from_dict(d: dict) -> RCNNTrainConfig:
    """:class:`RCNNTrainConfig` of a run's ``config.json`` (fields added since take their defaults)."""
    return _from_dict(RCNNTrainConfig, d)


def export_rcnn(path, variables, config: RCNNTrainConfig, meta: dict | None = None) -> pathlib.Path:
    """Write ``variables`` as ``<path>.npz`` (float32) and the config with ``meta`` as
    ``<path>.json``, each atomically; returns the npz path."""
    path = pathlib.Path(path).with_suffix("")
    flat: dict[str, Any] = {
        "/".join(str(getattr(k, "key", k)) for k in p): np.asarray(v, np.float32)
        for p, v in jax.tree_util.tree_leaves_with_path(variables)
    }
    npz = path.with_suffix(".npz")
    tmp = path.with_name(path.name + ".tmp.npz")
    np.savez_compressed(tmp, **flat)
    tmp.replace(npz)
    info = {"config": config_json(config), **(meta or {})}
    tmp_json = path.with_name(path.name + ".tmp.json")
    tmp_json.write_text(json.dumps(info, indent=1))
    tmp_json.replace(path.with_suffix(".json"))
    return npz


def load_rcnn(path=None, step: int | None = None) -> LoadedModel:
    """A shipped LM-O detect-and-lift model (``path`` None or ``"lmo-rcnn"``: the default; or
    another name of :data:`SHIPPED_RCNNS` or :data:`ADOPTED_RCNNS`), an exported
    ``.npz`` (with its ``.json``), or a training workdir's checkpoint (``step``, default the
    latest), as a :class:`jaxsem.training.LoadedModel`."""
    if isinstance(path, str) and path in ADOPTED_RCNNS:
        if step is not None:
            raise ValueError(f"step: only a training workdir has checkpoint steps, got {path}")
        detector, kind, size = ADOPTED_RCNNS[path]
        one = adopt_separate_lift(load_rcnn(detector), load_pretrained(kind=kind))
        if size is not None:
            one = at_input_size(one, size)
        return one._replace(meta={**one.meta, "name": path})
    if path is None:
        p = PRETRAINED_DIR / f"{SHIPPED_RCNN}.npz"
    elif isinstance(path, str) and path in SHIPPED_RCNNS:
        p = PRETRAINED_DIR / f"{SHIPPED_RCNNS[path]}.npz"
    else:
        p = pathlib.Path(path)
    if step is not None and not p.is_dir():
        raise ValueError(f"step: only a training workdir has checkpoint steps, got {p}")
    if p.is_dir():
        cfg_path = p / "config.json"
        if not cfg_path.is_file():
            raise ValueError(f"model: {p} is not a training workdir (no config.json)")
        config = rcnn_config_from_dict(read_json(cfg_path, "training config"))
        # the variables' shapes only (nothing is compiled): the checkpoint brings the values
        model = VoluMonRCNN(config.model)
        variables = dict(jax.eval_shape(lambda k: init_rcnn(k, config.model, 1)[1], jax.random.PRNGKey(0)))
        step = latest_step(p / "checkpoints") if step is None else int(step)
        if step is None:
            raise ValueError(f"model: no checkpoint under {p / 'checkpoints'}")
        if not (p / "checkpoints" / str(step)).is_dir():
            raise ValueError(f"step: no checkpoint {step} under {p / 'checkpoints'}")
        like = {"params": variables["params"], "batch_stats": variables["batch_stats"]}
        state = restore_checkpoint(
            p / "checkpoints",
            {**like, "opt_state": _opt_like(config, variables), "step": np.asarray(0, np.int64)},
            step,
        )
        return LoadedModel(
            model,
            {"params": state["params"], "batch_stats": state["batch_stats"]},
            config,
            {"name": str(p), "step": step},
        )
    meta_path = p.with_suffix(".json")
    if not p.is_file() or not meta_path.is_file():
        raise ValueError(f"model: no exported R-CNN at {p} (expected {p.name} and {meta_path.name})")
    config, variables, meta = read_exported(p, rcnn_config_from_dict)
    return LoadedModel(VoluMonRCNN(config.model), variables, config, meta)


def average_models(models) -> LoadedModel:
    """The parameter average of checkpoints of one network (weights and batch statistics, in
    float64 then cast back): the first model with the mean of all their variables. Averaging
    the last checkpoints of a run evens out the step-to-step swing of the weights."""
    models = list(models)
    if not models:
        raise ValueError("models: expected at least one model to average")
    first = models[0]
    shapes = jax.tree.map(np.shape, first.variables)
    for m in models[1:]:
        if m.config.model != first.config.model or jax.tree.map(np.shape, m.variables) != shapes:
            raise ValueError("models: expected checkpoints of one network (the same config and variable shapes)")
    mean = jax.tree.map(
        lambda *xs: np.asarray(sum(np.asarray(x, np.float64) for x in xs) / len(xs), np.asarray(xs[0]).dtype),
        *[m.variables for m in models],
    )
    steps = [m.meta.get("step") for m in models]
    return LoadedModel(first.model, mean, first.config, {**first.meta, "averaged_steps": steps})


#: The settings of :class:`RCNNConfig` that only the lift's weights depend on: a lift grafted on a
#: detector (:func:`graft_lift`) brings its own.
LIFT_SETTINGS = ("lift_stride8", "lift_crop", "lift_features", "param_rule", "rotation_init", "reconstruction")


def _assembled(fresh, pick, names: str, kind: str) -> dict:
    """The variables of a network put together from others: for each layer of ``fresh`` (its
    variables' shapes), ``pick(collection, layer)`` gives ``(source name, value)``; a value missing
    or of another shape is refused, naming ``names`` (the arguments it came from)."""
    variables = {}
    for collection in ("params", "batch_stats"):
        variables[collection] = {}
        for layer, like in fresh[collection].items():
            name, value = pick(collection, layer)
            if value is None or jax.tree.map(np.shape, value) != jax.tree.map(np.shape, like):
                raise ValueError(f"{names}: no {collection} {name!r} of the {kind} network's shape")
            variables[collection][layer] = value
    return variables


def graft_lift(detector: LoadedModel, lifter: LoadedModel) -> LoadedModel:
    """One network with ``detector``'s boxes and classes and ``lifter``'s ellipsoids.

    The result (``lift_features="backbone"``) runs ``detector``'s backbone, proposal stage and
    box and class heads, and beside them a backbone and RoI layers of the lift's own holding
    ``lifter``'s, under ``lifter``'s VoluMon head. A lift trained with every layer of a network
    learning reads features that its detection got worse for; grafted, it keeps those features
    while the detections are ``detector``'s. Both are networks whose lift reads the detector's
    features (``lift_features="shared"``) and that agree on every setting outside
    :data:`LIFT_SETTINGS` and the test-time ones; the lift's settings and training config are
    ``lifter``'s, ``lift_at`` is ``detector``'s."""
    dc, lc = detector.config.model, lifter.config.model
    for name, c in (("detector", dc), ("lifter", lc)):
        if c.lift_features != "shared":
            raise ValueError(
                f"{name}: expected a network whose lift reads the detector's features, got {c.lift_features!r}"
            )
    keep = {k: getattr(lc, k) for k in LIFT_SETTINGS + TEST_TIME_SETTINGS}
    if dataclasses.replace(dc, **keep) != lc:
        raise ValueError("lifter: expected the detector's network (the same settings outside the lift's)")
    model_cfg = dataclasses.replace(lc, lift_features="backbone", lift_at=dc.lift_at)
    fresh = jax.eval_shape(lambda k: init_rcnn(k, model_cfg, 1)[1], jax.random.PRNGKey(0))

    def source(layer):
        """(the network, its layer) that ``layer`` of the grafted network takes its values from:
        the lift's own doubles of the detector's layers hold the lifter's (shared) ones"""
        doubled = _doubled_layer(layer, fresh["params"])
        if doubled is not None:
            return lifter, doubled
        return (lifter if layer.startswith(LIFT_LAYERS) else detector), layer

    def pick(collection, layer):
        net, name = source(layer)
        return name, net.variables[collection].get(name)

    variables = _assembled(fresh, pick, "detector, lifter", "grafted")
    config = dataclasses.replace(lifter.config, model=model_cfg)
    meta = {**lifter.meta, "grafted": {"detector": detector.meta.get("name"), "lift": lifter.meta.get("name")}}
    return LoadedModel(VoluMonRCNN(model_cfg), variables, config, meta)


def adopt_separate_lift(detector: LoadedModel, separate: LoadedModel) -> LoadedModel:
    """One network with ``detector``'s boxes and classes and the separate VoluMon network
    ``separate``'s ellipsoids (the parallel design of thesis 5.3 as one network).

    The result (``lift_features="volumon"``) runs ``detector``'s backbone, proposal stage and box
    and class heads, and lifts each detection with ``separate``'s weights, its reconstruction
    constants and rotation start, reading its two inputs cut from the network's own image. The
    separate network must be the "volumon" lift's design (``RCNNConfig.volumon_lift``: the
    shipped LM-O model's backbone, input and hidden sizes, box features as input) over
    ``detector``'s classes in the same order. Its training
    signal comes with it: the shipped LM-O model learnt from rendered depth points as well as
    boxes, so a network adopted from it is not trained from 2D labels only."""
    dc = detector.config.model
    sc = separate.config.model
    want = dc.volumon_lift
    for name in ("backbone", "cnn_width", "input_size", "hidden", "box_input", "num_classes", "global_padding"):
        got, expected = getattr(sc, name, None), getattr(want, name)
        if got != expected:
            raise ValueError(f"separate: expected a VoluMon network with {name}={expected!r}, got {got!r}")
    d_names = list(getattr(detector.config, "class_names", ()))
    s_names = list(getattr(separate.config, "class_names", ()))
    if d_names != s_names:
        raise ValueError(f"separate: expected the detector's classes in its order {d_names}, got {s_names}")
    model_cfg = dataclasses.replace(
        dc,
        lift_features="volumon",
        lift_crop=0,
        lift_stride8=False,
        reconstruction=separate.config.recon,
        rotation_init=sc.rotation_init,
    )
    fresh = jax.eval_shape(lambda k: init_rcnn(k, model_cfg, 1)[1], jax.random.PRNGKey(0))

    def pick(collection, layer):
        if layer == "volumon_net":  # the separate network's whole tree is the lift's layer
            return layer, separate.variables.get(collection)
        return layer, detector.variables[collection].get(layer)

    variables = _assembled(fresh, pick, "detector, separate", "adopted")
    config = dataclasses.replace(detector.config, model=model_cfg)
    meta = {
        **detector.meta,
        "adopted_lift": {"detector": detector.meta.get("name"), "separate": separate.meta.get("name")},
    }
    return LoadedModel(VoluMonRCNN(model_cfg), variables, config, meta)


#: The settings of :class:`RCNNConfig` that a trained network's weights do not depend on.
TEST_TIME_SETTINGS = ("input_size", "lift_at", "score_threshold", "det_nms", "max_detections")


def configured(loaded: LoadedModel, **settings) -> LoadedModel:
    """The same network under other test-time settings (``TEST_TIME_SETTINGS``), e.g.
    ``lift_at="proposal"`` or ``input_size=(W, H)`` (:func:`at_input_size`)."""
    bad = sorted(set(settings) - set(TEST_TIME_SETTINGS))
    if bad:
        raise ValueError(f"settings: {bad} are not test-time settings of a trained network {TEST_TIME_SETTINGS}")
    model_cfg = dataclasses.replace(loaded.config.model, **settings)
    config = dataclasses.replace(loaded.config, model=model_cfg)
    meta = {**loaded.meta, **{k: list(v) if isinstance(v, tuple) else v for k, v in settings.items()}}
    return LoadedModel(VoluMonRCNN(model_cfg), loaded.variables, config, meta)


def at_input_size(loaded: LoadedModel, input_size) -> LoadedModel:
    """The same network reading images of ``input_size`` ``(W, H)`` (multiples of 16): every
    layer is size-agnostic (convolutions, RoI pooling to a fixed grid), only the anchors and the
    feature map's shape change. Objects then appear at other pixel sizes than in training: the
    trade of speed against accuracy, measured by ``jaxsem volumon eval --input-size``."""
    W, H = (int(x) for x in input_size)
    return configured(loaded, input_size=(W, H))


def _opt_like(config: RCNNTrainConfig, variables):
    """The optimiser state's structure for ``variables`` (shapes only: traced, never run)."""
    return jax.eval_shape(_optimizer(config).init, variables["params"])


def _checked_photo(image, K):
    """``(image, K)`` as numpy uint8 (H, W, 3) and float64 (3, 3), or ValueError naming the argument."""
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
        raise ValueError(f"image: expected (H, W, 3) uint8 RGB, got {image.shape} {image.dtype}")
    K = np.asarray(K, np.float64)
    if K.shape != (3, 3) or not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise ValueError(f"K: expected a (3, 3) pinhole matrix with positive focal lengths, got {K.tolist()}")
    return image, K


def detect_image(loaded: LoadedModel, image, K) -> dict:
    """Detections of one photograph of any size: ``image`` (H, W, 3) uint8 RGB, ``K`` (3, 3) its
    intrinsics. The network reads it resized to its ``input_size``; boxes come back in the
    photograph's pixels, ellipsoids in its camera frame (metres). Returns numpy arrays of the
    valid detections: ``box`` (D, 4), ``class_id`` (D,), ``class_name`` (list), ``score`` (D,),
    ``probabilities`` (D, N), ``rotation`` (D, 3, 3), ``center`` (D, 3), ``radii`` (D, 3)."""
    image, K = _checked_photo(image, K)
    cfg: RCNNConfig = loaded.config.model
    frame = {"rgb": image, "K": K, "objects": []}
    arrays = frame_arrays([frame], cfg.input_size, max_objects=1)
    b = frames_batch(arrays)
    d = jax.device_get(_detect_fn(loaded.model)(loaded.variables, b["image"], b["K"]))
    ok = np.asarray(d.valid[0])
    W, H = (int(x) for x in cfg.input_size)
    h0, w0 = image.shape[:2]
    back = np.array([w0 / W, h0 / H] * 2)
    # Within the photograph on the library's box convention (pixel centres at integers, the
    # image from -0.5 to size - 0.5), so the boxes are valid input for the separate VoluMon network.
    box = np.clip(np.asarray(d.box[0])[ok] * back, -0.5, np.array([w0, h0, w0, h0]) - 0.5)
    names = list(loaded.config.class_names)
    cid = np.asarray(d.class_id[0])[ok]
    return {
        "box": box,
        "class_id": cid,
        "class_name": [names[int(c)] for c in cid],
        "score": np.asarray(d.score[0])[ok],
        "probabilities": np.asarray(d.probabilities[0])[ok],
        "rotation": np.asarray(d.ellipsoid.rotation[0])[ok],
        "center": np.asarray(d.ellipsoid.center[0])[ok],
        "radii": np.asarray(d.ellipsoid.radii[0])[ok],
    }


def lift_boxes(loaded: LoadedModel, image, K, boxes, class_ids) -> dict:
    """The network's lift at given boxes: for each box (``boxes`` (G, 4) in the photograph's
    pixels, ``class_ids`` (G,) in [0, N)) the ellipsoid its VoluMon head reconstructs there, read
    from the RoI features pooled at that very box (the proposal's place, not the head's refined
    box) with the class's row of free parameters (``param_rule`` "class"; "expectation" weighs the
    rows by the class probabilities the network gives that box). With the true visible boxes and
    classes this scores the lift apart from the detector: the same boxes for every network.
    Returns numpy ``rotation`` (G, 3, 3), ``center`` (G, 3), ``radii`` (G, 3) in the photograph's
    camera frame."""
    image, K = _checked_photo(image, K)
    boxes = np.asarray(boxes, np.float64).reshape(-1, 4)
    class_ids = np.asarray(class_ids).reshape(-1)
    n_cls = len(loaded.config.class_names)
    if len(class_ids) != len(boxes) or not np.all((class_ids >= 0) & (class_ids < n_cls)):
        raise ValueError(f"class_ids: expected {len(boxes)} ids in [0, {n_cls}), got {class_ids.tolist()}")
    if not np.all(np.isfinite(boxes)) or np.any(boxes[:, 2:] <= boxes[:, :2]):
        raise ValueError("boxes: expected finite (x0, y0, x1, y1) boxes with x1 > x0 and y1 > y0")
    G = len(boxes)
    if G == 0:
        return {"rotation": np.zeros((0, 3, 3)), "center": np.zeros((0, 3)), "radii": np.zeros((0, 3))}
    cfg: RCNNConfig = loaded.config.model
    b = frames_batch(frame_arrays([{"rgb": image, "K": K, "objects": []}], cfg.input_size, max_objects=1))
    W, H = (int(x) for x in cfg.input_size)
    h0, w0 = image.shape[:2]
    cap = max(8, 1 << (G - 1).bit_length())  # padded to a power of two: one program per bucket
    rois = np.zeros((1, cap, 4), np.float32)
    rois[0, :G] = boxes * np.array([W / w0, H / h0] * 2)
    rois[0, G:] = rois[0, :1]
    cid = np.zeros((1, cap), np.int32)
    cid[0, :G] = class_ids
    valid = np.arange(cap)[None] < G
    e = jax.device_get(_lift_fn(loaded.model)(loaded.variables, b["image"], b["K"], rois, valid, cid))
    return {k: np.asarray(getattr(e, k)[0, :G], np.float64) for k in ("rotation", "center", "radii")}


@functools.lru_cache(maxsize=4)
def _lift_fn(model):
    cfg = dataclasses.replace(model.config, lift_at="proposal")
    net = VoluMonRCNN(cfg)

    def fn(v, img, K, rois, valid, cid):
        out = net.apply(v, img, K, extra_rois=rois, extra_valid=valid)
        G = rois.shape[1]
        phi = free_params(out.phi[:, -G:], out.class_logits[:, -G:], cid, cfg.param_rule)
        return reconstruct(phi, rois, jnp.asarray(K)[:, None], cfg.reconstruction)

    return jax.jit(fn)


@functools.lru_cache(maxsize=4)
def _detect_fn(model):
    cfg = model.config
    return jax.jit(lambda v, img, K: detect(model.apply(v, img, K), K, cfg))


# ----------------------------------------------------------------------------- a real scene


def evaluate_scene(
    loaded: LoadedModel,
    scene_dir,
    split: str,
    *,
    min_visible: float = 0.5,
    parallel: LoadedModel | None = None,
    warmup: int = 2,
    progress=None,
    truth_boxes: bool = False,
    frame_range: tuple[int, int] | None = None,
) -> dict:
    """The figures of ``jaxsem volumon eval --model lmo-rcnn`` on one split of a BOP scene.

    Args:
      loaded: the R-CNN (:func:`jaxsem.volumon.rcnn.load_rcnn`).
      scene_dir, split: a BOP scene folder and ``"tune"``, ``"test"`` or ``"all"``.
      min_visible: objects at least this visible are the truth.
      parallel: a VoluMon model (:func:`jaxsem.volumon.load_pretrained`) fed the network's
        matched boxes and classes, or None.
      progress: None or a callable wrapping the frame iterator (e.g. ``tqdm``).
      truth_boxes: also score the lift on every true object's visible box and class
        (:func:`lift_boxes`), beside the separate network and the baseline on the same boxes, under
        ``on_true_boxes``: a figure of the lift that does not move with the detector.
      frame_range: ``(lo, hi)``: only the split's photographs with ids in ``[lo, hi)``.

    Returns a dict: ``detection`` (``ap50``, ``ap50_per_class``, ``recall50``), the 3D figures of
    the network's matched detections (``median_center_error_m``, ``trans_auc``,
    ``median_size_rel_error``, ``iou_auc``, ... of :func:`summarise_detections`, ``num_matched``,
    ``num_truth``), ``baseline`` (known-size, the same boxes), ``parallel`` (when given),
    ``ms_per_image`` (median, batch 1; the parallel design's ``ms_per_image_two_networks`` adds
    its network's time per detection times the detections per image) and ``frames``.
    """
    min_visible = float(min_visible)
    if not 0.0 <= min_visible <= 1.0:
        raise ValueError(f"min_visible: expected a fraction in [0, 1], got {min_visible}")
    scene = load_bop_split(scene_dir, split)
    if frame_range is not None:
        lo, hi = (int(x) for x in frame_range)
        scene = dataclasses.replace(scene, frames=tuple(f for f in scene.frames if lo <= f.frame_id < hi))
    if not scene.frames:
        where = "" if frame_range is None else f" with an id in {list(frame_range)}"
        raise ValueError(f"split: {scene_dir} has no frame{where} in the {split!r} split")
    names = list(loaded.config.class_names)
    dets, truth, matched_frames, times = [], [], [], []
    preds: dict[str, list] = {"rotation": [], "center": [], "radii": []}
    truth_preds: dict[str, list] = {"rotation": [], "center": [], "radii": []}
    truth_frames = []
    frames = scene.frames if progress is None else progress(scene.frames)
    for i, frame in enumerate(frames):
        image = read_rgb(frame.image_path)
        if i == 0:
            for _ in range(int(warmup)):
                detect_image(loaded, image, frame.K)
        t = time.perf_counter()
        d = detect_image(loaded, image, frame.K)
        times.append(time.perf_counter() - t)
        labelled = [o for o in frame.objects if np.all(np.isfinite(o.visible_box)) and o.class_name in names]
        counted = [o for o in labelled if o.visible_fraction >= min_visible and o.visible_fraction > 0]
        ignored = [o for o in labelled if not (o.visible_fraction >= min_visible and o.visible_fraction > 0)]
        tbox = np.array([o.visible_box for o in counted]).reshape(-1, 4)
        tcls = np.array([names.index(o.class_name) for o in counted], np.int64)
        if truth_boxes and counted:
            lifted = lift_boxes(loaded, image, frame.K, tbox, tcls)
            for key in truth_preds:
                truth_preds[key].extend(lifted[key])
            truth_frames.append(dataclasses.replace(frame, objects=tuple(counted)))
        box, cls, score = d["box"], np.asarray(d["class_id"], np.int64), d["score"]
        ibox = np.array([o.visible_box for o in ignored]).reshape(-1, 4)
        icls = np.array([names.index(o.class_name) for o in ignored], np.int64)
        keep = np.flatnonzero(_not_crowd(box, cls, tbox, tcls, ibox, icls))
        d = {k: (np.asarray(v)[keep] if k != "class_name" else [v[j] for j in keep]) for k, v in d.items()}
        box, cls, score = d["box"], np.asarray(d["class_id"], np.int64), d["score"]
        dets.append((np.full(len(box), i), box, cls, score))
        truth.append((np.full(len(tbox), i), tbox, tcls))
        pairs = _greedy_match(_same_class_iou(box, cls, tbox, tcls), score)
        if pairs:
            objs = []
            for t_i in sorted(pairs):
                k = pairs[t_i]
                objs.append(dataclasses.replace(counted[t_i], visible_box=np.asarray(box[k], np.float64)))
                for key in preds:
                    preds[key].append(np.asarray(d[key][k], np.float64))
            matched_frames.append(dataclasses.replace(frame, objects=tuple(objs)))
    cat = lambda parts, j: np.concatenate([p[j] for p in parts])
    ap, recall = metrics.average_precision(
        tuple(cat(dets, j) for j in range(4)), tuple(cat(truth, j) for j in range(3)), len(names)
    )
    num_truth = int(sum(len(t[0]) for t in truth))
    n_dets = int(sum(len(x[0]) for x in dets))
    out: dict = {
        "data": str(scene_dir),
        "split": split,
        "min_visible": min_visible,
        "frames": len(scene.frames),
        "frame_ids": [int(scene.frames[0].frame_id), int(scene.frames[-1].frame_id)],
        "model": str(loaded.meta.get("name", "")),
        "detection": {
            "ap50": float(np.nanmean(ap)),
            "ap50_per_class": {n: (None if np.isnan(a) else float(a)) for n, a in zip(names, ap)},
            "recall50": float(np.nanmean(recall)),
        },
        "num_truth": num_truth,
        "ms_per_image": 1000.0 * float(np.median(times)),
    }
    if truth_boxes and truth_frames:
        on_truth = _lift_figures(scene, truth_frames, truth_preds, parallel)
        on_truth.pop("parallel_ms_per_detection", None)
        out["on_true_boxes"] = {"num_objects": len(truth_preds["center"]), **on_truth}
    num_matched = len(preds["center"])
    out["num_matched"] = num_matched
    if not num_matched:
        return out
    figs = _lift_figures(scene, matched_frames, preds, parallel)
    ms_det = figs.pop("parallel_ms_per_detection", None)
    out.update(figs)
    if parallel is not None:
        per_image = out["ms_per_image"] + ms_det * n_dets / len(scene.frames)
        out["parallel"] = {
            **out["parallel"],
            "name": "the separate VoluMon network fed the R-CNN's matched boxes and classes (thesis 5.3)",
            "ms_per_image_two_networks": per_image,
        }
    return out


def _lift_figures(scene, frames, preds, parallel) -> dict:
    """The 3D figures of ellipsoids ``preds`` (lists of the objects of ``frames`` in order) against
    the truth, with the known-size baseline and (``parallel`` given) the separate network on the
    same boxes and classes."""
    chosen = dataclasses.replace(scene, frames=tuple(frames))
    size = parallel.config.model.input_size if parallel is not None else 48
    pad = parallel.config.model.global_padding if parallel is not None else 0.1
    batch = bop_eval_batch(chosen, input_size=size, global_padding=pad, min_visible=0.0)
    out = summarise_detections({k: np.stack(v) for k, v in preds.items()}, batch)
    R, c, r = known_size_ellipsoid(batch["box_input"], batch["K"], batch["gt_half_extents"])
    out["baseline"] = {
        "name": "known-size geometric baseline on the same boxes (true mesh extent, axis-aligned to the camera)",
        **summarise_detections({"rotation": np.asarray(R), "center": np.asarray(c), "radii": np.asarray(r)}, batch),
    }
    if parallel is not None:
        rows, mapping = class_rows(batch["class_name"], parallel.config, "generic", bop_class_extents(chosen))
        fig = evaluate_scene_batch(parallel.model, parallel.variables, parallel.config, batch, rows)
        fig.pop("pred")
        out["parallel_ms_per_detection"] = fig["network_ms_per_detection"]
        out["parallel"] = {
            "name": "the separate VoluMon network fed the same boxes and classes (thesis 5.3)",
            "model": str(parallel.meta.get("name", "")),
            **fig,
            "class_mapping": mapping,
        }
    return out
