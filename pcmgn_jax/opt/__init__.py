"""Design optimisation (paper §5): the constrained design box, surrogate objectives, GA and projected
gradient search, and the solver re-check of every optimum (see experiments/optimize.py)."""
