"""One resumable training-and-evaluation cell, shared by the ablation and the study runner.

A cell is ``experiments.train`` with some flags into ``workdir``, then ``experiments.evaluate`` on the
run's test split (and optionally on other directories). It never retrains a finished cell (its
``eval/metrics.json`` exists) and a killed training resumes from its last checkpoint.
"""
from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np


def use_compilation_cache(folder: str | Path, min_compile_seconds: float = 1.0) -> None:
    """Keep XLA's compiled executables on disk in ``folder`` (JAX's persistent compilation cache) for
    the rest of this process, so the cells of a study that compile the same program (the same model
    and shapes under another seed; every cell's evaluation rollout) load it instead of compiling it
    again. Call it before the process's first compilation: JAX decides once whether the cache is used."""
    import jax
    Path(folder).mkdir(parents=True, exist_ok=True)
    jax.config.update("jax_compilation_cache_dir", str(folder))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", float(min_compile_seconds))


def run_cell(workdir: str | Path, flags: list[str], *, extra_data: dict[str, str] | None = None) -> dict:
    """Train (unless finished) and evaluate; return the test metrics plus ``train_seconds``,
    ``checkpoint_step`` (:func:`checkpoint_step`) and, for each
    ``extra_data`` {name: directory}, the metrics of ``evaluate --data`` under ``eval_<name>``."""
    from experiments import evaluate, train
    from pcmgn_jax.data.trajectory_io import atomic_write_json
    workdir = Path(workdir)
    check_flags(workdir, flags)
    metrics = workdir / "eval" / "metrics.json"
    if not metrics.exists():
        resume = (workdir / "checkpoints" / "periodic").is_dir()
        t0 = time.perf_counter()
        if train.main([f"--workdir={workdir}", "--no_progress", *flags] + (["--resume"] if resume else [])) != 0:
            raise RuntimeError(f"training of {workdir} failed")
        secs = workdir / "train_seconds.json"
        if not (resume and secs.exists()):
            atomic_write_json(secs, {"seconds": time.perf_counter() - t0, "resumed": resume})
        if evaluate.main([f"--workdir={workdir}"]) != 0:
            raise RuntimeError(f"evaluation of {workdir} failed")
    m = json.loads(metrics.read_text())
    secs = workdir / "train_seconds.json"
    m["train_seconds"] = json.loads(secs.read_text())["seconds"] if secs.exists() else float("nan")
    m["checkpoint_step"] = checkpoint_step(workdir)
    for name, folder in (extra_data or {}).items():
        out = workdir / "eval" / name / "metrics.json"
        if not out.exists() and evaluate.main([f"--workdir={workdir}", f"--data={folder}", f"--name={name}"]) != 0:
            raise RuntimeError(f"evaluation of {workdir} on {folder} failed")
        m[f"eval_{name}"] = json.loads(out.read_text())
    return m


def check_flags(workdir: str | Path, flags: list[str]) -> None:
    """Refuse a cell directory trained with other values of the flags asked for: a cell is found by its
    directory, so a changed flag (a study's base flags edited) must not silently reuse the old model.
    Only the fields the flags name are compared (fields added to the config later keep their defaults)."""
    from pcmgn_jax.config import TrainConfig
    saved = Path(workdir) / "config.json"
    if not saved.exists():
        return
    stored = json.loads(saved.read_text())
    wanted = TrainConfig.from_flags(flags).to_dict()
    names = {f[2:].split("=", 1)[0].replace("-", "_") for f in flags if f.startswith("--")}
    diff = sorted(k for k in names if k in stored and k in wanted and stored[k] != wanted[k])
    if diff:
        raise ValueError(f"{saved}: this cell was trained with " + ", ".join(
            f"{k}={stored[k]!r}" for k in diff) + " but is asked for " + ", ".join(f"{k}={wanted[k]!r}" for k in diff)
            + f"; move {workdir} away to retrain it with the new flags")


def checkpoint_step(workdir: str | Path) -> int:
    """The training step of the checkpoint the evaluation uses (the best by validation): a cell whose
    best checkpoint is not its last was scored on an earlier model than its step count says."""
    from pcmgn_jax.mgn.checkpoint import checkpoint_dir, read_meta
    return int(read_meta(checkpoint_dir(workdir, "best"))[0])


def mean_pm(values) -> str:
    """'mean ± std' over seeds (population std), or the value alone for one seed."""
    v = np.asarray(list(values), float)
    return f"{v.mean():.3g} ± {v.std():.2g}" if len(v) > 1 else f"{v.mean():.3g}"
