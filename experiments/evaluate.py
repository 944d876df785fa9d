"""Evaluate a run: ``python -m experiments.evaluate --workdir RUN [--which best|periodic]``.

Writes RUN/eval/metrics.json and PNG plots (see pcmgn_jax.eval.evaluate).
"""
import json
import sys

from pcmgn_jax.config import parse_flags


def main(argv):
    flags = parse_flags(argv)
    workdir = flags.pop("workdir", None)
    which = flags.pop("which", "best")
    if workdir is None or flags:
        raise SystemExit(f"usage: python -m experiments.evaluate --workdir RUN [--which best|periodic]"
                         f"{'; unknown flags ' + str(sorted(flags)) if flags else ''}")
    from pcmgn_jax.eval import evaluate as evaluation
    from pcmgn_jax.config import TrainConfig
    from pcmgn_jax.data.dataset import load_splits
    cfg = TrainConfig.load(f"{workdir}/config.json")
    _, _, test = load_splits(cfg.resolved_dataset_dir, n_train=0, n_val=0, n_test=cfg.n_test)
    m = evaluation.evaluate(workdir, test_trajs=test, cfg=cfg, which=which)
    keys = ("position_mae_um", "position_rmse_um", "stress_mae_mpa", "stress_rmse_mpa", "penetration_max_um",
            "rollout_seconds_per_trajectory")
    print(json.dumps({k: m[k] for k in keys}, indent=1))
    print(f"wrote {workdir}/eval/metrics.json and PNGs")


if __name__ == "__main__":
    main(sys.argv[1:])
