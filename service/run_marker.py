"""Whether the previous run ended cleanly: a marker file in systemd's runtime directory.

The unit's `RuntimeDirectory=jsar-service` with `RuntimeDirectoryPreserve=restart` gives the daemon a
directory (`$RUNTIME_DIRECTORY`) that survives systemd's automatic restarts but not a stop, a reboot or
a clean exit's cleanup. The daemon writes `running` there at start and removes it when it stops
cleanly; finding it at start means the previous run was killed (SIGKILL, OOM killer, watchdog abort,
a crash), so the daemon says so in its log and status. Without `$RUNTIME_DIRECTORY` (not under systemd)
nothing is written and the previous exit is "unknown".
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

MARKER_NAME = "running"
PreviousExit = Literal["unclean", "clean_or_first", "unknown"]


@dataclass(frozen=True)
class PreviousRun:
    """What the marker said at start: exit "unclean" (marker left behind), "clean_or_first" (no marker),
    "unknown" (no runtime directory); the killed run's pid and start time (Unix s) when unclean."""

    exit: PreviousExit
    pid: int | None = None
    started_unix_s: float | None = None

    def as_json(self) -> dict[str, object]:
        return {"previous_exit": self.exit, "previous_pid": self.pid, "previous_started_unix_s": self.started_unix_s}


def runtime_directory(environ: dict[str, str] | os._Environ) -> Path | None:
    """systemd's `$RUNTIME_DIRECTORY` (the first, if several are listed), None when unset or empty."""
    value = environ.get("RUNTIME_DIRECTORY", "").split(":")[0]
    return Path(value) if value else None


def read_previous(directory: Path | None) -> PreviousRun:
    """The previous run's exit as the marker in `directory` tells it (a marker unreadable or not ours is
    still a marker: unclean, pid and time unknown)."""
    if directory is None:
        return PreviousRun("unknown")
    marker = directory / MARKER_NAME
    if not marker.exists():
        return PreviousRun("clean_or_first")
    try:
        data = json.loads(marker.read_text(encoding="utf-8"))
        return PreviousRun("unclean", int(data["pid"]), float(data["started_unix_s"]))
    except (OSError, ValueError, KeyError, TypeError):
        return PreviousRun("unclean")


def mark_running(directory: Path | None, pid: int, started_unix_s: float) -> None:
    """Write the marker (replacing a stale one) atomically; nothing without a directory."""
    if directory is None:
        return
    temporary = directory / f".{MARKER_NAME}.{pid}"
    temporary.write_text(json.dumps({"pid": pid, "started_unix_s": started_unix_s}), encoding="utf-8")
    os.replace(temporary, directory / MARKER_NAME)


def mark_stopped(directory: Path | None) -> None:
    """Remove the marker at a clean stop; nothing without a directory or marker."""
    if directory is None:
        return
    try:
        (directory / MARKER_NAME).unlink()
    except FileNotFoundError:
        pass
