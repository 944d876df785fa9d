"""Surrogates: every predictor of the fields or the objective behind one interface and one registry.

- :mod:`kinds`: the one list of predictor kinds (:data:`~kinds.KINDS`), the :class:`~kinds.Surrogate` interface
  (fields and objective, ``predict_objective``) and its one refusal (:class:`~kinds.CannotAnswer`)
- :mod:`registry`: ``fit(kind, train, ...)``, the one way to fit any kind
- the families: :mod:`regression` (none, nearest, poly2, rbf), :mod:`surface_kind` (kriging, mop; the fits in
  :mod:`surface_fit`, also :func:`~surface_fit.fit_gp`: a GP of any data), :mod:`rom` (rom, rom_contact, the
  stack rom), :mod:`mgn` (a trained run), :mod:`onepass` (a trained one-pass run)
- helpers: :mod:`objective` (a fields kind's objective, by the shared metric), :mod:`inputs` (designs, scene
  parameters), :mod:`transfer` (fields between meshes),
  :mod:`correction` (a baseline-corrected rollout's arithmetic), :mod:`residual` (a residual run's targets)

This package imports nothing at import time (the run config reads :mod:`kinds` without the families):
``from pcmgn_jax.surrogates.registry import fit``.
"""
