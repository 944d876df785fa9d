"""Training: ``run(cfg, workdir)`` (the pipeline, :mod:`pcmgn_jax.train.pipeline`) and its stages."""
from pcmgn_jax.train.pipeline import run

__all__ = ["run"]
