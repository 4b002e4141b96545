"""Scores the shipped VoluMon model (or a training run, --workdir / --model) on held-out detections.

In: synthetic held-out detections of several classes drawn from --seed (a stream no training seed
uses), the objects of a FAT-layout / make_synthetic directory (--data), or the real photographs of
a BOP scene (--data SCENE_DIR with scene_gt.json, e.g. LM-O test scene 000002; --split
tune|test|all, --min-visible). Out: JSON figures (median size and centre errors, size
correlation, AUCs) printed, written atomically with --json, and kept as the results of the run
directory's summary.json.

On a BOP scene the boxes are the objects' visible boxes (from scene_gt_info.json or rendered from
the meshes), ADI is ADD-S over the mesh's points, and the JSON adds ``per_class``,
``by_visibility``, ``class_mapping`` (which row of the model's class head scored each class: a
class the model lacks is scored with the class head's expectation, or with --class-mapping
nearest the model class nearest in size), ``baseline`` (the known-size geometric baseline: each
class's true mesh extent, axis-aligned to the camera, depth from the box's size, centre on the
box's ray; ``baseline_mesh_axes``: the same with the mesh's own axis order instead of the pair
of axes that matches the box's aspect) and, with --oracle DIR, ``oracle`` (that model scored the
same way; with --model lmo the fully supervised oracle shipped beside the LM-O model is scored by
default). On a folder of rendered desk detections (``python -m jaxsem.volumon.data.make_lmo_renders``)
the same keys (ADI there against the mesh extent's cuboid): the sim-to-real gap of the LM-O model.

With ``--model lmo-rcnn`` (or an exported VoluMon R-CNN, or its training run) on a BOP scene the
network finds the objects itself, from the photographs alone: the JSON holds ``detection``
(``ap50`` over the classes, ``ap50_per_class``, ``recall50``), the 3D figures of its detections
matched to an object at least --min-visible visible (box IoU >= 0.5), ``num_matched``,
``num_truth``, ``ms_per_image`` (batch 1), ``baseline`` (known-size, the same boxes) and
``parallel`` (the shipped LM-O VoluMon fed the same boxes and classes: thesis 5.3's design);
``--truth-boxes`` adds ``on_true_boxes``: the network's lift, the separate network and the baseline
on every true object's visible box and class, a figure of the lift that does not move with the
detector.

Example (the tuning split of LM-O; the test split, ids >= 600, is held out)::

    jaxsem volumon eval --model lmo --data DATA/lmo/test/000002 --split tune --json tune.json
"""

from __future__ import annotations

import argparse
import json
import pathlib

from jaxsem import scripting as sc

# Imports inside the functions below are deliberate: `jaxsem <command> --help` imports this module
# and must stay fast, so jax, the method's package and matplotlib load only when the command runs.

SPLITS = ("tune", "test", "all")


def build_parser(prog: str | None = None) -> argparse.ArgumentParser:
    p = sc.command_parser(prog, __doc__)
    p.add_argument("--seed", type=int, default=1, help="held-out seed (a stream no training seed uses)")
    p.add_argument("--num", type=sc.positive_int, default=256, help="number of detections")
    p.add_argument("--json", type=sc.output_file, help="write the figures here (atomically)")
    add_model_arguments(
        p, sc.existing_path, "a training run (config.json + checkpoints/) or a .npz model (default: the shipped model)"
    )
    p.add_argument("--postopt", type=sc.nonnegative_int, default=0, help="also refine with PostOpt for this many steps")
    p.add_argument(
        "--data",
        type=sc.existing_dir,
        help="score the objects of a FAT-layout or make_synthetic directory (the first --num), or of a BOP scene "
        "folder (with scene_gt.json: every object of --split at least --min-visible visible) instead of "
        "synthetic held-out detections",
    )
    p.add_argument(
        "--split",
        choices=SPLITS,
        help="BOP scene only, required there: 'tune' (frame ids below 600: LM-O's tuning split), 'test' (ids 600 "
        "and above, held out) or 'all'",
    )
    add_min_visible_argument(p, "BOP scene or desk renders only")
    p.add_argument(
        "--oracle",
        type=sc.existing_path,
        help="BOP scene or desk renders only: also score this model (a training run or .npz: the fully supervised "
        "oracle) as 'oracle' (default with --model lmo: the oracle shipped beside it)",
    )
    p.add_argument(
        "--input-size",
        type=sc.image_size,
        help="R-CNN only: run the network at this W,H (multiples of 16; default: the size it was trained at)",
    )
    p.add_argument(
        "--lift-at",
        choices=("refined", "proposal"),
        help="R-CNN only: the box whose features the lift reads, each RoI's refined box or the RoI itself "
        "(default: the model's own setting)",
    )
    p.add_argument(
        "--truth-boxes",
        action="store_true",
        default=None,
        help="R-CNN only: also score its lift, the separate network and the baseline on every true object's visible "
        "box and class (on_true_boxes: the lift's figure apart from the detector)",
    )
    add_class_mapping_argument(p, "BOP scene only")
    return p


