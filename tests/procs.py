"""Child processes, read from Linux's ``/proc`` (for the tests that a command's workers start, ignore a
Ctrl-C and die with their parent)."""

from __future__ import annotations

from pathlib import Path


def children(pid: int, cmdline_has: bytes | None = None, live_only: bool = False) -> set[int]:
    """The child processes of ``pid``; with ``cmdline_has``, those whose command line holds it (a pool's
    worker: ``b"spawn_main"``, not multiprocessing's resource tracker); ``live_only``: no zombies."""
    out = set()
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
            if int(fields[1]) != pid or (live_only and fields[0] == "Z"):
                continue
            if cmdline_has is not None and cmdline_has not in (stat.parent / "cmdline").read_bytes():
                continue
        except OSError:
            continue
        out.add(int(stat.parent.name))
    return out


def running(pid: int) -> bool:
    """Whether the process ``pid`` exists and is not a zombie."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False
