"""Surrogate objectives for the optimiser: designs (B, D) [m] in, docs/design.md §8's objective (B,) [MPa] out.

The designs are arrays because the searches (pymoo's GA, scipy's SLSQP, the projected gradient) are; each
objective turns a row into a :class:`~pcmgn_jax.data.family.Design` (:meth:`FieldObjective.designs`) where it
asks a surrogate at designs alone.

- :class:`FieldObjective` wraps any surrogate of :mod:`pcmgn_jax.surrogates`: a response surface (kriging, MOP:
  ``objective_surface``) is read at the designs (``predict_objective_at``, no fields); any other kind predicts
  fields at the designs and the objective is their von Mises' on each design's own mesh. Results are cached per
  design (rounded to ``resolution`` [m]), so a GA's repeated designs cost nothing and ``n_evals`` counts
  distinct surrogate evaluations. Its gradient is a central finite difference (the regressions and surfaces
  are smooth; ``nearest`` is piecewise constant and has none).
- :class:`MGNObjective` adds the exact gradient of the MGN's objective through the rollout and the mesh
  (:class:`~pcmgn_jax.sim.design_map.DesignMap`): forward mode (``jax.jacfwd``), because there are 2 design
  variables against ~10^5 rollout states: two tangents cost ~2 forward passes and store no activations,
  where reverse mode would keep 100 frames of message-passing activations (~GBs) or need rematerialising.
"""
from __future__ import annotations

import hashlib
import json
import time
from pathlib import Path
from typing import Sequence

import numpy as np

from pcmgn_jax import metrics
from pcmgn_jax.atomic import atomic_write_json
from pcmgn_jax.data.family import Design
from pcmgn_jax.scene import Scene
from pcmgn_jax.sim.design_map import DesignMap


def fitted_arrays(surrogate) -> list | None:
    """The numbers a fitted surrogate's values are of, for a fingerprint: the MGN's parameters and normalisation
    statistics, a response surface's training inputs; None for any other kind."""
    sim = getattr(surrogate, "sim", None)
    if sim is not None:
        import jax
        return jax.tree.leaves((sim.params, sim.stats))
    scenes = getattr(getattr(surrogate, "objective", None), "scenes", None)
    return None if scenes is None else [scenes.x]


