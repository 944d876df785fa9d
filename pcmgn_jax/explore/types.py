"""The explorer's vocabulary: its predictors and their labels, a slider, a prediction, a solver check, a view.

The predictors are the registry's kinds with ``explore`` (:data:`pcmgn_jax.surrogates.kinds.KINDS`), in its
order, labelled by it; the page prefers them by their ``rank`` (:func:`pcmgn_jax.surrogates.kinds.by_rank`).
"""
from __future__ import annotations

import threading
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np

from pcmgn_jax.data.stack import display
from pcmgn_jax.surrogates.kinds import KINDS, names
from pcmgn_jax.trajectory import Trajectory

PREDICTORS = names(explore=True)
LABELS = {k: KINDS[k].label for k in PREDICTORS}
DEFAULT_LIVE_SECONDS = 0.6  # the default predictor runs at once on a slider move when it takes at most this [s]
OTHER_LIVE_SECONDS = 0.1    # any other predictor too when it takes at most this [s]; slower ones follow the page
WIDEN = 0.25         # the sliders reach this fraction of the training box's span beyond each side
CACHE_DESIGNS = 8    # designs whose predictions (full fields) are kept


class RunError(ValueError):
    """A run directory the explorer cannot open (the message says what is missing and how to make it)."""


@dataclass(frozen=True)
class Parameter:
    """A slider: scene parameter ``name`` with its training box [low, high] [SI]; the page shows
    ``value * scale`` in ``unit``."""

    name: str
    low: float
    high: float
    unit: str
    scale: float
    label: str

    @property
    def varied(self) -> bool:
        return self.high > self.low

    def outside(self, value: float) -> bool:
        """``value`` [SI] lies outside the training box (beyond round-off)."""
        tol = 1e-9 * max(self.high - self.low, abs(self.high))
        return bool(value < self.low - tol or value > self.high + tol)

    @property
    def heading(self) -> str:
        """'label [unit]', or the label alone for a unitless parameter (a stack's presence flag)."""
        return f"{self.label} [{self.unit}]" if self.unit else self.label

    def text(self, *values: float) -> str:
        """Values [SI] on the page: '30 µm', or a range '50–150 µm'."""
        return "–".join(f"{v * self.scale:.4g}" for v in values) + f" {self.unit}"

    def slider_range(self) -> tuple[float, float]:
        """(min, max) of the slider [SI]: the training box widened by ``WIDEN`` of its span (or of the
        value, for a parameter training held fixed) on each side, kept positive."""
        w = WIDEN * ((self.high - self.low) if self.varied else abs(self.low))
        return max(self.low - w, 0.1 * self.low), self.high + w


def parameter(name: str, low: float, high: float) -> Parameter:
    """The slider of scene parameter ``name`` ('ball.radius' [m], 'ball.velocity' [m/s], a layer name
    (its thickness [m]), or a panel stack's padded-row name (:func:`pcmgn_jax.data.stack.display`: a layer's
    thickness, log10 modulus or presence flag)) over the training box [low, high]."""
    if name == "ball.velocity":
        return Parameter(name, low, high, "m/s", 1.0, "drop speed")
    if name == "ball.radius":
        return Parameter(name, low, high, "mm", 1e3, "ball radius")
    if (shown := display(name)) is not None:
        label, unit, scale = shown
        return Parameter(name, low, high, unit, scale, label)
    return Parameter(name, low, high, "µm", 1e6, f"{name} thickness")


class Prediction(NamedTuple):
    """One predictor's answer at a design."""

    name: str
    objective_mpa: float | None   # the OLED objective [MPa] (None: not applicable, see note)
    std_mpa: float | None         # its uncertainty [MPa]: kriging's GP posterior std, else None
    u: np.ndarray | None          # (T, N, 2) displacement [m] on the design's mesh (None: no fields)
    vm: np.ndarray | None         # (T, N) von Mises [Pa]
    seconds: float                # wall time of the prediction [s]
    note: str = ""                # why there is no value, or what the value is of


class Truth(NamedTuple):
    """The built-in solver's answer at a design (a solver check)."""

    traj: Trajectory              # ROI-cropped trajectory on the design's mesh
    force: np.ndarray             # (T,) contact force on the ball at each frame [N] (0 at t = 0)
    objective_mpa: float          # the OLED objective [MPa]
    seconds: float                # solver wall time [s]


class View(NamedTuple):
    """Everything the page shows for a design (see :meth:`Explorer.view`)."""

    headline: str                 # the default predictor's objective with its uncertainty, or why not
    rows: list                    # one dict per predictor (and the truth): name, label, text, error, test
    flags: list                   # out-of-box messages for this design ([] inside the box)
    notes: list                   # run-level notes (no checkpoint, no metrics, MGN on release, ...)
    show: str                     # whose fields the figures draw ('truth', 'error:<predictor>', or a predictor)
    figures: dict                 # 'field', 'oled', 'history', 'box': Plotly figure dicts


class Cache:
    """A small thread-safe LRU map (the page's callbacks run in the web server's threads)."""

    def __init__(self, size: int):
        self.size, self.items, self.lock = size, OrderedDict(), threading.Lock()

    def get(self, key, default=None):
        with self.lock:
            if key not in self.items:
                return default
            self.items.move_to_end(key)
            return self.items[key]

    def put(self, key, value):
        with self.lock:
            self.items[key] = value
            self.items.move_to_end(key)
            while len(self.items) > self.size:
                self.items.popitem(last=False)
        return value


def has_checkpoint(run: Path) -> bool:
    """Whether the run directory holds a saved model (RUN/checkpoints/best or /periodic)."""
    return any(p.name.isdigit() for sub in ("best", "periodic") for p in (run / "checkpoints" / sub).glob("*"))


def design_key(x) -> tuple:
    """The cache key of a design x (P,) [SI]: its values to 9 significant digits."""
    return tuple(float(f"{v:.9g}") for v in np.asarray(x, float))
