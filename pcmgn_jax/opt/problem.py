"""The design problem of docs/design.md §8: bounds per design layer and a band on their sum.

Designs are thicknesses [m], shape (B, D). Paper: 50 <= T1, T2 <= 150 µm, 150 <= T1 + T2 <= 250 µm.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class DesignBox:
    low: float = 50e-6        # lower bound of every design variable [m]
    high: float = 150e-6      # upper bound [m]
    sum_low: float = 150e-6   # lower bound on the sum of the design variables [m]
    sum_high: float = 250e-6  # upper bound on the sum [m]
    dim: int = 2              # number of design variables

    def __post_init__(self):
        if not (0 < self.low < self.high and self.sum_low <= self.sum_high):
            raise ValueError(f"design box: need 0 < low < high and sum_low <= sum_high, got {self}")
        if self.dim * self.low > self.sum_high or self.dim * self.high < self.sum_low:
            raise ValueError(f"design box: no design satisfies both the bounds and the sum band ({self})")

    @property
    def n_constraints(self) -> int:
        """The inequality constraints beyond the bounds (:meth:`constraints`: the sum band's two)."""
        return 2

    def constraints(self, designs) -> np.ndarray:
        """(B, 2) inequality constraints g <= 0 [m]: sum_low - sum, sum - sum_high."""
        s = np.atleast_2d(np.asarray(designs, float)).sum(axis=1)
        return np.stack([self.sum_low - s, s - self.sum_high], axis=1)

    def violation(self, designs) -> np.ndarray:
        """(B,) largest violation of any bound or constraint [m] (0 when feasible)."""
        d = np.atleast_2d(np.asarray(designs, float))
        parts = [self.low - d, d - self.high, self.constraints(d)]
        return np.maximum(0.0, np.concatenate(parts, axis=1).max(axis=1))

    def project(self, designs) -> np.ndarray:
        """Euclidean projection onto {low <= d <= high, sum_low <= sum(d) <= sum_high}, (B, D) [m].

        KKT: the projection is clip(d - tau, low, high) with one scalar tau per design (0 when the
        clipped design already meets the band); sum(clip(d - tau)) is monotone in tau, so bisection."""
        d = np.atleast_2d(np.asarray(designs, float))
        out = np.clip(d, self.low, self.high)
        for i, row in enumerate(d):
            s = out[i].sum()
            if self.sum_low <= s <= self.sum_high:
                continue
            target = self.sum_high if s > self.sum_high else self.sum_low
            lo, hi = row.min() - self.high, row.max() - self.low   # sum(clip) = D*high at lo, D*low at hi
            for _ in range(200):
                mid = 0.5 * (lo + hi)
                if np.clip(row - mid, self.low, self.high).sum() > target:
                    lo = mid
                else:
                    hi = mid
            out[i] = np.clip(row - 0.5 * (lo + hi), self.low, self.high)
        return out

    def starts(self, n: int, seed: int = 0) -> np.ndarray:
        """(n, D) feasible starting designs [m]: a seeded Latin hypercube over the box, projected."""
        from scipy.stats import qmc
        z = qmc.LatinHypercube(d=self.dim, rng=np.random.default_rng(seed)).random(n)
        return self.project(self.low + z * (self.high - self.low))

    def grid(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """(n*n, D=2) designs of a regular grid over the box [m] and a (n*n,) feasibility mask."""
        if self.dim != 2:
            raise ValueError("grid: only for two design variables")
        g = np.linspace(self.low, self.high, n)
        d = np.stack(np.meshgrid(g, g, indexing="xy"), axis=-1).reshape(-1, 2)
        return d, self.violation(d) <= 1e-12
