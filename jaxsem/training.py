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
- **one writer**: opening the run takes ``workdir/train.lock`` (:class:`WorkdirLock`: created with
  ``O_CREAT | O_EXCL``, holding the process id, host and start time) and :meth:`TrainingRun.close`
  releases it, also when the run raised; a second run on the same workdir raises
  :class:`WorkdirLockedError` naming the folder and the holder (pid, host), and a lock left by a
  process that is gone (same host, ``kill -9``, a crash) is taken over with a one-line notice (in
  a multi-host job, whose processes share the workdir, process 0 holds it); a lock file that holds
  no lock record (garbage, not UTF-8) is refused naming it and left in place;
- **corrupt checkpoints**: when the newest checkpoint cannot be read, :meth:`TrainingRun.restore`
  falls back to the newest readable one, saying so in one line that names the skipped checkpoint
  (moved aside to ``workdir/corrupt_checkpoints/``, so the run can save that step again);
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
import datetime
import json
import os
import pathlib
import shutil
import socket
import sys
import time
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from typing import Any, NamedTuple, TypeVar

import jax
import jax.numpy as jnp
import numpy as np

from ._files import check_npz, read_json
from ._process import process_alive as _alive, process_start as _proc_start
from .checkpoint import Checkpointer, CheckpointError

_Config = TypeVar("_Config")

__all__ = [
    "ConfigMismatchError",
    "TrainingRun",
    "WorkdirLock",
    "WorkdirLockedError",
    "config_json",
    "load_run_config",
    "read_exported",
    "read_metrics",
    "read_run_config",
]


class LoadedModel(NamedTuple):
    """A trained model as every loader returns it (:func:`jaxsem.volumon.load_pretrained`,
    :func:`jaxsem.lsd.load_model`): unpack it (``model, variables, config, meta = ...``) or read
    its fields.

    model: the flax module; variables: its parameters (VoluMon: ``params`` and ``batch_stats``;
    LSD: the parameter tree, also ``.params``); config: the training config it was made with;
    meta: where it came from (``name``, ``step`` where known, and what the export recorded).
    """

    model: Any
    variables: Any
    config: Any
    meta: dict

    @property
    def params(self):
        """``variables`` under the name LSD's code uses."""
        return self.variables


class ConfigMismatchError(ValueError):
    """A resumed run's config differs from the one its checkpoints were trained with."""


class WorkdirLockedError(ValueError):
    """Another live training run holds the workdir's lock (the message names it: pid, host)."""


LOCK_NAME = "train.lock"


