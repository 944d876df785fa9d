"""The regression family: none, nearest, poly2, rbf (designs or scenes in, fields out).

    s = fit("rbf", train_trajs)                       # registry.fit("rbf", train_trajs) does the same
    u, vm = s.predict(designs_m)                      # (B, T, N, 2) [m], (B, T, N) [Pa]
    us, vms = s.predict_trajectories(trajs)           # lists, each on the query's mesh

``designs_m`` is (B, D) [m], the thicknesses of the scene's ``design_layers`` (in the trajectories'
``meta['design']`` order). The kinds are fitted on the training split only; on one shared topology (every
training and predicted design has the same node numbering: true for the built-in solver's meshes at a
fixed preset, where a design moves nodes but never renumbers them) they are :class:`FieldRegression`:

- ``none``     nothing moves, zero stress (u = u_0 of the first training trajectory, i.e. 0)
- ``nearest``  the training trajectory whose design is nearest (Euclidean, in µm)
- ``poly2``    per node, frame and channel, a least-squares quadratic in the design variables
               (coordinates scaled to [-1, 1] over the training box)
- ``rbf``      per node, frame and channel, ``scipy.interpolate.RBFInterpolator`` (thin-plate spline
               with a linear tail) over the scaled design variables

When the meshes differ (a scene family: ball radius, drop speed and layer thicknesses vary, and with
them the node count), :class:`NearestScene` gives the kinds that need no shared node numbering (``fields``
'any' in :data:`~pcmgn_jax.surrogates.kinds.REGRESSION_KINDS`): ``none`` and ``nearest`` (the nearest training scene
in normalised scene-parameter space, its fields carried over to the test mesh); ``poly2`` and ``rbf`` do
not apply there (:func:`fit` says so).
"""
from __future__ import annotations

import time
from itertools import combinations_with_replacement
from typing import Sequence

import numpy as np
from scipy.interpolate import RBFInterpolator

from pcmgn_jax.surrogates.inputs import design_of, part_names_of, scene_vector, shared_mesh
from pcmgn_jax.surrogates.kinds import CannotAnswer, names
from pcmgn_jax.surrogates.objective import FromFields
from pcmgn_jax.surrogates.transfer import transfer_fields

REGRESSION_KINDS = names(family="regression")


def fit(kind: str, train_trajs: Sequence, *, queries: Sequence = (), readings=None, part=None):
    """``kind`` fitted on ``train_trajs``: a :class:`FieldRegression` when the training and ``queries``
    trajectories share one mesh, else a :class:`NearestScene` (``none``, ``nearest``); ValueError otherwise.
    (``readings``, ``part``: every trajectory family takes them; fields give every reading.)"""
    train = list(train_trajs)
    if not train or shared_mesh(train + list(queries)):
        return FieldRegression(kind, train)
    if kind in names(family="regression", fields="any"):
        return NearestScene(train, zero=kind == "none")
    n_train = sorted({t.n_nodes for t in train})
    raise ValueError(f"{kind}: per-node regression needs one shared topology (one node numbering for every "
                     f"training and predicted design); here the meshes differ (training node counts "
                     f"{n_train[0]}..{n_train[-1]}, test {sorted({t.n_nodes for t in queries})})")


class NearestScene(FromFields):
    """Baselines across meshes: the nearest training scene (scene parameters scaled to [-1, 1] over the
    training box, Euclidean) among those with the query's layers (:func:`part_names_of`; fields map part by
    part, so a stack of other layers has none: ValueError naming it), its fields carried over to each test
    mesh (:func:`transfer_fields`), or with ``zero`` nothing moves (zero fields on each test mesh)."""

    def __init__(self, train_trajs: Sequence, *, zero: bool = False):
        if not train_trajs:
            raise ValueError("a baseline needs at least one training trajectory")
        t0 = time.perf_counter()
        self.trajs, self.zero = list(train_trajs), zero
        names = {scene_vector(t)[0] for t in self.trajs}
        if len(names) != 1:
            raise ValueError(f"nearest scene: the training trajectories describe their scenes differently: {names}")
        self.names = names.pop()
        self.x = np.stack([scene_vector(t)[1] for t in self.trajs])
        self.lo, self.hi = self.x.min(0), self.x.max(0)
        self.fit_seconds = time.perf_counter() - t0
        self.name, self.warnings = "none" if zero else "nearest", []

    def _scale(self, d):
        return 2 * (np.asarray(d, np.float64) - self.lo) / np.where(self.hi > self.lo, self.hi - self.lo, 1.0) - 1

    def predict(self, designs_m):
        raise CannotAnswer(self.name, "fields at designs alone", "the training meshes differ, so a design names no "
                           "mesh to predict on: use predict_trajectories with trajectories on their own meshes")

    def nearest(self, traj) -> int:
        names, v = scene_vector(traj)
        if names != self.names:
            raise ValueError(f"nearest scene: {traj.meta.get('name', '?')} has scene parameters {names}, the "
                             f"training scenes {self.names}")
        parts = part_names_of(traj)
        same = np.array([part_names_of(t) == parts for t in self.trajs])
        if not same.any():
            raise ValueError(f"nearest scene: no training scene has the parts {list(parts)} of "
                             f"{traj.meta.get('name', '?')}: a field does not map onto a stack of other layers")
        d = ((self._scale(v)[None] - self._scale(self.x)) ** 2).sum(-1)
        return int(np.argmin(np.where(same, d, np.inf)))

    def predict_trajectories(self, trajs) -> tuple[list, list]:
        """Per test trajectory (on its own mesh): displacement (T, N, 2) [m] and von Mises (T, N) [Pa]."""
        us, vms = [], []
        for t in trajs:
            if self.zero:
                us.append(np.zeros(np.shape(t.displacement)))
                vms.append(np.zeros(np.shape(t.von_mises)))
                continue
            u, vm = transfer_fields(self.trajs[self.nearest(t)], t.points, t.node_part, t.meta["scene"])
            us.append(u)
            vms.append(vm)
        return us, vms


