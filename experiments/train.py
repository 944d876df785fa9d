"""Train the MeshGraphNet: ``python -m experiments.train [--preset cpu] [--workdir runs/cpu] [--lambda_pen=0]``.

Every TrainConfig field is a flag (``--key=value``); plus ``--workdir DIR`` and ``--resume``.
On a fresh machine the preset's dataset is generated first (data/<data_preset>, cached).
"""
import sys

from pcmgn_jax.config import TrainConfig, parse_flags


def main(argv):
    flags = parse_flags(argv)
    workdir = flags.pop("workdir", None)
    resume = bool(flags.pop("resume", False))
    cfg = TrainConfig.from_flags([f"--{k}={v}" for k, v in flags.items()])
    workdir = workdir or f"runs/{cfg.preset}"
    from pcmgn_jax.data.dataset import ensure_dataset, load_splits
    from pcmgn_jax.train import loop as training
    root = ensure_dataset(cfg.resolved_dataset_dir, preset=cfg.data_preset, n_train=cfg.n_train + cfg.n_val,
                          n_test=cfg.n_test, seed=cfg.data_seed)
    train, val, _ = load_splits(root, n_train=cfg.n_train, n_val=cfg.n_val, n_test=0)
    res = training.train(cfg, workdir, train_trajs=train, val_trajs=val, resume=resume)
    print(f"done: {res['step']} steps in {res['seconds']:.0f} s; best validation position MAE "
          f"{res['best_val_position_mae_um']:.3f} µm; run directory {workdir}")


if __name__ == "__main__":
    main(sys.argv[1:])