class WorkdirLock:
    """The lock of one training workdir: ``workdir/train.lock``, made with ``O_CREAT | O_EXCL``
    (atomic: of two runs starting at once exactly one creates it) and holding JSON with the
    holder's ``pid``, ``host``, ``started`` (UTC) and command line.

    :meth:`acquire` raises :class:`WorkdirLockedError` naming the folder and the holder while
    that process runs (or runs on another host, where it cannot be checked); a lock whose process
    is gone (same host) is stale and is taken over, with a one-line notice to ``notice``.
    :meth:`release` removes the file if it is still this process's lock.
    """

    def __init__(self, workdir: str | os.PathLike, notice: Callable[[str], None] | None = None):
        self.workdir = pathlib.Path(workdir)
        self.path = self.workdir / LOCK_NAME
        self.notice = notice
        self.held = False
        self._text = ""

    def _file_text(self) -> str:
        """The lock file's content as text (bytes that are not UTF-8 escaped, never an error)."""
        return self.path.read_bytes().decode("utf-8", "backslashreplace")

    def _read(self) -> tuple[dict[str, Any], str] | None:
        """The holder's record and the file's text; None when the file vanished. Retries briefly
        while the file is empty or unreadable (created, not written yet); then an empty file gives
        ``{"empty": ""}`` (a holder killed between creating and writing it) and anything else
        that is not a lock record (not UTF-8, not JSON, no pid) ``{"unreadable": ...}``."""
        text = ""
        for _ in range(10):
            try:
                text = self._file_text()
            except FileNotFoundError:
                return None
            except OSError as exc:
                raise WorkdirLockedError(
                    f"workdir {str(self.workdir)!r}: cannot read the lock file {str(self.path)!r} "
                    f"({exc.strerror or exc})"
                ) from None
            try:
                info = json.loads(text)
                if isinstance(info, dict) and isinstance(info.get("pid"), int):
                    return info, text
            except ValueError:
                pass
            time.sleep(0.05)
        return ({"empty": ""} if not text else {"unreadable": text[:80]}), text

    def acquire(self) -> WorkdirLock:
        """Takes the lock (see the class); returns self."""
        host = socket.gethostname()
        record = {
            "pid": os.getpid(),
            "host": host,
            "started": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
            "proc_start": _proc_start(os.getpid()),
            "command": " ".join(sys.argv)[:300],
        }
        self._text = json.dumps(record)
        stale = ""
        for _ in range(5):
            try:
                fd = os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
            except FileExistsError:
                got = self._read()
                if got is None:
                    continue  # released meanwhile: try again
                info, text = got
                if "unreadable" in info:
                    # Not a record this class writes: whose it is cannot be known, so it is not
                    # removed (an empty file is: the trace of a holder killed mid-creation).
                    raise WorkdirLockedError(
                        f"workdir {str(self.workdir)!r}: the lock file {str(self.path)!r} is not a training "
                        f"run's lock record (content {info['unreadable']!r}); delete it if no run uses this workdir"
                    )
                if "empty" in info:
                    holder, why = "an empty lock file", "its writer stopped before writing it"
                else:
                    holder = f"pid {info['pid']} on host {info.get('host')}"
                    if info.get("started"):
                        holder += f", started {info['started']}"
                    if info.get("host") != host:
                        raise WorkdirLockedError(
                            f"workdir {str(self.workdir)!r}: another training run holds it ({holder}; lock file "
                            f"{str(self.path)!r}); use another --workdir, or delete the lock file if that run is gone"
                        )
                    if _alive(info["pid"], info.get("proc_start")):
                        raise WorkdirLockedError(
                            f"workdir {str(self.workdir)!r}: another training run is writing here ({holder}); wait "
                            f"for it to finish or use another --workdir (lock file {str(self.path)!r})"
                        )
                    why = "that process is gone"
                try:  # stale: remove it, unless it changed meanwhile (then judge again)
                    if self._file_text() != text:
                        continue
                    self.path.unlink()
                except FileNotFoundError:
                    pass
                stale = f"workdir {str(self.workdir)!r}: took over the stale lock of {holder} ({why})"
                continue
            with os.fdopen(fd, "w") as f:
                f.write(self._text)
            self.held = True
            if stale and self.notice is not None:
                self.notice(stale)
            return self
        raise WorkdirLockedError(
            f"workdir {str(self.workdir)!r}: could not take the lock {str(self.path)!r} (other runs keep taking it)"
        )

    def release(self) -> None:
        if not self.held:
            return
        self.held = False
        try:
            if self._file_text() == self._text:  # still ours (not taken over as stale)
                self.path.unlink()
        except FileNotFoundError:
            pass

    def __enter__(self) -> WorkdirLock:
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()


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


def tree_digest(tree: Any) -> str:
    """SHA-256 (hex, 16 characters) of a pytree's leaves: their dtypes, shapes and bytes, in order.
    Files (``pathlib.Path`` leaves) count by their content. What a stamp records for inputs such
    as a map or a model's parameters."""
    import hashlib

    import numpy as np

    h = hashlib.sha256()
    for leaf in jax.tree_util.tree_leaves(tree):
        if isinstance(leaf, pathlib.PurePath):
            with open(leaf, "rb") as f:
                for chunk in iter(lambda: f.read(1 << 20), b""):
                    h.update(chunk)
            continue
        a = np.ascontiguousarray(np.asarray(leaf))
        h.update(f"{a.dtype.str}{a.shape}".encode())
        h.update(a.tobytes() if a.dtype != object else repr(a.tolist()).encode())
    return h.hexdigest()[:16]


def stamp_differences(made: Mapping[str, Any], now: Mapping[str, Any]) -> list[str]:
    """``"field: made with A, now B"`` for every (nested, dotted) field in which two stamps differ."""
    a = _flatten(json.loads(json.dumps(made, default=str)))
    b = _flatten(json.loads(json.dumps(now, default=str)))
    return [f"{k}: made with {a.get(k)!r}, now {b.get(k)!r}" for k in sorted(set(a) | set(b)) if a.get(k) != b.get(k)]


