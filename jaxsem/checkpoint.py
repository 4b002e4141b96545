"""Checkpoints of pytree training states with orbax (keep-latest-N, atomic, exact resume).

A thin wrapper over :class:`orbax.checkpoint.CheckpointManager` with ``StandardSave`` /
``StandardRestore``, as in the flax examples:

- writes are atomic (orbax writes into a temporary directory and renames it when complete, so an
  interrupted save never leaves a half-written step that :meth:`Checkpointer.latest_step` would
  return);
- only the latest ``max_to_keep`` steps are kept;
- :meth:`Checkpointer.save` and :meth:`Checkpointer.close` wait for the (possibly asynchronous)
  write to finish before returning, so a script can exit or kill itself right after a save;
- restoring needs a *target* pytree of the same structure (e.g. the freshly initialised state):
  its shapes and dtypes are used, its values are ignored. Missing or corrupt checkpoints raise
  :class:`CheckpointError` (a ``ValueError``) naming the path; orbax's own reports of a corrupt
  checkpoint (absl log lines, the TensorStore spec dumps and "Event loop is closed" tracebacks of
  its abandoned reads) are kept off the terminal (:func:`quiet_orbax`).

PRNG keys must be stored as raw ``uint32`` arrays (``jax.random.PRNGKey`` / ``key_data``), not
typed key arrays. Example::

    ckpt = Checkpointer(workdir / "checkpoints", max_to_keep=3)
    start = 0
    if ckpt.latest_step() is not None:
        state = ckpt.restore(state)          # state: the freshly initialised train state
        start = ckpt.latest_step()
    for step in range(start, num_steps):
        state = train_step(state, batch(step))
        if (step + 1) % every == 0:
            ckpt.save(step + 1, state)
    ckpt.close()
"""

from __future__ import annotations

import contextlib
import gc
import logging
import os
import pathlib
import sys
import time
from collections.abc import Iterator
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import orbax.checkpoint as ocp

__all__ = [
    "CheckpointError",
    "Checkpointer",
    "latest_step",
    "quiet_orbax",
    "restore_checkpoint",
    "save_checkpoint",
]


class CheckpointError(ValueError):
    """A checkpoint is missing, unreadable, or does not match the restore target."""


def _orbax_noise(unraisable: Any) -> bool:
    """Whether an unraisable exception is orbax's leftover of a failed read: a read coroutine of
    orbax/TensorStore collected with its exception, or TensorStore calling back into the closed
    event loop of a restore that already failed ("Event loop is closed")."""
    exc, obj = unraisable.exc_value, unraisable.object
    code = getattr(obj, "cr_code", None)
    if code is not None and ("orbax" in code.co_filename or "tensorstore" in code.co_filename):
        return True
    if isinstance(exc, RuntimeError) and "Event loop is closed" in str(exc):
        return True
    return "TensorStore" in str(exc)


_PREVIOUS_HOOK: Any = None


def _unraisable_hook(unraisable: Any) -> None:
    if _orbax_noise(unraisable):
        return
    (_PREVIOUS_HOOK or sys.__unraisablehook__)(unraisable)


@contextlib.contextmanager
def quiet_orbax() -> Iterator[None]:
    """Keeps orbax's reports of an unreadable checkpoint off the terminal while it runs: absl /
    orbax log records below CRITICAL are dropped, and from then on the unraisable exceptions its
    abandoned reads leave behind (printed whenever they are collected, even at exit) are filtered
    out of ``sys.unraisablehook`` (all other unraisable exceptions still reach the previous hook).
    The failure itself still raises; :class:`Checkpointer` turns it into one :class:`CheckpointError`."""
    global _PREVIOUS_HOOK
    if sys.unraisablehook is not _unraisable_hook:
        _PREVIOUS_HOOK = sys.unraisablehook
        sys.unraisablehook = _unraisable_hook
    loggers = [logging.getLogger(name) for name in ("absl", "orbax", "orbax.checkpoint", "asyncio")]
    levels = [lg.level for lg in loggers]
    for lg in loggers:
        lg.setLevel(logging.CRITICAL)
    try:
        yield
    except BaseException:
        # the failed read's other reads finish in TensorStore's threads: let them, then collect
        # their coroutines and futures now (filtered), not at exit
        time.sleep(0.2)
        gc.collect()
        raise
    finally:
        for lg, level in zip(loggers, levels):
            lg.setLevel(level)


def _abstract(target: Any) -> Any:
    """Shape/dtype structure of ``target`` (values are not needed to restore)."""

    def leaf(x):
        if isinstance(x, jax.ShapeDtypeStruct):
            return x
        x = np.asarray(x) if not isinstance(x, jax.Array) else x
        return jax.ShapeDtypeStruct(x.shape, x.dtype)

    return jax.tree.map(leaf, target)


def _like(restored: Any, target: Any) -> Any:
    """``restored`` as the kind of array ``target`` is: orbax hands back arrays committed to a
    device and never weak-typed, and ``jit`` keys its programs on both, so a resumed run would
    compile its step again for a state that differs only in that. An uncommitted target gets an
    uncommitted array, a weak-typed scalar (a Python number in the state) a weak-typed one; every
    other leaf is returned as orbax restored it."""
    if not isinstance(target, jax.Array) or target.committed:
        return restored
    value = np.asarray(restored)
    if target.weak_type and target.ndim == 0:
        weak = jnp.asarray(value.item())  # a Python scalar: weak-typed, the default dtype of its kind
        if weak.dtype == target.dtype:
            return weak
    return jnp.asarray(value, dtype=target.dtype)


