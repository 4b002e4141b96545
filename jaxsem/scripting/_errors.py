"""One-line errors for commands: :class:`UsageError`, :func:`run_main` (rule 1 of
:mod:`jaxsem.scripting`)."""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import sys
import zipfile
from collections.abc import Callable, Sequence


class UsageError(Exception):
    """Bad input found by a command: its message names the flag or file and what was wrong."""


class HelpFormatter(argparse.ArgumentDefaultsHelpFormatter, argparse.RawDescriptionHelpFormatter):
    """``--help`` that keeps the description's line breaks and shows every default (except on a
    required flag, which has none, and where the help text already says what the default is)."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        text = action.help or ""
        if action.required or "default" in text.lower():
            return text
        return super()._get_help_string(action)


_EXPECTED = (UsageError, ValueError, OSError, json.JSONDecodeError, zipfile.BadZipFile, KeyError)


def wants_debug(argv: Sequence[str] | None = None) -> bool:
    """True if ``--debug`` is among the arguments (or ``JAXSEM_DEBUG=1`` is set)."""
    argv = sys.argv[1:] if argv is None else argv
    return "--debug" in argv or os.environ.get("JAXSEM_DEBUG") == "1"


def _one_line(exc: BaseException) -> str:
    if isinstance(exc, KeyError) and exc.args:
        text = f"missing key {exc.args[0]!r}"
    elif isinstance(exc, FileNotFoundError) and exc.filename:
        text = f"{exc.filename}: no such file or directory"
    elif isinstance(exc, OSError) and exc.filename:
        text = f"{exc.filename}: {exc.strerror or exc}"
    else:
        text = str(exc) or type(exc).__name__
    return " ".join(text.split())


def run_main(
    main: Callable[[Sequence[str] | None], int | None], argv: Sequence[str] | None = None, prog: str | None = None
) -> int:
    """Runs ``main(argv)`` and turns expected failures into one line on stderr and an exit status.

    The one rule of every command: exit status 2 for bad usage or input (a flag, a file, a
    value; the line names it), 1 for a failure during the work itself (an exception whose
    ``exit_status`` attribute is 1, e.g. a registry that cannot be reached), 130 when
    interrupted. ``--debug`` (or ``JAXSEM_DEBUG=1``) re-raises with the full traceback.
    ``SystemExit`` from argparse passes through (it already printed its one-line usage error); a
    ``SystemExit`` carrying a message is printed and exits 2 (commands raise it for bad input).
    Returns the exit status (call as ``sys.exit(run_main(main))``).
    """
    prog = prog or pathlib.Path(sys.argv[0]).name
    try:
        status = main(argv)
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return 130
    except _EXPECTED as exc:
        if wants_debug(argv):
            raise
        print(f"{prog}: error: {_one_line(exc)}", file=sys.stderr)
        return int(getattr(exc, "exit_status", 2))
    except SystemExit as exc:
        if not isinstance(exc.code, str):
            raise
        print(exc.code, file=sys.stderr)
        return 2
    return int(status or 0)
