"""VoluMon inference: ellipsoids from an image and boxes (or held-out synthetic images).

Uses the model that ships in the package (``jaxsem/volumon/pretrained``, see its
``MODEL_CARD.md``) unless ``--workdir`` names a training run (``train/volumon.py``), or
``--train-steps N`` trains one from scratch first (into ``--workdir``).

Examples::

    # the shipped model on held-out synthetic images (seed 1)
    python infer/volumon.py --split test --num 8 --out out/volumon
    # a trained run on its synthetic held-out split
    python infer/volumon.py --workdir runs/both --split test --num 8 --out out/volumon
    # a real frame of a BOP scene (e.g. LM-O): its visible boxes, predictions beside the truth
    jaxsem volumon predict --data DATA/lmo/test/000002 --frame 3 --out out/volumon
    # your own image and boxes (JSON list of [u_min, v_min, u_max, v_max]) and intrinsics
    python infer/volumon.py --workdir runs/both --image img.png --boxes boxes.json \
        --K 110,110,63.5,47.5 --out out/volumon

Writes ``ellipsoids.json`` (per detection: rotation object-to-camera, center in the camera
frame, radii, all in metres) and ``overlay_*.png`` (input box green, projected conic blue,
3D box orange; dashed white: ground truth when known) into ``--out``; on a BOP frame
(``--data``, ``--frame``; the LM-O model unless --model or --workdir says otherwise) one figure, ``overlay_frame<ID>.png``: the predictions (left, with the
true cuboids dashed) beside the true ellipsoids drawn the same way (right); the run directory
(``--run-dir``) gets config.json and summary.json (the number of ellipsoids, the overlays).

The same command: ``jaxsem volumon predict`` (``python infer/volumon.py``).
"""

from __future__ import annotations

import argparse
import json
import math
import pathlib

import numpy as np

from jaxsem import scripting as sc
from jaxsem._checks import check_box  # the one box rule (sequence.json's too)
from jaxsem._commands.volumon_eval import (
    add_class_mapping_argument,
    add_min_visible_argument,
    add_model_arguments,
    resolve_model,
)
from jaxsem._files import read_text

# Imports inside the functions below are deliberate: `jaxsem <command> --help` imports this module
# and must stay fast, so jax, the method's package and matplotlib load only when the command runs.


