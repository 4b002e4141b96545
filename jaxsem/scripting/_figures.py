"""The commands' training-curve figures: one way to finish and write them."""

from __future__ import annotations

import os
import pathlib

from .._atomic import atomic_savefig


def save_step_figure(fig, axes, path: str | os.PathLike, *, dpi: int) -> pathlib.Path:
    """Finishes a figure of curves against the training step (``axes``: its axes, each labelled
    "step"), writes it to ``path`` atomically (:func:`atomic_savefig`) and closes it, so a
    command that draws one figure per run leaves no figure open."""
    import matplotlib.pyplot as plt  # deferred: matplotlib is optional (the sim extra)

    for ax in axes:
        ax.set_xlabel("step")
    fig.tight_layout()
    atomic_savefig(fig, path, dpi=dpi)
    plt.close(fig)
    return pathlib.Path(path)
