"""Whether a process recorded in a file (a lock's holder, a staging folder's owner) still runs:
one check for the training lock and the data fetcher (private to jaxsem)."""

from __future__ import annotations

import os
import pathlib


def process_start(pid: int) -> int | None:
    """The start time of process ``pid`` in clock ticks since boot (Linux ``/proc``), else None."""
    try:
        stat = pathlib.Path(f"/proc/{pid}/stat").read_text()
        return int(stat.rsplit(")", 1)[1].split()[19])  # field 22; the name in (...) may hold spaces
    except (OSError, ValueError, IndexError):
        return None


def process_alive(pid: int, proc_start: object = None) -> bool:
    """Whether process ``pid`` of this host is running (and is the one that wrote the record, when
    its start time was recorded: a reused pid is not the same process)."""
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        pass  # it exists, owned by another user
    try:  # a zombie (exited, not yet reaped) holds nothing
        if pathlib.Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] == "Z":
            return False
    except (OSError, IndexError):
        pass
    now = process_start(pid)
    return not (isinstance(proc_start, int) and now is not None and now != proc_start)
