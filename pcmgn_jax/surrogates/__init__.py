"""Surrogates: every predictor of the fields or the objective behind one interface and one registry.

- :mod:`kinds`: the one list of predictor kinds (:data:`~kinds.KINDS`) and the :class:`~kinds.Surrogate` interface
- :mod:`registry`: ``fit(kind, train, ...)``, the one way to fit any kind
- the families: :mod:`regression` (none, nearest, poly2, rbf), :mod:`surface_kind` (kriging, mop; the fits in
  :mod:`surface_fit`), :mod:`rom` (rom, rom_contact, the stack rom), :mod:`mgn` (a trained run)
- helpers: :mod:`inputs` (designs, scene parameters), :mod:`transfer` (fields between meshes),
  :mod:`correction` (a baseline-corrected rollout's arithmetic), :mod:`residual` (a residual run's targets)

This package imports nothing at import time (the run config reads :mod:`kinds` without the families):
``from pcmgn_jax.surrogates.registry import fit``.
"""
