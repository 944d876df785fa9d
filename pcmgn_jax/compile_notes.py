"""A console line while a large computation compiles, so a long silence is never a hang.

    with compile_notes.first_call("the training step", key):
        out = jax.block_until_ready(train_chunk(...))

The first time ``(label, key)`` is seen in this process (``key``: whatever decides the compilation, e.g.
the static shapes), ``compiling the training step…`` is printed before the call and
``compiled the training step in 12.3 s (XLA 10.1 s)`` after it: the first call's wall time (tracing,
compiling or loading from the persistent cache, and the one run) and, in brackets, the seconds XLA
spent compiling (JAX's ``backend_compile_duration`` events; ~0 when the program came from the
persistent cache, :mod:`pcmgn_jax.compile_cache`). Later calls with the same key print nothing.

:func:`log_to` names a JSON-lines file (a training run's ``RUN/compile.jsonl``; at start-up the environment
variable ``PCMGN_COMPILE_LOG``) that gets one record per note:
``{"compile": label, "seconds": wall, "xla_seconds": ..., "time": unix time at the end}``. ``PCMGN_COMPILE_NOTES=0``
silences the console lines (records are still kept). The key must be hashable; it is the caller's
statement of what compiles, so a key that misses a static shape only loses a note, never a result.
"""
from __future__ import annotations

import json
import os
import sys
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Hashable

_seen: set = set()
_records: list[dict] = []
_xla_seconds = [0.0]
_log: list[Path | None] = [Path(os.environ["PCMGN_COMPILE_LOG"]) if os.environ.get("PCMGN_COMPILE_LOG") else None]
_listening = [False]
_XLA_EVENT = "/jax/core/compile/backend_compile_duration"


def _listen() -> None:
    if _listening[0]:
        return
    import jax

    def on_duration(event: str, duration: float, **_):
        if event == _XLA_EVENT:
            _xla_seconds[0] += float(duration)
    try:
        jax.monitoring.register_event_duration_secs_listener(on_duration)
    except AttributeError:      # a jax without monitoring: no XLA split
        pass
    _listening[0] = True


def log_to(path: str | os.PathLike | None) -> None:
    """Append each later note to the JSON-lines file ``path`` (None: console only)."""
    _log[0] = None if path is None else Path(path)


def records() -> list[dict]:
    """The notes of this process so far (label, seconds, xla_seconds, time)."""
    return [dict(r) for r in _records]


def _quiet() -> bool:
    return os.environ.get("PCMGN_COMPILE_NOTES", "1").strip().lower() in ("0", "false", "no", "off")


@contextmanager
def first_call(label: str, key: Hashable = None):
    """Around the first (blocking) call of ``label`` for ``key``: a line before and one with the seconds
    after (module docstring). The body must block until the result is ready (``jax.block_until_ready``
    or a host read), or the seconds are the dispatch only."""
    k = (label, key)
    if k in _seen:
        yield
        return
    _listen()
    if not _quiet():
        print(f"compiling {label}…", file=sys.stderr, flush=True)
    t0, x0 = time.perf_counter(), _xla_seconds[0]
    yield
    _seen.add(k)      # only once the call went through: a failed first call is noted again
    rec = {"compile": label, "seconds": round(time.perf_counter() - t0, 3),
           "xla_seconds": round(_xla_seconds[0] - x0, 3), "time": round(time.time(), 3)}
    _records.append(rec)
    if not _quiet():
        print(f"compiled {label} in {rec['seconds']:.1f} s (XLA {rec['xla_seconds']:.1f} s)",
              file=sys.stderr, flush=True)
    if _log[0] is not None:
        try:
            with open(_log[0], "a") as f:
                f.write(json.dumps(rec) + "\n")
        except OSError as err:
            print(f"note: could not append to {_log[0]}: {err}", file=sys.stderr)
