"""VoluMon R-CNN on a photograph: objects detected and lifted to ellipsoids by one network.

    jaxsem volumon detect --model lmo-rcnn --image photo.png --K 572.4,573.6,325.3,242.0 --out out/det

``--model``: ``lmo-rcnn`` (the shipped LM-O model, see ``jaxsem/volumon/pretrained/MODEL_CARD.md``),
an exported ``.npz`` (with its ``.json``) or a training workdir (``train/volumon_rcnn.py``).
Writes ``detections.json`` (per detection: class, score, class probabilities, the box in the
photograph's pixels, the ellipsoid's rotation object-to-camera, centre in the camera frame and
radii, in metres) and ``detections.png`` (boxes and the ellipsoids' projected outlines) into
``--out``, atomically; the run directory gets config.json and summary.json.
"""

from __future__ import annotations

import json
import pathlib

from jaxsem import scripting as sc
from jaxsem._commands.volumon_eval import SHIPPED_NAMES
from jaxsem._commands.volumon_predict import intrinsics

# Imports inside the functions below are deliberate: `jaxsem <command> --help` imports this module
# and must stay fast, so jax, the method's package and matplotlib load only when the command runs.


def build_parser(prog: str | None = None):
    p = sc.command_parser(prog, __doc__)
    p.add_argument(
        "--model",
        default="lmo-rcnn",
        help="'lmo-rcnn' or 'lmo-rcnn-448' (shipped), an exported .npz or a training workdir",
    )
    p.add_argument("--image", type=sc.existing_file, required=True, help="the photograph (PNG or JPEG)")
    p.add_argument("--K", type=intrinsics, required=True, help="fx,fy,cx,cy of the photograph")
    p.add_argument("--out", type=sc.output_dir, required=True, help="folder for detections.json and detections.png")
    p.add_argument(
        "--min-score",
        type=sc.probability,
        default=0.3,
        help="detections below this score (in [0, 1]) are left out (default 0.3)",
    )
    return p


def _model_path(text: str):
    if text in SHIPPED_NAMES:
        return None
    path = pathlib.Path(text)
    if not path.exists():
        raise sc.UsageError(f"--model: {text}: neither a shipped model ({', '.join(SHIPPED_NAMES)}) nor a path")
    return path


def main(argv=None, prog: str | None = None) -> int:
    args = build_parser(prog).parse_args(argv)
    path = _model_path(args.model)
    import numpy as np

    from jaxsem import quadrics as Q
    from jaxsem.volumon.data import read_rgb
    from jaxsem.volumon.rcnn import detect_image, load_rcnn

    try:
        image = read_rgb(args.image)
    except ValueError as exc:
        raise sc.UsageError(f"--image: {exc}") from None
    fx, fy, cx, cy = args.K
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    try:
        loaded = load_rcnn(path)
    except ValueError as exc:
        raise sc.UsageError(f"--model: {exc}") from None
    det = detect_image(loaded, image, K)
    keep = det["score"] >= args.min_score
    rows = [
        {
            "class": det["class_name"][i],
            "score": float(det["score"][i]),
            "probabilities": dict(zip(loaded.config.class_names, map(float, det["probabilities"][i]))),
            "box": [float(x) for x in det["box"][i]],
            "rotation": det["rotation"][i].tolist(),
            "center": det["center"][i].tolist(),
            "radii": det["radii"][i].tolist(),
        }
        for i in np.flatnonzero(keep)
    ]
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    sc.atomic_write_text(
        out / "detections.json", json.dumps({"image": str(args.image), "K": K.tolist(), "detections": rows}, indent=1)
    )

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Rectangle

    fig, ax = plt.subplots(figsize=(image.shape[1] / 100, image.shape[0] / 100), dpi=100)
    ax.imshow(image)
    eye = np.eye(4)
    for r in rows:
        u0, v0, u1, v1 = r["box"]
        ax.add_patch(Rectangle((u0, v0), u1 - u0, v1 - v0, fill=False, color="lime", lw=1.5))
        conic = Q.project_dual_conic(
            Q.dual_quadric(np.array(r["rotation"]), np.array(r["center"]), np.array(r["radii"]), xp=np), K, eye, xp=np
        )
        pts, ok = Q.conic_outline(conic, 64, xp=np)
        if bool(np.all(ok)):
            ax.plot(pts[:, 0], pts[:, 1], color="deepskyblue", lw=1.2)
        ax.text(u0, v0 - 3, f"{r['class']} {r['score']:.2f}", color="yellow", fontsize=7)
    ax.set_axis_off()
    fig.subplots_adjust(0, 0, 1, 1)
    figure = sc.atomic_savefig(fig, out / "detections.png")
    plt.close(fig)
    sc.record(detections=len(rows))
    sc.record_output(out / "detections.json", figure)
    print(f"{len(rows)} detections -> {out / 'detections.json'}, {figure}")
    return 0
