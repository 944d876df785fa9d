"""The fits: response surfaces of the kind a CAE engineer builds from the same solver runs (kriging, MOP)
over any parameters x and named quantities; no trajectories, no kinds (the adapter is :mod:`surface_kind`).

    k = Kriging(x, {"area_mean": y}, names=names)      # x (B, P) parameters [SI]; y (B,) or (B, M)
    mean, std = k.predict(xq, return_std=True)         # {quantity: (Q,) or (Q, M)} each, y's units
    m = MOP(x, {"area_mean": y}, names=names)          # best of linear / quadratic / rbf / kriging
    m.report()                                         # the CoP of every candidate and the choice
    g = GEK(x, {"area_mean": y}, names=names, gradients={"area_mean": G})   # G (B, P) [y's unit per SI unit]

The kinds over trajectories (the ``kriging`` and ``mop`` kinds: the objective readings over the scene
parameters, the fields over the design) are adapted to the registry in :mod:`pcmgn_jax.surrogates.surface_kind`;
a GP of any other data (a model's residuals, an active loop's samples) is :func:`fit_gp`. Inputs are scaled to
[-1, 1] over the training box; a parameter constant over the training samples is left out of the inputs
(:class:`ParameterBox`). Every fit is float64. A query outside the training range of a parameter is
answered, and recorded: an :class:`ExtrapolationWarning` and a line in the surface's ``warnings`` (a list
of strings for metrics.json).

Candidates (each fitted per quantity; a quantity is a scalar (B,) or a whole field (B, M)):

- ``linear``     least squares in the scaled inputs: 1 + D coefficients
- ``quadratic``  least squares on poly2's features (:func:`regression.poly2_features`): (D + 1)(D + 2) / 2
- ``rbf``        ``scipy.interpolate.RBFInterpolator``, thin-plate spline with a linear tail
- ``kriging``    a Gaussian process (scikit-learn, zero prior mean, kernel :func:`gp_kernel`, seeded
                 restarts); the M outputs of a quantity are centred and share one kernel (:class:`PodGP`)

MOP (optiSLang's Metamodel of Optimal Prognosis) ranks the candidates by the coefficient of prognosis
CoP = 1 - SSE_LOO / SST (:func:`coefficient_of_prognosis`; leave-one-out; SST about the mean, pooled over a
field's outputs; the kriging folds keep the full fit's kernel). The highest CoP wins; candidates within
:data:`COP_TIE` of it go to the simpler one (the order of :data:`CANDIDATES`). A candidate with too few
samples for its leave-one-out fits is reported as not applicable, with the reason.
"""
from __future__ import annotations

import time
import warnings as _warnings
from typing import Callable, Mapping, Sequence

import numpy as np

from pcmgn_jax.metrics import OBJECTIVES, oled_objective_of
from pcmgn_jax.surrogates.regression import poly2_features

CANDIDATES = ("linear", "quadratic", "rbf", "kriging")   # simplest first (MOP's tie-break order)
GP_RESTARTS = 3          # optimiser restarts of the kernel hyperparameters
GP_RANDOM_STATE = 0      # their seed (fits are reproducible)
GEK_DELTA = 1e-3         # gradient-enhanced kriging's Taylor step in the scaled inputs [-1, 1] (:class:`GEK`)
# gek's PLS directions (n_comp) and Taylor points per sample (extra_points): min(D, 5). The fit's cost grows with
# both (a hyperparameter per direction, (1 + extra_points) x B points in the GP): all 26 directions of a stack
# row took 846 s on this project's CPU for 25 samples; the analytic 5-D test that fixed GEK's settings keeps all.
GEK_MAX_DIRECTIONS = 5
COP_TIE = 1e-9           # CoPs closer than this to the best count as equal (the simpler candidate wins)


class ExtrapolationWarning(UserWarning):
    """A surrogate was queried outside the training range of one of its parameters."""


