"""Evaluate a run: ``python -m experiments.evaluate --workdir RUN [--which best|periodic]``.

Writes RUN/eval/metrics.json and PNG plots (see pcmgn_jax.eval.evaluate).
"""
import json
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
    _, _, test = load_splits(cfg.resolved_dataset_dir, n_train=0, n_val=0, n_test=cfg.n_test)
    m = evaluation.evaluate(args.workdir, test_trajs=test, cfg=cfg, which=args.which)
    keys = ("position_mae_um", "position_rmse_um", "stress_mae_mpa", "stress_rmse_mpa", "penetration_max_um",
            "rollout_seconds_per_trajectory")
    print(json.dumps({k: m[k] for k in keys}, indent=1))
    print(f"wrote {args.workdir}/eval/metrics.json and PNGs")
    return 0


if __name__ == "__main__":
    sys.exit(cli.run(main))
