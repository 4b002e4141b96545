"""ROSHAN online object SLAM over a posed detection sequence (or a simulated one).

Examples::

    # a sequence directory (sequence.json + images; layout: jaxsem.slam._sequence docstring,
    # summarised below)
    python infer/roshan.py --sequence data/my_flight --out out/roshan
    # a simulated Forward flight past 10 cars (QuadricSLAM's setting), saved as a sequence too
    python infer/roshan.py --simulate forward --seed 0 --write-sequence out/sim_seq --out out/roshan
    # the baseline (boxes + pose priors only) on the same input
    python infer/roshan.py --simulate orbit --seed 1 --baseline --out out/baseline
    # a TUM RGB-D folder with any 2D detector's tracked boxes (layout: jaxsem.slam.load_tum_sequence),
    # texture planes measured on its images by ROSHAN's front end
    python infer/roshan.py --tum data/rgbd_dataset_freiburg1_desk --detections dets.jsonl \
        --frontend orb --out out/tum
    # posed photos only (sequence.json frames with "camera_T_world" and "image", no detections):
    # the shipped detect-and-lift network finds, classifies and lifts the objects
    python infer/roshan.py --sequence data/my_desk --detector lmo-rcnn --frontend orb --out out/desk
    # one stretch of a BOP scene (LM-O's desk: jaxsem data fetch lmo), as a user's sequence
    python infer/roshan.py --bop DATA/lmo/test/000002 --split tune --stretch 0 \
        --frontend orb --out out/lmo

Input layouts:

- ``--sequence DIR``: ``DIR/sequence.json`` (below) and the images it names.
- ``--tum DIR --detections FILE``: a TUM RGB-D folder, ``rgb.txt`` (``timestamp filename`` per
  line), ``groundtruth.txt`` (``timestamp tx ty tz qx qy qz qw``: camera-to-world, the pose
  prior), optional ``depth.txt`` (not read); ``#`` starts a comment. ``FILE`` is one JSON line per
  image: ``{"frame": "rgb/<t>.png" (or "timestamp": t), "detections": [{"box": [u_min, v_min,
  u_max, v_max], "class": name, "score": optional, "id": track id}]}``; images pair with the
  pose nearest in time (at most 0.02 s). Intrinsics from the folder's name (freiburg1/2/3).
- ``--bop DIR``: a BOP scene folder (``scene_gt.json``, ``camera.json`` or ``scene_camera.json``,
  ``rgb/``, ``models/obj_XXXXXX.ply`` beside or two levels up). The frames of ``--split`` are cut
  into stretches where at least three objects stay put (``jaxsem.slam.find_stretches``); stretch
  ``--stretch`` becomes a sequence with drifting odometry as pose priors, each still object's
  visible box (rendered from its mesh, with occlusion) plus 2 px noise, and user-style class
  sizes (``jaxsem.slam.stretch_sequence``, ``--setting``); the truth is kept for the errors.

``sequence.json``: ``{"K": 3x3, "image_size": [w, h], "frames": [{"camera_T_world": 4x4,
"image": optional file name, "detections": [{"box": [u_min, v_min, u_max, v_max], "class":
"car", "id": association id, "texture_depth": optional metres}]}], "initial": optional
[{"id", "center", "radii", "rotation"}] (world-frame initial ellipsoids used instead of the
single-view initialisation), "noise": optional {"box_sigma": px, "texture_sigma": m, "pose_translation_sigma": m,
"pose_rotation_sigma_deg": deg} (any subset; --box-sigma etc. override it; with ``--detector`` the
box sigma is the detector's), "truth": optional}``.
Bad input exits with one line naming the file and the JSON field, before the solve: a sequence
with no detection at all, a box outside the image or over 10 times its size, an unreadable image
of an overlay frame.

Frames are fed one at a time to the online smoother (``jaxsem.slam.online_init`` /
``online_update``: new ids initialised from one detection, re-optimised every
``--optimize-every`` frames), then ``--final-iterations`` LM steps run over everything kept.
Writes ``map.json`` (per object: id, class, center, radii, rotation; world frame, metres; and
the estimated camera poses), ``top_down.png`` and ``overlay_<frame>.png`` for ``--overlays``
frames (detections green, projected estimates blue; a blank canvas when there are no images).
With ground truth (simulated input) it prints the per-object errors.

The same command: ``jaxsem roshan`` (``python infer/roshan.py``).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import pathlib
import time

from jaxsem import scripting as sc
from jaxsem._commands.volumon_eval import SHIPPED_NAMES
from jaxsem.factors import ROBUST_LOSSES
from jaxsem.slam import SolverConfig

# Imports inside the functions below are deliberate: `jaxsem <command> --help` imports this module
# and must stay fast, so jax, the method's package and matplotlib load only when the command runs.


def _loss_name(text: str) -> str:
    """A robust loss's name (jaxsem.factors.ROBUST_LOSSES), checked while parsing."""
    if text not in ROBUST_LOSSES:
        raise argparse.ArgumentTypeError(f"expected one of {', '.join(ROBUST_LOSSES)}, got {text!r}")
    return text