def objective_table(trajs: Sequence, readings: Sequence[str] = OBJECTIVES, *,
                    part: int | None = None) -> dict[str, np.ndarray]:
    """{reading: (B,) objective [MPa]} of trajectories (:func:`metrics.oled_objective_of`, each on its mesh)."""
    return {r: np.array([float(oled_objective_of(t, part=part, reading=r)) for t in trajs]) for r in readings}


class ParameterBox:
    """The training box of parameters ``x`` (B, P) [SI] named ``names``: scaling to [-1, 1] over the D
    parameters that vary, and a record of queries outside it (``warnings``, also ExtrapolationWarning)."""

    def __init__(self, x, names: Sequence[str], *, model: str):
        x = np.asarray(x, np.float64)
        self.names, self.model = tuple(names), model
        if x.ndim != 2 or x.shape[1] != len(self.names) or not len(x):
            raise ValueError(f"{model}: parameters must be (B, {len(self.names)}) for {self.names}, got {x.shape}")
        self._finite(x, "training")
        self.lo, self.hi = x.min(0), x.max(0)
        self.varied = self.hi > self.lo
        self.n_inputs = int(self.varied.sum())                # D, the parameters that vary in training
        if not self.varied.any():
            raise ValueError(f"{model}: every parameter {list(self.names)} is constant over the training samples")
        self.warnings: list[str] = []                        # queries outside the box (for metrics.json)
        self.checking = True    # record queries outside the box (off where leaving it is the point: opt/active.py)


    def scale(self, x, labels: Sequence[str] | None = None) -> np.ndarray:
        """(Q, D) scaled inputs of parameters (Q, P) [SI]; queries outside the box are recorded (``labels``
        name them in the warning, default 'query i')."""
        x = np.atleast_2d(np.asarray(x, np.float64))
        if x.ndim != 2 or x.shape[1] != len(self.names):
            raise ValueError(f"{self.model}: queries must have {len(self.names)} parameters {self.names}, "
                             f"got shape {x.shape}")
        self._finite(x, "query")
        if self.checking:
            self._check(x, labels)
        v = self.varied
        return 2 * (x[:, v] - self.lo[v]) / (self.hi[v] - self.lo[v]) - 1

    def _finite(self, x, what):
        if not np.all(np.isfinite(x)):
            bad = self.names[np.isfinite(x).all(0).argmin()]
            raise ValueError(f"{self.model}: non-finite {what} parameter {bad!r}")

    def _check(self, x, labels):
        tol = 1e-9 * np.maximum(self.hi - self.lo, np.maximum(np.abs(self.lo), np.abs(self.hi)))
        for i, row in enumerate(x):
            for k in np.flatnonzero((row < self.lo - tol) | (row > self.hi + tol)):
                how = "extrapolated" if self.varied[k] else \
                    f"held fixed at {self.lo[k]:.6g} in training: answered as if it were unchanged"
                label = labels[i] if labels is not None else f"query {i}"
                self.note(f"{label}: {self.names[k]} = {row[k]:.6g} outside the training range "
                          f"[{self.lo[k]:.6g}, {self.hi[k]:.6g}] ({how})")

    def note(self, msg: str) -> None:
        """Record a departure from the training data (once): '<model>: <msg>' in ``warnings``, and warn."""
        msg = f"{self.model}: {msg}"
        if msg not in self.warnings:
            self.warnings.append(msg)
            _warnings.warn(msg, ExtrapolationWarning, stacklevel=3)


def gp_kernel(n_inputs: int):
    """The kriging kernel over ``n_inputs`` scaled inputs: C · Matérn(ν = 2.5, anisotropic) + White."""
    from sklearn.gaussian_process.kernels import ConstantKernel, Matern, WhiteKernel
    return (ConstantKernel(1.0, (1e-3, 1e3)) * Matern(np.ones(n_inputs), (1e-2, 1e3), nu=2.5)
            + WhiteKernel(1e-6, (1e-12, 1e-1)))