class FieldObjective:
    """The objective of a surrogate at designs (see the module docstring); ``names``: the design's parameters
    (default the paper scene's design layers, ``Scene().design_layers``)."""

    def __init__(self, surrogate, design_map: DesignMap, *, part: int, reading: str = metrics.DEFAULT_OBJECTIVE,
                 resolution: float = 1e-9, fd_step: float = 0.5e-6, names: Sequence[str] | None = None):
        if reading not in metrics.OBJECTIVES:
            raise ValueError(f"objective must be one of {metrics.OBJECTIVES}, got {reading!r}")
        self.surrogate, self.map, self.part, self.reading = surrogate, design_map, part, reading
        self.names = tuple(Scene().design_layers if names is None else names)
        self.resolution, self.fd_step = resolution, fd_step
        self.name = getattr(surrogate, "name", type(surrogate).__name__)
        self.cache: dict[tuple, float] = {}
        self.n_evals = 0
        self._store: Path | None = None     # see persist()
        self._meta: dict = {}
        self.prior_seconds = 0.0            # search time spent by earlier, killed runs of the same search
        self.timing = False                 # whether the wall clock since persist() counts as search time
        self._t0 = 0.0

    def fingerprint(self) -> str:
        """A short hash of what the values are of: the surrogate's name and its fitted numbers (the MGN's
        parameters and normalisation statistics; a response surface's or a regression's training inputs)."""
        h = hashlib.sha256(self.name.encode())
        arrays = fitted_arrays(self.surrogate)
        for a in [self.surrogate.x] if arrays is None else arrays:
            h.update(np.ascontiguousarray(np.asarray(a)).tobytes())
        return h.hexdigest()[:16]

    def persist(self, path, meta: dict) -> int:
        """Keep every value in ``path`` (JSON, written atomically after each surrogate batch) and load the
        ones already there. A seeded search killed part way and run again replays its designs from the
        file (pymoo's GA and the seeded starts are deterministic given the values) and carries on where
        it stopped; ``prior_seconds`` is the search time the earlier runs spent. ``meta`` names what the
        values are of (surrogate fingerprint, reading, search and its budget, ...): a file written for
        other meta is refused, naming the fields that differ. Returns the number of values loaded."""
        path = Path(path)
        meta = {**meta, "fingerprint": self.fingerprint(), "reading": self.reading, "resolution": self.resolution}
        loaded = 0
        if path.exists():
            try:
                d = json.loads(path.read_text())
                values, old = d["values"], d["meta"]
            except (ValueError, KeyError) as e:
                raise ValueError(f"{path}: not a resume file of the optimiser ({e}); delete it to start over") from e
            diff = sorted(k for k in set(old) | set(meta) if old.get(k) != meta.get(k))
            if diff:
                what = ", ".join(f"{k}: {old.get(k)!r} here {meta.get(k)!r}" for k in diff)
                raise ValueError(f"{path}: written for another search ({what}); delete it to start over")
            for key, v in values:
                self.cache[tuple(key)] = float("nan") if v is None else float(v)
            self.n_evals, self.prior_seconds, loaded = int(d["n_evals"]), float(d["seconds"]), len(values)
            self._restore(d)
        self._store, self._meta = path, meta
        self._t0, self.timing = time.perf_counter(), True
        return loaded

    def search_seconds(self) -> float:
        """Search time so far [s]: the earlier runs' (``prior_seconds``) and this one's since persist()."""
        return self.prior_seconds + (time.perf_counter() - self._t0 if self.timing else 0.0)

    def stop_timing(self) -> None:
        """The search has ended: later evaluations (the objective map) are not search time."""
        self.prior_seconds, self.timing = self.search_seconds(), False

    def _restore(self, saved: dict) -> None:
        """Hook of :meth:`persist`: what a subclass keeps in the resume file beyond the values (:meth:`_extra`)."""

    def _extra(self) -> dict:
        """Hook of :meth:`_flush`: more fields of the resume file (a subclass's; read back by :meth:`_restore`)."""
        return {}

    def _flush(self) -> None:
        if self._store is not None:
            atomic_write_json(self._store, {
                "meta": self._meta, "n_evals": self.n_evals, "seconds": self.search_seconds(),
                "values": [[list(k), None if np.isnan(v) else v] for k, v in self.cache.items()], **self._extra()})

    def weights(self, design) -> np.ndarray:
        m = self.map.mesh
        return metrics.objective_weights(self.map.points(np.asarray(design, float)), m.cells, m.cell_part,
                                         m.node_part, part=self.part, reading=self.reading)

    def _key(self, d) -> tuple:
        return tuple(np.round(np.asarray(d, float) / self.resolution).astype(np.int64).tolist())

    def __call__(self, designs) -> np.ndarray:
        """(B,) objective [MPa] of designs (B, D) [m]; new designs go to the surrogate as one batch."""
        d = np.atleast_2d(np.asarray(designs, float))
        new = list(dict.fromkeys(self._key(x) for x in d if self._key(x) not in self.cache))
        # one surrogate batch at a time, so a resume file (persist) loses at most one batch to a kill
        step = (getattr(self.surrogate, "batch", None) or len(new)) if self._store else len(new)
        for i in range(0, len(new), max(step, 1)):
            chunk = new[i:i + step]
            des = np.asarray(chunk, float) * self.resolution
            for key, v in zip(chunk, self._objectives(des)):
                self.cache[key] = float(v)
            self.n_evals += len(chunk)
            self._flush()
        return np.array([self.cache[self._key(x)] for x in d])

    def designs(self, x) -> list[Design]:
        """The :class:`~pcmgn_jax.data.family.Design` of each row of x (B, D) [SI] (the searches' arrays)."""
        return [Design.of(None, row, self.names) for row in np.atleast_2d(np.asarray(x, float))]

    def _objectives(self, designs) -> np.ndarray:
        """(B,) objective [MPa] of new designs (B, D) [m]: a response surface's at the designs, else the reading
        of the predicted von Mises."""
        if self.surrogate.objective_surface:
            return np.asarray(self.surrogate.predict_objective_at(self.designs(designs), reading=self.reading), float)
        _, vm = self._predict(designs)
        return np.array([float(metrics.oled_objective(v, self.weights(x), reading=self.reading))
                         for x, v in zip(designs, vm)])

    def _predict(self, designs):
        return self.surrogate.predict(designs)

    def value_and_grad(self, designs) -> tuple[np.ndarray, np.ndarray]:
        """(B,) [MPa] and (B, D) [MPa/m]: central differences with ``fd_step`` [m]."""
        if self.name == "nearest":
            raise ValueError("the nearest-design surrogate is piecewise constant: it has no gradient "
                             "(use --method ga)")
        d = np.atleast_2d(np.asarray(designs, float))
        D = d.shape[1]
        steps = np.eye(D) * self.fd_step
        probe = np.concatenate([d] + [d + s for s in steps] + [d - s for s in steps])
        f = self(probe).reshape(2 * D + 1, len(d))
        return f[0], ((f[1:D + 1] - f[D + 1:]) / (2 * self.fd_step)).T


