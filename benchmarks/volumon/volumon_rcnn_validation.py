"""VoluMon R-CNN models compared on a range of the real LM-O tuning photographs: the validation
that the choices between R-CNN runs are made on.

    python benchmarks/volumon/volumon_rcnn_validation.py --data DATA/lmo/test/000002 \
        --models lmo-rcnn runs/rcnn_augr runs/rcnn_lift8 [--frames 300 600] [--input-size 320,240] \
        [--lift-at refined proposal]

Each model (``lmo-rcnn``, an exported ``.npz`` or a training workdir's latest checkpoint) detects
the photographs with frame ids in ``[--frames LO HI)`` (at most 600: the test split is never
read) and is scored by ``jaxsem.volumon.rcnn.evaluate_detections``: AP50, the matched objects'
median centre error and translation AUC, and the centre error split into distance
(``median_depth_log_error``) and direction (``median_ray_error_m``). Writes
``--out/--name`` ``.json`` / ``.md``. ``--truth-boxes`` also scores each lift on every true
visible box and class, beside the separate LM-O VoluMon and the known-size baseline on the same
boxes (``jaxsem.volumon.rcnn.evaluate_scene(truth_boxes=True)``): the lift apart from its detector.
``--folds MODEL:LO-HI ...`` adds one row for the folds of a cross-validation scored as one set
(``jaxsem.volumon.rcnn.evaluate_folds``): each fold's model on the photos ``[LO, HI)`` its run held
out; their ranges together should be ``--frames``, so that the row compares with the others.

The photographs below 500 are the shipped model's real training photos (detection labels and
size consistency only; no 3D signal), 500-599 its held-out ones: 300-599 spans both, far enough
from the photos below 300 to show whether a lift carries to other views of the desk.
"""

from __future__ import annotations

import argparse
import pathlib
import sys

from jaxsem.volumon.rcnn import ADOPTED_RCNNS, SHIPPED_RCNNS

HERE = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

from _harness import fold_specs, header, machine, output_arguments, utc_now, write_results  # noqa: E402

KEYS = ("ap50", "recall50", "num_matched", "median_center_error_m", "trans_auc", "median_depth_log_error")
TRUTH_KEYS = ("median_center_error_m", "trans_auc", "median_size_rel_error")


