"""Acquisition functions for minimising an objective under a surrogate's uncertainty.

    ei = expected_improvement(mean, std, best)      # (Q,) >= 0, in the objective's units
    lcb = lower_confidence_bound(mean, std, kappa)  # (Q,), smaller is better
    i = propose(mean, std, best, kind="ei")         # the index of the candidate to run next

``mean`` and ``std`` are a surrogate's prediction and its spread at Q candidates (any one unit, e.g. MPa);
``best`` is the smallest solver value seen so far. Expected improvement (Jones et al. 1998, minimisation):
EI = (best - mean - xi) Φ(z) + std φ(z), z = (best - mean - xi) / std; where std is 0 (a candidate the
surrogate is sure of) EI is the plain improvement max(best - mean - xi, 0), never a 0/0. Written here
rather than taken from scikit-optimize: skopt's ``gaussian_ei`` needs its own model objects and the package
is unmaintained since 2021; the formula is three lines on scipy.stats.norm.
"""
from __future__ import annotations

import numpy as np
from scipy.stats import norm

ACQUISITIONS = ("ei", "lcb", "mean")
KAPPA = 2.0        # lower confidence bound: mean - KAPPA * std
XI = 0.0           # expected improvement: the improvement margin (objective units)
STD_FLOOR = 1e-12  # below this std a candidate counts as certain (objective units)


def _pair(mean, std) -> tuple[np.ndarray, np.ndarray]:
    m, s = np.asarray(mean, np.float64).reshape(-1), np.asarray(std, np.float64).reshape(-1)
    if m.shape != s.shape:
        raise ValueError(f"acquisition: mean {m.shape} and std {s.shape} differ in shape")
    if not (np.all(np.isfinite(m)) and np.all(np.isfinite(s))):
        raise ValueError("acquisition: non-finite mean or std")
    if np.any(s < 0):
        raise ValueError(f"acquisition: negative std (min {s.min():.3g})")
    return m, s


def expected_improvement(mean, std, best: float, xi: float = XI) -> np.ndarray:
    """(Q,) expected improvement below ``best`` (module docstring), >= 0, in the objective's units."""
    m, s = _pair(mean, std)
    imp = float(best) - m - xi
    sure = s <= STD_FLOOR
    z = np.where(sure, 0.0, imp / np.where(sure, 1.0, s))
    ei = imp * norm.cdf(z) + s * norm.pdf(z)
    return np.where(sure, np.maximum(imp, 0.0), np.maximum(ei, 0.0))


def lower_confidence_bound(mean, std, kappa: float = KAPPA) -> np.ndarray:
    """(Q,) mean - kappa * std (objective units): optimistic by kappa standard deviations."""
    m, s = _pair(mean, std)
    if not kappa >= 0:
        raise ValueError(f"lower confidence bound: kappa must be >= 0, got {kappa}")
    return m - kappa * s


def scores(mean, std, best: float, kind: str = "ei", *, kappa: float = KAPPA, xi: float = XI) -> np.ndarray:
    """(Q,) acquisition scores, larger is better: EI, -LCB or -mean (``kind`` 'ei' | 'lcb' | 'mean')."""
    if kind == "ei":
        return expected_improvement(mean, std, best, xi)
    if kind == "lcb":
        return -lower_confidence_bound(mean, std, kappa)
    if kind == "mean":
        return -_pair(mean, std)[0]
    raise ValueError(f"acquisition must be one of {ACQUISITIONS}, got {kind!r}")


def propose(mean, std, best: float, kind: str = "ei", *, exclude=None, **kw) -> int:
    """Index of the candidate with the best score (:func:`scores`); ``exclude`` (Q,) bool marks candidates
    not to pick (e.g. already run). Ties go to the lowest mean, then the lowest index. Raises
    ``ValueError`` when every candidate is excluded."""
    sc = scores(mean, std, best, kind, **kw)
    m = np.asarray(mean, np.float64).reshape(-1)
    ok = np.ones(len(sc), bool) if exclude is None else ~np.asarray(exclude, bool).reshape(-1)
    if not ok.any():
        raise ValueError("acquisition: every candidate is excluded (all were run already)")
    top = np.max(sc[ok])
    tied = np.flatnonzero(ok & (sc >= top - 1e-15 * max(1.0, abs(top))))
    return int(tied[np.argmin(m[tied])])
