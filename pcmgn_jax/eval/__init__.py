"""Evaluation: ``run(workdir)`` (the pipeline, :mod:`pcmgn_jax.eval.pipeline`), metrics, baselines and plots."""
from pcmgn_jax.eval.pipeline import run

__all__ = ["run"]