def check_stamp(path: str | os.PathLike, stamp: Mapping[str, Any], *, adopt: bool = False, hint: str = "") -> None:
    """Guards a resumable output (a folder of chunks or shards that a rerun skips) against inputs
    that changed: the first call writes ``stamp`` (the inputs and settings that make the output,
    as JSON) to ``path``; a later call with a different stamp raises :class:`ConfigMismatchError`
    naming each field that differs, so that no rerun mixes results made under other settings.

    adopt: when ``path`` is missing but its folder already holds output (made before stamps were
      kept), write the stamp rather than refuse. hint: what the user can do, appended to the error.
    """
    path = pathlib.Path(path)
    if not path.exists():
        if not adopt and path.parent.is_dir() and any(p.name != path.name for p in path.parent.iterdir()):
            raise ConfigMismatchError(
                f"{path.parent}: holds output with no record of the settings that made it ({path.name} is missing)"
                + (f"; {hint}" if hint else "")
            )
        path.parent.mkdir(parents=True, exist_ok=True)
        _write_atomic(path, json.dumps(stamp, indent=1, sort_keys=True, default=str))
        return
    try:  # bounded, and one line naming the file for a stamp that is not UTF-8 or not JSON
        made = read_json(path, "record of settings")
    except ValueError as exc:
        raise ConfigMismatchError(str(exc)) from None
    if not isinstance(made, dict):
        raise ConfigMismatchError(f"{path}: expected a JSON object of settings")
    diff = stamp_differences(made, stamp)
    if diff:
        raise ConfigMismatchError(
            f"{path.parent}: was made with other settings ({'; '.join(diff)})" + (f"; {hint}" if hint else "")
        )


def read_run_config(workdir: str | os.PathLike) -> dict[str, Any]:
    """The ``config.json`` of a training ``workdir`` as a dict.

    Raises:
      ValueError: naming the file when it is missing (not a training workdir), cannot be read,
        is not UTF-8 or not JSON, or is not a JSON object.
    """
    path = pathlib.Path(workdir) / "config.json"
    if not path.is_file():
        raise ValueError(f"workdir: no config.json in {str(workdir)!r} (not a training workdir)")
    config = read_json(path, "training run's config")
    if not isinstance(config, dict):
        raise ValueError(f"{path}: expected a JSON object of config fields, got {type(config).__name__}")
    return config


def load_run_config(workdir: str | os.PathLike, from_dict: Callable[[dict[str, Any]], _Config], kind: str) -> _Config:
    """The config of a training ``workdir``: its ``config.json`` (:func:`read_run_config`) built
    by ``from_dict`` (a method's ``config_from_dict``); a ``ValueError`` naming the file says it
    is not ``kind`` (e.g. "an LSD TrainConfig") when ``from_dict`` refuses its fields."""
    raw = read_run_config(workdir)
    try:
        return from_dict(raw)
    except (TypeError, ValueError, KeyError) as exc:
        raise ValueError(f"{pathlib.Path(workdir) / 'config.json'}: not {kind} ({exc})") from None


