"""The jaxsem side of the gtsam_quadrics peer: the ``--peer-python`` flag the benchmarks share, its
check, and one solve through a problem file.

The peer itself (``_quadricslam_peer.py``) runs under its own Python 3.10 interpreter with
``gtsam-quadrics`` and ``numpy<2``; the benchmarks write it an ``.npz`` of the problems, run it
and read its answer back. Import it from a benchmark script of this folder::

    sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
    import _peer_client  # noqa: E402
"""

from __future__ import annotations

import os
import pathlib
import subprocess
import sys
import tempfile
from collections.abc import Callable

import numpy as np

PEER_SCRIPT = pathlib.Path(__file__).resolve().parent / "_quadricslam_peer.py"


def add_peer_flag(parser) -> None:
    """``--peer-python``: the peer's interpreter (default ``$JAXSEM_PEER_PYTHON``; empty: not run)."""
    parser.add_argument(
        "--peer-python",
        default=os.environ.get("JAXSEM_PEER_PYTHON", ""),
        help="Python 3.10 with gtsam-quadrics and numpy<2 (default: $JAXSEM_PEER_PYTHON; empty: the peer "
        "is not run and the results say so)",
    )


def check_peer_flag(peer_python: str, error: Callable[[str], object]) -> None:
    """Calls ``error`` (the script's way to stop on a bad flag) where ``peer_python`` names no
    file; says on stderr that the peer is not run where it is empty."""
    if peer_python and not pathlib.Path(peer_python).exists():
        error(f"--peer-python: {peer_python} does not exist (pass '' to skip the peer)")
    if not peer_python:
        print("gtsam_quadrics: not run (give --peer-python or set JAXSEM_PEER_PYTHON)", file=sys.stderr)


def solve(peer_python: str, **arrays) -> dict:
    """The peer's answer (its output file's arrays) for the problem file of ``arrays`` (the keys
    ``_quadricslam_peer.py`` reads)."""
    with tempfile.TemporaryDirectory() as tmp:
        src, dst = os.path.join(tmp, "in.npz"), os.path.join(tmp, "out.npz")
        np.savez(src, **arrays)
        subprocess.run([peer_python, str(PEER_SCRIPT), src, dst], check=True)
        return dict(np.load(dst))