def main(argv=None) -> int:
    from jaxsem import scripting as sc

    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--data", type=sc.existing_dir, required=True, help="the LM-O scene folder (scene_gt.json)")
    p.add_argument("--models", nargs="+", required=True, help="lmo-rcnn, exported .npz files or training workdirs")
    p.add_argument(
        "--folds",
        nargs="+",
        action="append",
        default=[],
        metavar="MODEL:LO-HI",
        help="a pooled row: each fold's model on the photos it held out, scored as one set (repeat for more rows)",
    )
    p.add_argument("--frames", nargs=2, type=sc.nonnegative_int, default=[300, 600], metavar=("LO", "HI"))
    p.add_argument("--input-size", type=sc.image_size, help="W,H the networks read (default: each model's own)")
    p.add_argument(
        "--lift-at",
        nargs="+",
        choices=("refined", "proposal"),
        help="score each model with each of these lift rules (default: each model's own)",
    )
    p.add_argument(
        "--truth-boxes",
        action="store_true",
        help="also score each lift on every true visible box and class (rcnn.evaluate_scene(truth_boxes=True)), "
        "beside the separate LM-O VoluMon on the same boxes: the lift apart from the detector",
    )
    output_arguments(p, "volumon_rcnn_validation")
    a = p.parse_args(argv)
    lo, hi = a.frames
    if not lo < hi <= 600:
        p.error(f"--frames: expected LO < HI <= 600 (the tuning split), got {lo} {hi}")
    size = a.input_size
    for m in a.models:
        if m not in SHIPPED_RCNNS and m not in ADOPTED_RCNNS and not pathlib.Path(m).exists():
            p.error(f"--models: no model {m}")

    def exists(m):
        return m in SHIPPED_RCNNS or m in ADOPTED_RCNNS or pathlib.Path(m).exists()

    pooled = [fold_specs(group, lo, hi, flag="--folds", error=p.error, exists=exists) for group in a.folds]

    from jaxsem.volumon import data as df, rcnn as rc

    frames = [f for f in df.bop_frames(a.data, "tune") if lo <= f["frame_id"] < hi]
    if not frames:
        p.error(f"--frames: no tuning photo with an id in [{lo}, {hi})")
    rows, truth_rows = {}, {}
    parallel = None
    if a.truth_boxes:
        from jaxsem.volumon import load_pretrained

        parallel = load_pretrained(kind="lmo")

    def load(m):
        loaded = rc.load_rcnn(m)
        return loaded if size is None else rc.configured(loaded, input_size=tuple(size))

    for m in a.models:
        base = load(m)
        for rule in a.lift_at or [None]:
            loaded = base if rule is None else rc.configured(base, lift_at=rule)
            cfg = loaded.config.model
            r = rc.evaluate_detections(loaded.model, loaded.variables, df.frame_arrays(frames, cfg.input_size), cfg)
            name = m if rule is None else f"{m} ({rule})"
            rows[name] = {k: r[k] for k in (*KEYS, "median_ray_error_m")} | {"step": loaded.meta.get("step")}
            if a.truth_boxes:
                t = rc.evaluate_scene(
                    loaded, a.data, "tune", frame_range=(lo, hi), truth_boxes=True, parallel=parallel, warmup=0
                )["on_true_boxes"]
                rows[name]["on_true_boxes"] = {k: t[k] for k in TRUTH_KEYS} | {"num_objects": t["num_objects"]}
                if parallel is not None:
                    truth_rows = {"parallel": {k: t["parallel"][k] for k in TRUTH_KEYS}}
                    truth_rows["baseline"] = {k: t["baseline"][k] for k in TRUTH_KEYS}
                    parallel = None  # the same boxes for every model: scored once
            print(name, {k: round(v, 4) if isinstance(v, float) else v for k, v in rows[name].items()}, flush=True)
    for folds in pooled:
        parts, cfg = [], None
        for path, f_lo, f_hi in folds:
            loaded = load(path)
            cfg = loaded.config.model
            mine = [f for f in frames if f_lo <= f["frame_id"] < f_hi]
            parts.append((loaded.model, loaded.variables, df.frame_arrays(mine, cfg.input_size)))
        r = rc.evaluate_folds(parts, cfg)
        name = "folds: " + " + ".join(f"{m} on {f_lo}-{f_hi - 1}" for m, f_lo, f_hi in folds)
        rows[name] = {k: r[k] for k in (*KEYS, "median_ray_error_m")} | {"step": "-"}
        print(name, {k: round(v, 4) if isinstance(v, float) else v for k, v in rows[name].items()}, flush=True)
    command = "python benchmarks/volumon/volumon_rcnn_validation.py " + " ".join(sys.argv[1:] if argv is None else argv)
    md = header("# VoluMon R-CNN models on tuning photos", command, utc_now(), machine())
    md += [f"Photos {lo}-{hi - 1} ({len(frames)}), objects at least half visible.", ""]
    md += ["| model | step | AP50 | recall | matched | centre | trans AUC | depth log-ratio | ray |", "|" + "---|" * 9]
    for m, r in rows.items():
        md.append(
            f"| {m} | {r['step']} | {r['ap50']:.3f} | {r['recall50']:.3f} | {r['num_matched']} | "
            f"{100 * r['median_center_error_m']:.1f} cm | {r['trans_auc']:.2f} | {r['median_depth_log_error']:.3f} | "
            f"{100 * r['median_ray_error_m']:.1f} cm |"
        )
    if a.truth_boxes:
        md += ["", "On every true visible box and class (objects at least half visible):", ""]
        md += ["| lift | centre | trans AUC | size |", "|---|---|---|---|"]
        lifts = {m: r["on_true_boxes"] for m, r in rows.items()} | truth_rows
        for m, r in lifts.items():
            md.append(
                f"| {m} | {100 * r['median_center_error_m']:.1f} cm | {r['trans_auc']:.2f} | "
                f"{r['median_size_rel_error']:.3f} |"
            )
    out = {"frames": [lo, hi], "num_photos": len(frames), "models": rows, "on_true_boxes": truth_rows}
    write_results(a.out, a.name, out, md)
    return 0


if __name__ == "__main__":
    from jaxsem import scripting as sc

    sys.exit(sc.run_main(main))