# Convenience flags for SolverConfig fields (help from the dataclass; the sequence's "noise" and
# the simulator's noise come first, these flags override them).
CONFIG_FLAGS = (
    sc.ConfigFlag("noise.box_sigma", type=sc.positive_float),
    sc.ConfigFlag("noise.texture_sigma", type=sc.positive_float),
    sc.ConfigFlag("default_depth", type=sc.positive_float),
    sc.ConfigFlag("texture_plane_fraction", type=sc.nonnegative_float),
    sc.ConfigFlag("box_outward_scale", type=sc.positive_float),
    sc.ConfigFlag("box_loss", type=_loss_name),
)


def _class_table(args):
    """The built-in class table plus the rows of ``--classes`` (None without it)."""
    from jaxsem import classes

    if args.classes is None:
        return None
    return classes.ClassTable.from_json(args.classes, base=classes.DEFAULT_TABLE)


def build_parser(prog: str | None = None) -> argparse.ArgumentParser:
    p = sc.command_parser(prog, __doc__)
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument(
        "--sequence",
        type=pathlib.Path,
        help="sequence directory (or its sequence.json)",
    )
    src.add_argument(
        "--tum",
        type=sc.existing_dir,
        help="a TUM RGB-D folder (rgb.txt, groundtruth.txt); needs --detections",
    )
    src.add_argument(
        "--bop",
        type=sc.existing_dir,
        help="a BOP scene folder (scene_gt.json, camera.json, rgb/, models/): one stretch of it, see --stretch",
    )
    src.add_argument("--simulate", choices=("forward", "orbit"), help="simulate a sequence instead")
    p.add_argument(
        "--detections",
        type=sc.existing_file,
        help="with --tum: a JSON-lines file, one line per image: "
        '{"frame": "rgb/<t>.png", "detections": [{"box": [...], "class": ..., "id": track id, "score": ...}]}',
    )
    p.add_argument(
        "--detector",
        help="map from pixels: this detect-and-lift network reads every frame's image (lmo-rcnn: the "
        "shipped LM-O one; or an exported .npz); its boxes and classes replace any in the input, "
        "associated across frames by class, box overlap and viewing rays (jaxsem.slam.detected_sequence), "
        "its ellipsoids start the map; the box factors then take a detector's noise, sigma "
        "and loss (jaxsem.slam.SolverConfig.for_detector; --box-sigma and --box-loss override)",
    )
    p.add_argument(
        "--min-score", type=sc.nonnegative_float, default=0.5, help="with --detector: least detection score kept"
    )
    p.add_argument(
        "--split", choices=("tune", "test", "all"), default="all", help="with --bop: frame ids < 600, the rest, or all"
    )
    p.add_argument("--stretch", type=sc.nonnegative_int, default=0, help="with --bop: which stretch of the split")
    p.add_argument(
        "--setting",
        choices=("clean", "missed"),
        default="clean",
        help="with --bop: detections clean, or missed and cut by occluders",
    )
    p.add_argument(
        "--frontend",
        choices=("none", "lk", "orb"),
        default="none",
        help="measure texture planes on the images with ROSHAN's front end (jaxsem.slam.measure_texture): "
        "LK tracks, or ORB matches for frames far apart; needs int track ids",
    )
    p.add_argument(
        "--seed", type=sc.nonnegative_int, default=0, help="simulation seed (--simulate); noise seed (--bop)"
    )
    p.add_argument("--objects", type=sc.positive_int, default=10, help="cars in the simulated map")
    p.add_argument("--frames", type=sc.positive_int, default=60, help="frames of the simulated flight")
    p.add_argument(
        "--write-sequence",
        type=pathlib.Path,
        help="also save the simulated sequence as a sequence directory here",
    )
    p.add_argument("--out", type=sc.output_dir, required=True, help="output folder")
    p.add_argument(
        "--classes",
        type=sc.existing_file,
        help="JSON file of your own object classes, added to the built-in ones: "
        '{"classes": [{"name": "mug", "dimensions": [x, y, z] (full extents, m), '
        '"sigma": [x, y, z] (m), "shape": "cylinder"}]} (jaxsem.classes.ClassTable.from_json)',
    )
    p.add_argument(
        "--baseline",
        action="store_true",
        help="boxes + pose priors only (no texture, no prior)",
    )
    p.add_argument("--optimize-every", type=sc.positive_int, default=5, help="frames between optimisations")
    p.add_argument("--iterations", type=sc.positive_int, default=3, help="LM steps per online optimisation")
    p.add_argument("--final-iterations", type=sc.nonnegative_int, default=20, help="LM steps after the last frame")
    sc.add_config_flags(p, SolverConfig, CONFIG_FLAGS[:2])
    p.add_argument(
        "--pose-sigma",
        type=str,
        help="pose prior sigmas 'metres,degrees'",
    )
    sc.add_config_flags(p, SolverConfig, CONFIG_FLAGS[2:])
    p.add_argument("--overlays", type=sc.nonnegative_int, default=4, help="number of frames to draw overlays for")
    p.add_argument("--float64", action="store_true", help="solve in float64")
    p.add_argument("--quiet", action="store_true", help="no per-frame progress")
    return p