def intrinsics(text: str) -> tuple[float, float, float, float]:
    """``--K``: ``fx,fy,cx,cy``, four finite numbers with fx, fy > 0."""
    parts = [x for x in text.replace(",", " ").split() if x]
    try:
        values = [float(x) for x in parts]
    except ValueError:
        values = []
    if len(values) != 4 or not all(math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(f"expected fx,fy,cx,cy (4 finite numbers), got {text!r}")
    if values[0] <= 0 or values[1] <= 0:
        raise argparse.ArgumentTypeError(f"expected focal lengths fx, fy > 0, got {text!r}")
    fx, fy, cx, cy = values
    return fx, fy, cx, cy


def read_boxes(path: pathlib.Path, image_size: tuple[int, int]) -> np.ndarray:
    """The ``--boxes`` file: a JSON list of ``[u_min, v_min, u_max, v_max]`` (or of objects with a
    ``"box"``, as ``ellipsoids.json`` writes them; one box alone is taken as a list of one), each
    4 finite numbers with u_max > u_min, v_max > v_min, overlapping the ``image_size`` (w, h)
    image and not larger than 10 times it (the rule of ``sequence.json``'s boxes). Raises
    :class:`jaxsem.scripting.UsageError` (or the box rule's ``ValueError``) naming ``--boxes``, the
    file and the entry."""
    where = f"--boxes {path}"
    try:
        text = read_text(path, "box file")
    except ValueError as exc:
        raise sc.UsageError(f"--boxes {exc}") from None
    try:
        data = json.loads(text)
    except ValueError as exc:
        raise sc.UsageError(f"{where}: not valid JSON ({exc})") from None
    if isinstance(data, dict) or (isinstance(data, list) and data and not isinstance(data[0], (list, dict))):
        data = [data]  # one box
    if not isinstance(data, list) or not data:
        raise sc.UsageError(
            f"{where}: expected a non-empty JSON list of [u_min, v_min, u_max, v_max], got {data!r:.80}"
        )
    boxes = []
    for i, entry in enumerate(data):
        field = f"[{i}]"
        if isinstance(entry, dict):
            if "box" not in entry:
                raise sc.UsageError(f"{where}: {field}.box: missing (entries are boxes or objects with a 'box')")
            entry, field = entry["box"], f"{field}.box"
        boxes.append(check_box(where, field, entry, image_size))
    return np.stack(boxes)


def check_class_id(class_id: int, cfg) -> None:
    """``--class-id`` against the model's classes (:class:`jaxsem.scripting.UsageError` naming it)."""
    from jaxsem.volumon import VOLUMON_CLASS_NAMES

    n = int(cfg.model.num_classes)
    names = tuple(cfg.class_names) or (VOLUMON_CLASS_NAMES if n == len(VOLUMON_CLASS_NAMES) else ())
    if not 0 <= class_id < n:
        listed = ", ".join(f"{i} {name}" for i, name in enumerate(names)) if names else ""
        raise sc.UsageError(
            f"--class-id: {class_id} is not a class of the model: expected 0"
            + (f" to {n - 1}" if n > 1 else "")
            + (f" ({listed})" if listed else "")
        )


def build_parser(prog: str | None = None) -> argparse.ArgumentParser:
    p = sc.command_parser(prog, __doc__)
    add_model_arguments(p, pathlib.Path, "training run (config.json + checkpoints/); default: the shipped model")
    p.add_argument(
        "--train-steps",
        type=sc.positive_int,
        help="train from scratch for this many steps into --workdir first (fast preset)",
    )
    p.add_argument("--seed", type=int, default=1, help="held-out seed of --split test")
    p.add_argument("--step", type=int, help="checkpoint step (default latest)")
    p.add_argument("--image", type=sc.existing_file, help="image file (RGB)")
    p.add_argument("--boxes", type=sc.existing_file, help="JSON file: list of [u_min, v_min, u_max, v_max]")
    p.add_argument("--K", type=intrinsics, help="fx,fy,cx,cy (default: the training camera)")
    p.add_argument("--split", choices=("train", "test"), help="use the synthetic split instead")
    p.add_argument("--num", type=sc.positive_int, default=8, help="detections from --split")
    p.add_argument(
        "--class-id",
        type=int,
        default=0,
        help="class of the --boxes, one of the model's classes (shipped model: 0 cracker_box, 1 ball, 2 melon, "
        "3 soup_can)",
    )
    p.add_argument(
        "--data",
        type=sc.existing_dir,
        help="a BOP scene folder (scene_gt.json, rgb/, models): predict on the visible boxes of --frame",
    )
    p.add_argument("--frame", type=sc.nonnegative_int, help="frame id of the --data BOP scene")
    add_min_visible_argument(p, "--data")
    add_class_mapping_argument(p, "--data")
    p.add_argument("--out", type=sc.output_dir, required=True, help="output folder (ellipsoids.json, overlay_*.png)")
    return p


def main(argv=None, prog: str | None = None) -> int:
    p = build_parser(prog)
    a = p.parse_args(argv)

    import jax.numpy as jnp
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from jaxsem.volumon import (
        config_from_dict,
        draw_predictions,
        get_config,
        held_out_set,
        load_pretrained,
        load_trained,
        make_batch,
        make_predict_fn,
        predict_batch,
        prepare_inputs,
        train_and_evaluate,
    )

    img = boxes = None
    if a.data is not None or a.frame is not None:  # a real BOP frame: checked before any work
        if a.data is None or a.frame is None:
            raise sc.UsageError(f"{'--frame' if a.data is None else '--data'}: --data and --frame go together")
        if a.split is not None or a.image is not None or a.boxes is not None:
            raise sc.UsageError("--data: give --data/--frame, or --image/--boxes, or --split")
        if not (a.data / "scene_gt.json").is_file():
            raise sc.UsageError(f"--data: {a.data} is not a BOP scene folder (no scene_gt.json)")
        return _predict_bop_frame(a)
    if a.split is None:  # the inputs are checked before any work
        if a.image is None or a.boxes is None:
            p.error("give --image and --boxes, or --split")
        import cv2

        from jaxsem._files import read_image

        try:
            img = read_image(a.image, cv2.IMREAD_COLOR)
        except ValueError as exc:
            raise sc.UsageError(f"--image: {exc}") from None
        img = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
        boxes = read_boxes(a.boxes, (img.shape[1], img.shape[0]))
    if a.train_steps is not None:
        if a.workdir is None:
            p.error("--train-steps needs --workdir (where the new model is trained)")
        train_and_evaluate(get_config("both", "fast").replace(num_steps=a.train_steps), a.workdir, progress=False)
    if a.workdir is not None and a.step is not None:
        from jaxsem.training import read_run_config

        cfg = config_from_dict(read_run_config(a.workdir))
        model, variables, _ = load_trained(a.workdir, cfg, step=a.step)
    else:
        path, kind = resolve_model(a.model, a.workdir)
        try:
            model, variables, cfg, _ = load_pretrained(path, kind=kind)
        except ValueError as exc:
            raise SystemExit(f"{'--model' if a.model else '--workdir'}: {exc}")
    check_class_id(a.class_id, cfg)
    predict = make_predict_fn(model, cfg)
    a.out.mkdir(parents=True, exist_ok=True)
    records = []
    if a.split is not None:
        if cfg.data == "device" and a.split == "test":
            b = held_out_set(a.seed, a.num, cfg.scene, cfg.model.input_size, cfg.model.global_padding, keep_images=True)
        else:
            b = make_batch(
                cfg.seed,
                np.arange(a.num),
                cfg.scene,
                cfg.model.input_size,
                cfg.model.global_padding,
                a.split,
                keep_images=True,
            )
        _, ell, _ = predict_batch(model, cfg, variables, b)
        K = np.asarray(b["K"][0])
        for i in range(a.num):
            e = [np.asarray(x[i]) for x in ell]
            truth = [
                (np.asarray(b["gt_rotation"][i]), np.asarray(b["gt_center"][i]), np.asarray(b["gt_half_extents"][i]))
            ]
            records.append(
                {
                    "index": i,
                    "box": np.asarray(b["box_input"][i]).tolist(),
                    "rotation": e[0].tolist(),
                    "center": e[1].tolist(),
                    "radii": e[2].tolist(),
                    "true_center": truth[0][1].tolist(),
                }
            )
            fig, ax = plt.subplots(figsize=(4, 3))
            draw_predictions(ax, np.asarray(b["image"][i]), [e], K, np.asarray(b["box_input"][i : i + 1]), truth)
            sc.atomic_savefig(fig, a.out / f"overlay_{i:03d}.png", dpi=120, bbox_inches="tight")
            plt.close(fig)
    else:
        assert img is not None and boxes is not None
        if a.K:
            fx, fy, cx, cy = a.K
            K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]])
        else:
            K = cfg.scene.K().astype(np.float64)
        local, glob = prepare_inputs(img, boxes, cfg.model.input_size, cfg.model.global_padding)
        n = len(boxes)
        class_ids = jnp.full(n, a.class_id, jnp.int32)
        _, ell, _ = predict(
            variables,
            local,
            glob,
            jnp.asarray(boxes, jnp.float32),
            jnp.broadcast_to(jnp.asarray(K, jnp.float32), (n, 3, 3)),
            class_ids,
        )
        es = [[np.asarray(x[i]) for x in ell] for i in range(n)]
        for i, e in enumerate(es):
            records.append(
                {
                    "index": i,
                    "box": boxes[i].tolist(),
                    "rotation": e[0].tolist(),
                    "center": e[1].tolist(),
                    "radii": e[2].tolist(),
                }
            )
        fig, ax = plt.subplots(figsize=(6, 4.5))
        draw_predictions(ax, img, es, K, boxes)
        sc.atomic_savefig(fig, a.out / "overlay_000.png", dpi=120, bbox_inches="tight")
        plt.close(fig)
    sc.atomic_write_text(
        a.out / "ellipsoids.json",
        json.dumps({"frame": "camera (OpenCV axes)", "units": "metres", "detections": records}, indent=1),
    )
    sc.record(ellipsoids=len(records))
    print(f"wrote {len(records)} ellipsoids to {a.out / 'ellipsoids.json'} and overlays")
    return 0