class PodGP:
    """One GP with a shared kernel on outputs Y (B, M) over scaled inputs z (B, D), through the SVD of the
    centred outputs Y - mean = U S Vᵀ: the GP runs on the r coefficient columns U S, divided by one factor
    to unit mean square (M may be a whole field; the data-fit term of the likelihood is that of a GP on
    all M outputs). ``energy``: keep the fewest modes holding that fraction of sum S² (None: every mode
    above 1e-12 of the largest). ``kernel``: fixed hyperparameters (no optimisation); None:
    :func:`gp_kernel`, optimised. Attributes: ``n_modes`` r, ``energy_kept``, ``kernel_`` (fitted)."""

    def __init__(self, z, Y, *, energy: float | None = None, kernel=None, restarts: int = GP_RESTARTS,
                 random_state: int = GP_RANDOM_STATE):
        z = np.asarray(z, np.float64)
        Y = np.asarray(Y, np.float64).reshape(len(z), -1)
        if energy is not None and not 0 < energy <= 1:
            raise ValueError(f"POD energy cut-off must be in (0, 1], got {energy}")
        self.mean = Y.mean(0)
        U, S, Vt = np.linalg.svd(Y - self.mean, full_matrices=False)
        r = int((S > S[0] * 1e-12).sum()) if S.size and S[0] > 0 else 0
        if energy is not None and r:
            frac = np.cumsum(S[:r] ** 2) / np.sum(S[:r] ** 2)
            r = min(r, int(np.searchsorted(frac, energy * (1 - 1e-12))) + 1)
        self.n_modes = r
        self.energy_kept = float(np.sum(S[:r] ** 2) / np.sum(S ** 2)) if r else 1.0
        coef = U[:, :r] * S[:r]
        scale = float(np.sqrt(np.mean(coef ** 2))) if r else 1.0
        self.basis = Vt[:r] * scale                            # (r, M): Y ≈ mean + coefficients @ basis
        self.gp = self.kernel_ = None
        if r:
            from sklearn.exceptions import ConvergenceWarning
            from sklearn.gaussian_process import GaussianProcessRegressor
            fixed = dict(optimizer=None) if kernel is not None else dict(n_restarts_optimizer=restarts)
            gp = GaussianProcessRegressor(kernel=gp_kernel(z.shape[1]) if kernel is None else kernel,
                                          normalize_y=False, random_state=random_state, **fixed)
            with _warnings.catch_warnings():   # noise-free solver data drives the noise to its lower bound
                _warnings.simplefilter("ignore", ConvergenceWarning)
                self.gp = gp.fit(z, coef / scale)
            self.kernel_ = self.gp.kernel_

    def predict(self, z) -> tuple[np.ndarray, np.ndarray]:
        """(mean (Q, M), std (Q, M)) in Y's units at scaled inputs z (Q, D): the posterior mean and std."""
        z = np.atleast_2d(np.asarray(z, np.float64))
        if self.gp is None:
            return np.tile(self.mean, (len(z), 1)), np.zeros((len(z), len(self.mean)))
        a, sd = self.gp.predict(z, return_std=True)
        a, sd = np.reshape(a, (len(z), -1)), np.reshape(sd, (len(z), -1))
        return self.mean + a @ self.basis, np.sqrt(sd ** 2 @ self.basis ** 2)

    def __call__(self, z, return_std: bool = False):
        """The posterior mean (Q, M) at z (Q, D), or (mean, std) with ``return_std``."""
        return self.predict(z) if return_std else self.predict(z)[0]


def _poly_fit(degree: int) -> Callable:
    def fit(z, Y):
        def features(q):
            return poly2_features(q)[:, : 1 + q.shape[-1] if degree == 1 else None]
        coef = np.linalg.lstsq(features(z), Y, rcond=None)[0]
        return lambda q: features(np.atleast_2d(q)) @ coef
    return fit


def _rbf_fit(z, Y):
    from scipy.interpolate import RBFInterpolator
    return RBFInterpolator(z, Y, kernel="thin_plate_spline", degree=1)


_FITS = {"linear": _poly_fit(1), "quadratic": _poly_fit(2), "rbf": _rbf_fit, "kriging": PodGP}


