"""The evaluation pipeline as a library call: ``pcmgn_jax.eval.run(workdir)``.

Loads the run's splits from its config's dataset directory (:func:`pcmgn_jax.data.splits.load_splits`,
a generated or an imported dataset alike: test = the first ``n_test`` of DIR/test), or any directory of
trajectory files (``data``), and scores the run's model beside the baselines fitted on its training split
(:func:`pcmgn_jax.eval.evaluate.evaluate`). ``experiments/evaluate.py`` parses flags and calls :func:`run`.
The caller picks the matplotlib backend (the entry point sets ``Agg``).
"""
from __future__ import annotations

from pathlib import Path

from pcmgn_jax.lock import hold


def output_name(data: str = "", name: str = "") -> str | None:
    """The evaluation's folder under RUN/eval: ``name``, else the ``data`` folder's name, else None
    (RUN/eval itself, the run's test split)."""
    if name:
        return name
    return Path(data).resolve().name if data else None


def run(workdir: str | Path, *, which: str = "best", data: str = "", name: str = "",
        contact_projection: str = "", mgn_spread: bool = False, residual_ball: str = "", split: str = "test",
        baselines: bool = True) -> dict:
    """Evaluate the run in ``workdir`` and return the metrics dict written to
    ``WORKDIR/eval[/NAME]/metrics.json`` (:mod:`pcmgn_jax.eval.evaluate`; PNG plots beside it).

    ``which``: checkpoint, ``best`` (validation) or ``periodic`` (latest); ``data``: a directory of
    trajectory files ("" = the run's test split); ``name``: the output folder under RUN/eval (""= the
    ``data`` folder's name, :func:`output_name`); ``contact_projection``: ``on`` / ``off`` overrides the
    run's rollout contact projection ("" = the run's); ``residual_ball``: a residual run's ball override ("" =
    the run's); ``split``: ``val`` scores the run's validation trajectories instead (RUN/eval/val unless
    ``name``), where a rollout setting is chosen without looking at the test split; ``baselines=False``: the
    model only (:func:`pcmgn_jax.eval.evaluate.evaluate`)."""
    import json

    from pcmgn_jax.config import TrainConfig  # here, not at the top: `import pcmgn_jax.eval` stays light
    from pcmgn_jax.data.layout import check_run_element
    from pcmgn_jax.data.splits import load_directory, load_splits
    from pcmgn_jax.eval import evaluate as evaluation
    from pcmgn_jax.mgn.checkpoint import require_run
    require_run(workdir)   # a missing run, a file, no config or no checkpoint: one line, nothing written
    cfg = TrainConfig.load(Path(workdir) / "config.json")
    if split not in ("test", "val"):
        raise ValueError(f"evaluate: split={split!r} must be test or val")
    if split == "val" and data:
        raise ValueError("evaluate: split='val' scores the run's validation trajectories; it takes no data directory")
    if name and (Path(name).name != name or name in (".", "..")):
        raise ValueError(f"evaluate: name {name!r} must be one folder name (the evaluation goes to RUN/eval/NAME)")
    if residual_ball and not cfg.residual_of:
        raise ValueError(f"evaluate: residual_ball={residual_ball!r} is for a run with residual_of; {workdir} "
                         "predicts the fields themselves (its network moves the ball)")
    train, val, test = load_splits(cfg.resolved_dataset_dir, n_train=cfg.n_train,
                                   n_val=cfg.n_val if split == "val" else 0,
                                   n_test=0 if data or split == "val" else cfg.n_test)
    if data:
        test = load_directory(data)
    record = Path(workdir) / "data.json"
    check_run_element(Path(workdir), json.loads(record.read_text()) if record.is_file() else None, [*train, *test])
    if split == "val":  # what choices between rollout settings are made on, never the test split
        test, name = val, name or "val"
    out = Path(workdir) / "eval" / (output_name(data, name) or "")
    with hold(out, "evaluate"):   # one evaluation writes into RUN/eval[/NAME] at a time
        return evaluation.evaluate(workdir, test_trajs=test, train_trajs=train, which=which,
                                   name=output_name(data, name), contact_projection=contact_projection,
                                   mgn_spread=mgn_spread, residual_ball=residual_ball, baselines=baselines)