def _predict_bop_frame(a) -> int:
    """``--data SCENE --frame ID``: the model on the frame's visible boxes, drawn beside the truth."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from jaxsem.volumon import class_rows, draw_predictions, evaluate_scene_batch, load_pretrained

    from .. import data
    from ..volumon import data as vdata

    # A BOP scene's default is the model trained for real objects (LM-O's classes).
    path, kind = resolve_model(a.model if (a.model or a.workdir) else "lmo", a.workdir)
    try:
        model, variables, cfg, meta = load_pretrained(path, kind=kind)
    except ValueError as exc:
        raise SystemExit(f"{'--model' if a.model else '--workdir'}: {exc}")
    scene = data.load_bop_scene(a.data, frame_filter=lambda i: i == a.frame)
    if not scene.frames:
        raise sc.UsageError(f"--frame: {a.frame} is not a frame of {a.data}/scene_gt.json")
    frame = scene.frames[0]
    try:
        batch = vdata.bop_eval_batch(
            scene,
            input_size=cfg.model.input_size,
            global_padding=cfg.model.global_padding,
            min_visible=a.min_visible,
        )
    except ValueError as exc:
        raise sc.UsageError(f"--min-visible: {str(exc).removeprefix('min_visible: ')}") from None
    rows, mapping = class_rows(batch["class_name"], cfg, a.class_mapping, vdata.bop_class_extents(scene))
    pred = evaluate_scene_batch(model, variables, cfg, batch, rows, repeats=1)["pred"]
    image = vdata.read_rgb(frame.image_path)
    K = np.asarray(frame.K)
    n = len(batch["box_input"])
    predicted = [(pred["rotation"][i], pred["center"][i], pred["radii"][i]) for i in range(n)]
    truth = [(batch["gt_rotation"][i], batch["gt_center"][i], batch["gt_half_extents"][i]) for i in range(n)]
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.9))
    draw_predictions(axes[0], image, predicted, K, batch["box_input"], truth)
    draw_predictions(axes[1], image, truth, K, batch["box_input"])
    axes[0].set_title(f"VoluMon {meta.get('name')} (class mapping: {mapping['mode']})", fontsize=9)
    axes[1].set_title(f"truth: ellipsoids of the mesh extents (frame {frame.frame_id})", fontsize=9)
    for i in range(n):
        u, v = batch["box_input"][i][:2]
        axes[1].text(u, v - 3, str(batch["class_name"][i]), color="yellow", fontsize=6)
    fig.tight_layout()
    name = f"overlay_frame{frame.frame_id:06d}.png"
    sc.atomic_savefig(fig, a.out / name, dpi=90)
    plt.close(fig)
    records = [
        {
            "index": i,
            "frame": int(frame.frame_id),
            "class": str(batch["class_name"][i]),
            "visible_fraction": float(batch["visible_fraction"][i]),
            "box": batch["box_input"][i].tolist(),
            "rotation": pred["rotation"][i].tolist(),
            "center": pred["center"][i].tolist(),
            "radii": pred["radii"][i].tolist(),
            "true_center": batch["gt_center"][i].tolist(),
            "center_error_m": float(np.linalg.norm(pred["center"][i] - batch["gt_center"][i])),
        }
        for i in range(n)
    ]
    sc.atomic_write_text(
        a.out / "ellipsoids.json",
        json.dumps(
            {"frame": "camera (OpenCV axes)", "units": "metres", "class_mapping": mapping, "detections": records},
            indent=1,
        ),
    )
    sc.record(ellipsoids=n)
    print(f"wrote {n} ellipsoids to {a.out / 'ellipsoids.json'} and {a.out / name}")
    return 0