def add_model_arguments(p, workdir_type, workdir_help: str) -> None:
    """The model-source flags of the VoluMon commands, ``--workdir`` (of ``workdir_type``, a
    command's own meaning in ``workdir_help``) and ``--model``, read back together with
    :func:`resolve_model`."""
    p.add_argument("--workdir", type=workdir_type, help=workdir_help)
    p.add_argument(
        "--model",
        help="a shipped model by name ('object': the default tabletop model, 'door', 'lmo': the LM-O model, "
        "'lmo-rcnn': the LM-O detect-and-lift network, BOP scenes only) or a path (a training run "
        "or a .npz); the same as --workdir for a path (default: 'object'; on a BOP scene, --data with "
        "scene_gt.json: 'lmo')",
    )


def add_min_visible_argument(p, scope: str) -> None:
    """``--min-visible`` of the VoluMon commands that read a scene's objects (``scope``: when it
    applies): the visible fraction an object needs to be read."""
    p.add_argument(
        "--min-visible", type=sc.probability, default=0.5, help=f"{scope}: objects at least this fraction visible"
    )


def add_class_mapping_argument(p, scope: str) -> None:
    """``--class-mapping`` of the VoluMon commands that read a BOP scene (``scope``: when it
    applies): the modes of ``jaxsem.volumon.class_rows`` for an object of a class the model lacks."""
    p.add_argument(
        "--class-mapping",
        choices=("generic", "nearest"),
        default="generic",
        help=f"{scope}: how a class the model lacks is read: 'generic' (the class head's expectation over the "
        "model's classes) or 'nearest' (the model class nearest in size to the object's true extents)",
    )


def resolve_model(text: str | None, workdir):
    """``(path or None, kind)`` for :func:`jaxsem.volumon.load_pretrained` from ``--model`` / ``--workdir``;
    :class:`jaxsem.scripting.UsageError` naming ``--model`` when it is neither a shipped name nor a path."""
    from jaxsem.volumon import SHIPPED

    if text is not None and workdir is not None:
        raise sc.UsageError("--model: give --model or --workdir, not both")
    if text is None:
        return workdir, "object"
    if text in SHIPPED:
        return None, text
    path = pathlib.Path(text)
    if path.exists():
        return path, "object"
    if "/" not in text and "\\" not in text and not text.endswith(".npz"):
        raise sc.UsageError(
            f"--model: no shipped model named {text!r}; shipped: {', '.join(sorted(SHIPPED))}, or give a "
            "path to a training run or .npz"
        )
    raise sc.UsageError(f"--model: {text}: no such file or directory")


#: The shipped R-CNNs' names (jaxsem.volumon.rcnn.SHIPPED_RCNNS and ADOPTED_RCNNS, kept here so
#: that --help stays light).
SHIPPED_NAMES = ("lmo-rcnn", "lmo-rcnn-448", "lmo-rcnn-volumon", "lmo-rcnn-448-volumon")


def _rcnn_source(text: str | None, workdir):
    """``(is_rcnn, path)``: whether ``--model`` / ``--workdir`` name a VoluMon R-CNN (a shipped
    one by name; an export whose JSON or a run whose config.json configures anchors)."""
    if text in SHIPPED_NAMES:
        return True, text
    source = workdir if text is None else text
    if source is None:
        return False, None
    path = pathlib.Path(source)
    meta = path / "config.json" if path.is_dir() else path.with_suffix(".json")
    try:
        info = json.loads(meta.read_text())
    except (OSError, ValueError):
        return False, None
    model = info.get("config", info).get("model", {}) if isinstance(info, dict) else {}
    return isinstance(model, dict) and "anchor_sizes" in model, path