def not_applicable(candidate: str, n_samples: int, n_inputs: int) -> str | None:
    """Why ``candidate`` cannot be fitted and cross-validated on ``n_samples`` in ``n_inputs`` varied
    parameters (its leave-one-out fits see n_samples - 1), or None when it can."""
    if candidate not in CANDIDATES:
        raise ValueError(f"candidate must be one of {CANDIDATES}, got {candidate!r}")
    p = {"linear": n_inputs + 1, "quadratic": (n_inputs + 1) * (n_inputs + 2) // 2,
         "rbf": n_inputs + 1, "kriging": 2}[candidate]
    if n_samples - 1 >= p:
        return None
    what = {"kriging": "two samples per fit", "rbf": f"a linear tail in {n_inputs} parameters"}
    return (f"needs >= {p + 1} training samples for leave-one-out "
            f"({what.get(candidate, f'{p} coefficients in {n_inputs} parameters')}), got {n_samples}")


def coefficient_of_prognosis(y, y_pred) -> float | None:
    """CoP = 1 - sum (y - y_pred)² / sum (y - mean y)², pooled over the outputs of y (B,) or (B, M);
    ``y_pred``: the leave-one-out predictions. None when SST = 0 (a constant quantity: CoP undefined)."""
    y, p = np.asarray(y, np.float64), np.asarray(y_pred, np.float64)
    if y.shape != p.shape:
        raise ValueError(f"CoP: prediction shape {p.shape} != truth shape {y.shape}")
    sst = float(((y - y.mean(0)) ** 2).sum())
    if not sst > 1e-24 * float((y ** 2).sum()):
        return None
    return 1.0 - float(((y - p) ** 2).sum()) / sst


def loo_predictions(fit: Callable, z, Y) -> np.ndarray:
    """(B, M) leave-one-out predictions: sample i predicted by ``fit`` (z, Y) -> model on the others."""
    out = np.empty_like(Y)
    for i in range(len(z)):
        keep = np.arange(len(z)) != i
        out[i] = np.reshape(fit(z[keep], Y[keep])(z[i:i + 1]), -1)
    return out


class SurfaceFit:
    """Per-quantity fits over a :class:`ParameterBox`; ``predict`` -> {quantity: (Q,) or (Q, M)}."""

    name = "surface"

    def __init__(self, x, quantities: Mapping[str, np.ndarray], *, names: Sequence[str]):
        t0 = time.perf_counter()
        self.box = ParameterBox(x, names, model=self.name)
        self.z, self.warnings = self.box.scale(x), self.box.warnings   # warnings: the box's list
        if not quantities:
            raise ValueError(f"{self.name}: no quantities to fit")
        self.scalar, self.y = {}, {}
        for q, y in quantities.items():
            y = np.asarray(y, np.float64)
            if y.ndim not in (1, 2) or len(y) != len(self.z):
                raise ValueError(f"{self.name}: quantity {q!r} must be ({len(self.z)},) or ({len(self.z)}, M), "
                                 f"one row per sample, got {y.shape}")
            if not np.all(np.isfinite(y)):
                raise ValueError(f"{self.name}: quantity {q!r} has non-finite training values")
            self.scalar[q], self.y[q] = y.ndim == 1, y.reshape(len(self.z), -1)
        self.models = {q: self._fit(q, Y) for q, Y in self.y.items()}
        self.fit_seconds = time.perf_counter() - t0

    def _out(self, q, a):
        return a[:, 0] if self.scalar[q] else a

    def predict(self, x, labels: Sequence[str] | None = None) -> dict[str, np.ndarray]:
        """{quantity: (Q,) or (Q, M)} at parameters x (Q, P) [SI]."""
        z = self.box.scale(x, labels)
        return {q: self._out(q, np.reshape(m(z), (len(z), -1))) for q, m in self.models.items()}


