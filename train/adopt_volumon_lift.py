"""One VoluMon R-CNN network from a detector and a separate VoluMon network: the detector's
boxes and classes, the separate network's ellipsoids (``jaxsem.volumon.rcnn.adopt_separate_lift``).

    python train/adopt_volumon_lift.py --detector lmo-rcnn-448 --separate lmo \
        --out jaxsem/volumon/pretrained/volumon_lmo_rcnn_448_volumon

Writes ``OUT.npz`` and ``OUT.json`` (the detector's training config under the adopted network's
settings, and where both parts came from), each atomically. Nothing is trained: the lift is the
separate network's weights, reading its two inputs from the one network's image.
"""

from __future__ import annotations

import argparse
import pathlib
import sys

from jaxsem import scripting as sc


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python train/adopt_volumon_lift.py", description=__doc__.split("\n")[0])
    p.add_argument("--detector", required=True, help="a shipped R-CNN name, an exported .npz or a training workdir")
    p.add_argument("--separate", default="lmo", help="'lmo' (the shipped LM-O VoluMon), an exported .npz or a workdir")
    p.add_argument("--out", type=pathlib.Path, required=True, help="path stem of the adopted model")
    a = p.parse_args(argv)

    from jaxsem import volumon
    from jaxsem.volumon.rcnn import ADOPTED_RCNNS, SHIPPED_RCNNS, adopt_separate_lift, export_rcnn, load_rcnn

    if a.detector not in SHIPPED_RCNNS and a.detector not in ADOPTED_RCNNS and not pathlib.Path(a.detector).exists():
        p.error(f"--detector: no model {a.detector}")
    if a.separate != "lmo" and not pathlib.Path(a.separate).exists():
        p.error(f"--separate: no model {a.separate}")
    if not a.out.parent.is_dir():
        p.error(f"--out: no folder {a.out.parent}")
    try:
        detector = load_rcnn(a.detector)
    except ValueError as exc:
        p.error(f"--detector: {exc}")
    try:
        separate = volumon.load_pretrained(kind="lmo") if a.separate == "lmo" else volumon.load_pretrained(a.separate)
    except ValueError as exc:
        p.error(f"--separate: {exc}")
    try:
        one = adopt_separate_lift(detector, separate)
    except ValueError as exc:
        p.error(f"--separate: {exc}")
    meta = {
        "name": a.out.name,
        "step": detector.meta.get("step"),
        "seed": detector.config.seed,
        "data": detector.meta.get("data", ""),
        "adopted_lift": {
            "detector": a.detector,
            "detector_step": detector.meta.get("step"),
            "separate": a.separate,
            "separate_step": separate.meta.get("step"),
            "separate_data": separate.meta.get("data", ""),
        },
    }
    out = export_rcnn(a.out, one.variables, one.config, meta)
    print(f"wrote {out} and {out.with_suffix('.json')}")
    return 0


if __name__ == "__main__":
    sys.exit(sc.run_main(main))
