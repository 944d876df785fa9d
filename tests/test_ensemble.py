"""Trust figures (issue 26): Spearman on constructed cases, and the ensemble report on a tiny run."""
from __future__ import annotations

import numpy as np
import pytest

from pcmgn_jax.eval.ensemble import _collapse, _node_figures, spearman


def test_spearman_on_constructed_cases():
    e = np.array([0.1, 0.5, 0.2, 3.0, 1.0])
    assert spearman(e * 2 + 1, e)["rho"] == pytest.approx(1.0)            # any increasing map ranks perfectly
    assert spearman(np.exp(-e), e)["rho"] == pytest.approx(-1.0)
    assert spearman([1, 2, 3, 4], [1, 3, 2, 4])["rho"] == pytest.approx(0.8)   # 1 - 6·2 / (4·15)
    assert spearman([1, 2], [1, 2])["rho"] is None                           # too few
    got = spearman([1, 1, 1], [1, 2, 3])
    assert got["rho"] is None and "constant" in got["why"]
    with pytest.raises(ValueError, match="shape"):
        spearman([1, 2, 3], [1, 2])
    with pytest.raises(ValueError, match="non-finite"):
        spearman([1, np.nan, 3], [1, 2, 3])


def test_node_figures_and_the_collapse_ratio():
    class T:  # a trajectory with a known displacement
        displacement = np.zeros((2, 3, 2))
    # two members at +-d around a mean off the truth by m: spread = std (ddof 1) = d·√2, error = m
    d, m = 1e-6, np.array([1e-6, 2e-6, 4e-6])
    u0 = np.zeros((2, 3, 2))
    u0[..., 0] = m + d
    u1 = np.zeros((2, 3, 2))
    u1[..., 0] = m - d
    spread, err = _node_figures([[u0], [u1]], [T()])
    np.testing.assert_allclose(spread, np.full(3, np.sqrt(2)), rtol=1e-12)   # µm
    np.testing.assert_allclose(err, m * 1e6, rtol=1e-12)
    assert _collapse(spread, err) == pytest.approx(np.sqrt(2) / (7 / 3))
    assert _collapse(spread, np.zeros(3)) is None
