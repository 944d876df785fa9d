"""Gradient-enhanced kriging (surface_fit.GEK, SMT's GEKPLS): on an analytic function of five parameters in SI
units it beats plain kriging at the same number of samples; past five varied parameters it keeps five PLS
directions; a constant column is left out; and its inputs are refused by name."""
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


def test_directions_capped_and_constant_columns_left_out():
    """Seven varied parameters: SMT is given GEK_MAX_DIRECTIONS (5) PLS directions and as many Taylor points per
    sample, not 7. A column constant over the training samples (an absent stack slot, a flag that never changes)
    is left out of the inputs with its gradient, as kriging leaves it out: the fit with it equals the fit
    without it."""
    from pcmgn_jax.surrogates.surface_fit import GEK_MAX_DIRECTIONS
    rng = np.random.default_rng(2)
    w = np.linspace(1.0, 0.2, 7)
    x = rng.uniform(-1, 1, (10, 7))
    y, g = np.sin(x) @ w, np.cos(x) * w
    xq = rng.uniform(-0.8, 0.8, (20, 7))
    pad = lambda a, v: np.insert(a, 3, v, axis=1)    # noqa: E731  a constant 4th column (value v)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        plain = fit_surface("gek", x, {"q": y}, gradients={"q": g})
        padded = fit_surface("gek", pad(x, 0.0), {"q": y}, gradients={"q": pad(g, 5.0)})
        krig = fit_surface("kriging", pad(x, 0.0), {"q": y})
        got, want = padded.predict(pad(xq, 0.0))["q"], plain.predict(xq)["q"]
    assert GEK_MAX_DIRECTIONS == 5 and padded.box.n_inputs == krig.box.n_inputs == 7
    m = padded.smt["q"]
    assert (m.options["n_comp"], m.options["extra_points"]) == (5, 5)
    assert m.training_points[None][0][0].shape[1] == 7                   # the constant column is not an input
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-12)
    assert np.all(np.isfinite(want))
