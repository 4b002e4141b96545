"""Render desk scenes of the eight LM-O objects and write VoluMon training detections.

    python -m jaxsem.volumon.data.make_lmo_renders --models DIR/models --out OUT --frames N --seed S [--distractors YCB_DIR]

Thin entry point over :func:`jaxsem.volumon.data.write_desk_detections`: ``OUT/chunk_NNNN.npz`` files
(network inputs of the visible boxes, amodal stereo boxes, depth points; the 3D truth beside them
for the oracle and for scoring) and ``OUT/preview_K.jpg``. Re-running resumes (written chunks are
skipped). Train with ``jaxsem volumon train --size lmo --data OUT``.
"""

from __future__ import annotations

import argparse
import sys

from ... import scripting as sc
from ._lmo_renders import write_desk_detections


def build_parser(prog: str | None = None) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=prog, description=__doc__, formatter_class=sc.HelpFormatter)
    p.add_argument("--models", type=sc.existing_dir, required=True, help="BOP models/ folder with the LM-O obj_*.ply")
    p.add_argument("--out", type=sc.output_dir, required=True, help="output folder (chunk_NNNN.npz)")
    p.add_argument("--frames", type=sc.positive_int, required=True, help="frames to render")
    p.add_argument("--seed", type=int, default=0, help="seed (held-out renders: another seed)")
    p.add_argument("--distractors", type=sc.existing_dir, default=None, help="folder of .stl distractor meshes (YCB)")
    p.add_argument("--chunk", type=sc.positive_int, default=100, help="frames per written chunk")
    p.add_argument("--min-visible", type=float, default=0.3, help="objects at least this visible are kept")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    return p


def main(argv=None) -> int:
    a = build_parser("python -m jaxsem.volumon.data.make_lmo_renders").parse_args(argv)

    try:
        paths = write_desk_detections(
            a.out,
            a.frames,
            a.seed,
            models_dir=a.models,
            distractor_dir=a.distractors,
            chunk=a.chunk,
            min_visible=a.min_visible,
            progress=not a.quiet,
        )
    except ValueError as exc:
        sys.exit(f"error: {exc}")
    print(f"wrote {len(paths)} chunks to {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