def read_exported(
    path: pathlib.Path, from_dict: Callable[[dict[str, Any]], _Config]
) -> tuple[_Config, dict[str, Any], dict[str, Any]]:
    """``(config, variables, meta)`` of an exported model: ``path`` (a ``.npz`` of the variables,
    each leaf under its ``"a/b/c"`` tree path) and the ``.json`` beside it (``meta``, whose
    ``config`` entry ``from_dict`` builds). The archive's declared sizes are checked before
    anything is inflated; the variables come back as the nested tree of jax arrays.

    Raises:
      ValueError: naming the JSON file when it is not an object with a ``config`` object, or
        naming the archive when its sizes are over budget.
    """
    meta_path = path.with_suffix(".json")
    meta = read_json(meta_path, "model description")
    if not isinstance(meta, dict) or not isinstance(meta.get("config"), dict):
        raise ValueError(f"{meta_path}: expected a JSON object with the model's 'config'")
    config = from_dict(meta["config"])
    check_npz(path)
    variables: dict[str, Any] = {}
    with np.load(path) as z:
        for name in z.files:
            node = variables
            *parents, leaf = name.split("/")
            for part in parents:
                node = node.setdefault(part, {})
            node[leaf] = jnp.asarray(z[name])
    return config, variables, meta


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
      log: called with one line on resume (and by the model's loop for its rows); the notices of a
        stale lock taken over or a corrupt checkpoint skipped go to it too (without it: stderr).

    Raises:
      WorkdirLockedError: another live run holds ``workdir`` (:class:`WorkdirLock`).
      ConfigMismatchError: see :meth:`check_config`.
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
        self.log = log
        self._lock = WorkdirLock(self.workdir, notice=self._notice)
        if _process_index() == 0:  # a multi-host job shares one workdir: its process 0 holds the lock
            self._lock.acquire()
        try:
            self._open(config, keep, resumable, force, normalise)
        except BaseException:
            self._lock.release()
            raise

    def _open(self, config, keep, resumable, force, normalise) -> None:
        self.config = dict(config)
        self.resumable = tuple(resumable)
        self.force = bool(force)
        self.normalise = normalise
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

    def _notice(self, line: str) -> None:
        if self.log is not None:
            self.log(line)
        else:
            print(line, file=sys.stderr, flush=True)

    # ------------------------------------------------------------------ config

    def check_config(self) -> None:
        """Raise :class:`ConfigMismatchError` when ``config.json`` differs outside ``resumable``."""
        path = self.workdir / "config.json"
        if not path.exists() or self.force:
            return
        try:
            old = read_json(path, "training run's config")
        except ValueError as exc:
            raise ConfigMismatchError(
                f"cannot read the run's config: {exc}; pass force=True / --force to overwrite"
            ) from None
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
        """The checkpoint of ``step`` (default: the latest readable one) restored into the structure
        of ``like`` (a pytree, or a function of the step giving one); sets :attr:`start` and
        :attr:`latest_step`, cuts ``metrics.jsonl`` back to it and logs "resumed from step N".

        Without ``step``, a checkpoint that cannot be read (corrupt, truncated) is skipped for the
        next older one, with one line naming it; skipped checkpoints newer than the one restored
        are moved to ``workdir/corrupt_checkpoints/`` (so the run can write those steps again).
        When none can be read, the newest one's :class:`jaxsem.checkpoint.CheckpointError` is
        raised and nothing is moved."""
        if step is not None:
            steps = [int(step)]
        else:
            steps = sorted(self._ckpt.all_steps(), reverse=True)
            if not steps:
                raise ValueError(f"workdir: no checkpoint under {str(self.workdir / 'checkpoints')!r}")
        failures: list[tuple[int, CheckpointError]] = []
        for s in steps:
            try:
                state = self._ckpt.restore(like(s) if callable(like) else like, step=s)
            except CheckpointError as exc:
                if step is not None:
                    raise
                failures.append((s, exc))
                continue
            break
        else:
            raise failures[0][1]
        for bad, exc in failures:
            self._notice(f"{self._set_aside(bad)}; resuming from step {s} ({_short(exc)})")
        if failures:
            self._ckpt.reload()  # the steps moved aside can be saved again
        self.start = self.latest_step = s
        self._truncate_metrics(s)
        if self.log is not None:
            self.log(f"resumed from step {s}")
        return state

    def _set_aside(self, step: int) -> str:
        """Moves the unreadable checkpoint of ``step`` to ``corrupt_checkpoints/``; says so."""
        src = self._ckpt.directory / str(step)
        dst = self.workdir / "corrupt_checkpoints" / str(step)
        n = 1
        while dst.exists():
            dst = dst.with_name(f"{step}.{n}")
            n += 1
        try:
            dst.parent.mkdir(exist_ok=True)
            shutil.move(str(src), str(dst))
        except OSError as exc:
            return f"checkpoint {str(src)!r} is unreadable, skipped (could not move it aside: {exc})"
        return f"checkpoint {str(src)!r} is unreadable, skipped and moved to {str(dst)!r}"

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
            from tqdm.auto import tqdm  # deferred: tqdm.auto is slow to import; only a run with a progress bar needs it

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
        """Closes the metrics file and the progress bar, waits for checkpoint writes and releases
        the workdir's lock (also when one of these fails)."""
        try:
            if self._metrics_file is not None:
                self._metrics_file.close()
                self._metrics_file = None
            if self._bar is not None:
                self._bar.close()
                self._bar = None
            self._ckpt.close()
        finally:
            self._lock.release()

    def __enter__(self) -> TrainingRun:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _process_index() -> int:
    return jax.process_index()


def _short(exc: BaseException, limit: int = 160) -> str:
    """The first words of an exception's message, on one line (orbax's can run to pages)."""
    text = " ".join(str(exc).split())
    text = text.split(": ", 1)[-1] if text.startswith("could not restore checkpoint") else text
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _json_number(x: Any) -> Any:
    if isinstance(x, np.generic | np.ndarray):
        return x.tolist()
    return str(x)
