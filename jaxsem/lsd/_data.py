"""Expert data for LSD training: loading, splitting by building, batches, dihedral augmentation.

The shard format is :mod:`jaxsem.planning`'s (``expert_<family>_<seed>.npz``; the module
``jaxsem.lsd.EXPERT_SCHEMA`` lists the keys). Training needs four per-sample arrays:
``occupancy`` (S, k, k) int8, ``semantic`` (S, k, k) int8, ``context`` (S, 4) float32 and
``path_mask`` (S, k, k) bool; ``building_seed`` (S,) is used to hold out whole buildings.
"""

from __future__ import annotations

import os
import pathlib

import jax
import jax.numpy as jnp
import numpy as np

from ._expert import load_expert_dataset

TRAIN_KEYS = ("occupancy", "semantic", "context", "path_mask")


def check_expert_data(data: dict, map_size: int, context_dim: int) -> int:
    """Checks the arrays training needs; returns the sample count. ``ValueError`` names the key."""
    if not isinstance(data, dict):
        raise ValueError(f"data: expected a dict of arrays, got {type(data).__name__}")
    missing = [k for k in TRAIN_KEYS if k not in data]
    if missing:
        raise ValueError(f"data: missing keys {missing}; expected {list(TRAIN_KEYS)}")
    S = len(data["context"])
    if S < 1:
        raise ValueError("data: expected at least one sample, got 0")
    want = {
        "occupancy": (S, map_size, map_size),
        "semantic": (S, map_size, map_size),
        "context": (S, context_dim),
        "path_mask": (S, map_size, map_size),
    }
    for k, shape in want.items():
        arr = np.asarray(data[k])
        if arr.shape != shape:
            raise ValueError(f"data['{k}']: expected shape {shape}, got shape {arr.shape}")
    for k in ("occupancy", "semantic"):
        if not np.issubdtype(np.asarray(data[k]).dtype, np.integer):
            raise ValueError(f"data['{k}']: expected an integer dtype, got {np.asarray(data[k]).dtype}")
    return S


def load_expert_data(paths) -> dict:
    """Loads shards (a folder, one path, or a list) into one dict (see the planning schema)."""
    if isinstance(paths, (str, os.PathLike)) and not pathlib.Path(paths).is_dir():
        paths = [paths]
    return load_expert_dataset(paths)


def split_by_building(data: dict, val_fraction: float, seed: int, every_nth: int = 0) -> tuple:
    """``(train_idx, val_idx)`` int arrays. Whole buildings go to validation when there are
    several (``building_seed``); otherwise a random share of samples. Validation gets at least
    one sample when ``val_fraction > 0`` and there are at least two samples. ``every_nth > 0``:
    validation is the buildings whose seed is a multiple of it (fixed as shards are added)."""
    S = len(data["context"])
    if every_nth > 0 and "building_seed" in data:
        is_val = np.asarray(data["building_seed"]) % int(every_nth) == 0
        if 0 < is_val.sum() < S:
            return np.flatnonzero(~is_val), np.flatnonzero(is_val)
    rng = np.random.default_rng([int(seed), 0x5A11])
    if val_fraction <= 0 or S < 2:
        return np.arange(S), np.zeros(0, np.int64)
    groups = np.asarray(data.get("building_seed", np.zeros(S, np.int64)))
    uniq = np.unique(groups)
    if len(uniq) >= 2:
        n_val = max(1, int(round(val_fraction * len(uniq))))
        n_val = min(n_val, len(uniq) - 1)
        val_groups = rng.choice(uniq, n_val, replace=False)
        is_val = np.isin(groups, val_groups)
    else:
        n_val = min(S - 1, max(1, int(round(val_fraction * S))))
        is_val = np.zeros(S, bool)
        is_val[rng.choice(S, n_val, replace=False)] = True
    return np.flatnonzero(~is_val), np.flatnonzero(is_val)


def batch_indices(train_idx: np.ndarray, batch_size: int, step: int, seed: int) -> np.ndarray:
    """The batch of ``step``: a function of (seed, step) only, so a resumed run sees the same
    batches as an uninterrupted one. Epoch-wise shuffling without replacement."""
    n = len(train_idx)
    per_epoch = max(1, n // batch_size) if n >= batch_size else 1
    epoch, pos = divmod(step, per_epoch)
    perm = np.random.default_rng([int(seed), int(epoch), 0xBA7C]).permutation(n)
    if n >= batch_size:
        sel = perm[pos * batch_size : (pos + 1) * batch_size]
    else:  # fewer samples than a batch: repeat them
        sel = np.resize(perm, batch_size)
    return train_idx[sel]


def gather_batch(data: dict, idx: np.ndarray) -> dict:
    """The four training arrays of samples ``idx`` as numpy arrays."""
    return {
        "occupancy": np.asarray(data["occupancy"][idx], np.int8),
        "semantic": np.asarray(data["semantic"][idx], np.int8),
        "context": np.asarray(data["context"][idx], np.float32),
        "path_mask": np.asarray(data["path_mask"][idx], bool),
    }


def dihedral_augment(key, occupancy, semantic, context, path_mask):
    """Random flips / transposition of each sample's crops with the matching context change.

    occupancy, semantic, path_mask: (B, k, k); context: (B, C) with C >= 2 whose first two
    entries are the goal direction (x along columns, y along rows). Reversing columns negates x,
    reversing rows negates y, transposing swaps them; other context entries are unchanged.
    (The robot's cell [k/2, k/2] moves by at most one cell under a flip.) Jittable.
    """
    B = occupancy.shape[0]
    bits = jax.random.bernoulli(key, 0.5, (B, 3))

    def one(b, occ, sem, mask, ctx):
        def tf(g):
            g = jnp.where(b[0], g[:, ::-1], g)
            g = jnp.where(b[1], g[::-1, :], g)
            return jnp.where(b[2], g.T, g)

        x = jnp.where(b[0], -ctx[0], ctx[0])
        y = jnp.where(b[1], -ctx[1], ctx[1])
        x, y = jnp.where(b[2], y, x), jnp.where(b[2], x, y)
        ctx = ctx.at[0].set(x).at[1].set(y)
        return tf(occ), tf(sem), tf(mask), ctx

    occ, sem, mask, ctx = jax.vmap(one)(bits, occupancy, semantic, path_mask, context)
    return occ, sem, ctx, mask
