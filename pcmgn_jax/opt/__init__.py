"""Design optimisation (paper §5): the constrained design box, surrogate objectives, GA and projected
gradient search, and the solver re-check of every optimum; ``run(workdir, ...)`` is the pipeline
(:mod:`pcmgn_jax.opt.pipeline`, called by experiments/optimize.py)."""
from pcmgn_jax.opt.pipeline import run

__all__ = ["run"]
