"""One resumable training-and-evaluation cell, shared by the ablation and the study runner.

A cell is a training run of :meth:`TrainConfig.from_preset` ``(**settings)`` into ``workdir``
(:func:`pcmgn_jax.train.run`, without a progress bar), then :func:`pcmgn_jax.eval.run` on the run's test
split (and optionally on other directories). It never retrains a finished cell (its ``eval/metrics.json``
exists) and a killed training resumes from its last checkpoint. :func:`as_flags` writes settings as the
training command's flags, for records and tables.
"""
from __future__ import annotations

import json
import re
import time
from pathlib import Path

import numpy as np

from pcmgn_jax import compile_cache
from pcmgn_jax.config import FORMULATION_FIELDS, TrainConfig
from pcmgn_jax.lock import hold


def use_compilation_cache(folder: str | Path, min_compile_seconds: float = 1.0) -> None:
    """Keep XLA's compiled executables on disk in ``folder`` (JAX's persistent compilation cache) for
    the rest of this process, so the cells of a study that compile the same program (the same model
    and shapes under another seed; every cell's evaluation rollout) load it instead of compiling it
    again. Call it before the process's first compilation: JAX decides once whether the cache is used."""
    compile_cache.configure(folder, min_compile_s=min_compile_seconds)


def as_flags(settings: dict) -> list[str]:
    """``settings`` (TrainConfig.from_preset keyword arguments) as ``python -m experiments.train`` flags,
    in order: ``--key=value`` (floats as ``%g`` with the exponent unpadded, ``3e-7``), booleans as
    ``--key`` / ``--no_key``, feature tuples as a comma list (``none`` when empty)."""
    out = []
    for key, value in settings.items():
        if isinstance(value, bool):
            out.append(f"--{key}" if value else f"--no_{key}")
            continue
        if isinstance(value, float):
            value = re.sub(r"e([+-])0*(\d)", r"e\1\2", f"{value:g}")
        elif isinstance(value, (tuple, list)):
            value = ",".join(value) or "none"
        out.append(f"--{key}={value}")
    return out


def config_of(settings: dict) -> TrainConfig:
    """The cell's training config: ``TrainConfig.from_preset(**settings)`` (preset ``cpu`` unless named),
    without a progress bar."""
    kw = dict(settings)
    return TrainConfig.from_preset(kw.pop("preset", "cpu"), **kw).replace(progress=False)


def _resumed_config(saved: TrainConfig, settings: dict) -> TrainConfig:
    """The saved config of a killed cell with ``settings`` applied (the training refuses any change,
    :func:`pcmgn_jax.config.check_resume`); a formulation name in ``settings`` is compared, not applied,
    by :func:`check_settings`."""
    form = {k: v for k, v in settings.items() if k in FORMULATION_FIELDS}
    top = {k: v for k, v in settings.items() if k not in FORMULATION_FIELDS and k != "formulation"}
    if "scene_features" in form:
        form["scene_features"] = tuple(form["scene_features"])
    return saved.replace(**top, progress=False, formulation=saved.formulation.replace(**form))


def run_cell(workdir: str | Path, settings: dict, *, extra_data: dict[str, str] | None = None) -> dict:
    """Train (unless finished) and evaluate; return the test metrics plus ``train_seconds``,
    ``checkpoint_step`` (:func:`checkpoint_step`) and, for each ``extra_data`` {name: directory}, the
    metrics of the evaluation on that directory under ``eval_<name>``. The cell's folder is locked while it
    runs (:func:`pcmgn_jax.lock.hold`)."""
    workdir = Path(workdir)
    check_settings(workdir, settings)
    with hold(workdir, "study cell"):   # one writer per cell (another study on the same folder is refused)
        return _run_cell(workdir, settings, extra_data)


def _run_cell(workdir: Path, settings: dict, extra_data: dict[str, str] | None) -> dict:
    from pcmgn_jax import eval as evaluation, train
    from pcmgn_jax.atomic import atomic_write_json
    from pcmgn_jax.eval.evaluate import summary_table
    from pcmgn_jax.train.loop import best_line
    from pcmgn_jax.train.pipeline import fit_to_dataset
    metrics = workdir / "eval" / "metrics.json"
    if not metrics.exists():
        resume = (workdir / "checkpoints" / "periodic").is_dir()
        saved = workdir / "config.json"
        if resume and saved.exists():
            cfg = _resumed_config(TrainConfig.load(saved), settings)
        else:
            cfg = config_of(settings) if resume else fit_to_dataset(config_of(settings), given=set(settings))
        t0 = time.perf_counter()
        res = train.run(cfg, workdir, resume=resume)
        print(f"{workdir}: trained {res['step']} steps in {res['seconds']:.0f} s; {best_line(res)}", flush=True)
        secs = workdir / "train_seconds.json"
        if not (resume and secs.exists()):
            atomic_write_json(secs, {"seconds": time.perf_counter() - t0, "resumed": resume})
        print(summary_table(evaluation.run(workdir)), flush=True)
    m = json.loads(metrics.read_text())
    secs = workdir / "train_seconds.json"
    m["train_seconds"] = json.loads(secs.read_text())["seconds"] if secs.exists() else float("nan")
    m["checkpoint_step"] = checkpoint_step(workdir)
    for name, folder in (extra_data or {}).items():
        out = workdir / "eval" / name / "metrics.json"
        if not out.exists():
            print(summary_table(evaluation.run(workdir, data=folder, name=name)), flush=True)
        m[f"eval_{name}"] = json.loads(out.read_text())
    return m


def check_settings(workdir: str | Path, settings: dict) -> None:
    """Refuse a cell directory trained with other values of the settings asked for: a cell is found by its
    directory, so a changed setting (a study's base settings edited) must not silently reuse the old model.
    Only the config fields the settings name are compared (fields added to the config later keep their
    defaults; a formulation name compares the whole formulation)."""
    saved = Path(workdir) / "config.json"
    if not saved.exists():
        return
    stored = json.loads(saved.read_text())
    wanted = config_of(settings).to_dict()
    diff = sorted(k for k in settings if k in stored and k in wanted and stored[k] != wanted[k])
    if diff:
        raise ValueError(f"{saved}: this cell was trained with " + ", ".join(
            f"{k}={stored[k]!r}" for k in diff) + " but is asked for " + ", ".join(f"{k}={wanted[k]!r}" for k in diff)
            + f"; move {workdir} away to retrain it with the new settings")


def checkpoint_step(workdir: str | Path) -> int:
    """The training step of the checkpoint the evaluation uses (the best by validation): a cell whose
    best checkpoint is not its last was scored on an earlier model than its step count says."""
    from pcmgn_jax.mgn.checkpoint import checkpoint_dir, read_meta
    return int(read_meta(checkpoint_dir(workdir, "best"))[0])


def mean_pm(values) -> str:
    """'mean ± std' over seeds (population std), or the value alone for one seed."""
    v = np.asarray(list(values), float)
    return f"{v.mean():.3g} ± {v.std():.2g}" if len(v) > 1 else f"{v.mean():.3g}"
