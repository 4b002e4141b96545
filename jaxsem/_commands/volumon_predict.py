"""VoluMon inference: ellipsoids from an image and boxes (or held-out synthetic images).

Uses the model that ships in the package (``jaxsem/volumon/pretrained``, see its
``MODEL_CARD.md``) unless ``--workdir`` names a training run (``train/volumon.py``), or
``--train-steps N`` trains one from scratch first (into ``--workdir``).

Examples::

    # the shipped model on held-out synthetic images (seed 1)
    python infer/volumon.py --split test --num 8 --out out/volumon
    # a trained run on its synthetic held-out split
    python infer/volumon.py --workdir runs/both --split test --num 8 --out out/volumon
    # your own image and boxes (JSON list of [u_min, v_min, u_max, v_max]) and intrinsics
    python infer/volumon.py --workdir runs/both --image img.png --boxes boxes.json \
        --K 110,110,63.5,47.5 --out out/volumon

Writes ``ellipsoids.json`` (per detection: rotation object-to-camera, center in the camera
frame, radii, all in metres) and ``overlay_*.png`` (input box green, projected conic blue,
3D box orange; dashed white: ground truth when known) into ``--out``; the run directory
(``--run-dir``) gets config.json and summary.json (the number of ellipsoids, the overlays).

The same command: ``jaxsem volumon predict`` (``python infer/volumon.py``).
"""

from __future__ import annotations

import argparse
import json
import pathlib

import numpy as np

from jaxsem import scripting as sc


def build_parser(prog: str | None = None) -> argparse.ArgumentParser:
    p = sc.command_parser(prog, __doc__)
    p.add_argument(
        "--workdir",
        type=pathlib.Path,
        default=None,
        help="training run (config.json + checkpoints/); default: the shipped model",
    )
    p.add_argument(
        "--train-steps",
        type=sc.positive_int,
        default=None,
        help="train from scratch for this many steps into --workdir first (fast preset)",
    )
    p.add_argument("--seed", type=int, default=1, help="held-out seed of --split test")
    p.add_argument("--step", type=int, default=None, help="checkpoint step (default latest)")
    p.add_argument("--image", type=sc.existing_file, help="image file (RGB)")
    p.add_argument("--boxes", type=sc.existing_file, help="JSON file: list of [u_min, v_min, u_max, v_max]")
    p.add_argument("--K", type=str, default=None, help="fx,fy,cx,cy (default: the training camera)")
    p.add_argument("--split", choices=("train", "test"), default=None, help="use the synthetic split instead")
    p.add_argument("--num", type=sc.positive_int, default=8, help="detections from --split")
    p.add_argument(
        "--class-id",
        type=int,
        default=0,
        help="class of the --boxes (shipped model: 0 cracker_box, 1 ball, 2 melon, 3 soup_can)",
    )
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
        prepare_inputs,
        train_and_evaluate,
    )

    if a.train_steps is not None:
        if a.workdir is None:
            p.error("--train-steps needs --workdir (where the new model is trained)")
        train_and_evaluate(get_config("both", "fast").replace(num_steps=a.train_steps), a.workdir, progress=False)
    if a.workdir is not None and a.step is not None:
        cfg = config_from_dict(json.loads((a.workdir / "config.json").read_text()))
        model, variables, _ = load_trained(a.workdir, cfg, step=a.step)
    else:
        try:
            model, variables, cfg, _ = load_pretrained(a.workdir)
        except ValueError as exc:
            raise SystemExit(f"--workdir: {exc}")
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
        _, ell, _ = predict(variables, b["local"], b["global"], b["box_input"], b["K"], b["class_id"])
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
        if a.image is None or a.boxes is None:
            p.error("give --image and --boxes, or --split")
        import cv2

        img = cv2.imread(str(a.image), cv2.IMREAD_COLOR)
        if img is None:
            raise SystemExit(f"could not read image {a.image}")
        img = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
        boxes = np.asarray(json.loads(a.boxes.read_text()), np.float64).reshape(-1, 4)
        if a.K:
            fx, fy, cx, cy = (float(x) for x in a.K.split(","))
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
