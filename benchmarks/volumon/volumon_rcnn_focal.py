"""VoluMon R-CNN models under cameras of other focal lengths: held-out rendered desks, scored as the
real photographs are.

    python benchmarks/volumon/volumon_rcnn_focal.py --models lmo-rcnn-448 runs/rcnn_448Z_avg.npz \
        --scales 0.7 1.0 1.4 --frames 64 --seed 777001 --renders runs/focal_desks

Renders ``--frames`` LM-O desks (``jaxsem.volumon.data.render_desk_frames``, seed ``--seed``: not one
the training renders use) once per focal-length factor in ``--scales`` (LM-O's intrinsics with both
focal lengths times the factor, 640 x 480), writes each set as a BOP scene under ``--renders``
(``data.write_bop_scene``; kept and reused: a folder made with other arguments is refused), and
scores each model there with ``jaxsem.volumon.rcnn.evaluate_scene(truth_boxes=True)``: AP50, its
matched detections' centre error and translation AUC, and its lift on every true visible box and
class beside the separate LM-O VoluMon and the known-size baseline on the same boxes. A lift that
reads depth from an object's apparent size rather than from its box over the focal length holds
at factor 1 and fails at the others. Needs ``jaxsem data fetch lmo`` (the meshes) and ``ycb``
(distractors; without them the desks hold primitives only). Writes ``--out/--name`` ``.json`` /
``.md`` / ``.png`` (translation AUC on the true boxes against the factor).
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys

HERE = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

from _harness import header, machine, output_arguments, utc_now, write_results  # noqa: E402

KEYS = ("median_center_error_m", "trans_auc", "median_size_rel_error")


def _scene(root: pathlib.Path, scale: float, frames: int, seed: int, meshes_dir: pathlib.Path, ycb) -> pathlib.Path:
    """The BOP scene of ``frames`` desks at focal-length factor ``scale`` under ``root`` (rendered
    on first use; its stamp must match)."""
    import numpy as np

    from jaxsem.volumon import data as df

    scene = root / f"lmo_focal_{scale:g}" / "test" / "000001"
    stamp = {"frames": frames, "seed": seed, "scale": scale, "meshes": str(meshes_dir), "ycb": str(ycb)}
    path = scene.parent.parent / "stamp.json"
    if (scene / "scene_gt.json").is_file():
        old = json.loads(path.read_text()) if path.is_file() else None
        if old != stamp:
            raise ValueError(f"--renders: {scene} was made with other arguments ({old}); give another folder")
        return scene
    if scene.exists():
        raise ValueError(f"--renders: {scene} exists without a whole scene; give another folder")
    K = np.array(df.LMO_K, np.float64)
    K[0, 0] *= scale
    K[1, 1] *= scale
    meshes = df.load_lmo_meshes(meshes_dir)
    distractors = df.load_distractor_meshes(ycb) if ycb is not None else []
    rendered = df.render_desk_frames(meshes, frames, seed=seed, distractors=distractors, K=K)
    df.write_bop_scene(rendered, scene)
    models = scene.parent.parent / "models"
    if not models.exists():
        models.symlink_to(meshes_dir.resolve(), target_is_directory=True)
    path.write_text(json.dumps(stamp))
    return scene


def main(argv=None) -> int:
    from jaxsem import scripting as sc
    from jaxsem.volumon.rcnn import ADOPTED_RCNNS, SHIPPED_RCNNS

    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--models", nargs="+", required=True, help="lmo-rcnn-448, exported .npz files or training workdirs")
    p.add_argument("--scales", nargs="+", type=sc.positive_float, default=[0.7, 1.0, 1.4], help="focal-length factors")
    p.add_argument("--frames", type=sc.positive_int, default=64, help="desks rendered per factor (default 64)")
    p.add_argument("--seed", type=sc.nonnegative_int, default=777001, help="the renders' seed (default 777001)")
    p.add_argument("--renders", type=pathlib.Path, required=True, help="folder of the rendered BOP scenes (kept)")
    p.add_argument(
        "--meshes", type=sc.existing_dir, default=pathlib.Path("data/lmo/test/000002/models"), help="LM-O meshes"
    )
    p.add_argument("--ycb", type=pathlib.Path, default=pathlib.Path("data/ycb/meshes"), help="distractor meshes")
    output_arguments(p, "volumon_rcnn_focal", ".json / .md / .png")
    a = p.parse_args(argv)
    for m in a.models:
        if m not in SHIPPED_RCNNS and m not in ADOPTED_RCNNS and not pathlib.Path(m).exists():
            p.error(f"--models: no model {m}")
    if len(set(a.scales)) != len(a.scales):
        p.error(f"--scales: each factor once, got {a.scales}")
    ycb = a.ycb if a.ycb.is_dir() else None

    from jaxsem.volumon import load_pretrained, rcnn as rc

    scenes = {}
    for s in a.scales:
        try:
            scenes[s] = _scene(a.renders, float(s), a.frames, a.seed, a.meshes, ycb)
        except ValueError as e:
            p.error(str(e))
        print(f"renders at x{s:g}: {scenes[s]}", flush=True)
    separate = load_pretrained(kind="lmo")
    rows: dict = {}
    on_truth: dict = {"parallel": {}, "baseline": {}}
    for m in a.models:
        loaded = rc.load_rcnn(m)
        rows[m] = {}
        for s, scene in scenes.items():
            r = rc.evaluate_scene(loaded, scene, "all", truth_boxes=True, parallel=separate, warmup=1)
            t = r["on_true_boxes"]
            rows[m][f"{s:g}"] = {
                "ap50": r["detection"]["ap50"],
                "num_matched": r["num_matched"],
                **{f"matched_{k}": r.get(k) for k in KEYS},
                "on_true_boxes": {k: t[k] for k in KEYS} | {"num_objects": t["num_objects"]},
            }
            on_truth["parallel"][f"{s:g}"] = {k: t["parallel"][k] for k in KEYS}
            on_truth["baseline"][f"{s:g}"] = {k: t["baseline"][k] for k in KEYS}
            print(m, f"x{s:g}", json.dumps(rows[m][f"{s:g}"]), flush=True)
    command = "python benchmarks/volumon/volumon_rcnn_focal.py " + " ".join(sys.argv[1:] if argv is None else argv)
    md = header("# VoluMon R-CNN under other focal lengths (held-out renders)", command, utc_now(), machine())
    md += [f"{a.frames} desks a factor, seed {a.seed}, LM-O's intrinsics with the focal lengths times the factor.", ""]
    md += ["| model | factor | AP50 | matched | matched centre / AUC | true boxes: centre / AUC / size |"]
    md += ["|---|---|---|---|---|---|"]
    for m, by in rows.items():
        for s, r in by.items():
            t = r["on_true_boxes"]
            md.append(
                f"| {m} | {s} | {r['ap50']:.3f} | {r['num_matched']} | "
                f"{100 * (r['matched_median_center_error_m'] or float('nan')):.1f} cm / "
                f"{r['matched_trans_auc'] or float('nan'):.2f} | {100 * t['median_center_error_m']:.1f} cm / "
                f"{t['trans_auc']:.2f} / {t['median_size_rel_error']:.3f} |"
            )
    for name, by in on_truth.items():
        label = "separate LM-O VoluMon" if name == "parallel" else "known-size baseline"
        for s, t in by.items():
            md.append(
                f"| {label} (true boxes) | {s} | - | - | - | {100 * t['median_center_error_m']:.1f} cm / "
                f"{t['trans_auc']:.2f} / {t['median_size_rel_error']:.3f} |"
            )
    out = {"frames": a.frames, "seed": a.seed, "scales": a.scales, "models": rows, "on_true_boxes": on_truth}
    where = write_results(a.out, a.name, out, md)
    _figure(rows, on_truth, where / f"{a.name}.png")
    return 0


def _figure(rows, on_truth, path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from jaxsem.scripting import atomic_savefig

    fig, ax = plt.subplots(figsize=(5.5, 3.6))
    for m, by in rows.items():
        xs = sorted(by, key=float)
        ax.plot([float(x) for x in xs], [by[x]["on_true_boxes"]["trans_auc"] for x in xs], "o-", label=m)
    styles = {"parallel": ("s--", "separate LM-O VoluMon"), "baseline": ("^:", "known-size baseline")}
    for name, by in on_truth.items():
        xs = sorted(by, key=float)
        ax.plot([float(x) for x in xs], [by[x]["trans_auc"] for x in xs], styles[name][0], label=styles[name][1])
    ax.set_xlabel("focal length / LM-O's")
    ax.set_ylabel("translation AUC, true boxes")
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    atomic_savefig(fig, path, dpi=120)
    plt.close(fig)


if __name__ == "__main__":
    from jaxsem import scripting as sc

    sys.exit(sc.run_main(main))
