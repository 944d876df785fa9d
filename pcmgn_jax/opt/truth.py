"""Design on the truth: the built-in solver as the optimiser's objective, every evaluation a solver run with
its exact design gradient (``python -m experiments.optimize --surrogate solver --method slsqp``).

:class:`SolverObjective` has the interface of :mod:`pcmgn_jax.opt.objectives` (designs (B, D) [m] in,
objective (B,) [MPa] out; ``value_and_grad`` with the gradient [MPa/m]; ``n_evals``; ``name`` = ``solver``;
``fingerprint``; ``persist`` / ``search_seconds`` / ``stop_timing``). A design (T1, T2) [m] sets the parameters
``<layer>.thickness`` of the scene's design layers (:mod:`pcmgn_jax.sim.parameters`); every design is solved by
ONE :class:`pcmgn_jax.sim.differentiable.GradientSetup`, compiled once for the search (one design per call,
float64, under ``jax.enable_x64``, as :mod:`pcmgn_jax.sim.gradient_check`).

The time step. ``differentiable.setup`` holds dt and the substeps per frame n_sub fixed at the stable step of
its batch (``prepare``: the smallest over the batch; a thinner layer has shorter elements and can shorten it).
The batch here is the box's extreme designs (:func:`extreme_designs`: for the paper's box its six vertices and
two projected corners), so dt = output_dt / n_sub with n_sub = ceil(output_dt / min stable step): a step
stable for every extreme design of the box, the same for every design of the search. A gradient is the
derivative of the discrete run at that fixed dt. Where the host solver's own step at a design gives the same
n_sub (:meth:`SolverObjective.check`, recorded at the optimum), the value IS the host solver's run there, so
the optimum needs no second solver run.

The trace: every evaluation's design [m and µm], value [MPa], gradient [MPa/m] (None for a value only), its own
wall time and the search's wall time at its end [s]. It goes to the resume file after every evaluation
(:meth:`FieldObjective.persist`'s file, atomic): a killed search run again replays its evaluations from the file
(SLSQP is deterministic given the values) and solves only what is new; a file written for another search is
refused, naming the fields that differ.
"""
from __future__ import annotations

import functools
import hashlib
import itertools
import json
import time

import numpy as np

from pcmgn_jax import metrics
from pcmgn_jax.opt.objectives import FieldObjective
from pcmgn_jax.opt.problem import DesignBox
from pcmgn_jax.scene import Scene

RESOLUTION = 1e-15   # [m] designs closer than this are one evaluation (SLSQP hands an iterate back in last bits)


def extreme_designs(box: DesignBox) -> np.ndarray:
    """(K, D) designs [m]: each design layer at each bound with the others sharing an edge of the sum band,
    and the corners of the bounds' cube, all projected onto the box (deduplicated): the designs with the
    thinnest and thickest layers, where the stable step is set up (the module docstring)."""
    d = box.dim
    cands = [np.array(c, float) for c in itertools.product((box.low, box.high), repeat=d)]
    for i, v, s in itertools.product(range(d), (box.low, box.high), (box.sum_low, box.sum_high)):
        c = np.full(d, (s - v) / max(d - 1, 1))
        c[i] = v
        cands.append(c)
    proj = box.project(np.stack(cands))
    return np.unique(np.round(proj / RESOLUTION) * RESOLUTION, axis=0)


class TruthSolver:   # arrays, not Designs: each row goes straight into one jitted solver call (x64)
    """The solver of one scene, preset and reading over a box: value and exact gradient of designs [m] in Pa
    and Pa/m, one design per jitted call (compiled on first use, once per process: :func:`truth_solver`)."""

    name, batch = "solver", 1

    def __init__(self, scene: Scene, preset, box: DesignBox, reading: str):
        import jax

        from pcmgn_jax.sim import differentiable as dsim
        self.scene, self.preset, self.box, self.reading = scene, preset, box, reading
        self.names = tuple(f"{layer}.thickness" for layer in scene.design_layers)
        self.extremes = extreme_designs(box)
        t0 = time.perf_counter()
        with jax.enable_x64(True):
            self.gs = dsim.setup([scene.with_design(*x) for x in self.extremes], preset, names=self.names,
                                 reading=reading)
        self._value, self._both = dsim.value_fn(self.gs), dsim.value_and_grad_fn(self.gs)
        self.setup_seconds = time.perf_counter() - t0   # [s] the host's preparation of the extreme designs

    def _call(self, fn, design):
        import jax
        with jax.enable_x64(True):
            return jax.device_get(fn(np.asarray(design, np.float64).reshape(1, -1)))

    def value(self, design) -> float:
        """The objective [Pa] of one design (D,) [m]."""
        return float(np.asarray(self._call(self._value, design))[0])

    def value_and_grad(self, design) -> tuple[float, np.ndarray]:
        """The objective [Pa] and its gradient (D,) [Pa/m] of one design (D,) [m], one reverse pass."""
        v, g = self._call(self._both, design)
        return float(np.asarray(v)[0]), np.asarray(g, float)[0]

    def host_substeps(self, design) -> int:
        """The substeps per frame the host solver (``prepare``'s own stable step) takes at ``design`` [m]."""
        from pcmgn_jax.sim.prepare import prepare
        dt = prepare([self.scene.with_design(*np.asarray(design, float))], self.preset).dt_stable
        return max(1, int(np.ceil(self.gs.output_dt / dt)))


