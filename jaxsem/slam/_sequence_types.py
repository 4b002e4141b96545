"""The data types of a posed detection sequence (the JSON layout: :mod:`jaxsem.slam._sequence`)."""

from __future__ import annotations

import dataclasses
import pathlib
from typing import Any

import numpy as np

from .._files import MAX_PIXELS, image_size as _image_size, read_image as _read_image

SEQUENCE_FILE = "sequence.json"
FORMAT_TAG = "jaxsem.roshan.sequence/1"


# --------------------------------------------------------------------------------------------
# The sequence layout.


@dataclasses.dataclass(frozen=True)
class SequenceFrame:
    """One posed frame with its detections (N of them; numpy, not padded).

    Attributes:
      camera_T_world: (4, 4) odometry / VIO pose (the pose prior).
      boxes: (N, 4) ``[u_min, v_min, u_max, v_max]`` pixels.
      classes: (N,) class names of the sequence's class table (:attr:`Sequence.classes`).
      ids: (N,) association ids as written in the file (int or str).
      texture_depth: (N,) metres, NaN where the detection has none.
      image: image file name relative to the sequence directory, or None.
    """

    camera_T_world: np.ndarray
    boxes: np.ndarray
    classes: tuple
    ids: tuple
    texture_depth: np.ndarray
    image: str | None = None


@dataclasses.dataclass(frozen=True)
class Sequence:
    """A posed detection sequence (its JSON layout is in :mod:`jaxsem.slam._sequence`'s docstring).

    Attributes:
      K: (3, 3) intrinsics; image_size: ``(width, height)`` pixels.
      frames: tuple of :class:`SequenceFrame` in time order.
      root: directory the image names are relative to (None: no images).
      truth: optional ``{"camera_T_world": (T, 4, 4), "objects": [{"id", "class", "center" (3,),
        "radii" (3,), "rotation" (3, 3)}]}`` (numpy arrays), for evaluation.
      noise: optional noise model ``{"box_sigma", "texture_sigma", "pose_translation_sigma",
        "pose_rotation_sigma_deg"}`` (any subset; :func:`noise_model` makes it a NoiseModel).
      initial: optional ``{id: {"center" (3,), "radii" (3,), "rotation" (3, 3)}}`` (world frame,
        numpy): the initial ellipsoid of each listed object, used by :func:`run_sequence` in
        place of the single-view initialisation from its first detection.
      classes: the :class:`jaxsem.classes.ClassTable` of the detections' class names (None: the
        built-in table); the JSON layout's optional ``"classes"`` rows are added to it.
    """

    K: np.ndarray
    image_size: tuple
    frames: tuple
    root: pathlib.Path | None = None
    truth: dict | None = None
    noise: dict | None = None
    initial: dict | None = None
    classes: Any = None

    @property
    def object_ids(self) -> tuple:
        """Association ids in order of first appearance; object slot ``j`` holds ``object_ids[j]``."""
        seen: dict = {}
        for frame in self.frames:
            for i in frame.ids:
                seen.setdefault(i, None)
        return tuple(seen)

    @property
    def object_classes(self) -> tuple:
        """Class name of each object slot (from its first detection)."""
        first: dict = {}
        for frame in self.frames:
            for i, c in zip(frame.ids, frame.classes):
                first.setdefault(i, c)
        return tuple(first[i] for i in self.object_ids)

    def image_path(self, index: int) -> pathlib.Path | None:
        """Path of frame ``index``'s image, or None when the frame names none."""
        name = self.frames[index].image
        if name is None:
            return None
        return (self.root or pathlib.Path(".")) / name

    def image(self, index: int, *, max_pixels: int = MAX_PIXELS) -> np.ndarray | None:
        """RGB image (H, W, 3) uint8 of frame ``index``, or None when the frame names none.

        Raises ValueError naming the file when it cannot be read, its header declares more than
        ``max_pixels`` pixels (default 8192 x 8192) or a size that is not ``image_size``: both
        checked before any pixel is decoded.
        """
        path = self.image_path(index)
        if path is None:
            return None
        try:
            width, height = _image_size(path, max_pixels=max_pixels)
        except ValueError as exc:
            raise ValueError(f"frames[{index}].image: {exc}") from None
        if (width, height) != tuple(self.image_size):
            raise ValueError(
                f"frames[{index}].image: {str(path)!r} is {width}x{height}, expected "
                f"image_size {self.image_size[0]}x{self.image_size[1]}"
            )
        try:
            bgr = _read_image(path, 1, max_pixels=max_pixels)  # 1: cv2.IMREAD_COLOR
        except ValueError:
            raise ValueError(f"frames[{index}].image: cannot read image file {str(path)!r}") from None
        return np.ascontiguousarray(bgr[..., ::-1])
