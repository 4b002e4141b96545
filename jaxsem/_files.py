"""Bounded, checked reads of the files a user hands the package (private to jaxsem).

Two ways a file can hurt a reader that trusts it, handled once for every reader:

- **size**: an image's header declares its width and height, and a decoder allocates what the
  header says. A 1 MB PNG of one colour can declare 30000 x 30000 pixels (900 MB as grey bytes,
  more as colour or as floats). :func:`image_size` reads the header alone (PIL opens lazily)
  and refuses a declared size over a pixel budget before any pixel is decoded;
  :func:`read_image` decodes (OpenCV) only after that check. The budget is the caller's
  argument (``max_pixels``, or ``max_cells`` for a map), named in the message with the declared
  width and height. PIL's own decompression-bomb limit (``PIL.Image.MAX_IMAGE_PIXELS``, whose
  error gives a pixel count but no width and height) is lifted for the header read alone, under a
  lock, and applied again by :func:`image_size` itself: a size over twice it (PIL's error
  threshold) is refused even within the budget, so a process that lowered it stays protected.
- **text**: :func:`read_text` and :func:`read_json` give one ``ValueError`` naming the file for
  a file that cannot be read, is larger than its byte budget (its size and the budget in the
  message), is not UTF-8 or (``read_json``) is not JSON (never the parser's bare "Expecting
  value: line 1 column 11").

This module imports nothing else of the package.
"""

from __future__ import annotations

import json
import os
import pathlib
import threading

import numpy as np

#: Default pixel budget of an image read (a camera frame, a map image): 2**26 = 67,108,864
#: pixels, 8192 x 8192 (a 4K frame is 8.3 million). Below PIL's own decompression-bomb limit.
MAX_PIXELS = 2**26
_PIL_LIMIT_LOCK = threading.Lock()

#: Default cell budget of a map read from a file (``max_cells`` of :func:`jaxsem.planning.load_map`):
#: 2**26 = 67,108,864 cells, 8192 x 8192 (819 m square at 0.1 m). The planner's grids and the
#: semantics' work arrays are a few bytes per cell each, so a map within it fits a few GB.
MAX_CELLS = 2**26
#: Default element budget of an ``.npz`` read (a model's weights, a data shard): 2**30 array
#: elements in all (1 GiB as bytes, 8 GiB as float64); the shipped models hold a few million.
MAX_NPZ_ELEMENTS = 2**30
#: Default byte budget of a JSON file (a BOP data set's largest ``scene_gt.json`` is tens of MB).
MAX_JSON_BYTES = 2**28
#: Default byte budget of a text file (a TUM sequence's ``groundtruth.txt`` of a long sequence, a
#: detections list: a few MB).
MAX_TEXT_BYTES = 2**28


