"""One writer per folder: an advisory lock file (``FOLDER/.lock``) held while a command writes there.

    with hold(workdir, "train"):        # LockedError (a ValueError: exit status 2) if another process holds it
        ...

The lock is ``fcntl.flock`` on ``FOLDER/.lock`` (exclusive, non-blocking): the kernel releases it when the
holder exits, however it exits (SIGKILL included), so a lock never outlives its process. The file records
the holder (JSON: pid, host, command, start time, UTC) for the message a second writer gets; a clean release
empties it. A file that still names a holder when the lock is free is a *stale* lock: that process was killed
(its pid is dead on this host) or ran on another host; the new holder takes it over and says so on stderr
(:func:`stale_holder`). A lock that is held while its recorded pid is dead on this host (a child process kept
the file open) is named as such in the refusal.

Re-entrant within a process (a study cell holds its run's lock while :func:`pcmgn_jax.train.run` takes it
again). Who locks what (docs/reliability.md): ``train`` its workdir, dataset generation and the training
cache's build their dataset folder, ``evaluate`` / ``optimize`` / ``active`` the folder they write into.
Top-level and dependency-free (standard library only). POSIX only (``fcntl``); elsewhere holding is a no-op.
"""
from __future__ import annotations

import json
import os
import socket
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

try:
    import fcntl
except ImportError:          # pragma: no cover - not POSIX: no advisory locks
    fcntl = None

LOCK_NAME = ".lock"
_held: dict[Path, list] = {}   # resolved folder -> [open file, depth]: this process's locks (re-entrant)


class LockedError(ValueError):
    """Another process holds the folder's lock (message: the folder, the holder, what to do)."""


def _alive(pid: int) -> bool:
    """Whether a process ``pid`` runs on this host (a zombie counts as running)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def read_holder(folder: str | os.PathLike, name: str = LOCK_NAME) -> dict | None:
    """The holder recorded in ``FOLDER/NAME`` ({pid, host, command, since}), or None (no file, empty, unreadable)."""
    try:
        text = (Path(folder) / name).read_text()
        info = json.loads(text) if text.strip() else None
    except (OSError, json.JSONDecodeError):
        return None
    return info if isinstance(info, dict) else None


def describe(info: dict) -> str:
    """``pid 123 on host h (command 'train ...', since 2026-12-04 16:00:00 UTC)``."""
    return (f"pid {info.get('pid')} on host {info.get('host')} (command {info.get('command')!r}, "
            f"since {info.get('since')})")


def stale_holder(folder: str | os.PathLike, name: str = LOCK_NAME) -> dict | None:
    """The recorded holder of a lock that nobody holds, or None; only meaningful while the caller holds it
    (then a recorded holder other than itself is a killed process's)."""
    info = read_holder(folder, name)
    if info is None or (info.get("pid") == os.getpid() and info.get("host") == socket.gethostname()):
        return None
    return info


def _command() -> str:
    return " ".join([Path(sys.argv[0]).name if sys.argv and sys.argv[0] else "python", *sys.argv[1:]])[:300]


@contextmanager
def hold(folder: str | os.PathLike, what: str, *, name: str = LOCK_NAME, shared: bool = False,
         wait: bool = False) -> Iterator[Path]:
    """Hold the lock ``FOLDER/NAME`` (the folder is created if missing) while the block runs; ``what`` names
    the command (``train``, ``generate`` ...) in the record. LockedError naming the folder and the holder when
    another process holds it (``wait``: block until it is free instead); a stale record (a killed holder) is
    taken over with a note on stderr. ``shared``: a reader's / co-writer's lock (several may hold it, an
    exclusive holder excludes them all); it records nothing (e.g. ``generate --shard``: each shard holds the
    dataset's lock shared and its own part's exclusively)."""
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise ValueError(f"{folder}: exists and is not a folder ({what} writes into a folder there)")
    created = _missing_top(folder)
    folder.mkdir(parents=True, exist_ok=True)
    key = folder.resolve() / name
    if key in _held:
        _held[key][1] += 1
        try:
            yield folder
        finally:
            _held[key][1] -= 1
        return
    if fcntl is None:        # pragma: no cover
        yield folder
        return
    f = open(folder / name, "a+")
    try:
        fcntl.flock(f.fileno(), (fcntl.LOCK_SH if shared else fcntl.LOCK_EX) | (0 if wait else fcntl.LOCK_NB))
    except BlockingIOError:
        f.close()
        raise LockedError(_refusal(folder, what, name)) from None
    if shared:
        _held[key] = [f, 1]
        try:
            yield folder
        finally:
            del _held[key]
            f.close()
        return
    try:
        stale = stale_holder(folder, name)
        if stale is not None:
            here = stale.get("host") == socket.gethostname()
            gone = "no longer running" if here and not _alive(int(stale.get("pid", 0))) else "not holding it"
            print(f"note: {folder}: stale lock of {describe(stale)}, {gone}; taken over (check what it left "
                  "half-done: the command resumes where it can)", file=sys.stderr)
        record = {"pid": os.getpid(), "host": socket.gethostname(), "command": f"{what}: {_command()}",
                  "since": time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime())}
        f.seek(0)
        f.truncate()
        f.write(json.dumps(record) + "\n")
        f.flush()
        _held[key] = [f, 1]
        try:
            yield folder
        except BaseException:
            if created is not None:
                _remove_if_bare(folder, name, created)
            raise
        finally:
            del _held[key]
            f.seek(0)
            f.truncate()     # released cleanly: an empty file is no stale lock
            f.flush()
    finally:
        f.close()            # closing the file releases the flock


def _missing_top(folder: Path) -> Path | None:
    """The outermost of ``folder`` and its parents that does not exist yet (what ``mkdir -p`` creates), or None."""
    top = None
    for p in (folder, *folder.parents):
        if p.exists():
            break
        top = p
    return top


def _remove_if_bare(folder: Path, name: str, created: Path) -> None:
    """A command refused inside :func:`hold` leaves nothing behind: when ``folder`` (made by this hold, up to
    ``created``) holds only its lock file, the file and the folders made for it are removed (while the lock is
    still held, so no other writer can be holding the file)."""
    try:
        if [p.name for p in folder.iterdir()] != [name]:
            return
        (folder / name).unlink()
        for p in (folder, *folder.parents):
            p.rmdir()
            if p == created:
                break
    except OSError:
        pass


def _refusal(folder: Path, what: str, name: str) -> str:
    info = read_holder(folder, name)
    if info is None:
        return (f"{folder} is in use by another process (its lock {folder / name} is held); "
                f"wait for it to finish, or run {what} on another folder")
    dead = info.get("host") == socket.gethostname() and not _alive(int(info.get("pid", 0)))
    why = (" -- that pid is no longer running, but a process it started still holds the lock file open; stop "
           "that process" if dead else "; wait for it to finish or stop it")
    return f"{folder} is in use by {describe(info)}{why} (one writer per folder; {what} refused)"