class Checkpointer:
    """Save / restore a pytree train state under ``directory/<step>/``.

    Args:
      directory: folder of the checkpoints (created if absent; must be absolute or is made so).
      max_to_keep: keep only the latest N steps (None keeps all).
      save_interval_steps: saves at steps that are not a multiple of this are skipped (the
        final step can be forced with ``save(..., force=True)``).
    """

    def __init__(self, directory, max_to_keep: int | None = 3, save_interval_steps: int = 1):
        if max_to_keep is not None and int(max_to_keep) < 1:
            raise ValueError(f"max_to_keep: expected a positive int or None, got {max_to_keep!r}")
        if int(save_interval_steps) < 1:
            raise ValueError(f"save_interval_steps: expected a positive int, got {save_interval_steps!r}")
        self.directory = pathlib.Path(os.path.abspath(os.fspath(directory)))
        if self.directory.exists() and not self.directory.is_dir():
            raise CheckpointError(f"checkpoint directory {str(self.directory)!r} exists and is not a folder")
        options = ocp.CheckpointManagerOptions(
            max_to_keep=max_to_keep,
            create=True,
        )
        # The interval is applied here, not by orbax (which always saves the first step).
        self.save_interval_steps = int(save_interval_steps)
        with quiet_orbax():
            self._manager = ocp.CheckpointManager(self.directory, options=options)

    # -- queries ---------------------------------------------------------------------------
    def latest_step(self) -> int | None:
        """The newest complete step, or None when there is no checkpoint."""
        with quiet_orbax():
            self._manager.reload()
            return self._manager.latest_step()

    def reload(self) -> None:
        """Re-reads the steps on disk (after checkpoints were moved or deleted by hand)."""
        with quiet_orbax():
            self._manager.reload()

    def all_steps(self) -> list[int]:
        """All complete steps on disk, ascending."""
        with quiet_orbax():
            self._manager.reload()
            return sorted(int(s) for s in self._manager.all_steps())

    # -- save / restore ---------------------------------------------------------------------
    def save(self, step: int, state: Any, *, force: bool = False) -> bool:
        """Save ``state`` as ``step``; returns whether a checkpoint was written.

        Waits for the write to finish (so the step is on disk when this returns).
        """
        step = int(step)
        if step < 0:
            raise ValueError(f"step: expected a non-negative int, got {step}")
        if not force and step % self.save_interval_steps != 0:
            return False
        with quiet_orbax():  # e.g. its warning on removing the unfinished save of a killed run
            saved = self._manager.save(step, args=ocp.args.StandardSave(state), force=True)
            self._manager.wait_until_finished()
        return bool(saved)

    def restore(self, target: Any, step: int | None = None) -> Any:
        """Restore ``step`` (default: the latest) into the structure of ``target`` (its leaves as
        ``target``'s are: uncommitted and weak-typed where they are, so a jitted step does not compile
        again for the restored state).

        Raises:
          CheckpointError: no checkpoint in the directory, the step is absent, or the stored
            checkpoint is unreadable / does not match ``target``'s tree structure; the message names
            the path.
        """
        steps = self.all_steps()
        if step is None:
            if not steps:
                raise CheckpointError(f"no checkpoint found in {str(self.directory)!r}")
            step = max(steps)
        step = int(step)
        path = self.directory / str(step)
        if step not in steps:
            raise CheckpointError(
                f"checkpoint step {step} not found at {str(path)!r} (available steps: {sorted(steps)})"
            )
        try:
            with quiet_orbax():
                restored = self._manager.restore(step, args=ocp.args.StandardRestore(_abstract(target)))
        except Exception as exc:  # orbax raises many types (ValueError, KeyError, OSError, ...)
            raise CheckpointError(
                f"could not restore checkpoint {str(path)!r} (corrupt, or its tree does not match the "
                f"target): {type(exc).__name__}: {exc}"
            ) from exc
        return jax.tree.map(_like, restored, target)

    def wait_until_finished(self) -> None:
        self._manager.wait_until_finished()

    def close(self) -> None:
        """Wait for pending writes and release the manager."""
        self._manager.wait_until_finished()
        self._manager.close()

    def __enter__(self) -> Checkpointer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def save_checkpoint(directory, step: int, state: Any, max_to_keep: int | None = 3) -> None:
    """One-shot save of ``state`` as ``step`` in ``directory`` (keeps the latest ``max_to_keep``)."""
    with Checkpointer(directory, max_to_keep=max_to_keep) as ckpt:
        ckpt.save(step, state, force=True)


def restore_checkpoint(directory, target: Any, step: int | None = None) -> Any:
    """One-shot restore of ``step`` (default latest) from ``directory`` into ``target``'s structure.

    Raises CheckpointError naming the path when the folder or step is missing or unreadable.
    """
    directory = pathlib.Path(os.path.abspath(os.fspath(directory)))
    if not directory.is_dir():
        raise CheckpointError(f"checkpoint directory {str(directory)!r} does not exist")
    with Checkpointer(directory, max_to_keep=None) as ckpt:
        return ckpt.restore(target, step)


def latest_step(directory) -> int | None:
    """The newest complete step in ``directory`` (None if the folder is absent or empty)."""
    directory = pathlib.Path(os.path.abspath(os.fspath(directory)))
    if not directory.is_dir():
        return None
    with Checkpointer(directory, max_to_keep=None) as ckpt:
        return ckpt.latest_step()
