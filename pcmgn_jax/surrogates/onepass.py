"""The one-pass family: a trained one-pass run (:mod:`pcmgn_jax.mgn.onepass`) as the ``onepass`` kind.

    s = fit("onepass", train, workdir="runs/onepass")     # registry.fit: the run's best checkpoint
    s.objectives(test)                                    # {reading: (B,) [MPa]}, every reading of metrics.OBJECTIVES
    s.time_fields(test)                                   # {target: list of (N_b,)}: the fields it predicts

It predicts, per design, the time-mean and the peak von Mises stress and the peak deflection of every node, in one
pass from the design's initial state (frame 0 of each query trajectory, on its own mesh: the box's designs, a
scene family's or a stack family's alike), and the objective readings from them, each on the query's own mesh, by
the one definition (:func:`pcmgn_jax.metrics.oled_objective`: a linear reading of the
time-mean field as one frame, ``peak`` of the peak field). It has no per-frame fields: ``predict_trajectories``
and ``predict`` refuse, naming them.
"""
from __future__ import annotations

import time
from typing import Sequence

import numpy as np

from pcmgn_jax.metrics import DEFAULT_OBJECTIVE, OBJECTIVES, objective_weights, oled_objective
from pcmgn_jax.mgn import onepass as op
from pcmgn_jax.surrogates.kinds import CannotAnswer
from pcmgn_jax.surrogates.objective import check_reading, needs_a_mesh

PER_FRAME = "the per-frame fields (displacement (T, N, 2) and von_mises (T, N) of every frame)"


class OnePassSurrogate:
    """A trained one-pass run as a surrogate (module docstring). ``part``: the objective's part id (default: the
    run's ``objective_part`` found by name in each query); ``readings``: the objective readings it answers."""

    name = "onepass"
    objective_surface = False   # its objective is its predicted time fields' (kinds.Surrogate)

    def __init__(self, workdir, *, which: str = "best", readings: Sequence[str] = OBJECTIVES, part: int | None = None):
        t0 = time.perf_counter()
        self.run = op.load(workdir, which)
        bad = [r for r in readings if r not in OBJECTIVES]
        if bad:
            raise ValueError(f"onepass: readings {bad} must be among {OBJECTIVES}")
        self.readings, self.part, self.workdir = tuple(readings), part, workdir
        self.fit_seconds, self.warnings = time.perf_counter() - t0, []
        self.predict_seconds = 0.0

    def time_fields(self, trajs) -> dict[str, list[np.ndarray]]:
        """{target: one (N_b,) array per trajectory} of :data:`pcmgn_jax.mgn.onepass.TARGETS` [Pa, Pa, m], each on the
        query's own mesh (the queries' graphs joined in padded unions of one size, whatever their meshes:
        :func:`pcmgn_jax.mgn.onepass.predict_fields`)."""
        trajs = list(trajs)
        t0 = time.perf_counter()
        out = self.run.predict([self.run.inputs(t) for t in trajs])
        self.predict_seconds = time.perf_counter() - t0
        return {name: [f[:, k] for f in out] for k, name in enumerate(op.TARGETS)}

    def objectives(self, trajs, *, return_std: bool = False, readings: Sequence[str] | None = None,
                   part: int | None = None) -> dict[str, np.ndarray]:
        """{reading: (B,) [MPa]} at each trajectory's design, from the predicted time fields (``readings``
        default: the fitted ones; ``part`` default: the fitted part, else the run's found by name)."""
        if return_std:
            raise CannotAnswer(self.name, "a posterior std of the objective", "kriging has one")
        trajs = list(trajs)
        readings = self.readings if readings is None else tuple(readings)
        fields = self.time_fields(trajs)
        out = {r: [] for r in readings}
        part = self.part if part is None else part
        for t, mean, peak in zip(trajs, fields["mean_von_mises"], fields["peak_von_mises"]):
            pid = op.part_id(t, self.run.cfg.objective_part) if part is None else part
            for r in readings:
                w = objective_weights(t.points, t.cells, t.cell_part, t.node_part, part=pid, reading=r)
                out[r].append(float(oled_objective((peak if r == "peak" else mean)[None], w, reading=r)))
        return {r: np.asarray(v) for r, v in out.items()}

    def predict_objective(self, trajs, *, reading: str = DEFAULT_OBJECTIVE, part: int | None = None,
                          return_std: bool = False) -> np.ndarray:
        """(B,) [MPa]: the objective ``reading`` of each trajectory's design from the predicted time fields."""
        check_reading(self.name, reading)
        return self.objectives(trajs, return_std=return_std, readings=(reading,), part=part)[reading]

    def predict_objective_at(self, designs, **_):
        raise needs_a_mesh(self.name)

    def predict_trajectories(self, trajs):
        raise CannotAnswer(self.name, PER_FRAME, "it predicts the time-mean and peak von Mises and the peak "
                           "deflection of each node (time_fields) and the objective from them (predict_objective)")

    def predict(self, designs_m):
        raise CannotAnswer(self.name, f"fields at designs alone, or {PER_FRAME}", "use predict_objective(trajs) "
                           "or time_fields(trajs) with the designs' trajectories (their meshes and initial states)")


def fit(kind: str, train_trajs=(), *, workdir, which: str = "best", readings: Sequence[str] = OBJECTIVES,
        part: int | None = None, queries: Sequence = ()) -> OnePassSurrogate:
    """The one-pass run in ``workdir`` as the ``onepass`` kind (``train_trajs`` and ``queries`` are not used: the
    run was trained on its own split)."""
    return OnePassSurrogate(workdir, which=which, readings=readings, part=part)
