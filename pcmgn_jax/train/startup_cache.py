"""What a training start derives from its data, kept beside the compiled programs, so a warm start skips
it: the normalisation statistics and the model's initial parameters.

The statistics (:func:`pcmgn_jax.train.setup.compute_stats`: one jitted call and host sums per training
pair) cost ~3 s of a ~10 s warm start to the first training step on the ``cpu`` preset, and tracing the
model for its initial parameters (:func:`pcmgn_jax.train.loop.init_params`) another 1-2 s. Both are pure
functions of the training trajectories' content, the run config and the code, so a process whose
compiled programs come from the persistent compilation cache (:mod:`pcmgn_jax.compile_cache`) keeps them
there too, in ``<cache>/start/``: the statistics as ``<key>.json`` (:meth:`Stats.to_json`: float32
values, exact in JSON), the parameters as ``<key>.npz`` (one array per parameter path; read without
pickle). The key is a sha256 of

- what it is (``stats`` | ``params``) and the caller's inputs (``extra``: frames used, seed, contact
  radius and buffer);
- every trajectory's content hash, in order (``meta['source_sha256']``: the dataset's sidecars, checked by
  its read cache); a trajectory without one (built in memory) turns the cache off for the call;
- the whole run config (``TrainConfig.to_dict``);
- the text of every module of the package, jax's, jaxlib's, flax's and numpy's versions and the backend:
  a code change, an upgrade or another device never reads numbers made by other code.

Off whenever the compilation cache is (``PCMGN_JAX_CACHE=0``; a library call outside the entry points,
e.g. the tests). A file that does not read back is computed again and replaced; a failed write only
loses the saving.
"""
from __future__ import annotations

import hashlib
import json
from collections.abc import Callable, Sequence
from pathlib import Path

import flax
import jax
import jaxlib
import numpy as np
from flax.traverse_util import flatten_dict, unflatten_dict

from pcmgn_jax import compile_cache
from pcmgn_jax.atomic import atomic_dir, atomic_write_text
from pcmgn_jax.mgn.normalization import Stats

STARTUP_CACHE_VERSION = 1   # the entries' layout: a change makes every older entry a miss
_PACKAGE = Path(__file__).resolve().parents[1]
_code: list[str] = []


def code_hash() -> str:
    """sha256 of every module's path and text in the package (~120 files, a few ms; once per process)."""
    if not _code:
        h = hashlib.sha256()
        for f in sorted(_PACKAGE.rglob("*.py")):
            h.update(str(f.relative_to(_PACKAGE)).encode() + b"\0" + f.read_bytes() + b"\0")
        _code.append(h.hexdigest())
    return _code[0]


def key(what: str, cfg, trajs: Sequence, extra: dict) -> str | None:
    """The cache key (module docstring), or None when a trajectory carries no content hash."""
    hashes = [t.meta.get("source_sha256") for t in trajs]
    if not hashes or not all(hashes):
        return None
    parts = {"format": STARTUP_CACHE_VERSION, "what": what, "extra": extra, "trajectories": hashes,
             "config": cfg.to_dict(),
             "code": code_hash(), "versions": [jax.__version__, jaxlib.__version__, flax.__version__, np.__version__],
             "backend": jax.default_backend()}
    return hashlib.sha256(json.dumps(parts, sort_keys=True, default=str).encode()).hexdigest()


def _path(what: str, cfg, trajs, extra, suffix: str) -> Path | None:
    folder = compile_cache.active()
    k = None if folder is None else key(what, cfg, trajs, extra)
    return None if k is None else Path(folder) / "start" / f"{k}{suffix}"


def stats(cfg, trajs: Sequence, extra: dict, compute: Callable[[], Stats]) -> Stats:
    """``compute()``'s statistics, read from the cache when there, else computed and kept there."""
    path = _path("stats", cfg, trajs, extra, ".json")
    if path is None:
        return compute()
    try:
        return Stats.from_json(json.loads(path.read_text()))
    except (OSError, ValueError, KeyError, TypeError):
        pass                                   # missing or unreadable: computed again
    out = compute()
    try:
        path.parent.mkdir(parents=True, exist_ok=True, mode=0o700)
        atomic_write_text(path, json.dumps(out.to_json(), allow_nan=False))
    except (OSError, ValueError):             # a read-only folder, or non-finite numbers: not kept
        pass
    return out


def params(cfg, trajs: Sequence, extra: dict, compute: Callable[[], dict]) -> dict:
    """``compute()``'s parameters (nested dicts of arrays), read from the cache when there, else computed
    and kept there."""
    path = _path("params", cfg, trajs, extra, ".npz")
    if path is None:
        return compute()
    try:
        with np.load(path, allow_pickle=False) as z:
            return unflatten_dict({name: jax.numpy.asarray(z[name]) for name in z.files}, sep="/")
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        pass                                   # missing or unreadable: computed again
    out = compute()
    flat = {name: np.asarray(v) for name, v in flatten_dict(out, sep="/").items()}
    try:
        with atomic_dir(path.parent, files=[path.name]) as tmp:
            np.savez(tmp / path.name, **flat)
    except OSError:
        pass
    return out
