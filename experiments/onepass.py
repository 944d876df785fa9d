"""Train and score the one-pass model (issue 49, item 4): a scene's graph -> time-mean / peak fields -> the objective.

  python -m experiments.onepass --dataset_dir /tmp/clean/data/cpu --workdir runs/onepass --num_steps 2000 --seed 0
  python -m experiments.onepass --workdir runs/onepass --dataset_dir ... --resume      # continue (or only score)

Every field of :class:`pcmgn_jax.mgn.onepass.OnePassConfig` is a flag (``--help``), except what a generated dataset's
manifest decides: its ``preset``, and that preset's ``part_identity``, ``origin`` and (unless ``--scene_features`` is
given) ``scene_features``, the rollout MGN's inputs for the preset (:func:`pcmgn_jax.train.onepass.for_dataset`), so
the box (task (a)), the scene family (task (b), each design its own mesh) and the stacks of 5-7 layers (task (e2))
each get theirs. Designs of different meshes train and predict together as padded unions of one static size
(:mod:`pcmgn_jax.mgn.onepass_union`). Trains on the first ``n_train``
designs of the dataset's train split, validates on the next ``n_val`` (best on validation: ``checkpoints/best``),
then scores the best checkpoint on the first ``n_test`` of the test split by the evaluation's one scoring of an
objective prediction (:func:`pcmgn_jax.eval.baselines.objective_scores`), beside kriging fitted on the same training
designs, and times the prediction of one design (jitted, after warm-up). Writes ``WORKDIR/onepass_eval.json``
(and ``--out FILE``, a copy).
"""
from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pcmgn_jax import cli
from pcmgn_jax.mgn.onepass import OnePassConfig


@dataclass(frozen=True)
class OnePassArgs:
    workdir: str                                         # the run folder (onepass.json, checkpoints, metrics.jsonl)
    config: OnePassConfig = field(default_factory=OnePassConfig)
    resume: bool = False                                 # continue the run in --workdir (its settings must match)
    out: str = ""                                        # also write the scores here (JSON)
    timing_repeats: int = 20                             # predictions timed for the cost per design


def _cost(surrogate, traj, repeats: int) -> dict:
    """Seconds per design after warm-up: the network alone (a prepared union of the one design) and the whole
    answer (the design's graph from its trajectory, the network, the objective readings)."""
    import jax

    from pcmgn_jax.mgn import onepass as op, onepass_union as union
    run = surrogate.run
    d = run.inputs(traj)
    u = union.make_union([d], union.union_sizes([d], 1))
    jax.block_until_ready(op.predict_jit(run.cfg, run.params, run.stats, u))
    t0 = time.perf_counter()
    for _ in range(repeats):
        jax.block_until_ready(op.predict_jit(run.cfg, run.params, run.stats, u))
    net = (time.perf_counter() - t0) / repeats
    surrogate.objectives([traj])
    t0 = time.perf_counter()
    for _ in range(repeats):
        surrogate.objectives([traj])
    return {"network_seconds_per_design": net, "answer_seconds_per_design": (time.perf_counter() - t0) / repeats}


MANIFEST_FIELDS = ("preset", "part_identity", "origin")   # read from the dataset's manifest, never flags


def main(argv=None) -> int:
    args = cli.parse(OnePassArgs, argv, description=__doc__, prog="python -m experiments.onepass")
    cfg = args.config
    if not cfg.dataset_dir:
        raise ValueError("--dataset_dir: required (a generated dataset, e.g. /tmp/clean/data/cpu)")
    from pcmgn_jax.atomic import atomic_write_json
    from pcmgn_jax.data.layout import load_manifest
    from pcmgn_jax.data.splits import load_splits
    from pcmgn_jax.eval.baselines import objective_scores
    from pcmgn_jax.surrogates.registry import fit
    from pcmgn_jax.train.onepass import for_dataset, train

    given = cli.given_flags(sys.argv[1:] if argv is None else argv)
    manifest = load_manifest(cfg.dataset_dir)
    if manifest is not None:
        cli.refuse_inapplicable(given, {f: f"read from {cfg.dataset_dir}/manifest.json (the dataset's preset)"
                                        for f in MANIFEST_FIELDS})
    cfg = for_dataset(cfg, manifest, given=given)

    train_t, val_t, test_t = load_splits(cfg.dataset_dir, n_train=cfg.n_train, n_val=cfg.n_val, n_test=cfg.n_test)
    workdir = Path(args.workdir)
    summary = train(cfg, workdir, train_trajs=train_t, val_trajs=val_t, resume=args.resume)
    out = {"command": cli.command_line("experiments.onepass", argv), "config": cfg.to_dict()}
    if (workdir / "train_summary.json").exists():
        import json
        out["training"] = json.loads((workdir / "train_summary.json").read_text())
    if not test_t:
        print(f"done: {summary['step']} steps; no test designs (--n_test 0): nothing scored")
        return 0
    onepass = fit("onepass", train_t, workdir=workdir)
    out["onepass"] = {**objective_scores(test_t, onepass.objectives(test_t)), **_cost(onepass, test_t[0],
                                                                                        args.timing_repeats)}
    kriging = fit("kriging", train_t, queries=test_t, fields=False, readings=("node_mean", "area_mean"))
    out["kriging"] = objective_scores(test_t, kriging.objectives(test_t))
    out["test_designs"] = [t.meta.get("name", str(i)) for i, t in enumerate(test_t)]
    atomic_write_json(workdir / "onepass_eval.json", out)
    if args.out:
        atomic_write_json(args.out, out, parents=True)
    key = "oled_objective_area_rel_error_pct"
    for name in ("onepass", "kriging"):
        m = out[name]
        print(f"{name:8s} test objective (area mean) error: mean {m[key + '_mean']:.3f} %, "
              f"worst {m[key + '_max']:.3f} %")
    tr = out.get("training", {})
    print(f"training: {tr.get('step')} steps in {tr.get('seconds', np.nan):.0f} s "
          f"({tr.get('step_seconds', np.nan):.4f} s/step); best validation objective error "
          f"{tr.get('best_val_objective_error_pct', np.nan):.3f} %; "
          f"one design {out['onepass']['network_seconds_per_design'] * 1e3:.2f} ms (network), "
          f"{out['onepass']['answer_seconds_per_design'] * 1e3:.1f} ms (whole answer); "
          f"wrote {workdir}/onepass_eval.json")
    return 0


if __name__ == "__main__":
    sys.exit(cli.run(main))
