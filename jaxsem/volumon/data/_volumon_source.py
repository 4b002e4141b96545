"""VoluMon training and evaluation batches from a FAT-layout or ``make_synthetic`` directory.

:func:`volumon_batch_source` joins :class:`VolumonDataset` (this package's input pipeline) to
:func:`jaxsem.volumon.train_and_evaluate` (``config.data == "directory"``): ``batch_fn(step)`` is
a pure function of the seed and the step (so a resumed run sees the same batches), in the keys of
:data:`jaxsem.volumon._train.TRAIN_KEYS`, and the evaluation batch holds every usable object of the
evaluation directory once, with ground truth.
"""

from __future__ import annotations

import pathlib
from collections.abc import Callable, Sequence

import numpy as np

from .._synthetic import VOLUMON_CLASS_NAMES
from ._pipeline import PipelineConfig, VolumonDataset, as_volumon_batch

__all__ = ["volumon_batch_source", "volumon_eval_batch"]


def _keys(batch: dict) -> dict:
    out = as_volumon_batch(batch)
    # the class's drawn shape (0 cuboid, 1 ellipsoid, 2 cylinder: the ids of jaxsem.volumon), which
    # the shape-aware losses use; gt_shape_id scores a cylinder as its bounding cuboid
    out["class_shape"] = np.asarray(batch["shape_id"], np.int32)
    return out


def _names_and_config(class_names, input_size, global_padding, num_points) -> tuple[tuple, PipelineConfig]:
    """The class list (default: VoluMon's) and the pipeline sized like the network's inputs."""
    names = tuple(VOLUMON_CLASS_NAMES if class_names is None else class_names)
    cfg = PipelineConfig(
        patch_size=int(input_size),
        global_size=int(input_size),
        global_margin=float(global_padding),
        n_points=int(num_points),
    )
    return names, cfg


def _dataset(path, config: PipelineConfig, class_names, seed: int, loader_options) -> VolumonDataset:
    path = pathlib.Path(path)
    if not path.is_dir():
        raise ValueError(f"data: {path} is not a directory")
    return VolumonDataset.from_directory(
        path, config, class_names=class_names, augment=False, seed=seed, loader_options=loader_options
    )


def volumon_eval_batch(
    path,
    *,
    input_size: int,
    global_padding: float,
    num_points: int,
    class_names: Sequence[str] | None = None,
    num: int | None = None,
    loader_options: dict | None = None,
) -> dict:
    """Every usable object of the directory ``path`` once (the first ``num``), as one batch.

    Keys of :func:`jaxsem.volumon.data.as_volumon_batch` plus ``class_shape``; ``class_names`` default:
    :data:`jaxsem.volumon.VOLUMON_CLASS_NAMES` (objects of other classes are skipped). Raises
    ValueError naming the directory when it holds no usable object.
    """
    names, cfg = _names_and_config(class_names, input_size, global_padding, num_points)
    ds = _dataset(path, cfg, names, 0, loader_options)
    if ds.num_samples == 0:
        raise ValueError(f"data: {path} holds no usable object of the classes {list(names)} (skipped: {ds.skipped})")
    parts = [_keys(b) for b in ds.eval_batches(min(64, ds.num_samples))]
    out = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    keep = np.asarray(out["sample_mask"], bool)
    out = {k: v[keep] for k, v in out.items()}
    if num is not None:
        out = {k: v[: int(num)] for k, v in out.items()}
    return out


def volumon_batch_source(
    path,
    *,
    input_size: int,
    global_padding: float,
    num_points: int,
    batch_size: int,
    seed: int = 0,
    class_names: Sequence[str] | None = None,
    loader_options: dict | None = None,
) -> tuple[Callable[[int], dict], int]:
    """``(batch_fn, num_samples)`` for training VoluMon on the directory ``path``.

    ``batch_fn(step)``: batch ``step`` counted across epochs of the usable objects of ``path``
    (seeded permutation per epoch; the network's own hue / saturation / erasing augmentation is
    applied by the train step). Raises ValueError naming the directory when it holds fewer usable
    objects than one batch.
    """
    names, cfg = _names_and_config(class_names, input_size, global_padding, num_points)
    ds = _dataset(path, cfg, names, int(seed), loader_options)
    if ds.num_samples < int(batch_size):
        raise ValueError(
            f"data: {path} holds {ds.num_samples} usable objects of the classes {list(names)}, fewer than one batch "
            f"of {batch_size} (skipped: {ds.skipped})"
        )

    def batch_fn(step: int) -> dict:
        return _keys(ds.batch_at(int(step), int(batch_size)))

    return batch_fn, ds.num_samples