class MGNObjective(FieldObjective):
    """The MGN's objective with its exact gradient (see the module docstring).

    ``surrogate`` is a :class:`~pcmgn_jax.surrogates.mgn.MGNSurrogate`; values go through its batched
    rollout, gradients through one jitted ``jax.jacfwd`` of (design -> mesh -> rollout -> objective).
    The objective weights are held at the design's value (their derivative is not taken: for OCA
    designs the OLED section only translates, so its weights do not depend on the design at all).
    """

    def __init__(self, surrogate, design_map: DesignMap, **kw):
        super().__init__(surrogate, design_map, **kw)
        self._grad_fn = None

    def _predict(self, designs):
        """Fields on the design map's meshes (the same map the gradient differentiates)."""
        pts = np.asarray(self.map.points(np.asarray(designs, float)))
        return self.surrogate.rollout(pts, *self.surrogate.initial_state(pts), designs=designs)

    def _build_grad(self):
        import jax
        import jax.numpy as jnp

        from pcmgn_jax.mgn.inputs import with_scene
        from pcmgn_jax.mgn.rollout import rollout

        s = self.surrogate.sim
        ref = self.surrogate.ref
        n_steps = ref.n_frames - 1
        u0, v0, vm0 = (jnp.asarray(a, jnp.float32) for a in self.surrogate.initial_state(self.map.p0[None]))
        reading = self.reading
        names = s.spec.formulation.scene_features
        scene = ref.meta["scene"]

        def objective(design, weights, index):
            pts = self.map.points(design)
            # scene features that follow the design (layer_thickness) carry its tangent too
            topology = with_scene(s.topology, scene, names, design=design)
            res = rollout(s.spec, n_steps, s.params, s.stats, topology, index, pts, u0[0], v0[0], vm0[0])
            f = metrics.oled_objective(res.von_mises, weights, reading=reading)
            return f, (f, jnp.any(res.overflow), jnp.max(res.contact_count))

        self._grad_fn = jax.jit(jax.jacfwd(objective, has_aux=True))

    def value_and_grad(self, designs) -> tuple[np.ndarray, np.ndarray]:
        """(B,) [MPa] and exact (B, D) [MPa/m], one design at a time (contact buffer grown as needed)."""
        from pcmgn_jax.mgn import contact as contact_lib

        if self._grad_fn is None:
            self._build_grad()
        d = np.atleast_2d(np.asarray(designs, float))
        vals, grads = [], []
        for x in d:
            w = np.asarray(self.weights(x), np.float32)
            for _ in range(7):
                index = self.surrogate.sim.index
                g, (f, ovf, need) = self._grad_fn(np.asarray(x, np.float32), w, index)
                if not bool(ovf):
                    break
                self.surrogate.sim = self.surrogate.sim._replace(index=contact_lib.grow(index, int(need)))
            else:
                raise RuntimeError("MGN objective: the contact buffer kept overflowing")
            vals.append(float(f))
            grads.append(np.asarray(g, np.float64))
            self.cache.setdefault(self._key(x), float(f))
            self.n_evals += 1
            self._flush()
        return np.array(vals), np.stack(grads)
