"""The objective of a fields kind: its predicted von Mises scored on each query's own mesh, by the one definition
(:func:`pcmgn_jax.metrics.oled_objective_of`).

    class MyKind(FromFields):                      # predict_trajectories(trajs) -> (us, vms): fields
        ...
    MyKind(...).predict_objective(trajs, reading="area_mean")    # (B,) [MPa]

Objective surfaces (:mod:`surface_kind`) and the one-pass model (:mod:`onepass`) answer the same call their own
way; a std or a reading a kind does not have is refused with :class:`~pcmgn_jax.surrogates.kinds.CannotAnswer`, and
so is the objective at designs alone (``predict_objective_at``) by every kind whose objective needs a query's mesh
(:func:`needs_a_mesh`): only a response surface reads it at parameter rows.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from pcmgn_jax.metrics import DEFAULT_OBJECTIVE, OBJECTIVES, oled_objective_of
from pcmgn_jax.surrogates.kinds import CannotAnswer


def check_reading(kind: str, reading: str, readings: Sequence[str] = OBJECTIVES) -> None:
    """CannotAnswer naming ``kind`` and ``reading`` when ``reading`` is not among ``readings`` (what it answers)."""
    if reading not in readings:
        raise CannotAnswer(kind, f"the objective reading {reading!r}", f"it answers {tuple(readings)}")


def objective_of_fields(trajs: Sequence, vms, *, reading: str = DEFAULT_OBJECTIVE,
                        part: int | None = None) -> np.ndarray:
    """(B,) [MPa]: the objective ``reading`` of predicted von Mises ``vms`` (one (T, N_b) [Pa] per query, NumPy or
    JAX) on each query trajectory's mesh; ``part``: the OLED part id (None: found by name in each query). The one
    scoring of predicted fields: evaluation, the residual spread and the explorer call it too."""
    return np.array([float(oled_objective_of(t, np.asarray(vm), part=part, reading=reading))
                     for t, vm in zip(trajs, vms)])


def needs_a_mesh(kind: str) -> CannotAnswer:
    """The refusal of ``predict_objective_at`` by a kind whose objective is scored on each query's own mesh."""
    return CannotAnswer(kind, "the objective at designs alone", "its objective is scored on each design's mesh: "
                        "ask predict_objective with the designs' query trajectories (a response surface reads it "
                        "at parameter rows)")


class FromFields:
    """Mixin of a fields kind (it has ``name`` and ``predict_trajectories``): :meth:`predict_objective` from its
    fields. No posterior std: ``return_std`` is refused; nor the objective at designs without their meshes."""

    name: str
    objective_surface = False   # its objective is its fields' (kinds.Surrogate)

    def predict_objective(self, trajs: Sequence, *, reading: str = DEFAULT_OBJECTIVE, part: int | None = None,
                          return_std: bool = False) -> np.ndarray:
        """(B,) [MPa]: the objective ``reading`` of this kind's von Mises at each query, on the query's mesh."""
        check_reading(self.name, reading)
        if return_std:
            raise CannotAnswer(self.name, "a posterior std of the objective",
                               "it predicts fields only (kriging has a std)")
        trajs = list(trajs)
        _, vms = self.predict_trajectories(trajs)
        return objective_of_fields(trajs, vms, reading=reading, part=part)

    def predict_objective_at(self, designs, **_):
        raise needs_a_mesh(self.name)
