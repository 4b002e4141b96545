"""Train VoluMon R-CNN (thesis 5.7) on rendered LM-O desks and the real LM-O tuning photographs.

    python train/volumon_rcnn.py --workdir runs/rcnn --renders runs/desk_frames --frames 2000 \\
        --lmo data/lmo/test/000002 --steps 100000

Renders ``--frames`` desk frames into ``--renders`` first (resumable chunks; needs
``jaxsem data fetch lmo`` and ``ycb``), plus 64 held-out frames of another seed, then trains in
``--workdir`` (re-running resumes). ``--oracle`` trains the fully supervised oracle (3D labels in
place of the dual loss) on the same data. The LM-O test split (frame ids 600 and above) is never
read.
"""

from __future__ import annotations

import argparse
import dataclasses
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
    p.add_argument("--seed", type=int, default=0)
    a = p.parse_args(argv)
    models = a.models or (a.lmo / "models" if a.lmo else None)
    if models is None or not models.is_dir():
        p.error(f"--models: no LM-O meshes folder {models} (give --lmo or --models)")
    if a.lmo is not None and not (a.lmo / "scene_gt.json").is_file():
        p.error(f"--lmo: {a.lmo} holds no scene_gt.json (jaxsem data fetch lmo --out data)")

    from jaxsem.volumon import data as df, rcnn as rc

    loss = rc.RCNNLossConfig(burn_in=a.burn_in)
    if a.oracle:
        loss = dataclasses.replace(loss, dual=0.0, size=0.0, oracle=1.0)
    config = rc.RCNNTrainConfig(loss=loss, batch_size=a.batch, num_steps=a.steps, seed=a.seed)
    size = config.model.input_size
    ycb = a.ycb if a.ycb.is_dir() else None
    df.write_desk_frames(
        a.renders / "train", a.frames, seed=1000 + a.seed, models_dir=models, distractor_dir=ycb, image_size=size
    )
    df.write_desk_frames(
        a.renders / "heldout", 64, seed=999_999, models_dir=models, distractor_dir=ycb, image_size=size
    )
    renders = df.load_frame_chunks(a.renders / "train")
    held = df.load_frame_chunks(a.renders / "heldout")
    real = df.frame_arrays(df.bop_frames(a.lmo, "tune"), size) if a.lmo is not None else None
    rc.train_rcnn(config, a.workdir, renders, real, held, stop_at=a.stop_at, log=print)
    return 0


if __name__ == "__main__":
    sys.exit(sc.run_main(main))
