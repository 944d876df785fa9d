"""Train the MeshGraphNet: ``python -m experiments.train [--preset cpu] [--workdir runs/cpu] [--lambda_pen=0]``.

Every TrainConfig field is a flag (``--key=value``; ``--help`` lists them); ``--preset tiny|cpu|paper``
fills the defaults (pcmgn_jax.config.PRESETS); plus ``--workdir DIR`` and ``--resume``, which continues the
run from its last checkpoint and refuses flags that change its saved config.json. ``--devices`` splits each
batch over several devices; ``--coordinator_address``, ``--num_processes``, ``--process_id``: several hosts
(README, "Several machines").
On a fresh machine the preset's dataset is generated first (data/<data_preset>, cached).

``--dataset_dir DIR`` (pcmgn_jax.data.dataset.dataset_source, prepare_dataset): a directory that does not
exist or holds a generator manifest gets the preset's designs from the solver (resumable); a directory of
trajectory files without a manifest (``DIR/train/*.json|.h5|.xdmf``, ``DIR/test/...``, e.g. from
``python -m experiments.import_ansys --exports EXPORTS --out DIR``) is trained on as it is: ``--n_train``
by name order, validation on the last ``--n_val`` of DIR/train (pcmgn_jax.data.dataset.load_splits);
anything else is a one-line error and nothing is written. RUN/data.json records the dataset directory,
its source (generate | imported) and every training and validation trajectory (name, content hash,
meta 'source', node count).
"""
import sys

from pcmgn_jax import cli


def main(argv=None) -> int:
    args = cli.parse_train(argv, description=__doc__, prog="python -m experiments.train")
    args.initialize_distributed()  # several hosts only (--coordinator_address); before jax computes anything
    cfg, workdir = args.config, args.run_dir
    from pcmgn_jax.data.dataset import IMPORTED, load_splits, prepare_dataset, split_stems
    from pcmgn_jax.train import loop as training
    root, source = prepare_dataset(cfg.resolved_dataset_dir, preset=cfg.data_preset,
                                   n_train=cfg.n_train + cfg.n_val, n_test=cfg.n_test, seed=cfg.data_seed)
    train, val, _ = load_splits(root, n_train=cfg.n_train, n_val=cfg.n_val, n_test=0)
    if source == IMPORTED:
        have = len(split_stems(root, "train"))
        unused = have - len(train) - len(val)
        print(f"data: {root} (imported, no manifest): training on the first {len(train)} and validating on the "
              f"last {len(val)} of {have} trajectories in {root / 'train'} by name"
              + (f"; {unused} in between unused (raise --n_train to use them)" if unused else ""))
    _write_data_record(workdir, root, source, train, val)
    res = training.train(cfg, str(workdir), train_trajs=train, val_trajs=val, resume=args.resume)
    print(f"done: {res['step']} steps in {res['seconds']:.0f} s; best validation position MAE "
          f"{res['best_val_position_mae_um']:.3f} µm; run directory {workdir}")
    return 0


def _write_data_record(workdir, root, source: str, train, val) -> None:
    """RUN/data.json (atomic; process 0 only): which trajectories this run trains and validates on."""
    import jax
    from pathlib import Path
    from pcmgn_jax.data.trajectory_io import atomic_write_json
    if jax.process_index() != 0:
        return
    item = lambda t: {"name": t.meta.get("name"), "sha256": t.meta.get("source_sha256"),  # noqa: E731
                      "source": t.meta.get("source"), "n_nodes": int(t.n_nodes)}
    Path(workdir).mkdir(parents=True, exist_ok=True)
    atomic_write_json(Path(workdir) / "data.json", {
        "format": "pcmgn_jax.run_data", "format_version": 1, "dataset_dir": str(Path(root).resolve()),
        "source": source, "train": [item(t) for t in train], "val": [item(t) for t in val]})


if __name__ == "__main__":
    sys.exit(cli.run(main))
