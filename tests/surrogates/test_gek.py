"""Gradient-enhanced kriging (surface_fit.GEK, SMT's GEKPLS): on an analytic function of five parameters in SI
units it beats plain kriging at the same number of samples, and its inputs are refused by name."""
import warnings

import numpy as np
import pytest

from pcmgn_jax.surrogates.surface_fit import fit_surface

LO = np.array([4e-3, 0.5, 50e-6, 50e-6, 30e-6])     # the scene family's box [SI]
HI = np.array([6e-3, 0.75, 150e-6, 150e-6, 70e-6])
W = np.array([1.0, 0.5, 0.3, 0.2, 0.1])


def _z(x):
    return 2 * (x - LO) / (HI - LO) - 1


def f(x):
    z = _z(x)
    return np.sin(1.3 * z) @ W + 0.3 * z[:, 0] * z[:, 1]


def grad(x):
    z = _z(x)
    g = 1.3 * np.cos(1.3 * z) * W
    g[:, 0] += 0.3 * z[:, 1]
    g[:, 1] += 0.3 * z[:, 0]
    return g * 2 / (HI - LO)        # per SI unit


def test_gradients_buy_accuracy():
    rng = np.random.default_rng(0)
    x = LO + (HI - LO) * rng.random((12, 5))
    xq = LO + (HI - LO) * (0.1 + 0.8 * rng.random((100, 5)))     # inside the samples' span
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        k = fit_surface("kriging", x, {"q": f(x)})
        g = fit_surface("gek", x, {"q": f(x)}, gradients={"q": grad(x)})
        err_k = np.abs(k.predict(xq)["q"] - f(xq)).mean()
        err_g = np.abs(g.predict(xq)["q"] - f(xq)).mean()
    assert err_g < 0.5 * err_k, (err_g, err_k)


def test_gek_refuses_what_it_cannot_fit():
    x = np.array([[0.0, 1.0], [1.0, 0.0], [0.5, 0.5]])
    with pytest.raises(ValueError, match=r"gek of 'q': needs a scalar quantity and finite gradients \(3, 2\)"):
        fit_surface("gek", x, {"q": np.ones(3)}, gradients={"q": np.ones((3, 3))})
    with pytest.raises(ValueError, match="needs >= 2 varied parameters"):
        fit_surface("gek", x[:, :1], {"q": np.arange(3.0)}, gradients={"q": np.ones((3, 1))})
    with pytest.raises(TypeError):
        fit_surface("gek", x, {"q": np.arange(3.0)})      # no gradients