def parse_args(argv=None, prog: str | None = None):
    parser = build_parser(prog)
    args = parser.parse_args(argv)
    if (args.tum is None) != (args.detections is None):
        parser.error("--detections: goes with --tum (a TUM folder and its detections file, both or neither)")
    if args.frontend != "none" and args.simulate:
        parser.error("--frontend: needs images (--sequence, --tum or --bop), not --simulate")
    if args.classes is not None and args.simulate:
        # a simulated flight's cars use the built-in table: the file would go unread
        parser.error(
            f"--classes: {args.classes} applies to --sequence, --tum or --bop; --simulate uses the built-in classes"
        )
    if args.write_sequence is not None and not args.simulate:
        parser.error("--write-sequence: saves a simulated flight (--simulate); the input is already a sequence")
    if args.write_sequence is not None and pathlib.Path(args.write_sequence).is_file():
        parser.error(f"--write-sequence: {args.write_sequence} is a file; a sequence is a folder")
    if args.detector is not None:
        if args.simulate or args.tum:
            parser.error("--detector: reads the images of --sequence or --bop (not --simulate or --tum)")
        if args.detector not in SHIPPED_NAMES and not pathlib.Path(args.detector).exists():
            parser.error(
                f"--detector: expected {' or '.join(SHIPPED_NAMES)} or an exported model file, got {args.detector!r}"
            )
        if args.min_score > 1.0:
            parser.error(f"--min-score: expected a score in [0, 1], got {args.min_score}")
    return args


def _detected(args, sequence):
    """``sequence`` with the detector's tracks (its boxes, classes and lifted ellipsoids) in place
    of its own detections. Classes the sequence's table lacks get rows from the network's own
    lifts (full extents the median of its detections', sigma 30 %)."""
    import numpy as np

    from .. import slam
    from ..classes import DEFAULT_TABLE, ClassTable
    from ..volumon import rcnn

    loaded = rcnn.load_rcnn(args.detector)
    dets = []
    for t in range(len(sequence.frames)):
        image = sequence.image(t)
        if image is None:
            raise ValueError(f"frames[{t}].image: --detector reads every frame's image; this frame names none")
        dets.append(rcnn.detect_image(loaded, image, sequence.K))
        if not args.quiet:
            print(f"detect {t + 1:4d}/{len(sequence.frames)}: {len(dets[-1]['box'])} detections", flush=True)
    table = sequence.classes if sequence.classes is not None else DEFAULT_TABLE
    rows = []
    for name in sorted({c for d in dets for c in d["class_name"]} - set(table.names)):
        radii = np.concatenate([d["radii"][[c == name for c in d["class_name"]]] for d in dets])
        dims = 2.0 * np.median(radii, axis=0)
        rows.append({"name": name, "dimensions": dims.tolist(), "sigma": (0.3 * dims).tolist()})
    if rows:
        table = ClassTable.from_dict(rows, base=table)
    out = slam.detected_sequence(dataclasses.replace(sequence, classes=table), dets, min_score=args.min_score)
    if not out.object_ids:
        raise ValueError(f"--detector: no object seen in three frames or more (min score {args.min_score})")
    return out


