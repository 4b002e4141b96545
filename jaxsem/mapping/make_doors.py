"""Render stereo views of the doors of generated LSD buildings in the FAT layout (thesis 5.8.1).

    python -m jaxsem.mapping.make_doors --out DIR --scenes N --seed S [--split test]

Thin entry point over :func:`jaxsem.mapping.write_door_dataset`: ``--scenes`` buildings (train-family
for ``--split train`` / ``val``, test-family for ``test``), one scene directory
``DIR/<split>/scene_NNN/`` of ``--frames-per-scene`` stereo frames each, every frame one door seen
whole by the robot's camera (box from the rendered segmentation, pose and size from the building
generator). Read it with ``jaxsem.volumon.data.volumon_batch_source(DIR/<split>, class_names=("door",),
loader_options={"baseline": B})`` or train the door model with ``python -m jaxsem.mapping.train_doors``.
"""

from __future__ import annotations

import argparse
import pathlib
import sys

from .. import scripting as sc
from ._doors import DOOR_BASELINE, write_door_dataset


def build_parser(prog: str | None = None) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=prog, description=__doc__, formatter_class=sc.HelpFormatter)
    p.add_argument("--out", type=sc.output_dir, required=True, help="root directory (the split goes in a subdirectory)")
    p.add_argument("--scenes", type=sc.positive_int, required=True, help="buildings (scene directories) to render")
    p.add_argument("--seed", type=int, default=0, help="dataset seed (with --split it fixes the buildings and views)")
    p.add_argument(
        "--split",
        choices=("train", "val", "test"),
        default="train",
        help="train / val: train-family buildings (disjoint seeds); test: test-family buildings",
    )
    p.add_argument("--frames-per-scene", type=sc.positive_int, default=40, help="stereo frames per building")
    p.add_argument("--width", type=sc.positive_int, default=224, help="image width (px)")
    p.add_argument("--height", type=sc.positive_int, default=168, help="image height (px)")
    p.add_argument("--baseline", type=sc.positive_float, default=DOOR_BASELINE, help="stereo baseline (m)")
    p.add_argument("--min-distance", type=sc.positive_float, default=2.5, help="nearest camera-to-door distance (m)")
    p.add_argument("--max-distance", type=sc.positive_float, default=8.0, help="farthest camera-to-door distance (m)")
    p.add_argument("--min-area", type=sc.positive_int, default=150, help="fewest segmented pixels of a door box")
    p.add_argument("--format", choices=("jpg", "png"), default="jpg", help="RGB image format")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--debug", action="store_true", help="show tracebacks")
    return p


def main(argv=None) -> int:
    p = build_parser("python -m jaxsem.mapping.make_doors")
    a = p.parse_args(argv)
    if a.min_distance > a.max_distance:
        p.error(f"--min-distance: {a.min_distance} exceeds --max-distance {a.max_distance}")

    dirs = write_door_dataset(
        a.out,
        a.scenes,
        seed=a.seed,
        split=a.split,
        frames_per_scene=a.frames_per_scene,
        image_size=(a.width, a.height),
        baseline=a.baseline,
        distance=(a.min_distance, a.max_distance),
        min_area=a.min_area,
        image_format=a.format,
        progress=not a.quiet,
    )
    print(
        f"{a.split}: {len(dirs)} buildings of {a.frames_per_scene} stereo door frames under {pathlib.Path(a.out) / a.split}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(sc.run_main(main, prog="python -m jaxsem.mapping.make_doors"))
