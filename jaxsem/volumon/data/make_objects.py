"""Render stereo scenes of textured object meshes (robosuite's by default) in the FAT layout.

    python -m jaxsem.volumon.data.make_objects --out DIR --scenes N --seed S [--split test]

Thin entry point over :func:`jaxsem.volumon.data.write_object_dataset`: ``--scenes`` scene directories
``DIR/<split>/scene_NNN/`` of ``--frames-per-scene`` stereo frames each, readable by
``jaxsem.data.load_fat_annotations``, ``jaxsem volumon eval --data DIR/<split>`` and
``train/volumon.py --data DIR/<split>``. The meshes and textures come from the installed
robosuite 1.5.2 package (the optional extra: pip install 'jaxsem[objects]'); nothing is downloaded.
"""

from __future__ import annotations

import argparse
import pathlib
import sys

from ... import scripting as sc
from ._objects import robosuite_assets, write_object_dataset


def build_parser(prog: str | None = None) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=prog, description=__doc__, formatter_class=sc.HelpFormatter)
    p.add_argument("--out", type=sc.output_dir, required=True, help="root directory (the split goes in a subdirectory)")
    p.add_argument("--scenes", type=sc.positive_int, required=True, help="scene directories to write")
    p.add_argument("--seed", type=int, default=0, help="dataset seed (with --split it fixes every random choice)")
    p.add_argument("--split", choices=("train", "val", "test"), default="train", help="split (disjoint seed streams)")
    p.add_argument("--frames-per-scene", type=sc.positive_int, default=10, help="stereo frames per scene")
    p.add_argument("--width", type=sc.positive_int, default=256, help="image width (px)")
    p.add_argument("--height", type=sc.positive_int, default=192, help="image height (px)")
    p.add_argument(
        "--labels",
        choices=("volumon", "own"),
        default="volumon",
        help="'volumon': write each object as the VoluMon class of the same shape it stands in for (the shipped "
        "model reads these); 'own': its own class of jaxsem.classes",
    )
    p.add_argument("--max-objects", type=sc.positive_int, default=3, help="labelled objects per frame, at most")
    p.add_argument("--distractors", type=sc.nonnegative_int, default=3, help="distractor primitives per scene")
    p.add_argument("--min-depth", type=sc.positive_float, default=0.45, help="nearest object centre (m)")
    p.add_argument("--max-depth", type=sc.positive_float, default=1.1, help="farthest object centre (m)")
    p.add_argument("--format", choices=("jpg", "png"), default="jpg", help="RGB image format")
    p.add_argument("--bbox-order", choices=("yx", "xy"), default="yx", help="'yx' reproduces FAT's box quirk")
    p.add_argument(
        "--assets",
        type=sc.existing_dir,
        default=None,
        help="robosuite's models/assets folder (default: the installed robosuite package's)",
    )
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--debug", action="store_true", help="show tracebacks")
    return p


def main(argv=None) -> int:
    a = build_parser("python -m jaxsem.volumon.data.make_objects").parse_args(argv)

    dirs = write_object_dataset(
        a.out,
        a.scenes,
        seed=a.seed,
        split=a.split,
        assets=robosuite_assets(a.assets),
        frames_per_scene=a.frames_per_scene,
        image_size=(a.width, a.height),
        labels=a.labels,
        max_objects=a.max_objects,
        num_distractors=a.distractors,
        depth_range=(a.min_depth, a.max_depth),
        image_format=a.format,
        bbox_order=a.bbox_order,
        progress=not a.quiet,
    )
    print(f"{a.split}: {len(dirs)} scenes of {a.frames_per_scene} stereo frames under {pathlib.Path(a.out) / a.split}")
    return 0


if __name__ == "__main__":
    sys.exit(sc.run_main(main, prog="python -m jaxsem.volumon.data.make_objects"))
