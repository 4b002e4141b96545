"""Texture planes for a posed detection sequence with images: ROSHAN's front end run over it with
the sequence's own association (a tracker's ids), :func:`measure_texture`."""

from __future__ import annotations

import dataclasses

import numpy as np

from ._sequence_types import Sequence

__all__ = ["measure_texture"]


def measure_texture(sequence: Sequence, config=None):
    """``(sequence with texture depths, detections)``: every frame's image through
    :class:`jaxsem.slam.FrontEnd` (``config``: a :class:`jaxsem.slam.FrontEndConfig`), each
    detection associated by the sequence's ids (``track_ids``), its texture-plane depth written
    where the front end accepted one (NaN elsewhere; depths already in the sequence are
    replaced). ``detections``: per frame, the front end's :class:`AssociatedDetection` list
    (status, point count, baseline of each measurement).

    Raises:
      ValueError: a frame without an image, an unreadable image, or an id that is not a
        non-negative int (the front end's landmark ids are ints).
    """
    from ._frontend import FrontEnd
    from ._sequence import load_image

    if not isinstance(sequence, Sequence):
        raise ValueError(f"sequence: expected a Sequence, got {type(sequence).__name__}")
    fe = FrontEnd(sequence.K, config)
    frames, out = [], []
    for t, fr in enumerate(sequence.frames):
        if fr.image is None:
            raise ValueError(f"frames[{t}].image: the front end needs every frame's image")
        bad = [i for i in fr.ids if not isinstance(i, (int, np.integer)) or isinstance(i, bool) or i < 0]
        if bad:
            raise ValueError(f"frames[{t}].ids: the front end needs non-negative int ids, got {bad[0]!r}")
        dets = fe.process(
            load_image(sequence, t), fr.camera_T_world, fr.boxes, list(fr.classes), track_ids=list(fr.ids)
        )
        depth = np.array([np.nan if d.texture_depth is None else d.texture_depth for d in dets], np.float64)
        frames.append(dataclasses.replace(fr, texture_depth=depth.reshape(len(fr.ids))))
        out.append(dets)
    return dataclasses.replace(sequence, frames=tuple(frames)), out
