"""The one training scaffold of jaxsem's learned models (VoluMon and LSD).

A training run lives in a *workdir*::

    workdir/config.json      the run's config (written atomically when the run starts)
    workdir/checkpoints/     orbax checkpoints of the train state (:mod:`jaxsem.checkpoint`)
    workdir/metrics.jsonl    one JSON object per logged row, each with its ``step``

:class:`TrainingRun` owns the rules every model's ``train_and_evaluate(config, workdir)`` shares:

- **resume**: when ``checkpoints/`` has a step, the run restores it and continues from there; a
  "resumed from step N" line goes to ``log``; rows of ``metrics.jsonl`` after step N (written
  after the checkpoint by an interrupted run) are dropped, so a resumed run never duplicates
  rows;
- **config check**: a config that differs from the run's ``config.json`` in any field that is
  not listed as resumable (run length, logging and evaluation settings) raises
  :class:`ConfigMismatchError` naming the fields, unless ``force=True``;
- **atomic writes**: ``config.json`` and the metrics truncation go through a temporary file and
  a rename; checkpoints are atomic in orbax;
- **progress**: :meth:`TrainingRun.steps` is the step iterator, with a tqdm bar over the run's
  total when asked.

The loop itself stays in the model's module (its train step, data and evaluation differ), in
this shape::

    with TrainingRun(workdir, config_json, keep=3, resumable=RESUMABLE, force=force, log=log) as run:
        state = init_state(config)
        if run.latest_step is not None:
            state = run.restore(state)
        for step in run.steps(run.start, end, total=config.num_steps, desc="model"):
            state, terms = train_step(state)
            run.log_metrics({"step": step + 1, **terms})
            if (step + 1) % every == 0 or step + 1 == end:
                run.save(step + 1, state)
"""

from __future__ import annotations

import dataclasses
import json
import os
import pathlib
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from typing import Any

import numpy as np

from .checkpoint import Checkpointer

__all__ = ["ConfigMismatchError", "TrainingRun", "config_json", "read_metrics"]


class ConfigMismatchError(ValueError):
    """A resumed run's config differs from the one its checkpoints were trained with."""


def config_json(config: Any) -> dict[str, Any]:
    """A frozen-dataclass config as plain JSON types (tuples as lists, other values as ``str``)."""
    if dataclasses.is_dataclass(config) and not isinstance(config, type):
        config = dataclasses.asdict(config)
    if not isinstance(config, Mapping):
        raise ValueError(f"config: expected a dataclass or a mapping, got {type(config).__name__}")
    return json.loads(json.dumps(config, default=str))


def _write_atomic(path: pathlib.Path, text: str) -> None:
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    tmp.write_text(text)
    tmp.replace(path)


def read_metrics(path: str | os.PathLike) -> list[dict[str, Any]]:
    """The rows of a ``metrics.jsonl`` (or of the workdir holding one); unreadable lines skipped."""
    path = pathlib.Path(path)
    if path.is_dir():
        path = path / "metrics.jsonl"
    if not path.exists():
        return []
    rows = []
    for line in path.read_text().splitlines():
        try:
            row = json.loads(line)
        except ValueError:
            continue
        if isinstance(row, dict):
            rows.append(row)
    return rows


