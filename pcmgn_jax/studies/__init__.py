"""Studies: resumable training-and-evaluation cells (:mod:`pcmgn_jax.studies.cells`), the formulation
ablation (:mod:`pcmgn_jax.studies.ablation`) and the paper's studies (:mod:`pcmgn_jax.studies.paper`).

A cell's settings are :meth:`pcmgn_jax.config.TrainConfig.from_preset` keyword arguments (``preset`` among
them); it trains with :func:`pcmgn_jax.train.run` and scores with :func:`pcmgn_jax.eval.run`. The entry
points ``experiments/ablation.py`` and ``experiments/study.py`` parse flags and call these. Training,
evaluation and optimisation never import this package (pyproject.toml, import-linter).
"""