@functools.lru_cache(maxsize=2)
def truth_solver(scene: Scene, preset, box: DesignBox, reading: str) -> TruthSolver:
    """The :class:`TruthSolver` of these arguments, built and compiled once per process (searches of the same
    scene share its compilation)."""
    return TruthSolver(scene, preset, box, reading)


class TruthObjective(FieldObjective):
    """What a search on the solver does with each evaluation, whatever its box: values [MPa] (a screen, a map)
    and values with their exact gradient [MPa per box unit], one solver run each, cached by design, each
    appended to ``trace`` (the subclass's ``_record``) and written to the resume file before the next;
    ``n_solver_runs``: this process's solver calls (a replayed evaluation costs none). The subclass sets
    ``surrogate`` (a truth with ``value``, ``value_and_grad`` [Pa] and ``gs``) and defines ``_record``,
    ``_restore``, ``fingerprint`` and ``check``."""

    def _start_trace(self) -> None:
        self.grads: dict[tuple, np.ndarray] = {}
        self.trace: list[dict] = []
        self.n_solver_runs = 0

    @property
    def dt(self) -> float:
        """The fixed substep [s] of every evaluation."""
        return self.surrogate.gs.dt

    def _record(self, x, value: float, grad, wall: float) -> None:
        raise NotImplementedError

    def _objectives(self, designs) -> np.ndarray:
        """(B,) [MPa] of new designs (B, D), values only (a screen, a map), one solver run each."""
        out = []
        for x in designs:
            t0 = time.perf_counter()
            out.append(self.surrogate.value(x) * 1e-6)
            self._record(x, out[-1], None, time.perf_counter() - t0)
        return np.array(out)

    def value_and_grad(self, designs) -> tuple[np.ndarray, np.ndarray]:
        """(B,) [MPa] and the exact (B, D) [MPa per box unit], one solver run and reverse pass per design not yet
        evaluated with its gradient (each written to the resume file before the next)."""
        d = np.atleast_2d(np.asarray(designs, float))
        for x in d:
            key = self._key(x)
            if key in self.grads:
                continue
            t0 = time.perf_counter()
            v, g = self.surrogate.value_and_grad(x)
            self.cache[key], self.grads[key] = v * 1e-6, g * 1e-6
            self.n_evals += 1
            self._record(x, v * 1e-6, g * 1e-6, time.perf_counter() - t0)
            self._flush()
        return (np.array([self.cache[self._key(x)] for x in d]), np.stack([self.grads[self._key(x)] for x in d]))

    def _extra(self) -> dict:
        return {"trace": self.trace}


class SolverObjective(TruthObjective):
    """The solver's objective with its exact gradient over ``box`` (the module docstring); ``part``: the OLED's
    part id (as the other objectives; the section is the setup's). ``n_solver_runs``: this process's solver
    calls (a replayed evaluation costs none); ``n_evals``: every evaluation of the search, replayed ones too."""

    def __init__(self, scene: Scene, preset, box: DesignBox = DesignBox(), *, part: int,
                 reading: str = metrics.DEFAULT_OBJECTIVE):
        if reading not in metrics.OBJECTIVES:
            raise ValueError(f"objective must be one of {metrics.OBJECTIVES}, got {reading!r}")
        super().__init__(truth_solver(scene, preset, box, reading), None, part=part, reading=reading,
                         resolution=RESOLUTION)
        self._start_trace()

    def fingerprint(self) -> str:
        """A short hash of what the values are of: scene, preset, reading, the parameters, dt and substeps."""
        gs = self.surrogate.gs
        what = {"scene": self.surrogate.scene.to_dict(), "preset": str(self.surrogate.preset), "reading": self.reading,
                "names": list(self.surrogate.names), "dt": gs.dt, "n_sub": gs.n_sub, "n_frames": gs.n_frames,
                "element": gs.element, "dtype": gs.dtype}
        return hashlib.sha256(json.dumps(what, sort_keys=True).encode()).hexdigest()[:16]

    def _record(self, x, value: float, grad, wall: float) -> None:
        self.n_solver_runs += 1
        self.trace.append({"design_m": [float(v) for v in x], "design_um": [float(v) * 1e6 for v in x],
                           "mpa": value, "grad_mpa_per_m": None if grad is None else [float(v) for v in grad],
                           "wall_s": wall, "seconds": self.search_seconds()})

    def _restore(self, saved: dict) -> None:
        self.trace = list(saved.get("trace", []))
        for e in self.trace:
            if e["grad_mpa_per_m"] is not None:
                self.grads[self._key(e["design_m"])] = np.asarray(e["grad_mpa_per_m"], float)

    def check(self, design) -> dict:
        """Whether the search's value at ``design`` [m] is the host solver's run: its fixed dt [s] and
        substeps per frame against the host's own substeps there (one ``prepare``, no solver run); the setup's
        designs [µm] and its wall time [s] (before the search's clock: compilation is the search's)."""
        host = self.surrogate.host_substeps(design)
        gs = self.surrogate.gs
        return {"dt_s": gs.dt, "n_substeps_per_frame": gs.n_sub, "host_substeps_per_frame": host,
                "same_run": host == gs.n_sub, "setup_designs_um": (self.surrogate.extremes * 1e6).tolist(),
                "setup_seconds": self.surrogate.setup_seconds}
