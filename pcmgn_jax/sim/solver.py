"""Explicit central-difference dynamics in JAX: the built-in ground truth.

Small-strain linear elasticity on Q4 elements (plane strain or axisymmetric with the hoop
term), row-sum lumped mass, a node-to-segment penalty contact between the ball's lower
surface (slaves) and the top layer's upper surface (masters), clamped plate bottom and a
symmetry axis (u_x = 0 at x = 0). Units SI.

Numerics (docs/design.md §3):
- the state is the displacement u (not absolute coordinates), so float32 keeps the ~1e-9 m
  per-step increments next to mm coordinates; world positions are formed only in the contact
  gap, relative to reference coordinates of the same magnitude;
- contact forces are minus the gradient (jax.grad) of the penalty energy
  0.5 * k_s * min(g, 0)^2 with the gap g measured in the deformed configuration, so the
  contact is conservative by construction (no radial/vertical mismatch);
- the stable step includes the contact springs: dt = safety * 2 / sqrt(w_mesh^2 + w_c^2),
  w_mesh^2 the largest eigenvalue of M^-1/2 K M^-1/2 (scipy Lanczos), w_c^2 a Gershgorin bound
  of M^-1 K_contact. On the default meshes the 25 / 10 um glass, steel and aluminium elements at
  the contact set w_mesh; the bound adds 60-70 % to w_mesh^2 while the coupled eigenvalue with all
  springs engaged (``Prepared.omega2_coupled``) adds only ~9 %, but a step from the latter
  destabilised a run near separation (see :func:`prepare`), so the bound stays;
- energy (kinetic + internal + contact; no external work: the supports are fixed) is
  checked at every frame; a drift above ``energy_tol`` of the initial kinetic energy, or a
  non-finite value, raises :class:`SolverError` naming the frame, and nothing is returned.

The whole run is one jitted ``lax.scan`` (frames) over a ``lax.scan`` (substeps), no host sync
inside. The stiffness is applied as shifted slices of contiguous node rows
(:mod:`pcmgn_jax.sim.stencil`); node arrays are (2, B, N) with a design axis kept in the arrays
rather than vmapped, so designs of one topology can run in one call
(``SolverSettings.designs_per_call``; on CPU they run one at a time, which is faster; on an
accelerator 64 at a time, :func:`designs_per_call`). Every call of a batch has the same number of designs
(a short last call is padded with copies of a design whose results are dropped; a batch of one call is
padded to the next power of two, :func:`call_size`), so a batch compiles once.

Modules: :mod:`pcmgn_jax.sim.prepare` (operators, masses, penalties, stable step),
:mod:`pcmgn_jax.sim.integrate` (the jitted integration), :mod:`pcmgn_jax.sim.output` (the result
and its trajectories), :mod:`pcmgn_jax.sim.initial` (the initial state); this module runs a batch
(:func:`simulate`, :func:`solve_designs`) and re-exports their public names.
"""
from __future__ import annotations

import math
import time
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from pcmgn_jax import compile_notes
from pcmgn_jax.scene import Scene
from pcmgn_jax.sim.initial import initial_velocity
from pcmgn_jax.sim.integrate import (
    _device_arrays,
    _frame_stress,
    _run,
    _run_batch,
    ball_weights,
    contact_energy,
)
from pcmgn_jax.sim.mesh import MeshSpec
from pcmgn_jax.sim.output import RunResult, _spec_dict, contact_phases, to_trajectories
from pcmgn_jax.sim.prepare import (
    DEFAULT_SETTINGS,
    Prepared,
    SolverSettings,
    _contact_stiffness,
    _largest_omega2,
    _material_arrays,
    _node_slots,
    _tributary,
    prepare,
)
from pcmgn_jax.trajectory import Trajectory

__all__ = [
    "ACCELERATOR_DESIGNS_PER_CALL",
    "Calls",
    "DEFAULT_SETTINGS",
    "Prepared",
    "RunResult",
    "SolverError",
    "SolverSettings",
    "_contact_stiffness",
    "_device_arrays",
    "_frame_stress",
    "_largest_omega2",
    "_material_arrays",
    "_node_slots",
    "_run",
    "_run_batch",
    "_spec_dict",
    "_tributary",
    "contact_energy",
    "call_size",
    "contact_phases",
    "designs_per_call",
    "initial_velocity",
    "prepare",
    "simulate",
    "solve_designs",
    "to_trajectories",
]


