"""Design on the truth over a panel stack: the built-in solver as the objective of a stack search, every
evaluation a solver run with its exact gradient (``python -m experiments.optimize --surrogate solver --method
slsqp --stack CG,OCA1,POL,OCA2,OLED,PLATE``; :func:`pcmgn_jax.opt.stack_search.optimize_stack`).

The searched numbers are a :func:`pcmgn_jax.opt.scenes.stack_box` row (by default every layer's thickness [m]
and log10 modulus [log10 Pa]; the ball's ``ball.radius`` [m] / ``ball.velocity`` [m/s] when named), the rest
held at the box's base (nominal) row. Each maps to a parameter of the differentiable solver
(:mod:`pcmgn_jax.sim.parameters`): ``<layer>.thickness`` as it is, ``<layer>.log10_youngs`` to
``<layer>.youngs`` = 10^x [Pa], whose derivative the chain rule carries back: dF/dlog10E = dF/dE * E * ln 10.
:class:`StackTruth` returns the objective [Pa] and its gradient per unit of each box number (Pa/m, Pa per
decade, ...); :class:`StackSolverObjective` the same in MPa, the interface of
:mod:`pcmgn_jax.opt.objectives` (cache, ``n_evals``, resume file, fingerprint) as
:class:`pcmgn_jax.opt.truth.SolverObjective` has it for the paper's box.

One topology, one compilation. A stack preset's mesh sizes its layers by their thickness
(``thickness_elems``); here it is pinned at the box's base stack (:func:`pcmgn_jax.sim.mesh.pinned_spec`, as
:func:`pcmgn_jax.sim.differentiable.setup` pins at its first scene): every iterate is that mesh with its nodes
moved affinely by the thicknesses, so ONE :class:`~pcmgn_jax.sim.differentiable.GradientSetup` (float64, one
design per jitted call) serves the search. The time step: dt and the substeps per frame are fixed once, the
smallest stable step over the base stack and the box's thin/stiff corner (:func:`stiff_corner`: thicknesses
and the ball's radius at their lows, moduli and the speed at their highs), recorded in the result. A value is
the discrete run at that dt on the pinned mesh; at the optimum :meth:`StackSolverObjective.check` says
whether it is also the host solver's own run there (the host's element counts and its own stable step).
"""
from __future__ import annotations

import hashlib
import json
import math
import time

import numpy as np

from pcmgn_jax import metrics
from pcmgn_jax.opt.scenes import ParameterBox
from pcmgn_jax.opt.truth import RESOLUTION, TruthObjective  # RESOLUTION [SI]: rows closer are one evaluation
from pcmgn_jax.scene import Scene

LOG10 = ".log10_youngs"


def solver_names(box: ParameterBox) -> tuple[str, ...]:
    """The differentiable solver's parameter of each box name: '<layer>.log10_youngs' -> '<layer>.youngs', the
    rest ('<layer>.thickness', 'ball.radius', 'ball.velocity') as they are."""
    return tuple(n[:-len(LOG10)] + ".youngs" if n.endswith(LOG10) else n for n in box.names)


def stiff_corner(box: ParameterBox) -> np.ndarray:
    """(D,) the box's thin/stiff corner: every thickness and the ball's radius at its low (shorter elements),
    every log10 modulus and the ball's speed at its high (faster waves, a stiffer contact penalty)."""
    high = np.array([n.endswith(LOG10) or n == "ball.velocity" for n in box.names])
    return np.where(high, box.high, box.low).astype(float)


class StackTruth:   # arrays, not Designs: each row goes straight into one jitted solver call (x64)
    """The solver of a stack box (module docstring): value [Pa] and exact gradient [Pa per box unit] of a box
    row (D,), one design per jitted call, compiled on first use (once per process: :func:`stack_truth`)."""

    name, batch = "solver", 1

    def __init__(self, scene0: Scene, family, preset: str, box: ParameterBox, reading: str):
        import jax

        from pcmgn_jax.sim import differentiable as dsim
        from pcmgn_jax.sim.mesh import pinned_spec
        self.scene0, self.family, self.preset, self.box, self.reading = scene0, family, preset, box, reading
        self.names = solver_names(box)
        self.log = np.array([n.endswith(LOG10) for n in box.names])
        self.nominal = np.array([box.base[n] for n in box.names], float)
        self.corner = stiff_corner(box)
        t0 = time.perf_counter()
        scenes = [self.scene(self.nominal), self.scene(self.corner)]
        self.spec = pinned_spec(scenes[0], preset)         # the mesh every iterate shares
        with jax.enable_x64(True):
            self.gs = dsim.setup(scenes, self.spec, names=self.names, reading=reading)
        self._value, self._both = dsim.value_fn(self.gs), dsim.value_and_grad_fn(self.gs)
        self.setup_seconds = time.perf_counter() - t0   # [s] the host's preparation (not the compilation)

    def scene(self, x) -> Scene:
        """The scene of box row x (D,) [SI]: the family's scene of the box's full row on ``scene0``."""
        return self.box.design(np.asarray(x, float), self.family).scene(self.scene0)

    def theta(self, x) -> np.ndarray:
        """(1, P) the solver's parameters [SI] of box row x (D,): a log10 modulus as 10^x [Pa]."""
        x = np.asarray(x, np.float64).reshape(-1)
        return np.where(self.log, 10.0 ** x, x)[None]

    def _call(self, fn, x):
        import jax
        with jax.enable_x64(True):
            return jax.device_get(fn(self.theta(x)))

    def value(self, x) -> float:
        """The objective [Pa] at box row x (D,)."""
        return float(np.asarray(self._call(self._value, x))[0])

    def value_and_grad(self, x) -> tuple[float, np.ndarray]:
        """The objective [Pa] and its gradient (D,) per unit of each box number (Pa/m for a thickness, Pa per
        decade for a log10 modulus: dF/dE * E * ln 10) at box row x (D,), one reverse pass."""
        v, g = self._call(self._both, x)
        theta = self.theta(x)[0]
        g = np.asarray(g, float)[0] * np.where(self.log, theta * math.log(10.0), 1.0)
        return float(np.asarray(v)[0]), g

    def host_check(self, x) -> dict:
        """Whether the host solver's own run at x is the search's: its substeps per frame on the pinned mesh
        (``prepare``'s own stable step) and its own element counts against the pinned ones (no solver run)."""
        from pcmgn_jax.sim.mesh import pinned_spec
        from pcmgn_jax.sim.prepare import prepare
        scene = self.scene(x)
        dt = prepare([scene], self.spec).dt_stable
        host = max(1, int(np.ceil(self.gs.output_dt / dt)))
        own = dict(pinned_spec(scene, self.preset).layer_elems)
        return {"host_substeps_per_frame": host, "pinned_layer_elems": dict(self.spec.layer_elems),
                "host_layer_elems": own, "same_mesh": own == dict(self.spec.layer_elems)}