class Kriging(SurfaceFit):
    """A GP response surface per quantity (module docstring, ``kriging``), with its posterior std."""

    name = "kriging"

    def _fit(self, q, Y):
        if (why := not_applicable("kriging", len(Y), self.box.n_inputs)) is not None:
            raise ValueError(f"kriging of {q!r}: {why}")
        return PodGP(self.z, Y)

    def predict(self, x, labels=None, *, return_std: bool = False):
        """{quantity: mean} at x (Q, P) [SI], or (means, stds) with ``return_std`` (same units)."""
        if not return_std:
            return super().predict(x, labels)
        got = {q: m.predict(self.box.scale(x, labels)) for q, m in self.models.items()}
        return tuple({q: self._out(q, pair[i]) for q, pair in got.items()} for i in (0, 1))


class MOP(SurfaceFit):
    """optiSLang-style Metamodel of Optimal Prognosis: per quantity the candidate of best leave-one-out
    CoP (module docstring); ``choice`` {quantity: candidate}, ``cop`` {quantity: {candidate: CoP | None}},
    ``reasons`` {quantity: {candidate: why not applicable / why no CoP}}."""

    name = "mop"

    def __init__(self, x, quantities, *, names, candidates: Sequence[str] = CANDIDATES):
        unknown = [c for c in candidates if c not in CANDIDATES]
        if unknown or not candidates:
            raise ValueError(f"mop candidates must be a non-empty subset of {CANDIDATES}, got {list(candidates)}")
        self.candidates = tuple(c for c in CANDIDATES if c in candidates)
        self.choice, self.cop, self.reasons = {}, {}, {}
        super().__init__(x, quantities, names=names)

    def _fit(self, q, Y):
        cops, reasons, full = {}, {}, {}
        for c in self.candidates:
            why = not_applicable(c, len(Y), self.box.n_inputs)
            if why is None:
                fit = _FITS[c]
                if c == "kriging":   # the folds keep the full fit's kernel
                    full[c] = PodGP(self.z, Y)
                    fit = lambda z, y, k=full[c].kernel_: PodGP(z, y, kernel=k)  # noqa: E731
                try:
                    cops[c] = coefficient_of_prognosis(Y, loo_predictions(fit, self.z, Y))
                except np.linalg.LinAlgError as e:   # e.g. rbf on samples that lie on a line
                    why = f"a leave-one-out fit failed: {e}"
                if cops.get(c, 0.0) is None:
                    why = "the quantity is constant over the training samples (SST = 0): CoP undefined"
            if why is not None:
                reasons[c] = why
        if not cops:
            raise ValueError(f"mop of {q!r}: no candidate applies: {reasons}")
        scored = [c for c in cops if cops[c] is not None]
        best = max((cops[c] for c in scored), default=None)
        self.choice[q] = next(c for c in scored if cops[c] >= best - COP_TIE) if scored else next(iter(cops))
        self.cop[q] = {c: cops.get(c) for c in self.candidates}
        self.reasons[q] = reasons
        return full.get(self.choice[q]) or _FITS[self.choice[q]](self.z, Y)

    def report(self) -> dict:
        """JSON-able {quantity: {chosen, cop: {candidate: float | None}, not_applicable: {candidate: why}}}."""
        return {q: dict(chosen=self.choice[q], cop=dict(self.cop[q]), not_applicable=dict(self.reasons[q]))
                for q in self.choice}