#: designs per compiled call on an accelerator when SolverSettings.designs_per_call is 0
#: (benchmarks/solver_throughput.py measures designs per second against this number)
ACCELERATOR_DESIGNS_PER_CALL = 64


def designs_per_call(settings: SolverSettings = DEFAULT_SETTINGS) -> int:
    """Designs one compiled solver call integrates: ``settings.designs_per_call``, or for 0 the device's
    default (1 on CPU, where single runs are faster than a vectorised batch; on an accelerator
    :data:`ACCELERATOR_DESIGNS_PER_CALL`). A call with fewer designs is padded to this size."""
    if not isinstance(settings.designs_per_call, int) or settings.designs_per_call < 0:
        raise ValueError(f"designs_per_call must be an integer >= 0, got {settings.designs_per_call!r}")
    if settings.designs_per_call:
        return settings.designs_per_call
    return 1 if jax.default_backend() == "cpu" else ACCELERATOR_DESIGNS_PER_CALL


def call_size(n_designs: int, settings: SolverSettings = DEFAULT_SETTINGS) -> int:
    """Designs per compiled call for a batch of ``n_designs``: :func:`designs_per_call` when the batch needs
    several calls (the last one is padded to it: one compilation, whatever the batch's remainder), else the
    next power of two >= ``n_designs`` up to it (a single design on a GPU is not padded to 64)."""
    full = designs_per_call(settings)
    return full if n_designs >= full else min(full, 1 << (max(1, n_designs) - 1).bit_length())


class SolverError(RuntimeError):
    """The explicit run became unstable (energy drift or non-finite values)."""


class Calls:
    """The integration of a prepared batch, cut into compiled calls (host side): :meth:`inputs` gives the
    arguments of :func:`_run` for the designs ``part`` (indices into the prepared batch, repeats allowed:
    padding, or a benchmark's tiled batch). ``dt`` [s] and ``n_sub`` are shared by the whole batch."""

    def __init__(self, scenes: Sequence[Scene], prep: Prepared, *, settings: SolverSettings, n_frames: int,
                 output_dt: float):
        base, m0 = scenes[0], prep.mesh
        self.prep, self.n_frames = prep, n_frames
        self.n_sub = max(1, math.ceil(output_dt / prep.dt_stable))
        self.dt = output_dt / self.n_sub
        self.dtype = jnp.dtype(settings.dtype)
        if self.dtype == jnp.float64 and not jax.config.read("jax_enable_x64"):
            raise ValueError("simulate: dtype float64 needs `with jax.enable_x64(True):`")
        self.ball_w = ball_weights(prep.mass, m0.node_part)
        # stiffness rows of nodes touching no design-layer element are the same for every design
        # (the layers above only translate), so the batch reads them once
        design_parts = [m0.part_names.index(name) for name in base.design_layers]
        self.shared_rows = np.ones(m0.n_nodes, bool)
        self.shared_rows[m0.cells[np.isin(m0.cell_part, design_parts)].ravel()] = False
        self.v0 = np.moveaxis(np.stack([initial_velocity(s, m0.node_part) for s in scenes]), -1, 0)  # (2,B,N)
        self.rigid_x = base.analysis == "plane_strain"

    def inputs(self, part: np.ndarray) -> tuple[tuple, dict]:
        """(positional, static keyword) arguments of :func:`_run` for the designs ``part``."""
        prep, m0, dtype = self.prep, self.prep.mesh, self.dtype
        arrays, layout = _device_arrays(
            points=prep.points[part], cells=m0.cells, ke=prep.ke[part], db=prep.db[part],
            mass=prep.mass[part], free=prep.free, ball_weight=self.ball_w[part], slaves=prep.slaves,
            masters=prep.masters, k_slave=prep.k_slave[part], node_slots=prep.node_slots,
            avg_weight=prep.avg_weight, shared_rows=self.shared_rows, dtype=dtype)
        nb = len(part)
        return ((arrays, jnp.zeros((2, nb, m0.n_nodes), dtype), jnp.asarray(self.v0[:, part], dtype),
                 jnp.full((nb,), self.dt, dtype)),
                dict(layout=layout, n_frames=self.n_frames, n_sub=self.n_sub, rigid_x=self.rigid_x))

    def note_key(self, static: dict, n_designs: int) -> tuple:
        """What decides the compilation of a call (:mod:`pcmgn_jax.compile_notes`)."""
        return (self.prep.mesh.n_nodes, n_designs, str(self.dtype), *sorted(static.items()))


