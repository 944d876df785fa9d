"""Evaluate a run: ``python -m experiments.evaluate --workdir RUN [--which best|periodic]``.

Rolls the model out on the run's test split and scores it beside the baselines fitted on its training
split (nothing moves, nearest training design, per-node quadratic and RBF regression over the design).
Writes RUN/eval/metrics.json and PNG plots (see pcmgn_jax.eval.evaluate).
"""
import sys
from dataclasses import dataclass
from typing import Literal

from pcmgn_jax import cli


@dataclass(frozen=True)
class EvaluateArgs:
    workdir: str                               # training run directory (config.json, checkpoints)
    which: Literal["best", "periodic"] = "best"  # checkpoint: best validation or latest periodic


def main(argv=None) -> int:
    args = cli.parse(EvaluateArgs, argv, description=__doc__, prog="python -m experiments.evaluate")
    import matplotlib
    matplotlib.use("Agg")  # files only; set here, in the entry point, not in the library
    from pcmgn_jax.eval import evaluate as evaluation
    from pcmgn_jax.config import TrainConfig
    from pcmgn_jax.data.dataset import load_splits
    cfg = TrainConfig.load(f"{args.workdir}/config.json")
    train, _, test = load_splits(cfg.resolved_dataset_dir, n_train=cfg.n_train, n_val=0, n_test=cfg.n_test)
    m = evaluation.evaluate(args.workdir, test_trajs=test, train_trajs=train, which=args.which)
    print(evaluation.summary_table(m))
    print(f"wrote {args.workdir}/eval/metrics.json and PNGs")
    return 0


if __name__ == "__main__":
    sys.exit(cli.run(main))
