"""The adapter of the surface family: the ``kriging``, ``mop`` and ``gek`` kinds over trajectories, for the registry and
the :class:`~pcmgn_jax.surrogates.kinds.Surrogate` calls (the numerical fits are :mod:`surface_fit`).

    s = fit("mop", train_trajs)                  # registry.fit("mop", train_trajs) does the same
    s.predict_objective(test_trajs, reading="area_mean")   # (B,) [MPa]: the objective surface
    s.objectives(test_trajs)                     # {reading: (B,) [MPa]}: every fitted reading
    s.predict_objective_at(designs, reading="area_mean")   # (B,) [MPa] at Design objects, no mesh (the optimiser)
    s.predict_trajectories(test_trajs)           # fields, from the field surface (one shared mesh only)

- :class:`ObjectiveSurface`: the OLED objective readings [MPa] over the training trajectories' scene
  parameters (:class:`inputs.TrainingScenes`: ``meta['scene_params']`` of a scene family, else the design;
  what training held fixed is checked there too); any meshes
- :class:`FieldSurface`: the fields over the design, on one shared mesh (like ``regression.FieldRegression``)
- :class:`Surface`: the kind as one surrogate, holding either or both (``fields``)
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from pcmgn_jax.data.family import Design
from pcmgn_jax.metrics import DEFAULT_OBJECTIVE, OBJECTIVES
from pcmgn_jax.surrogates.inputs import TrainingScenes, design_of, shared_mesh, trajectory_labels
from pcmgn_jax.surrogates.kinds import KINDS, CannotAnswer
from pcmgn_jax.surrogates.objective import check_reading
from pcmgn_jax.surrogates.regression import FieldRegression
from pcmgn_jax.surrogates.surface_fit import fit_surface, objective_table


class ObjectiveSurface:
    """``kind`` 'kriging', 'mop' or 'gek' of the OLED objective readings [MPa] over the training trajectories'
    scene parameters (:class:`scene_inputs.TrainingScenes`); ``part``: the OLED part id (default: found by name).
    ``gradients`` (gek, and only it): {reading: {parameter: (B,) [Pa per its SI unit]}} at the training
    trajectories (:func:`pcmgn_jax.data.gradients.aligned_gradients`), every parameter of ``names``; it fits
    those readings."""

    def __init__(self, kind: str, train_trajs: Sequence, *, readings: Sequence[str] = OBJECTIVES,
                 part: int | None = None, gradients=None):
        if not train_trajs:
            raise ValueError(f"{kind}: a response surface needs training trajectories")
        if KINDS[kind].gradients != (gradients is not None):   # the registry says which kinds take them
            raise ValueError(f"{kind}: needs the objective's gradients at the training designs (python -m "
                             "experiments.gradient --dataset_dir)" if KINDS[kind].gradients else
                             f"{kind}: takes no gradients (gek does)")
        self.name, self.scenes, self.part = kind, TrainingScenes(train_trajs), part
        self.names = self.scenes.names
        options = {} if gradients is None else {"gradients": {r: self._columns(g) for r, g in gradients.items()}}
        readings = tuple(gradients) if gradients is not None else readings
        self.model = fit_surface(kind, self.scenes.x, objective_table(train_trajs, readings, part=part),
                                 names=self.names, **options)
        self.fit_seconds, self.warnings = self.model.fit_seconds, self.model.warnings

    def _columns(self, g) -> np.ndarray:
        """(B, P) [MPa per SI unit, the objective table's] of {parameter: (B,) [Pa per SI unit]} in ``names`` order."""
        missing = [n for n in self.names if n not in g]
        if missing:
            raise ValueError(f"{self.name}: no gradient with respect to {missing} (given: {sorted(g)})")
        return np.stack([np.asarray(g[n], np.float64) for n in self.names], axis=1) * 1e-6

    def predict(self, x, labels=None, **kw):
        """{reading: (Q,) [MPa]} at scene parameters x (Q, P) [SI] (``names`` order)."""
        return self.model.predict(x, labels, **kw)

    def predict_trajectories(self, trajs, **kw):
        """{reading: (B,) [MPa]} at each trajectory's scene parameters (kriging: ``return_std=True`` too)."""
        return self.model.predict(self.scenes.inputs(trajs, self.model.box.note), trajectory_labels(trajs), **kw)

    def predict_designs(self, designs: Sequence[Design], **kw):
        """{reading: (B,) [MPa]} at :class:`~pcmgn_jax.data.family.Design` objects (their canonical rows)."""
        return self.model.predict(self.scenes.rows(designs, self.model.box.note), **kw)


class FieldSurface:
    """``kind`` 'kriging' or 'mop' of the fields of training trajectories on one shared mesh, per field
    (u: every frame, node and component; vm: every frame and node) over the design [m], behind
    FieldRegression's interface: ``predict(designs_m) -> (u (B, T, N, 2) [m], vm (B, T, N) [Pa])``."""

    def __init__(self, kind: str, train_trajs: Sequence):
        base = FieldRegression("none", train_trajs)     # checks the shared topology
        self.name, self.shape = kind, base.shape        # (T, N, 2)
        d = train_trajs[0].meta.get("design")
        names = train_trajs[0].meta.get("scene", {}).get("design_layers") or \
            (list(d) if isinstance(d, dict) else [f"design[{i}]" for i in range(base.x.shape[1])])
        B = len(train_trajs)
        u = np.stack([np.asarray(t.displacement, np.float64) for t in train_trajs]).reshape(B, -1)
        vm = np.stack([np.asarray(t.von_mises, np.float64) for t in train_trajs]).reshape(B, -1)
        self.model = fit_surface(kind, base.x, {"u": u, "vm": vm}, names=names)
        self.fit_seconds, self.warnings = self.model.fit_seconds, self.model.warnings

    def _shaped(self, got):
        B = len(got["u"])
        return got["u"].reshape((B,) + self.shape), got["vm"].reshape((B,) + self.shape[:2])

    def predict(self, designs_m) -> tuple[np.ndarray, np.ndarray]:
        """Designs (B, D) [m] -> (u (B, T, N, 2) [m], vm (B, T, N) [Pa])."""
        labels = [f"design {i}" for i in range(len(np.atleast_2d(designs_m)))]
        return self._shaped(self.model.predict(designs_m, labels))

    def predict_std(self, designs_m) -> tuple[np.ndarray, np.ndarray]:
        """kriging only: the posterior std of u [m] and vm [Pa] at designs (B, D) [m], shaped as predict's."""
        if self.name != "kriging":
            raise ValueError(f"predict_std: {self.name!r} has no posterior std (kriging has)")
        return self._shaped(self.model.predict(designs_m, return_std=True)[1])


class Surface:
    """The ``kriging`` / ``mop`` kind as one surrogate: ``objective`` (an :class:`ObjectiveSurface` of
    ``readings``, or None with the reason in ``objective_not_applicable`` when ``fields`` is asked for and it
    cannot be fitted, e.g. no OLED part) and ``fields`` (a :class:`FieldSurface`, or None). ``fields``: fit
    the field surface too (it needs one shared mesh). ``fit_seconds``: the objective surface's fit."""

    objective_surface = True   # its objective is its own, read off a surface over the parameters (kinds.Surrogate)

    def __init__(self, kind: str, train_trajs: Sequence, *, readings: Sequence[str] = OBJECTIVES,
                 part: int | None = None, fields: bool = False, gradients=None):
        self.name, self.objective, self.fields, self.objective_not_applicable = kind, None, None, ""
        try:
            self.objective = ObjectiveSurface(kind, train_trajs, readings=readings, part=part, gradients=gradients)
        except ValueError as err:  # e.g. no OLED part: the fields may still apply
            if not fields:
                raise
            self.objective_not_applicable = str(err)
        if fields:
            self.fields = FieldSurface(kind, train_trajs)
        self.fit_seconds = self.objective.fit_seconds if self.objective is not None else 0.0

    @property
    def warnings(self) -> list[str]:
        """The objective surface's out-of-box queries, then the field surface's not already listed."""
        out = list(self.objective.warnings) if self.objective is not None else []
        return out + [w for w in (self.fields.warnings if self.fields is not None else []) if w not in out]

    def _surface(self, return_std: bool) -> ObjectiveSurface:
        if self.objective is None:
            raise CannotAnswer(self.name, "the objective", f"no objective surface: {self.objective_not_applicable}")
        if return_std and not KINDS[self.name].std:
            raise CannotAnswer(self.name, "a posterior std of the objective", "kriging has one")
        return self.objective

    def objectives(self, trajs, *, return_std: bool = False):
        """{reading: (B,) [MPa]} at each trajectory's scene parameters (``return_std``: (means, stds), kriging)."""
        return self._surface(return_std).predict_trajectories(trajs, **({"return_std": True} if return_std else {}))

    def _reading(self, got, reading: str, part: int | None, return_std: bool):
        check_reading(self.name, reading, tuple(got[0] if return_std else got))
        if part is not None and self.objective.part is not None and part != self.objective.part:
            raise CannotAnswer(self.name, f"the objective of part {part}",
                               f"its surface was fitted for part {self.objective.part}")
        return tuple(g[reading] for g in got) if return_std else got[reading]

    def predict_objective(self, trajs, *, reading: str = DEFAULT_OBJECTIVE, part: int | None = None,
                          return_std: bool = False):
        """(B,) [MPa] of the objective ``reading`` at each trajectory's scene parameters, read off the objective
        surface (``return_std``: (mean, std), kriging); CannotAnswer for a reading or ``part`` it was not fitted for."""
        return self._reading(self.objectives(trajs, return_std=return_std), reading, part, return_std)

    def predict_objective_at(self, designs: Sequence[Design], *, reading: str = DEFAULT_OBJECTIVE,
                             part: int | None = None, return_std: bool = False):
        """(B,) [MPa] of the objective ``reading`` at :class:`~pcmgn_jax.data.family.Design` objects, no mesh
        built: the objective surface at their canonical rows (``return_std``: (mean, std), kriging); refusals as
        :meth:`predict_objective`."""
        got = self._surface(return_std).predict_designs(designs, **({"return_std": True} if return_std else {}))
        return self._reading(got, reading, part, return_std)

    def objective_model(self, reading: str) -> str:
        """The fit behind the objective ``reading``: MOP's chosen candidate ('poly2', 'kriging', ...), else the kind."""
        return getattr(self._surface(False).model, "choice", {}).get(reading, self.name)

    def _field_surface(self) -> FieldSurface:
        if self.fields is None:
            raise CannotAnswer(self.name, "fields", "it is an objective surface; its field surface is fitted on one "
                               "shared mesh only, when asked for (fields=True)")
        return self.fields

    def predict(self, designs_m):
        """Fields at designs (B, D) [m] on the shared mesh (:meth:`FieldSurface.predict`)."""
        return self._field_surface().predict(designs_m)

    def predict_trajectories(self, trajs) -> tuple[list, list]:
        """Fields at each trajectory's design, as lists (the shared mesh)."""
        u, vm = self._field_surface().predict(np.stack([design_of(t) for t in trajs]))
        return list(u), list(vm)


def fit(kind: str, train_trajs: Sequence, *, queries: Sequence = (), readings: Sequence[str] = OBJECTIVES,
        part: int | None = None, fields: bool | None = None, gradients=None) -> Surface:
    """A :class:`Surface`; ``fields`` None: fit the field surface when the kind has one and training and
    ``queries`` share one mesh; ``gradients``: gek's (:class:`ObjectiveSurface`)."""
    train = list(train_trajs)
    if fields is None:
        fields = bool(train) and bool(KINDS[kind].fields) and shared_mesh(train + list(queries))
    return Surface(kind, train, readings=readings, part=part, fields=fields, gradients=gradients)