def _bop_sequence(args):
    """Stretch ``--stretch`` of the BOP scene's ``--split`` as a sequence (truth attached)."""
    from .. import slam
    from ..volumon import data as vdata

    scene = vdata.load_bop_split(args.bop, args.split)
    stretches = slam.find_stretches(scene)
    if args.stretch >= len(stretches):
        raise ValueError(
            f"--stretch: the {args.split} split of {args.bop} has {len(stretches)} stretches, got {args.stretch}"
        )
    table, _ = slam.user_class_table(vdata.bop_class_extents(scene))
    if args.classes is not None:
        from jaxsem import classes

        table = classes.ClassTable.from_json(args.classes, base=table)
    seq, _ = slam.stretch_sequence(stretches[args.stretch], table, setting=args.setting, seed=args.seed)
    return seq


def solver_config(args, sim_cfg=None, sequence=None):
    """SolverConfig from the flags (simulated input: noise matched to the simulator; a sequence's
    optional ``"noise"`` object next; the flags override both)."""
    import math

    from .. import slam
    from ..slam import sim

    system = sim.BASELINE if args.baseline else sim.ROSHAN
    if sim_cfg is not None:
        cfg = sim.solver_config(system, sim_cfg)
    elif args.baseline:
        cfg = slam.baseline_config()  # the one definition of the baseline
    else:
        cfg = slam.SolverConfig()
    if sequence is not None and sequence.noise:
        cfg = _replace(cfg, noise=slam.noise_model(sequence, cfg.noise))
    if getattr(args, "detector", None) is not None:  # the network's boxes, not the input's
        cfg = cfg.for_detector(robust=not args.baseline)
    cfg = sc.apply_config_flags(cfg, args, CONFIG_FLAGS)
    noise = {}
    if args.pose_sigma is not None:  # two fields in one flag, set here
        try:
            m, deg = (float(x) for x in args.pose_sigma.split(","))
        except ValueError:
            raise ValueError(f"--pose-sigma: expected 'metres,degrees', got {args.pose_sigma!r}") from None
        noise.update(pose_translation_sigma=m, pose_rotation_sigma=math.radians(deg))
    for name, value in noise.items():
        if not value > 0:
            raise ValueError(f"--{name.replace('_', '-')}: expected a positive number, got {value}")
    if noise:
        values = {k: getattr(cfg.noise, k) for k in cfg.noise.__dataclass_fields__}
        cfg = _replace(cfg, noise=type(cfg.noise)(**{**values, **noise}))
    return cfg


def _replace(module, **fields):
    values = {k: getattr(module, k) for k in module.__dataclass_fields__}
    return type(module)(**{**values, **fields})


