"""Evaluation scores: ``run(workdir)`` (the pipeline, :mod:`pcmgn_jax.eval.pipeline`), the model and the baselines
scored (:mod:`evaluate`, :mod:`baselines`, :mod:`ensemble`), tables and plots. The predictors it scores are
fitted by :mod:`pcmgn_jax.surrogates` (its registry), the metrics are :mod:`pcmgn_jax.metrics`."""
from pcmgn_jax.eval.pipeline import run

__all__ = ["run"]
