"""Write a synthetic FAT-layout dataset: ``python -m jaxsem.volumon.data.make_synthetic --out DIR --frames N``.

Thin entry point over :func:`jaxsem.volumon.data.write_synthetic_dataset`.
"""

from __future__ import annotations

import argparse
import pathlib

from ._synthetic import write_synthetic_dataset


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--out", type=pathlib.Path, required=True, help="root directory (splits go in subdirectories)")
    p.add_argument("--frames", type=int, required=True, help="stereo frames of the (train) split")
    p.add_argument(
        "--split",
        choices=("train", "val", "test", "both"),
        default="both",
        help="'both' writes train with --frames and test with --test-frames",
    )
    p.add_argument("--test-frames", type=int, default=None, help="test frames for --split both (default frames / 4)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--width", type=int, default=160)
    p.add_argument("--height", type=int, default=120)
    p.add_argument("--frames-per-scene", type=int, default=25, help="frames sharing a background and lights")
    p.add_argument("--max-objects", type=int, default=3)
    p.add_argument("--format", choices=("jpg", "png"), default="jpg", help="RGB image format")
    p.add_argument("--bbox-order", choices=("yx", "xy"), default="yx", help="'yx' reproduces FAT's box quirk")
    a = p.parse_args(argv)
    jobs = (
        [(a.split, a.frames)]
        if a.split != "both"
        else [("train", a.frames), ("test", a.test_frames if a.test_frames is not None else max(1, a.frames // 4))]
    )
    for split, n in jobs:
        dirs = write_synthetic_dataset(
            a.out,
            n,
            seed=a.seed,
            split=split,
            image_size=(a.width, a.height),
            frames_per_scene=a.frames_per_scene,
            max_objects=a.max_objects,
            image_format=a.format,
            bbox_order=a.bbox_order,
        )
        print(f"{split}: {n} frames in {len(dirs)} scenes under {a.out / split}")


if __name__ == "__main__":
    main()