def check_budget(name: str, value) -> int:
    """``value`` as a positive int (a size budget); ``ValueError`` naming ``name`` otherwise."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value <= 0:
        raise ValueError(f"{name}: expected a positive whole number, got {value!r}")
    return int(value)


def image_size(path, *, max_pixels: int = MAX_PIXELS, argument: str = "max_pixels") -> tuple[int, int]:
    """``(width, height)`` an image file declares, read from its header alone (no pixel decoded).

    Raises:
      ValueError: naming the file when it is not a readable image, and naming the file, its
        declared size and ``argument`` when ``width * height > max_pixels``.
    """
    from PIL import Image  # deferred: only image readers need it

    max_pixels = check_budget(argument, max_pixels)
    path = pathlib.Path(path)
    with _PIL_LIMIT_LOCK:
        pil_limit = Image.MAX_IMAGE_PIXELS
        Image.MAX_IMAGE_PIXELS = None  # the header alone is read; the checks below replace PIL's
        try:
            with Image.open(path) as img:
                width, height = (int(v) for v in img.size)
        except (OSError, SyntaxError, ValueError) as exc:  # PIL's UnidentifiedImageError is an OSError
            raise ValueError(f"{path}: not a readable image ({exc})") from None
        finally:
            Image.MAX_IMAGE_PIXELS = pil_limit
    if width <= 0 or height <= 0:
        raise ValueError(f"{path}: declares an empty image ({width} x {height} pixels)")
    if width * height > max_pixels:
        raise ValueError(
            f"{path}: declares {width} x {height} = {width * height:,} pixels, more than "
            f"{argument}={max_pixels:,}; pass a larger {argument} to read it"
        )
    if pil_limit is not None and width * height > 2 * pil_limit:
        raise ValueError(
            f"{path}: declares {width} x {height} = {width * height:,} pixels, more than twice "
            f"PIL.Image.MAX_IMAGE_PIXELS={pil_limit:,} (its decompression-bomb limit); raise that too to read it"
        )
    return width, height


def read_image(path, flags: int | None = None, *, max_pixels: int = MAX_PIXELS, argument: str = "max_pixels"):
    """The pixels of an image file (OpenCV's ``cv2.imread(path, flags)``, default
    ``IMREAD_UNCHANGED``: BGR channel order) after :func:`image_size` has checked its declared size.

    Raises:
      ValueError: naming the file (see :func:`image_size`; also when OpenCV cannot decode it).
    """
    import cv2  # deferred: cv2 is slow to import

    image_size(path, max_pixels=max_pixels, argument=argument)
    try:
        img = cv2.imread(os.fspath(path), cv2.IMREAD_UNCHANGED if flags is None else flags)
    except cv2.error as exc:
        raise ValueError(f"{path}: not a readable image ({' '.join(str(exc).split())[-200:]})") from None
    if img is None:
        raise ValueError(f"{path}: not a readable image (OpenCV cannot decode it)")
    return img


def npz_shapes(path) -> dict[str, tuple[int, ...]]:
    """The shape each array of an ``.npz`` file declares, from the array headers alone (nothing
    is inflated: a few kB of deflated zeros can declare gigabytes). ``ValueError`` naming the file
    when it is not a readable ``.npz``."""
    import zipfile

    path = pathlib.Path(path)
    shapes = {}
    try:
        with zipfile.ZipFile(path) as archive:
            for name in archive.namelist():
                if not name.endswith(".npy"):
                    continue
                with archive.open(name) as f:
                    version = np.lib.format.read_magic(f)
                    read = (
                        np.lib.format.read_array_header_1_0
                        if version == (1, 0)
                        else np.lib.format.read_array_header_2_0
                    )
                    shapes[name[: -len(".npy")]] = tuple(int(n) for n in read(f)[0])
    except (OSError, ValueError, zipfile.BadZipFile) as exc:
        raise ValueError(f"{path}: not a readable .npz file ({exc})") from None
    return shapes


def check_npz(path, *, max_elements: int = MAX_NPZ_ELEMENTS, argument: str = "max_elements") -> dict:
    """The declared shapes of an ``.npz`` (:func:`npz_shapes`), after checking that their elements
    add up to at most ``max_elements``: ``ValueError`` naming the file, the largest array, the
    total and the argument otherwise, before anything is inflated."""
    budget = check_budget(argument, max_elements)
    shapes = npz_shapes(path)
    sizes = {k: int(np.prod(v, dtype=np.int64)) if v else 1 for k, v in shapes.items()}
    total = sum(sizes.values())
    if total > budget:
        big = max(sizes, key=lambda k: sizes[k])
        raise ValueError(
            f"{path}: declares {total:,} array elements (the largest, {big!r}, {shapes[big]}), "
            f"more than {argument}={budget:,}"
        )
    return shapes


def read_text(path, what: str = "text file", *, max_bytes: int = MAX_TEXT_BYTES) -> str:
    """The UTF-8 text of a file; one ``ValueError`` naming the file (and ``what`` it should be)
    when it cannot be read, is over ``max_bytes`` (the message gives its size and the budget:
    the size is read before any byte is, so a huge file is refused without being loaded) or is
    not UTF-8."""
    path = pathlib.Path(path)
    budget = check_budget("max_bytes", max_bytes)
    try:
        size = path.stat().st_size
        if size > budget:
            raise ValueError(f"{path}: {size:,} bytes, more than the max_bytes={budget:,} a {what} may hold")
        raw = path.read_bytes()
    except OSError as exc:
        raise ValueError(f"{path}: cannot read the {what} ({exc.strerror or exc})") from None
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ValueError(f"{path}: not a readable {what} (not UTF-8 text: byte {exc.start})") from None


def read_json(path, what: str = "JSON file", *, max_bytes: int = MAX_JSON_BYTES):
    """The parsed content of a JSON file; one ``ValueError`` naming the file (and ``what`` it
    should be) when it cannot be read, is over ``max_bytes``, is not UTF-8 or is not JSON
    (the text read by :func:`read_text`)."""
    text = read_text(path, what, max_bytes=max_bytes)
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not a readable {what} (not JSON: {exc.msg} at line {exc.lineno})") from None
