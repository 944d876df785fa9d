"""Train the MeshGraphNet: ``python -m experiments.train [--preset cpu] [--workdir runs/cpu] [--lambda_pen=0]``.

Every TrainConfig field is a flag (``--key=value``; ``--help`` lists them); ``--preset NAME``
fills the defaults (the preset's training settings, pcmgn_jax.presets.PRESETS: tiny, cpu, paper, family, family_tiny,
stack, stack_tiny); plus ``--workdir DIR`` and ``--resume``, which continues the
run from its last checkpoint and refuses flags that change its saved config.json. A workdir that holds a run
is refused without ``--resume`` unless ``--overwrite`` (the earlier run is moved to ``DIR.old-<time>``); a
workdir another process trains in is refused (docs/reliability.md). ``--devices`` splits each
batch over several devices; ``--coordinator_address``, ``--num_processes``, ``--process_id``: several hosts
(README, "Several machines").
On a fresh machine the preset's dataset is generated first (data/<data_preset>, cached).
``--formulation=paper|default|dynamic|realtime`` selects the formulation; its fields are flags of their own
(``--ball_target``, ``--panel_target``, ``--rigid_ball``, ``--contact_projection``, ``--scene_features``...).
``--n_train`` counts training trajectories, validation excluded (the train split holds n_train + n_val).
With ``--lambda_pen`` > 0 the best checkpoint is chosen among validations after the term switched on
(``--lambda_start``); if there were none, the final state is kept and the run says so.

``--dataset_dir DIR`` (pcmgn_jax.data.layout.dataset_source, pcmgn_jax.data.splits.prepare_dataset): a directory
that does not exist or holds a generator manifest gets the preset's designs from the solver (resumable); with a
manifest, the sizes it records are used unless --n_train / --n_val / --n_test say otherwise
(pcmgn_jax.train.pipeline.fit_to_dataset); a directory of
trajectory files without a manifest (``DIR/train/*.json|.h5|.xdmf``, ``DIR/test/...``, e.g. from
``python -m experiments.import_ansys --exports EXPORTS --out DIR``) is trained on as it is: ``--n_train``
by name order, validation on the last ``--n_val`` of DIR/train (pcmgn_jax.data.splits.load_splits);
anything else is a one-line error and nothing is written. RUN/data.json records the dataset directory,
its source (generate | imported) and every training and validation trajectory (name, content hash,
meta 'source', node count).
"""
import sys

from pcmgn_jax import cli


def main(argv=None) -> int:
    args = cli.parse_train(argv, description=__doc__, prog="python -m experiments.train")
    args.initialize_distributed()  # several hosts only (--coordinator_address); before jax computes anything
    from pcmgn_jax.train import run
    from pcmgn_jax.train.loop import best_line
    from pcmgn_jax.train.pipeline import RunFolderError, fit_to_dataset
    cfg = args.config if args.resume else fit_to_dataset(args.config, given=cli.given_flags(argv or sys.argv[1:]))
    try:
        res = run(cfg, args.run_dir, resume=args.resume, overwrite=args.overwrite)
    except RunFolderError as err:   # the library names values; say it in this command's flags
        raise ValueError(flag_message(err)) from None
    print(f"done: {res['step']} steps in {res['seconds']:.0f} s; {best_line(res)}; run directory {args.run_dir}")
    if res.get("best_predates_penalty"):
        print(f"note: --lambda_pen={cfg.lambda_pen:g} never switched on (lambda_start); the kept model was "
              "trained without the penetration term (checkpoint meta best_predates_penalty)")
    return 0


def flag_message(err) -> str:
    """A :class:`pcmgn_jax.train.pipeline.RunFolderError` in this command's flags."""
    if err.reason == "resume_and_overwrite":
        return "--resume and --overwrite exclude each other: continue the run, or start it over"
    if err.reason == "not_a_folder":
        return f"--workdir {err.workdir}: exists and is not a folder"
    return (f"{err.workdir}: holds a run ({', '.join(err.found)}); continue it with --resume, or start over with "
            "--overwrite (moves it aside to WORKDIR.old-<time>)")


if __name__ == "__main__":
    sys.exit(cli.run(main))