def _fields(trajs) -> np.ndarray:
    """(B, T*N*3) float64: displacement x, y and von Mises of every frame and node."""
    return np.stack([np.concatenate([np.asarray(t.displacement, np.float64),
                                     np.asarray(t.von_mises, np.float64)[..., None]], axis=-1).reshape(-1)
                     for t in trajs])


class FieldRegression(FromFields):
    """A baseline fitted on training trajectories of one topology (see the module docstring)."""

    def __init__(self, kind: str, train_trajs: Sequence):
        if kind not in REGRESSION_KINDS:
            raise ValueError(f"baseline must be one of {REGRESSION_KINDS}, got {kind!r}")
        if not train_trajs:
            raise ValueError("a baseline needs at least one training trajectory")
        ref = train_trajs[0]
        for t in train_trajs:
            if t.displacement.shape != ref.displacement.shape or not np.array_equal(t.cells, ref.cells):
                raise ValueError(f"baseline {kind!r}: per-node regression needs one shared topology; "
                                 f"{t.meta.get('name', '?')} differs from {ref.meta.get('name', '?')}")
        self.name, self.warnings = kind, []
        self.shape = ref.displacement.shape  # (T, N, 2)
        self.x = np.stack([design_of(t) for t in train_trajs])
        self.lo, self.hi = self.x.min(0), self.x.max(0)
        t0 = time.perf_counter()
        if kind == "poly2":
            self.y = _fields(train_trajs)
            A = self._poly(self._scale(self.x))
            if A.shape[0] < A.shape[1]:
                raise ValueError(f"poly2 needs >= {A.shape[1]} training designs, got {A.shape[0]}")
            self.coef = np.linalg.lstsq(A, self.y, rcond=None)[0]
        elif kind == "rbf":
            self.rbf = RBFInterpolator(self._scale(self.x), _fields(train_trajs), kernel="thin_plate_spline",
                                       degree=1)
        elif kind == "nearest":
            self.y = _fields(train_trajs)
        self.fit_seconds = time.perf_counter() - t0

    def _scale(self, d):
        return 2 * (np.asarray(d, np.float64) - self.lo) / np.where(self.hi > self.lo, self.hi - self.lo, 1.0) - 1

    @staticmethod
    def _poly(z) -> np.ndarray:
        cols = [np.ones(len(z))] + [z[:, i] for i in range(z.shape[1])]
        cols += [z[:, i] * z[:, j] for i, j in combinations_with_replacement(range(z.shape[1]), 2)]
        return np.stack(cols, axis=1)

    def predict(self, designs_m) -> tuple[np.ndarray, np.ndarray]:
        d = np.atleast_2d(np.asarray(designs_m, np.float64))
        B = len(d)
        if self.name == "none":
            flat = np.zeros((B, int(np.prod(self.shape[:2])) * 3))
        elif self.name == "nearest":
            k = np.argmin(((d[:, None] - self.x[None]) ** 2).sum(-1), axis=1)
            flat = self.y[k]
        elif self.name == "poly2":
            flat = self._poly(self._scale(d)) @ self.coef
        else:
            flat = self.rbf(self._scale(d))
        f = flat.reshape((B,) + self.shape[:2] + (3,))
        return f[..., :2], f[..., 2]

    def predict_trajectories(self, trajs) -> tuple[list, list]:
        """:meth:`predict` at each trajectory's design (:func:`design_of`), as lists (the shared mesh)."""
        u, vm = self.predict(np.stack([design_of(t) for t in trajs]))
        return list(u), list(vm)


def poly2_features(z) -> np.ndarray:
    """(B, (D + 1)(D + 2) / 2) the poly2 baseline's features of scaled inputs z (B, D): 1, z_i, z_i z_j (i <= j)."""
    return FieldRegression._poly(np.atleast_2d(np.asarray(z, np.float64)))
