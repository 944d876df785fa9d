"""``fit(kind, train, ...)``: every predictor kind of :data:`~pcmgn_jax.surrogates.kinds.KINDS` fitted one way.

    s = fit("kriging", train, readings=("area_mean",), fields=False)   # a Surrogate (kinds.Surrogate)
    s = fit("mgn", train, workdir="runs/cpu", ref=test[0])             # the run's model
    s = fit_objective("mop", train, readings=("area_mean",))           # for its objective (no field surface)

Evaluation (:mod:`pcmgn_jax.eval.baselines`), the optimiser (:mod:`pcmgn_jax.opt.pipeline`), the active loop,
the residual mode (:mod:`residual`) and the explorer fit their predictors here. A kind's ``family``
names the module that fits it (:data:`FITTERS`). Every family fitted on trajectories takes ``queries``
(the trajectories to be predicted), ``readings`` (the objective readings, default all) and ``part`` (the
OLED part id, default found by name), and uses them where they matter; other options a family does not
take are refused (TypeError):

- ``regression`` (none, nearest, poly2, rbf): one shared mesh of training and ``queries``, or ``none`` /
  ``nearest`` across meshes
- ``surface`` (kriging, mop, gek): ``fields`` (fit the field surface too; default: on a shared mesh);
  ``gradients`` (gek only: the objective's gradients at the training designs, :mod:`surface_kind`)
- ``rom`` (rom, rom_contact): ``energy`` (the POD's kept energy fraction)
- ``mgn``: ``workdir`` (the run), ``ref``, ``which``, ``batch``, ``cfg`` (:func:`mgn.fit`)
- ``time_fields`` (onepass): ``workdir`` (a one-pass run), ``which`` (:func:`onepass.fit`): objectives only

To add a predictor: a :class:`~pcmgn_jax.surrogates.kinds.Kind` row in :data:`KINDS` (its name, label, family
and where it is used) and, for a new family, a module with ``fit(kind, train, **options)`` returning an
object with the :class:`~pcmgn_jax.surrogates.kinds.Surrogate` methods, named in :data:`FITTERS`: a fields kind
subclasses :class:`~pcmgn_jax.surrogates.objective.FromFields` for ``predict_objective``; what it cannot answer
it refuses with :class:`~pcmgn_jax.surrogates.kinds.CannotAnswer` (``tests/surrogates/test_interface.py`` fits a
toy kind so, and checks every kind of :data:`KINDS` answers or refuses).
"""
from __future__ import annotations

from typing import Sequence

from pcmgn_jax.surrogates import mgn, onepass, regression, rom, surface_kind
from pcmgn_jax.surrogates.kinds import KINDS, Kind, Surrogate, kind, names

__all__ = ["FITTERS", "KINDS", "Kind", "Surrogate", "fit", "fit_objective", "kind", "names"]

FITTERS = {"regression": regression.fit, "surface": surface_kind.fit, "rom": rom.fit, "mgn": mgn.fit,
           "time_fields": onepass.fit}  # by Kind.family


def fit(name: str, train: Sequence = (), **options) -> Surrogate:
    """The kind ``name`` fitted on the training trajectories ``train`` (``options``: the family's, module
    docstring). ValueError naming ``name`` when it is no registered kind; a kind that does not apply to
    these trajectories raises ValueError saying why."""
    family = kind(name).family
    if family == "mgn":
        options.setdefault("fit_base", fit)   # a residual_of run's baseline, fitted by this registry
    return FITTERS[family](name, train, **options)


def fit_objective(name: str, train: Sequence = (), *, fields: bool = False, **options) -> Surrogate:
    """The kind ``name`` fitted to answer the objective (:func:`fit` with ``options``), as the optimiser and the
    explorer ask it: a response surface (family ``surface``) with its field surface only when ``fields`` (its
    objective does not need one; MOP over every node is slow), refusing (ValueError, the reason) when its objective
    surface cannot be fitted; any other kind as :func:`fit` (its objective is its fields'; ``fields`` unused)."""
    if kind(name).family == "surface":
        options["fields"] = fields
    model = fit(name, train, **options)
    if why := getattr(model, "objective_not_applicable", ""):
        raise ValueError(why)
    return model
