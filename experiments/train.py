"""Train the MeshGraphNet: ``python -m experiments.train [--preset cpu] [--workdir runs/cpu] [--lambda_pen=0]``.

Every TrainConfig field is a flag (``--key=value``; ``--help`` lists them); ``--preset tiny|cpu|paper``
fills the defaults (pcmgn_jax.config.PRESETS); plus ``--workdir DIR`` and ``--resume``, which continues the
run from its last checkpoint and refuses flags that change its saved config.json. ``--devices`` splits each
batch over several devices; ``--coordinator_address``, ``--num_processes``, ``--process_id``: several hosts
(README, "Several machines").
On a fresh machine the preset's dataset is generated first (data/<data_preset>, cached).
"""
import sys

from pcmgn_jax import cli


def main(argv=None) -> int:
    args = cli.parse_train(argv, description=__doc__, prog="python -m experiments.train")
    args.initialize_distributed()  # several hosts only (--coordinator_address); before jax computes anything
    cfg, workdir = args.config, args.run_dir
    from pcmgn_jax.data.dataset import ensure_dataset, load_splits
    from pcmgn_jax.train import loop as training
    root = ensure_dataset(cfg.resolved_dataset_dir, preset=cfg.data_preset, n_train=cfg.n_train + cfg.n_val,
                          n_test=cfg.n_test, seed=cfg.data_seed)
    train, val, _ = load_splits(root, n_train=cfg.n_train, n_val=cfg.n_val, n_test=0)
    res = training.train(cfg, str(workdir), train_trajs=train, val_trajs=val, resume=args.resume)
    print(f"done: {res['step']} steps in {res['seconds']:.0f} s; best validation position MAE "
          f"{res['best_val_position_mae_um']:.3f} µm; run directory {workdir}")
    return 0


if __name__ == "__main__":
    sys.exit(cli.run(main))