def _rcnn_figures(args, path) -> dict:
    """The detect-and-lift network's figures on a BOP scene (see the module docstring)."""
    from jaxsem.volumon import load_pretrained
    from jaxsem.volumon.rcnn import configured, evaluate_scene, load_rcnn

    settings = {"input_size": args.input_size and tuple(args.input_size), "lift_at": args.lift_at}
    loaded = configured(load_rcnn(path), **{k: v for k, v in settings.items() if v is not None})
    parallel = load_pretrained(kind="lmo")
    from tqdm.auto import tqdm

    bar = lambda frames: tqdm(frames, desc="volumon rcnn eval", unit="photo")
    return evaluate_scene(
        loaded,
        args.data,
        args.split,
        min_visible=args.min_visible,
        parallel=parallel,
        progress=bar,
        truth_boxes=bool(args.truth_boxes),
    )


def _is_bop(path) -> bool:
    return path is not None and (pathlib.Path(path) / "scene_gt.json").is_file()


def _bop_figures(args, model, variables, config) -> dict:
    """The BOP-scene figures (see the module docstring)."""
    import numpy as np

    from jaxsem.volumon import (
        class_rows,
        evaluate_scene_batch,
        known_size_ellipsoid,
        summarise_detections,
    )

    from ..volumon import data as vdata

    oracle = _load_oracle(args)
    scene = vdata.load_bop_split(args.data, args.split)
    if not scene.frames:
        raise sc.UsageError(f"--split: {args.data} has no frame in the {args.split!r} split")
    batch = vdata.bop_eval_batch(
        scene,
        input_size=config.model.input_size,
        global_padding=config.model.global_padding,
        min_visible=args.min_visible,
    )
    extents = vdata.bop_class_extents(scene)
    rows, mapping = class_rows(batch["class_name"], config, args.class_mapping, extents)
    net = evaluate_scene_batch(model, variables, config, batch, rows)
    net.pop("pred")

    def baseline(match_aspect):
        R, c, r = known_size_ellipsoid(
            batch["box_input"], batch["K"], batch["gt_half_extents"], match_aspect=match_aspect
        )
        return summarise_detections({"rotation": np.asarray(R), "center": np.asarray(c), "radii": np.asarray(r)}, batch)

    out = {
        "data": str(args.data),
        "split": args.split,
        "min_visible": args.min_visible,
        "frames": len(scene.frames),
        "frame_ids": [int(scene.frames[0].frame_id), int(scene.frames[-1].frame_id)],
        **net,
        "class_mapping": mapping,
        "baseline": {
            "name": "known-size geometric baseline: true mesh extent, axis-aligned to the camera (the pair of axes "
            "matching the box's aspect across the image, the third along the ray), depth from the box's size, "
            "centre on the box's ray",
            **baseline(True),
        },
        "baseline_mesh_axes": {
            "name": "the same with the mesh's own axis order (mesh x, y, z along camera x, y, z)",
            **baseline(False),
        },
    }
    if oracle is not None:
        o_model, o_vars, o_config, o_meta = oracle
        o_batch = batch
        if (o_config.model.input_size, o_config.model.global_padding) != (
            config.model.input_size,
            config.model.global_padding,
        ):
            o_batch = vdata.bop_eval_batch(
                scene,
                input_size=o_config.model.input_size,
                global_padding=o_config.model.global_padding,
                min_visible=args.min_visible,
            )
        o_rows, o_mapping = class_rows(o_batch["class_name"], o_config, args.class_mapping, extents)
        o_fig = evaluate_scene_batch(o_model, o_vars, o_config, o_batch, o_rows)
        o_fig.pop("pred")
        out["oracle"] = {"model": str(o_meta.get("name")), **o_fig, "class_mapping": o_mapping}
    return out


def _load_oracle(args):
    """The ``--oracle`` model, or with ``--model lmo`` the oracle shipped beside it; None otherwise."""
    from jaxsem.volumon import ORACLES, PRETRAINED_DIR, load_pretrained

    if args.oracle is not None:  # load before the long work: a bad oracle fails first
        return load_pretrained(args.oracle)
    name = ORACLES.get(args.model or "")
    if name is not None and (PRETRAINED_DIR / f"{name}.npz").exists():
        return load_pretrained(PRETRAINED_DIR / f"{name}.npz")
    return None


