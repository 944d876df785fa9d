"""The predictor kinds: the one list (:data:`KINDS`) and the interface every fitted kind offers (:class:`Surrogate`).

    from pcmgn_jax.surrogates.registry import fit
    s = fit("rom", train)                      # any kind of KINDS (registry.fit: which family fits it)
    us, vms = s.predict_trajectories(test)     # fields on each query's own mesh: lists (T, N, 2) [m], (T, N) [Pa]
    f = s.predict_objective(test, reading="area_mean")   # (B,) [MPa]: every kind, fields kinds by their fields
    f = s.predict_objective_at(designs, reading="area_mean")   # (B,) [MPa] at data.family.Design objects: surfaces
    s.fit_seconds, s.warnings

What a kind cannot answer (an objective surface asked for fields, the one-pass model for per-frame fields, a
kind without a posterior std for one, a kind whose objective needs each design's mesh for it at designs alone) it
refuses through the same call with :class:`CannotAnswer`, naming the kind and what it cannot answer.

Every list of predictors in the project is a subset of :data:`KINDS` chosen by one of its fields
(:func:`names`): evaluate's baselines (``baseline``), the explorer's predictors (``explore``), the
optimiser's surrogates (``optimise``), the active loop's (``active``), the bases a ``residual_of`` run
can correct (``residual_base``). This module imports nothing of the library (the run config validates
``residual_of`` against it); the fitting lives in the family modules, bound in :mod:`registry`.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, Sequence, runtime_checkable


@dataclass(frozen=True)
class Kind:
    """One predictor kind: how it is fitted (``family``: a module of this package, :data:`registry.FITTERS`)
    and where it is used.

    ``fields``: where it predicts fields: 'any' (each query on its own mesh), 'shared' (one shared mesh
    of training and queries), '' (no fields: objective readings only); where its objective comes from is the
    fitted surrogate's to say (:class:`Surrogate` ``objective_surface``). ``std``: its objective comes
    with a posterior std. ``rank``: the explorer's preference (lower first: its default predictor and the
    order of the field figures). ``floor``: a reference floor (zero fields), never a default."""

    name: str
    label: str                  # what the explorer's page calls it
    family: str                 # 'mgn' | 'regression' | 'surface' | 'rom' | 'time_fields' (registry.FITTERS)
    fields: str = "any"
    std: bool = False
    baseline: bool = True       # fitted on the training split and scored beside the model by evaluate
    explore: bool = True        # offered by the explorer
    curve: bool = False         # drawn beside the MGN in a learning curve (eval/learning_curve.py)
    optimise: bool = False      # a surrogate of the design optimiser (opt/pipeline.py)
    active: bool = False        # a surrogate of the active loop (opt/active.py)
    residual_base: bool = False  # a baseline a residual_of run can learn the correction of
    gradients: bool = False     # fitted with the solver's gradients at the training designs (data/gradients.py)
    gradient_curve: bool = False  # drawn in the gradient curve: error against solver cost (eval/gradient_curve.py)
    rank: int = 99
    floor: bool = False


KINDS: dict[str, Kind] = {k.name: k for k in (
    Kind("mgn", "MGN (the run's model)", "mgn", baseline=False, optimise=True, active=True, rank=0),
    Kind("none", "nothing moves", "regression", rank=7, floor=True),
    Kind("nearest", "nearest training design", "regression", optimise=True, rank=6, curve=True,
         gradient_curve=True),
    Kind("poly2", "per-node quadratic", "regression", fields="shared", optimise=True, rank=4),
    Kind("rbf", "per-node RBF", "regression", fields="shared", optimise=True, rank=5),
    Kind("kriging", "kriging", "surface", fields="shared", std=True, optimise=True,
         active=True, rank=1, curve=True, gradient_curve=True),
    Kind("mop", "MOP", "surface", fields="shared", optimise=True, rank=2, curve=True),
    # gradient-enhanced kriging of the objective (surface_fit.GEK): fitted with the solver's gradients at the
    # training designs (pcmgn_jax.data.gradients), which evaluation's baselines do not have: scored by its curve
    Kind("gek", "gradient-enhanced kriging", "surface", fields="", baseline=False, explore=False, rank=10,
         gradients=True, gradient_curve=True),
    Kind("rom", "POD reduced-order model", "rom", residual_base=True, rank=3, curve=True),
    # the rom with the MGN rollout's hard contact (surrogates.correction.rigid_contact): what the constraint
    # alone gives, beside a baseline-corrected MGN (residual_of=rom); scored by evaluate only
    Kind("rom_contact", "POD reduced-order model + the rollout's contact", "rom", explore=False, rank=8),
    # a trained one-pass run (mgn/onepass.py): the time-mean and peak fields and the objective, no per-frame fields
    Kind("onepass", "one-pass graph model (the run's)", "time_fields", fields="", baseline=False, explore=False,
         rank=9),
)}


def names(**where) -> tuple[str, ...]:
    """The kinds (in :data:`KINDS` order) whose fields equal ``where``: ``names(baseline=True)``."""
    for key in where:
        if key not in Kind.__dataclass_fields__:
            raise ValueError(f"kinds: no field {key!r} (fields: {list(Kind.__dataclass_fields__)})")
    return tuple(n for n, k in KINDS.items() if all(getattr(k, f) == v for f, v in where.items()))


def by_rank(kinds) -> list[str]:
    """``kinds`` (names) in the order of preference of their ``rank`` (the explorer's default first)."""
    return sorted(kinds, key=lambda k: KINDS[k].rank)


AUTO = "auto"   # the optimiser's and the active loop's extra choice: MOP's pick by CoP (the loop: with kriging's std)
# the optimiser's choice that predicts nothing: the solver itself, every value a solver run with its exact gradient
# (pcmgn_jax/opt/truth.py); no predictor kind (nothing is fitted), so not in KINDS
TRUTH = "solver"


def choices(use: str) -> tuple[str, ...]:
    """What a user may name for ``use`` ('optimise' | 'active'): its kinds, then (optimise) :data:`TRUTH`, then
    :data:`AUTO`."""
    if use not in ("optimise", "active"):
        raise ValueError(f"choices: use must be 'optimise' or 'active', got {use!r}")
    return names(**{use: True}) + ((TRUTH,) if use == "optimise" else ()) + (AUTO,)


def kind(name: str) -> Kind:
    """The :class:`Kind` called ``name``; ValueError naming it and the registered kinds otherwise."""
    if name not in KINDS:
        raise ValueError(f"no predictor kind {name!r}: the registered kinds are {tuple(KINDS)} "
                         "(pcmgn_jax/surrogates/kinds.py)")
    return KINDS[name]


class CannotAnswer(ValueError):
    """A fitted kind asked for what it does not predict (fields of an objective surface, per-frame fields of the
    one-pass model, a std of a kind without one): the one refusal of the :class:`Surrogate` calls. ``kind``:
    the kind's name; ``what``: what it cannot answer; ``why``: the reason (and what it answers instead)."""

    def __init__(self, kind: str, what: str, why: str = ""):
        self.kind, self.what, self.why = kind, what, why
        super().__init__(f"{kind}: cannot answer {what}" + (f": {why}" if why else ""))


@runtime_checkable
class Surrogate(Protocol):
    """What a fitted kind offers; a call it cannot answer raises :class:`CannotAnswer` (a ValueError) naming
    the kind and what it cannot answer.

    - ``predict_trajectories(trajs)`` -> (u list of (T, N_b, 2) [m], vm list of (T, N_b) [Pa]), each on the
      query trajectory's own mesh, at its design / scene parameters
    - ``predict(designs_m)`` -> (u (B, T, N, 2) [m], vm (B, T, N) [Pa]) at designs (B, D) [m] (the
      thicknesses of the scene's design layers) on the training mesh (or each design's own mesh: mgn)
    - ``predict_objective(trajs, *, reading, part=None, return_std=False)`` -> (B,) [MPa] (with ``return_std``:
      (mean, std) (B,) each [MPa]): the OLED objective ``reading`` at the trajectories' scenes, read off the
      kind's objective surface or scored on its fields on each query's mesh (:mod:`objective`); ``part``: the
      OLED part id (None: found by name)
    - ``predict_objective_at(designs, *, reading, part=None, return_std=False)`` -> as ``predict_objective`` at
      :class:`~pcmgn_jax.data.family.Design` objects, no mesh built: what the optimiser asks a response surface at
      its parameter rows; a kind whose objective needs each design's mesh refuses (:func:`objective.needs_a_mesh`)
    - ``objective_surface``: True when its objective is its own, read off a response surface over the parameters
      (``predict_objective_at`` answers; evaluation reports it apart from its fields'), False when it is its
      (time) fields' scored on each query's mesh
    - ``fit_seconds`` [s], ``warnings`` (queries outside the training box so far, strings for metrics.json)

    A new kind: a row of :data:`KINDS` and its family's ``fit`` (:mod:`registry`); a fields kind inherits
    ``predict_objective`` from :class:`~pcmgn_jax.surrogates.objective.FromFields`.
    """

    name: str
    fit_seconds: float
    warnings: list
    objective_surface: bool

    def predict_trajectories(self, trajs: Sequence): ...

    def predict(self, designs_m): ...

    def predict_objective(self, trajs: Sequence, *, reading: str, part: int | None = None,
                          return_std: bool = False): ...

    def predict_objective_at(self, designs: Sequence, *, reading: str, part: int | None = None,
                             return_std: bool = False): ...
