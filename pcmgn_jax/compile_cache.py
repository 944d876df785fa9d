"""JAX's persistent compilation cache, on by default for every entry point.

A compiled XLA program is written to a per-user folder and read back by the next process that compiles
the same program (same jax/jaxlib, backend, shapes, flags), so a second run of a command skips most of
its compilation: on a GPU the project's first training step, validation rollout and solver call each
took 15-70 s to compile (docs/gpu.md).

:func:`enable_compile_cache` (called by ``experiments/__init__.py`` and ``benchmarks/__init__.py``,
before any JAX computation) sets

- ``jax_compilation_cache_dir`` to ``$PCMGN_JAX_CACHE_DIR``, else ``$XDG_CACHE_HOME/pcmgn_jax/jax``,
  else ``~/.cache/pcmgn_jax/jax``;
- ``jax_persistent_cache_min_compile_time_secs`` to :data:`MIN_COMPILE_S` = 0 (JAX's default, 1 s, would
  skip the many sub-second compiles of a start-up, which add up to seconds) and
  ``jax_persistent_cache_min_entry_size_bytes`` to 0 (no size floor);
- ``jax_persistent_cache_enable_xla_caches`` to ``xla_gpu_per_fusion_autotune_cache_dir``: on a GPU,
  XLA's per-fusion autotuning results go to a folder inside the cache (JAX creates it; other backends
  have no such cache and ignore it).

Switched off with ``PCMGN_JAX_CACHE=0`` (or false/no/off); then nothing is set and nothing is written.
The folder is trusted input (JAX runs what it reads from it): keep it private to its user, as the
default under the home folder is. Delete the folder to drop the cache; JAX keys entries by its own
version, so an upgrade never reads stale programs.
"""
from __future__ import annotations

import os
from pathlib import Path

ENV_DIR = "PCMGN_JAX_CACHE_DIR"      # the cache folder (overrides the default)
ENV_SWITCH = "PCMGN_JAX_CACHE"       # 0 / false / no / off: no persistent cache
MIN_COMPILE_S = 0.0                  # compiles shorter than this [s] are not written (0: all)
XLA_CACHES = "xla_gpu_per_fusion_autotune_cache_dir"

_OFF = ("0", "false", "no", "off")
_state: dict[str, Path | None] = {}


def cache_dir(environ=None) -> Path | None:
    """The folder the cache would use under ``environ`` (default ``os.environ``); None when switched off."""
    env = os.environ if environ is None else environ
    if env.get(ENV_SWITCH, "1").strip().lower() in _OFF:
        return None
    if env.get(ENV_DIR, "").strip():
        return Path(env[ENV_DIR]).expanduser()
    base = env.get("XDG_CACHE_HOME", "").strip() or str(Path.home() / ".cache")
    return Path(base).expanduser() / "pcmgn_jax" / "jax"


def configure(folder: str | os.PathLike, *, min_compile_s: float = MIN_COMPILE_S) -> Path:
    """Point JAX's persistent cache at ``folder`` (made if missing, private to the user) with the options
    above; compiles shorter than ``min_compile_s`` [s] are not written. Before the first compilation."""
    import jax

    folder = Path(folder).expanduser()
    folder.mkdir(parents=True, exist_ok=True, mode=0o700)
    jax.config.update("jax_compilation_cache_dir", str(folder))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", float(min_compile_s))
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    try:
        jax.config.update("jax_persistent_cache_enable_xla_caches", XLA_CACHES)
    except (AttributeError, KeyError):
        pass                                             # a jax without the option: programs only
    return folder


def enable_compile_cache() -> Path | None:
    """Turn the persistent cache on in :func:`cache_dir` (once per process; later calls return the first
    answer). Returns the folder, or None when switched off (``PCMGN_JAX_CACHE=0``) or when the folder
    cannot be made (a note is printed). Must run before the first compilation."""
    if "dir" in _state:
        return _state["dir"]
    _state["dir"] = None
    folder = cache_dir()
    if folder is None:
        return None
    try:
        _state["dir"] = configure(folder)
    except (OSError, AttributeError, KeyError) as err:   # a read-only home, or a jax without the options
        print(f"note: no persistent compilation cache in {folder} ({type(err).__name__}: {err})")
    return _state["dir"]


def active() -> Path | None:
    """The folder :func:`enable_compile_cache` set in this process (None: off or not called)."""
    return _state.get("dir")