def main(argv=None, prog: str | None = None) -> int:
    args = parse_args(argv, prog)
    import jax

    if args.float64:
        jax.config.update("jax_enable_x64", True)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from .. import quadrics, slam
    from ..slam import sim

    sim_cfg = None
    if args.simulate:
        sim_cfg = sim.quadricslam_config(args.simulate, num_objects=args.objects, num_frames=args.frames)
        if args.simulate == "forward" and args.frames != 60:  # keep the path length
            sim_cfg = sim_cfg.replace(forward_step=0.75 * 59 / max(args.frames - 1, 1))
        one = jax.jit(sim.simulate, static_argnums=1)(jax.random.key(args.seed), sim_cfg)
        sequence = sim.sequence_from_simulation(one, sim_cfg.image_size)
        if args.write_sequence:
            print(f"wrote {slam.save_sequence(sequence, args.write_sequence)}")
    elif args.tum:
        sequence = slam.load_tum_sequence(args.tum, args.detections, classes=_class_table(args))
    elif args.bop:
        sequence = _bop_sequence(args)
    else:
        sequence = slam.load_sequence(
            args.sequence, classes=_class_table(args), require_detections=args.detector is None
        )
    if args.detector is not None:
        sequence = _detected(args, sequence)
    if args.frontend != "none":
        sequence, _ = slam.measure_texture(sequence, slam.FrontEndConfig(matcher=args.frontend))
    config = solver_config(args, sim_cfg, sequence)
    n = len(sequence.frames)
    print(
        f"{n} frames, {len(sequence.object_ids)} objects, "
        f"{sum(len(f.ids) for f in sequence.frames)} detections; "
        f"{'baseline' if args.baseline else 'ROSHAN'}",
        flush=True,
    )

    # images are checked now, before the solve: an unreadable one fails the run at once (every
    # frame's by its header, the overlays' by reading them)
    import cv2

    for t in range(n):
        path = sequence.image_path(t)
        if path is not None and not cv2.haveImageReader(str(path)):
            raise ValueError(f"frames[{t}].image: cannot read image file {str(path)!r} (not an image format)")
    picks = np.unique(np.linspace(0, n - 1, max(args.overlays, 0)).round().astype(int)) if args.overlays else []
    images = {int(t): sequence.image(int(t)) for t in picks}

    def progress(t, state, seconds):
        if not args.quiet:
            objects = int(np.sum(np.asarray(state.problem.object_mask)))
            print(
                f"frame {t + 1:4d}/{n}: {len(sequence.frames[t].ids):2d} detections, {objects:3d} objects, "
                f"{1e3 * seconds:7.1f} ms",
                flush=True,
            )

    start = time.perf_counter()
    result = slam.run_sequence(
        sequence,
        config,
        optimize_every=args.optimize_every,
        iterations=args.iterations,
        final_iterations=args.final_iterations,
        callback=progress,
    )
    after_first = result.frame_seconds[1:] if n > 1 else result.frame_seconds
    print(
        f"solved in {time.perf_counter() - start:.1f} s (first frame {result.frame_seconds[0]:.1f} s with "
        f"compilation, then median {1e3 * np.median(after_first):.1f} ms per frame)",
        flush=True,
    )

    args.out.mkdir(parents=True, exist_ok=True)
    map_json = slam.map_to_json(
        result.object_ids,
        result.object_classes,
        result.ellipsoid,
        result.camera_T_world,
    )

    truth = sequence.truth
    fig, ax = plt.subplots(figsize=(9, 6))
    if truth and truth.get("objects"):
        o = truth["objects"]
        slam.draw_top_down(
            ax,
            quadrics.Ellipsoid(*(np.stack([x[k] for x in o]) for k in ("rotation", "center", "radii"))),
            color="k",
            lw=2.0,
            label="truth",
        )
    slam.draw_top_down(
        ax,
        result.ellipsoid,
        color="tab:blue",
        lw=1.3,
        label="estimate",
        labels=[str(i) for i in result.object_ids],
    )
    slam.draw_camera_path(ax, result.camera_T_world, color="tab:green", label="estimated camera path")
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    sc.atomic_savefig(fig, args.out / "top_down.png", dpi=110)
    plt.close(fig)

    for t in picks:
        fr = sequence.frames[t]
        W, H = sequence.image_size
        fig, ax = plt.subplots(figsize=(6, 6 * H / W))
        slam.draw_overlay(
            ax,
            images[int(t)],
            quadrics.Camera(sequence.K, result.camera_T_world[t]),
            sequence.image_size,
            fr.boxes,
            fr.ids,
            result.ellipsoid,
            result.object_ids,
            title=f"frame {t}: detections (green), estimates projected (blue)",
        )
        fig.tight_layout()
        sc.atomic_savefig(fig, args.out / f"overlay_{t:06d}.png", dpi=100)
        plt.close(fig)

    # map.json last: a run that failed on the way leaves none behind
    sc.atomic_write_text(args.out / "map.json", json.dumps(map_json, indent=1))
    if truth and truth.get("objects"):
        err = sim.truth_errors(result, truth)
        print("| id | shape (m) | position (m) | orientation (deg) |\n|---|---|---|---|")
        for k, i in enumerate(err["ids"]):
            print(f"| {i} | {err['shape'][k]:.2f} | {err['position'][k]:.2f} | {err['orientation'][k]:.1f} |")
        m = err["mean"]
        print(f"| mean | {m['shape']:.2f} | {m['position']:.2f} | {m['orientation']:.1f} |")
        sc.record(mean_error=m)
    sc.record(frames=n, objects=len(result.object_ids), median_frame_ms=1e3 * float(np.median(after_first)))
    print(f"wrote {args.out / 'map.json'}, top_down.png and {len(picks)} overlays")
    return 0