def _desk_figures(args, model, variables, config) -> dict:
    """Figures on held-out rendered desk detections (``python -m jaxsem.volumon.data.make_lmo_renders``):
    the same keys as on a BOP scene (network, known-size baseline, oracle), the objects at least
    ``--min-visible`` visible. ADI here scores against the mesh extent's cuboid (the detections
    keep no mesh points), not ADD-S."""
    import numpy as np

    from jaxsem.volumon import class_rows, evaluate_scene_batch, known_size_ellipsoid, summarise_detections

    from ..volumon import data as vdata

    oracle = _load_oracle(args)
    batch = vdata.desk_eval_batch(args.data, num=args.num, min_visible=args.min_visible)
    batch["class_name"] = np.asarray(vdata.LMO_CLASS_NAMES)[batch["class_id"]]
    extents = {n: None for n in vdata.LMO_CLASS_NAMES}

    def figures(m, v, c):
        rows, mapping = class_rows(batch["class_name"], c, "generic", extents)
        fig = evaluate_scene_batch(m, v, c, batch, rows)
        fig.pop("pred")
        return {**fig, "class_mapping": mapping}

    R, ctr, r = known_size_ellipsoid(batch["box_input"], batch["K"], batch["gt_half_extents"])
    out = {
        "data": str(args.data),
        "min_visible": args.min_visible,
        **figures(model, variables, config),
        "baseline": {
            "name": "known-size geometric baseline (as on a BOP scene)",
            **summarise_detections(
                {"rotation": np.asarray(R), "center": np.asarray(ctr), "radii": np.asarray(r)}, batch
            ),
        },
    }
    if oracle is not None:
        o_model, o_vars, o_config, o_meta = oracle
        out["oracle"] = {"model": str(o_meta.get("name")), **figures(o_model, o_vars, o_config)}
    return out


def main(argv=None, prog: str | None = None) -> int:
    """``jaxsem volumon eval``: held-out figures of the shipped model (or ``--workdir``) as JSON."""
    args = build_parser(prog).parse_args(argv)
    bop = _is_bop(args.data)
    from ..volumon.data import is_desk_detections

    desk = args.data is not None and is_desk_detections(args.data)
    if bop and args.split is None:
        raise sc.UsageError("--split: required with a BOP scene (--data with scene_gt.json): tune, test or all")
    if bop and args.postopt:
        raise sc.UsageError("--postopt: not available on a BOP scene (no depth points to refine on)")
    if desk and args.postopt:
        raise sc.UsageError("--postopt: not available on rendered desk detections")
    if not bop:
        for flag, value in (("--split", args.split), ("--oracle", None if desk else args.oracle)):
            if value is not None:
                raise sc.UsageError(f"{flag}: only with --data SCENE_DIR, a BOP scene folder with scene_gt.json")
    if bop and args.model is None and args.workdir is None:
        args.model = "lmo"  # a BOP scene's default: the model trained for real objects (and its oracle)
    is_rcnn, rcnn_path = _rcnn_source(args.model, args.workdir)
    for flag, value in (
        ("--input-size", args.input_size),
        ("--lift-at", args.lift_at),
        ("--truth-boxes", args.truth_boxes),
    ):
        if value is not None and not is_rcnn:
            raise sc.UsageError(f"{flag}: only with the R-CNN (--model lmo-rcnn or an R-CNN run)")
    if is_rcnn:
        if not bop:
            raise sc.UsageError(
                "--model: the R-CNN is scored on a BOP scene only (--data SCENE_DIR with scene_gt.json)"
            )
        for flag, value in (("--oracle", args.oracle), ("--postopt", args.postopt)):
            if value:
                raise sc.UsageError(f"{flag}: not available with the R-CNN")
        try:
            result = _rcnn_figures(args, rcnn_path)
        except ValueError as exc:
            if args.debug:
                raise
            raise SystemExit(f"{prog or 'jaxsem volumon eval'}: {exc}")
        return _write(args, result)
    path, kind = resolve_model(args.model, args.workdir)
    from jaxsem.volumon import evaluate_held_out, load_pretrained

    try:
        model, variables, config, meta = load_pretrained(path, kind=kind)
        if bop:
            result = _bop_figures(args, model, variables, config)
        elif desk:
            result = _desk_figures(args, model, variables, config)
        else:
            batch = None
            if args.data is not None:
                from ..volumon.data import volumon_eval_batch

                batch = volumon_eval_batch(args.data, num=args.num, **config.data_sizes())
            result = evaluate_held_out(
                model, variables, config, args.seed, args.num, postopt_steps=args.postopt, batch=batch
            )
    except ValueError as exc:
        if args.debug:
            raise
        raise SystemExit(f"{prog or 'jaxsem volumon eval'}: {exc}")
    result = {"model": str(meta.get("name")), "model_step": meta.get("step"), **result}
    return _write(args, result)


def _write(args, result: dict) -> int:
    text = json.dumps(result, indent=1)
    if args.json:
        sc.atomic_write_text(args.json, text + "\n")
    sc.record(**result)
    print(text)
    return 0