def simulate(scenes: Sequence[Scene], preset: str | MeshSpec = "cpu", *,
             settings: SolverSettings = DEFAULT_SETTINGS, n_frames: int | None = None,
             output_dt: float | None = None) -> RunResult:
    """Run a batch of designs (same topology) and check energy; raises SolverError."""
    if not scenes:
        raise ValueError("simulate: no scenes given")
    base = scenes[0]
    n_frames = base.n_frames if n_frames is None else n_frames
    output_dt = base.output_dt if output_dt is None else output_dt
    per_call = call_size(len(scenes), settings)
    calls = Calls(scenes, prepare(scenes, preset, settings), settings=settings, n_frames=n_frames,
                  output_dt=output_dt)
    prep, n_sub, dt = calls.prep, calls.n_sub, calls.dt
    b = len(scenes)
    outs, wall = [], 0.0
    for lo in range(0, b, per_call):
        # every call integrates exactly per_call designs (one compilation): a short last call is padded
        # with copies of its last design, whose results are dropped (designs do not interact)
        real = np.arange(lo, min(lo + per_call, b))
        args, static = calls.inputs(np.concatenate([real, np.full(per_call - len(real), real[-1])]))
        t0 = time.perf_counter()
        with compile_notes.first_call("the solver", calls.note_key(static, per_call)):
            out = jax.block_until_ready(_run(*args, **static))
        wall += time.perf_counter() - t0
        outs.append(jax.tree.map(lambda x, n=len(real): np.asarray(x)[:n], out))
    # each call returns u, v, von Mises, energy, (force, approach) with the designs leading
    us, vs, vm, es, force, approach = (
        np.concatenate(per_output)
        for per_output in zip(*[(u, v, m, e, f, a) for u, v, m, e, (f, a) in outs]))
    us, vs, vm, es = (np.asarray(x, np.float64) for x in (us, vs, vm, es))
    ke0 = es[:, 0, 0]
    total = es.sum(axis=2)
    err = np.abs(total - total[:, :1]) / ke0[:, None]
    for i in range(b):
        bad = ~np.isfinite(us[i]).all(axis=(1, 2)) | ~np.isfinite(vs[i]).all(axis=(1, 2)) | \
            ~np.isfinite(err[i])
        if bad.any():
            raise SolverError(f"design {i} {scenes[i].design}: non-finite values at frame "
                              f"{int(np.argmax(bad))} (t = {np.argmax(bad) * output_dt:.3e} s)")
        over = err[i] > settings.energy_tol
        if over.any():
            f = int(np.argmax(over))
            raise SolverError(
                f"design {i} {scenes[i].design}: energy error {err[i, f]:.3%} of the initial "
                f"kinetic energy exceeds {settings.energy_tol:.1%} at frame {f} "
                f"(t = {f * output_dt:.3e} s); dt = {dt:.3e} s")
    return RunResult(prepared=prep, u=us, v=vs, von_mises=vm, energy=es,
                     force=np.asarray(force, np.float64), approach=np.asarray(approach, np.float64),
                     dt=dt, n_sub=n_sub, wall_time_s=wall, energy_error=err.max(axis=1))


def solve_designs(scene: Scene, designs: np.ndarray, *, preset: str | MeshSpec = "cpu",
                  settings: SolverSettings = DEFAULT_SETTINGS) -> list[Trajectory]:
    """Simulate designs (B, n_design) [m] of ``scene`` in one batched call; ROI-cropped
    Trajectories with meta (source 'solver', design, solver settings, energy, wall time)."""
    designs = np.atleast_2d(np.asarray(designs, float))
    scenes = [scene.with_design(*d) for d in designs]
    result = simulate(scenes, preset, settings=settings)
    return to_trajectories(result, scenes, preset, settings=settings)