def _flatten(d: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in d.items():
        name = f"{prefix}{k}"
        if isinstance(v, Mapping):
            out.update(_flatten(v, name + "."))
        else:
            out[name] = v
    return out


class TrainingRun:
    """One training run in ``workdir``: config check, resume, metrics, checkpoints, progress.

    Args:
      workdir: the run's folder (created).
      config: the run's config as JSON types (:func:`config_json`).
      keep: checkpoints kept (the latest ``keep`` steps).
      resumable: top-level config fields that may differ between the chunks of one run.
      force: resume even when another field differs (the new config is written).
      normalise: maps a ``config.json`` read from disk to the current config schema (e.g. through
        the dataclass, so that fields added since the run was written take their defaults)
        before it is compared; exceptions in it are ignored (the raw file is compared).
      log: called with one line on resume (and by the model's loop for its rows).
    """

    def __init__(
        self,
        workdir: str | os.PathLike,
        config: Mapping[str, Any],
        *,
        keep: int | None = 3,
        resumable: Sequence[str] = (),
        force: bool = False,
        normalise: Callable[[dict[str, Any]], Mapping[str, Any]] | None = None,
        log: Callable[[str], None] | None = None,
    ):
        self.workdir = pathlib.Path(workdir)
        self.workdir.mkdir(parents=True, exist_ok=True)
        self.config = dict(config)
        self.resumable = tuple(resumable)
        self.force = bool(force)
        self.normalise = normalise
        self.log = log
        self.metrics_path = self.workdir / "metrics.jsonl"
        self._ckpt = Checkpointer(self.workdir / "checkpoints", max_to_keep=keep)
        self.latest_step: int | None = self._ckpt.latest_step()
        self.start = 0
        self._metrics_file = None
        self._bar = None
        if self.latest_step is not None:
            try:
                self.check_config()
            except ConfigMismatchError:
                self._ckpt.close()
                raise

    # ------------------------------------------------------------------ config

    def check_config(self) -> None:
        """Raise :class:`ConfigMismatchError` when ``config.json`` differs outside ``resumable``."""
        path = self.workdir / "config.json"
        if not path.exists() or self.force:
            return
        try:
            old = json.loads(path.read_text())
        except (OSError, ValueError) as exc:
            raise ConfigMismatchError(
                f"{path}: cannot read the run's config ({exc}); pass force=True / --force to overwrite"
            ) from exc
        if self.normalise is not None and isinstance(old, dict):
            try:
                old = json.loads(json.dumps(self.normalise(old), default=str))
            except (TypeError, ValueError, KeyError):
                pass
        if not isinstance(old, dict):
            raise ConfigMismatchError(f"{path}: expected a JSON object; pass force=True / --force to overwrite")
        new = self.config
        diff = sorted(k for k in set(old) | set(new) if k not in self.resumable and old.get(k) != new.get(k))
        if diff:
            parts = []
            for k in diff:
                a, b = old.get(k), new.get(k)
                if isinstance(a, Mapping) and isinstance(b, Mapping):  # name the nested fields that differ
                    fa, fb = _flatten(a, k + "."), _flatten(b, k + ".")
                    for f in sorted(x for x in set(fa) | set(fb) if fa.get(x) != fb.get(x)):
                        parts.append(f"{f}: checkpoint {fa.get(f)!r}, now {fb.get(f)!r}")
                else:
                    parts.append(f"{k}: checkpoint {a!r}, now {b!r}")
            raise ConfigMismatchError(
                f"{path}: the config differs from the one the checkpoints in {self.workdir / 'checkpoints'} were "
                f"trained with ({'; '.join(parts)}); use another workdir, or force=True / --force to resume anyway"
            )

    def write_config(self) -> None:
        _write_atomic(self.workdir / "config.json", json.dumps(self.config, indent=1))

    # ------------------------------------------------------------------ state

    def restore(self, like: Any, step: int | None = None) -> Any:
        """The checkpoint of ``step`` (default: the latest) restored into the structure of ``like``;
        sets :attr:`start`, cuts ``metrics.jsonl`` back to it and logs "resumed from step N"."""
        step = self.latest_step if step is None else int(step)
        if step is None:
            raise ValueError(f"workdir: no checkpoint under {str(self.workdir / 'checkpoints')!r}")
        state = self._ckpt.restore(like, step=step)
        self.start = step
        self._truncate_metrics(step)
        if self.log is not None:
            self.log(f"resumed from step {step}")
        return state

    def begin(self) -> None:
        """Start writing: a fresh run drops any stale ``metrics.jsonl``; ``config.json`` is written."""
        if self.start == 0:
            self._truncate_metrics(0)
        self.write_config()

    def save(self, step: int, state: Any) -> None:
        """Checkpoint ``state`` as ``step`` (atomic; waits for the write)."""
        self._ckpt.save(int(step), state, force=True)

    # ------------------------------------------------------------------ metrics

    def _truncate_metrics(self, step: int) -> None:
        if not self.metrics_path.exists():
            return
        keep = []
        for line in self.metrics_path.read_text().splitlines():
            try:
                if int(json.loads(line).get("step", 0)) <= step:
                    keep.append(line)
            except (ValueError, AttributeError, TypeError):
                continue
        _write_atomic(self.metrics_path, "".join(x + "\n" for x in keep))

    def log_metrics(self, row: Mapping[str, Any]) -> None:
        """Append one row (it must have a ``step``) to ``metrics.jsonl`` and flush it."""
        if "step" not in row:
            raise ValueError(f"row: expected a 'step' key, got keys {sorted(row)}")
        if self._metrics_file is None:
            self._metrics_file = open(self.metrics_path, "a")
        self._metrics_file.write(json.dumps(dict(row), default=_json_number) + "\n")
        self._metrics_file.flush()

    def metrics(self) -> list[dict[str, Any]]:
        """All rows of this run's ``metrics.jsonl`` (previous chunks included)."""
        if self._metrics_file is not None:
            self._metrics_file.flush()
        return read_metrics(self.metrics_path)

    # ------------------------------------------------------------------ loop

    def steps(self, start: int, end: int, *, total: int, desc: str, progress: bool = True) -> Iterator[int]:
        """``range(start, end)``, with a tqdm bar over ``total`` steps when ``progress``."""
        it: Iterable[int] = range(int(start), int(end))
        if progress:
            from tqdm.auto import tqdm

            self._bar = tqdm(it, initial=int(start), total=int(total), desc=desc, leave=False)
            it = self._bar
        yield from it

    def postfix(self, values: Mapping[str, Any]) -> None:
        """Show ``values`` after the progress bar (no-op without one)."""
        if self._bar is not None:
            self._bar.set_postfix({k: (f"{v:.3g}" if isinstance(v, float) else v) for k, v in values.items()})

    def write(self, line: str) -> None:
        """Pass ``line`` to ``log``; without one, print it above the progress bar (if any)."""
        if self.log is not None:
            self.log(line)
        elif self._bar is not None:
            self._bar.write(line)

    def close(self) -> None:
        if self._metrics_file is not None:
            self._metrics_file.close()
            self._metrics_file = None
        if self._bar is not None:
            self._bar.close()
            self._bar = None
        self._ckpt.close()

    def __enter__(self) -> TrainingRun:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _json_number(x: Any) -> Any:
    if isinstance(x, np.generic | np.ndarray):
        return x.tolist()
    return str(x)