class GEK(SurfaceFit):
    """Gradient-enhanced kriging of scalar quantities with their gradients: SMT's ``GEKPLS`` (Bouhlel & Martins
    2019: kriging over PLS directions, each training point joined by first-order Taylor points along them).
    ``gradients`` {quantity: (B, P) [the quantity's unit per SI unit of each parameter]}; in the scaled inputs
    z the derivative is g (hi - lo) / 2. A parameter constant over the training samples (an absent-everywhere
    stack slot, a flag that never changes) is left out of the inputs, its gradient column with it, as kriging
    leaves it (:class:`ParameterBox`). Settings fixed before any project data was seen (a 5-D analytic test
    function): every direction up to :data:`GEK_MAX_DIRECTIONS` (``n_comp`` = ``extra_points`` =
    min(D, 5)), Taylor step :data:`GEK_DELTA` in z. ``smt`` {quantity: the fitted SMT model}."""

    name = "gek"

    def __init__(self, x, quantities, *, names, gradients: Mapping[str, np.ndarray]):
        self.gradients, self.smt = gradients, {}
        super().__init__(x, quantities, names=names)

    def _fit(self, q, Y):
        from smt.surrogate_models import GEKPLS
        G = np.asarray(self.gradients.get(q, np.zeros(0)), np.float64)
        if Y.shape[1] != 1 or G.shape != (len(Y), len(self.box.names)) or not np.all(np.isfinite(G)):
            raise ValueError(f"gek of {q!r}: needs a scalar quantity and finite gradients ({len(Y)}, "
                             f"{len(self.box.names)}) for {self.box.names}, got {Y.shape[1]} output(s), {G.shape}")
        v, D = self.box.varied, self.box.n_inputs
        if D < 2 or len(Y) < 2:   # SMT builds its Taylor points for 2 or more inputs
            raise ValueError(f"gek of {q!r}: SMT's GEKPLS needs >= 2 varied parameters and >= 2 samples, got "
                             f"{D} and {len(Y)}; kriging fits one parameter")
        dz = G[:, v] * (self.box.hi[v] - self.box.lo[v]) / 2
        k = min(D, GEK_MAX_DIRECTIONS)
        m = GEKPLS(xlimits=np.tile([-1.0, 1.0], (D, 1)), n_comp=k, extra_points=k, delta_x=GEK_DELTA,
                   print_global=False)
        m.set_training_values(self.z, Y[:, 0])
        for k in range(D):
            m.set_training_derivatives(self.z, dz[:, k], k)
        with _warnings.catch_warnings():    # sklearn's PLS on exact Taylor points: 'y residual is constant'
            _warnings.simplefilter("ignore", UserWarning)
            m.train()
        self.smt[q] = m
        return lambda z: m.predict_values(np.asarray(z, np.float64))[:, 0]


SURFACES = {fit.name: fit for fit in (Kriging, MOP, GEK)}   # by the fits' names (the kinds' names)


def fit_surface(kind: str, x, quantities: Mapping[str, np.ndarray], *, names: Sequence[str] | None = None,
                checking: bool = True, **options) -> SurfaceFit:
    """A :class:`Kriging`, :class:`MOP` or :class:`GEK` (``kind`` 'kriging' | 'mop' | 'gek'; ``options`` the
    class's own: GEK's ``gradients``) of ``quantities`` {name: (B,) or (B, M)}
    over x (B, P) [SI], named ``names`` (default ``x[0]``, ``x[1]``, ...: the names its warnings use).
    ``checking`` False: queries outside the samples' span are neither warned about nor recorded (where leaving
    the span is the point, e.g. an active loop's candidates). ValueError naming ``kind`` when it is neither."""
    if kind not in SURFACES:
        raise ValueError(f"response surface must be one of {tuple(SURFACES)}, got {kind!r}")
    if names is None:
        names = [f"x[{i}]" for i in range(np.shape(x)[1] if np.ndim(x) == 2 else 0)]
    with _warnings.catch_warnings():
        if not checking:
            _warnings.simplefilter("ignore", ExtrapolationWarning)
        out = SURFACES[kind](x, quantities, names=names, **options)
    out.box.checking = checking
    return out


def fit_gp(x, quantities: Mapping[str, np.ndarray], *, names: Sequence[str] | None = None,
           checking: bool = True) -> Kriging:
    """A kriging GP of arbitrary data: ``quantities`` {name: (B,) or (B, M), any units} over x (B, P) [SI];
    ``predict(xq, return_std=True)`` gives {name: mean}, {name: std} in the quantities' units. The one way
    to build a GP outside the kinds (a model's residual GP, an active loop's samples): :func:`fit_surface`."""
    return fit_surface("kriging", x, quantities, names=names, checking=checking)
