"""What every jaxsem command shares: one-line errors, checked flags, atomic outputs.

A command (``jaxsem ...``, ``train/*.py``, ``infer/*.py``, ``benchmarks/*.py``) follows these rules:

1. **Bad input fails well.** It exits non-zero with one line naming the flag or file and what
   was wrong; no traceback unless ``--debug`` is given. :func:`run_main` does this for a
   ``main(argv) -> int`` function: :class:`UsageError`, ``ValueError``, ``OSError`` (missing or
   unreadable files), ``json.JSONDecodeError``, ``zipfile.BadZipFile`` and ``KeyError`` become
   ``<prog>: error: <message>`` and exit status 2.
2. **Validate before long work.** The ``argparse`` types below (:func:`positive_int`,
   :func:`probability`, :func:`existing_file`, ...) reject a bad flag while parsing, naming it.
3. **Outputs are atomic.** :func:`atomic_write_text`, :func:`atomic_write_bytes`,
   :func:`atomic_savefig` and :func:`atomic_save_npz` write to a temporary name next to the
   target and rename it into place, so a failed run leaves nothing half-written.
4. **Every run is recorded.** A command's parser comes from :func:`command_parser` (the shared
   ``--run-dir``, ``--no-compilation-cache`` and ``--debug`` flags); ``jaxsem.cli`` starts a
   :class:`Run` around it (:func:`start_run`): a run directory named at the start and printed as
   the first line, holding ``config.json`` (every argument after defaults, versions, the command
   line) and, at the end, ``summary.json`` (status, wall time, headline numbers, figures and
   outputs; status ``"error"`` and the one-line message when the run failed). The command reports
   its headline numbers with :func:`record`; what it writes through the atomic helpers is listed
   in the summary by itself (figures under ``figures``, other files under ``outputs``).
5. **No flag copied by hand.** Any config field is settable with ``--set KEY=VALUE``; the few
   convenience flags a command offers for config fields (``--steps``, ``--batch-size``, ...)
   are made by :func:`add_config_flags` from the config dataclass (type, help text, default) and
   applied by :func:`apply_config_flags` through :func:`jaxsem.config.override`, the path of
   ``--set``, so the config's own checks and the one-line errors naming the flag are shared.
   :func:`add_config_flags` adds ``--set`` itself, once per parser, so every command with a
   config (``roshan``, ``volumon train``, ``lsd data``, ``lsd train``, ``lsd plan``, the door
   trainer) takes it the same way.

What a command calls, by job:

- errors and the entry point: :class:`UsageError`, :func:`run_main`, :class:`HelpFormatter`;
- checked flags: :func:`positive_int`, :func:`nonnegative_int`, :func:`positive_float`,
  :func:`nonnegative_float`, :func:`finite_float`, :func:`probability`,
  :func:`positive_probability`, :func:`int_list`, :func:`image_size`, :func:`existing_file`, :func:`existing_dir`,
  :func:`existing_path`, :func:`output_file`, :func:`output_dir`, :func:`add_devices_argument`,
  :func:`add_force_argument`, :func:`devices_mesh`;
- config flags: :class:`ConfigFlag`, :func:`add_config_flags`, :func:`apply_config_flags`;
- atomic outputs: :func:`atomic_write_text`, :func:`atomic_write_bytes`, :func:`atomic_savefig`,
  :func:`atomic_save_npz`, :func:`save_step_figure`;
- runs: :func:`command_parser`, :class:`Run`, :func:`start_run`, :func:`default_run_dir`,
  :func:`active_run`, :func:`record`, :func:`record_config`, :func:`record_output`.

The rest (the parser class, the run-directory variable, the ``--set`` helpers, ...) stays
importable from the private modules, e.g. ``jaxsem.scripting._runs``, for tests.
"""

from __future__ import annotations

from .._atomic import (
    atomic_save_npz as atomic_save_npz,
    atomic_savefig as atomic_savefig,
    atomic_write_bytes as atomic_write_bytes,
    atomic_write_text as atomic_write_text,
)
from ._arguments import (
    add_devices_argument as add_devices_argument,
    add_force_argument as add_force_argument,
    devices_mesh as devices_mesh,
    existing_dir as existing_dir,
    existing_file as existing_file,
    existing_path as existing_path,
    finite_float as finite_float,
    image_size as image_size,
    int_list as int_list,
    nonnegative_float as nonnegative_float,
    nonnegative_int as nonnegative_int,
    output_dir as output_dir,
    output_file as output_file,
    positive_float as positive_float,
    positive_int as positive_int,
    positive_probability as positive_probability,
    probability as probability,
)
from ._config_flags import (
    ConfigFlag as ConfigFlag,
    add_config_flags as add_config_flags,
    apply_config_flags as apply_config_flags,
)
from ._errors import (
    HelpFormatter as HelpFormatter,
    UsageError as UsageError,
    run_main as run_main,
)
from ._figures import save_step_figure as save_step_figure
from ._runs import (
    Run as Run,
    active_run as active_run,
    command_parser as command_parser,
    default_run_dir as default_run_dir,
    record as record,
    record_config as record_config,
    record_output as record_output,
    start_run as start_run,
)

__all__ = [
    "UsageError",
    "run_main",
    "HelpFormatter",
    "positive_int",
    "nonnegative_int",
    "positive_float",
    "nonnegative_float",
    "finite_float",
    "probability",
    "positive_probability",
    "existing_file",
    "existing_dir",
    "existing_path",
    "output_dir",
    "output_file",
    "int_list",
    "ConfigFlag",
    "add_config_flags",
    "apply_config_flags",
    "atomic_write_text",
    "atomic_write_bytes",
    "atomic_savefig",
    "save_step_figure",
    "atomic_save_npz",
    "command_parser",
    "Run",
    "start_run",
    "active_run",
    "record",
    "record_config",
    "record_output",
    "default_run_dir",
]
