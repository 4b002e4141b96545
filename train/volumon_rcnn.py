"""Train VoluMon R-CNN (thesis 5.7) on rendered LM-O desks and the real LM-O tuning photographs.

    python train/volumon_rcnn.py --workdir runs/rcnn --renders runs/desk_frames --frames 2000 \\
        --lmo data/lmo/test/000002 --steps 100000

Renders ``--frames`` desk frames into ``--renders`` first (resumable chunks; needs
``jaxsem data fetch lmo`` and ``ycb``), plus 64 held-out frames of another seed, then trains in
``--workdir`` (re-running resumes). The tuning photos from ``--val-from`` (to ``--val-to``) are the held-out
validation (scored every evaluation; the rendered held-out frames when there are none). ``--oracle`` trains the fully supervised oracle (3D labels in
place of the dual loss) on the same data. The LM-O test split (frame ids 600 and above) is never
read.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import pathlib
import sys

from jaxsem import scripting as sc


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python train/volumon_rcnn.py", description=__doc__.split("\n")[0])
    p.add_argument("--workdir", type=pathlib.Path, required=True)
    p.add_argument("--renders", type=pathlib.Path, required=True, help="folder of rendered desk frame chunks")
    p.add_argument("--frames", type=sc.positive_int, default=2000, help="desk frames to render (default 2000)")
    p.add_argument("--lmo", type=pathlib.Path, default=None, help="LM-O scene folder: its tuning photos join training")
    p.add_argument("--models", type=pathlib.Path, default=None, help="LM-O meshes (default: <lmo>/models)")
    p.add_argument("--ycb", type=pathlib.Path, default=pathlib.Path("data/ycb/meshes"), help="distractor meshes")
    p.add_argument("--steps", type=sc.positive_int, default=100_000)
    p.add_argument("--stop-at", type=sc.positive_int, default=None, help="end this chunk of the run at this step")
    p.add_argument("--batch", type=sc.positive_int, default=8)
    p.add_argument("--burn-in", type=int, default=2000)
    p.add_argument("--oracle", action="store_true", help="the fully supervised oracle (3D labels)")
    p.add_argument(
        "--backbone", choices=("mobilenet_v2", "plain_cnn"), default="mobilenet_v2", help="plain_cnn: the CPU preset"
    )
    p.add_argument("--input-size", type=sc.image_size, default=None, help="W,H of the images (default 320,240)")
    p.add_argument(
        "--anchor-scale", type=sc.positive_float, default=1.0, help="anchor sizes times this (1.4 at 448,336)"
    )
    p.add_argument("--cnn-width", type=sc.positive_int, default=16, help="plain_cnn's first width (default 16)")
    p.add_argument(
        "--val-from",
        type=sc.nonnegative_int,
        default=500,
        help="tuning photos with this frame id or above are the held-out validation, not trained on (default 500)",
    )
    p.add_argument(
        "--val-to",
        type=sc.positive_int,
        default=None,
        help="the held-out validation ends below this frame id; tuning photos from here on are trained on again "
        "(a fold of cross-validation; default: where the tuning photos end)",
    )
    p.add_argument("--real-per-batch", type=sc.nonnegative_int, default=2, help="real photos in each batch")
    p.add_argument(
        "--augment-real", action="store_true", help="zoom, shift and colour-jitter the real photos (data.augment_batch)"
    )
    p.add_argument(
        "--augment-renders",
        action="store_true",
        help="colour-jitter the rendered frames too (no zoom: the head reads depth from apparent size)",
    )
    p.add_argument(
        "--zoom-renders",
        type=sc.positive_float,
        default=1.0,
        help="zoom each rendered frame by a factor log-uniform in [1/Z, Z], the intrinsics changed to match "
        "(data.augment_batch): other cameras' focal lengths (default 1: none)",
    )
    p.add_argument(
        "--virtual-depth",
        action="store_true",
        help="the lift's depth is the renders' camera's, scaled to each image's focal length "
        "(ReconstructionConfig.reference_focal: the renders' focal length at the input size)",
    )
    p.add_argument(
        "--multiview-real",
        action="store_true",
        help="pair the real photos for the dual loss (data.multiview_frames: a second photo of the same desk)",
    )
    p.add_argument(
        "--lift-stride8",
        action="store_true",
        help="the VoluMon head also reads the RoIs from the stride-8 features (plain_cnn; a branch that starts at zero)",
    )
    p.add_argument(
        "--lift-crop",
        type=sc.nonnegative_int,
        default=0,
        help="pixels per side of an image crop the VoluMon head also reads at each RoI (a branch that starts at zero)",
    )
    p.add_argument(
        "--lift-features",
        choices=("shared", "own", "stage", "backbone", "volumon"),
        default="shared",
        help="own: the VoluMon head reads RoI layers of its own (started as copies of --init-from's "
        "detector's), so the lift's features can learn while the detector's stay; stage: the "
        "backbone's last stage (stride 8 to 16) of its own too; backbone: a whole backbone of its own; "
        "volumon: the separate VoluMon network's two crops and branches (the old lift's layers are not adopted)",
    )
    p.add_argument(
        "--train-only",
        choices=("all", "lift", "heads"),
        default="all",
        help="lift: only the VoluMon head learns; the detector (backbone, proposals, box and class heads, "
        "batch-norm statistics) stays --init-from's. heads: only the proposal stage and the box and class "
        "outputs learn; the RoI features and the lift stay --init-from's",
    )
    p.add_argument(
        "--detector-lr-scale",
        type=sc.positive_float,
        default=1.0,
        help="the detector's layers (all but the VoluMon head's) learn at the rate times this (default 1)",
    )
    p.add_argument(
        "--init-from", type=sc.existing_path, default=None, help="start from this model (a workdir or an exported .npz)"
    )
    p.add_argument(
        "--distill-from",
        default=None,
        help="a VoluMon teacher ('lmo': the shipped LM-O model, or a model path) whose ellipsoids on the real "
        "photos' 2D labels the lift learns from (rc.teacher_labels)",
    )
    p.add_argument(
        "--distill-weight", type=sc.positive_float, default=0.01, help="the distillation term's weight (default 0.01)"
    )
    primal_help = "weight of VoluMon's primal loss on the renders' depth points (ray distance; RCNNLossConfig.primal)"
    p.add_argument("--primal", type=sc.positive_float, default=None, help=primal_help)
    p.add_argument(
        "--points", type=sc.positive_int, default=64, help="depth points stored per rendered label with --primal"
    )
    p.add_argument(
        "--keep", type=sc.positive_int, default=2, help="checkpoints kept, the latest (default 2; more to average)"
    )
    p.add_argument("--learning-rate", type=sc.positive_float, default=1e-3, help="Adam's step size (default 1e-3)")
    p.add_argument("--seed", type=int, default=0)
    a = p.parse_args(argv)
    if a.zoom_renders < 1.0:
        p.error(f"--zoom-renders: expected a factor of at least 1 (1: no zoom), got {a.zoom_renders}")
    models = a.models or (a.lmo / "models" if a.lmo else None)
    if models is None or not models.is_dir():
        p.error(f"--models: no LM-O meshes folder {models} (give --lmo or --models)")
    if a.lmo is not None and not (a.lmo / "scene_gt.json").is_file():
        p.error(f"--lmo: {a.lmo} holds no scene_gt.json (jaxsem data fetch lmo --out data)")
    if a.val_to is not None and a.val_to <= a.val_from:
        p.error(f"--val-to: expected a frame id above --val-from ({a.val_from}), got {a.val_to}")
    val_to = max(a.val_from, 600) if a.val_to is None else a.val_to
    if a.train_only != "all" and a.init_from is None:
        p.error(f"--train-only: '{a.train_only}' keeps trained layers; give them with --init-from")
    if a.detector_lr_scale > 1.0:
        p.error(f"--detector-lr-scale: expected a number in (0, 1], got {a.detector_lr_scale}")
    if a.train_only != "all" and a.detector_lr_scale != 1.0:
        p.error("--detector-lr-scale: --train-only already sets which layers learn")
    if a.distill_from is not None and a.lmo is None:
        p.error("--distill-from: needs --lmo (the teacher labels the real photographs)")
    if a.distill_from not in (None, "lmo") and not pathlib.Path(a.distill_from).exists():
        p.error(f"--distill-from: expected 'lmo' or a VoluMon model path, got {a.distill_from}")

    from jaxsem.volumon import data as df, rcnn as rc

    loss = rc.RCNNLossConfig(burn_in=a.burn_in)
    if a.oracle:
        loss = dataclasses.replace(loss, dual=0.0, size=0.0, oracle=1.0)
    if a.distill_from is not None:
        loss = dataclasses.replace(loss, distill=a.distill_weight)
    if a.primal is not None:
        volumon = dataclasses.replace(loss.volumon, primal_distance="ray")
        loss = dataclasses.replace(loss, primal=a.primal, volumon=volumon)
    points = a.points if a.primal is not None else 0
    model = rc.RCNNTrainConfig().model
    model = dataclasses.replace(
        model,
        backbone=a.backbone,
        cnn_width=a.cnn_width,
        lift_stride8=a.lift_stride8,
        lift_crop=a.lift_crop,
        lift_features=a.lift_features,
        input_size=a.input_size or model.input_size,
        anchor_sizes=tuple(a.anchor_scale * float(s) for s in model.anchor_sizes),
    )
    if a.virtual_depth:  # the renders' focal length at the input size (write_desk_frames scales LM-O's K)
        W, H = model.input_size
        focal = math.sqrt(df.LMO_K[0, 0] * W / 640.0 * df.LMO_K[1, 1] * H / 480.0)
        model = dataclasses.replace(
            model, reconstruction=dataclasses.replace(model.reconstruction, reference_focal=focal)
        )
    config = rc.RCNNTrainConfig(
        model=model,
        loss=loss,
        batch_size=a.batch,
        real_per_batch=a.real_per_batch,
        num_steps=a.steps,
        seed=a.seed,
        learning_rate=a.learning_rate,
        augment_real=a.augment_real,
        augment_renders=a.augment_renders,
        zoom_renders=a.zoom_renders,
        keep=a.keep,
        multiview_real=a.multiview_real,
        distill_from=a.distill_from or "",
        train_only="" if a.train_only == "all" else a.train_only,
        detector_lr_scale=a.detector_lr_scale,
        init_from="" if a.init_from is None else str(a.init_from),
    )
    size = config.model.input_size
    ycb = a.ycb if a.ycb.is_dir() else None
    df.write_desk_frames(
        a.renders / "train",
        a.frames,
        seed=1000 + a.seed,
        models_dir=models,
        distractor_dir=ycb,
        image_size=size,
        num_points=points,
    )
    df.write_desk_frames(
        a.renders / "heldout", 64, seed=999_999, models_dir=models, distractor_dir=ycb, image_size=size
    )
    renders = df.load_frame_chunks(a.renders / "train")
    held = df.load_frame_chunks(a.renders / "heldout")
    real = None
    if a.lmo is not None:
        tune = df.bop_frames(a.lmo, "tune")
        held_out = [a.val_from <= f["frame_id"] < val_to for f in tune]
        fit = [f for f, h in zip(tune, held_out) if not h]
        val = [f for f, h in zip(tune, held_out) if h]
        if not fit:
            p.error(f"--val-from: no tuning photo outside frame ids {a.val_from}-{val_to - 1} is left to train on")
        if a.multiview_real:  # each split paired within itself: no label crosses into validation
            fit = df.multiview_frames(fit)
        if a.distill_from is not None:
            from jaxsem.volumon import load_pretrained

            path = None if a.distill_from == "lmo" else a.distill_from
            fit = rc.teacher_labels(fit, load_pretrained(path, kind="lmo"))
        real = df.frame_arrays(fit, size)
        if val:  # the real validation photos are the held-out figures that matter
            held = df.frame_arrays(val, size)
    rc.train_rcnn(config, a.workdir, renders, real, held, stop_at=a.stop_at, log=print)
    return 0


if __name__ == "__main__":
    sys.exit(sc.run_main(main))