_SOLVERS: dict[str, StackTruth] = {}


def _key(scene0: Scene, family, preset: str, box: ParameterBox, reading: str) -> str:
    """What the values are of: the nominal stack's scene (every row's scene is the family's scene of that row on
    ``scene0``: its layers and ball are the row's, the rest ``scene0``'s), the preset, reading and box."""
    nominal = box.design(np.array([box.base[n] for n in box.names], float), family).scene(scene0)
    return json.dumps({"nominal_scene": nominal.to_dict(), "preset": str(preset), "reading": reading,
                       "names": list(box.names), "low": box.low.tolist(), "high": box.high.tolist(),
                       "base": sorted(box.base.items())}, sort_keys=True)


def stack_truth(scene0: Scene, family, preset: str, box: ParameterBox, reading: str) -> StackTruth:
    """The :class:`StackTruth` of these arguments, built and compiled once per process (the last two kept)."""
    key = _key(scene0, family, preset, box, reading)
    if key not in _SOLVERS:
        while len(_SOLVERS) >= 2:
            _SOLVERS.pop(next(iter(_SOLVERS)))
        _SOLVERS[key] = StackTruth(scene0, family, preset, box, reading)
    return _SOLVERS[key]


class StackSolverObjective(TruthObjective):
    """The solver's objective [MPa] with its exact gradient [MPa per box unit] over a stack box (module
    docstring). ``n_solver_runs``: this process's solver calls (a replayed evaluation costs none); ``n_evals``:
    every evaluation of the search, replayed ones too; ``trace``: every evaluation's row {name: SI}, value
    [MPa], gradient {name: MPa per unit} (None for a value only), its own wall time and the search's wall
    time at its end [s], written to the resume file after each evaluation."""

    def __init__(self, scene0: Scene, family, preset: str, box: ParameterBox, *,
                 reading: str = metrics.DEFAULT_OBJECTIVE):
        if reading not in metrics.OBJECTIVES:
            raise ValueError(f"objective must be one of {metrics.OBJECTIVES}, got {reading!r}")
        super().__init__(stack_truth(scene0, family, preset, box, reading), None, part=-1, reading=reading,
                         resolution=RESOLUTION, names=box.names)
        self.box, self.family, self.scene0, self.preset = box, family, scene0, preset
        self._start_trace()

    def fingerprint(self) -> str:
        """A short hash of what the values are of: scene, family, preset, reading, the box, dt and substeps."""
        gs = self.surrogate.gs
        what = {"key": _key(self.scene0, self.family, self.preset, self.box, self.reading), "dt": gs.dt,
                "n_sub": gs.n_sub, "n_frames": gs.n_frames, "element": gs.element, "dtype": gs.dtype}
        return hashlib.sha256(json.dumps(what, sort_keys=True).encode()).hexdigest()[:16]

    def designs(self, x) -> list:
        """The :class:`~pcmgn_jax.data.family.Design` of each row of x (B, D) [SI]: the box's full row."""
        return [self.box.design(r, self.family) for r in np.atleast_2d(np.asarray(x, float))]

    def _record(self, x, value: float, grad, wall: float) -> None:
        self.n_solver_runs += 1
        self.trace.append({"design": dict(zip(self.box.names, map(float, x))), "mpa": value,
                           "grad_mpa": None if grad is None else dict(zip(self.box.names, map(float, grad))),
                           "wall_s": wall, "seconds": self.search_seconds()})

    def _restore(self, saved: dict) -> None:
        self.trace = list(saved.get("trace", []))
        for e in self.trace:
            if e["grad_mpa"] is not None:
                x = [e["design"][n] for n in self.box.names]
                self.grads[self._key(x)] = np.array([e["grad_mpa"][n] for n in self.box.names], float)

    def check(self, x) -> dict:
        """Whether the search's value at row x is the host solver's run (``same_run``: the host's own element
        counts there are the pinned ones and its own stable step gives the same substeps; one ``prepare``, no
        solver run), the fixed dt [s] and substeps, the rows the step was set at, and the setup's wall time [s]
        (before the search's clock: compilation is the search's)."""
        t = self.surrogate
        host = t.host_check(x)
        return {"dt_s": t.gs.dt, "n_substeps_per_frame": t.gs.n_sub, **host,
                "same_run": host["same_mesh"] and host["host_substeps_per_frame"] == t.gs.n_sub,
                "step_set_at": {"nominal": dict(zip(self.box.names, t.nominal.tolist())),
                                "thin_stiff_corner": dict(zip(self.box.names, t.corner.tolist()))},
                "setup_seconds": t.setup_seconds}
