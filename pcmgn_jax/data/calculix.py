"""Run a scene in CalculiX and read it back: ``.inp`` -> ``ccx`` -> ``.frd`` -> :class:`Trajectory`.

CalculiX is optional (Debian / Ubuntu: ``apt install calculix-ccx``); nothing here is imported by the
rest of the library, and a missing ``ccx`` is :class:`CalculixNotFoundError` when a run is asked for.

* :func:`run_ccx`: ``ccx -i JOB`` in the deck's folder with ``OMP_NUM_THREADS`` threads, the console output
  kept in ``JOB.log``; :class:`CalculixRunError` (naming the log) when ccx stops with ``*ERROR``, fails,
  or writes no .frd.
* :func:`frd_trajectory`: the .frd of a deck written by :mod:`pcmgn_jax.data.exporters.calculix` -> a
  trajectory on the project's mesh (CalculiX node i + 1 = mesh node i; the coordinates are checked), with
  frame 0 the initial state (u = 0, the ball at -``velocity``, zero stress), cropped to the preset's region
  of interest like the built-in solver's output. von Mises per node in one of two readings:
  ``stress="recovered"`` (default): the built-in solver's own rule applied to CalculiX's displacements
  (centroid stress of each Q4, hoop stress included, averaged over the node's own part:
  :func:`pcmgn_jax.sim.solver._frame_stress`), so a comparison sees the two solvers, not two post-
  processors; ``stress="frd"``: CalculiX's nodal stresses (integration points extrapolated to the nodes
  and averaged over every element at the node, across materials), von Mises of all six components.
* :func:`static_fields`: the .frd of a static deck (the panel under a pressure, no impact) -> displacement
  and the recovered von Mises on the full mesh.
* :func:`ball_force`: the contact force on the ball per frame interval [N] from the ball's momentum
  (row-sum masses x CalculiX's velocities; the momentum of a consistent mass matrix is exactly that), the
  interval mean of the contact force, since the ball feels no other force.
"""
from __future__ import annotations

import dataclasses
import math
import os
import shutil
import subprocess
import time
from pathlib import Path
from typing import Any

import numpy as np

from pcmgn_jax.data.exporters.calculix import (
    CCX_COUNTERPART,
    ELEMENT_TYPE,
    CalculixSettings,
    calculix_mesh,
    write_inp,
)
from pcmgn_jax.data.importers.d3plot import (
    von_mises_from_tensor,  # (s_rr, s_zz, s_tt, s_rz, s_rt, s_tz): normals, then shears
)
from pcmgn_jax.data.importers.errors import InputFileError
from pcmgn_jax.data.importers.frd import FrdResult, read_frd
from pcmgn_jax.data.trajectory_io import SI_UNITS
from pcmgn_jax.scene import Scene
from pcmgn_jax.sim import fem
from pcmgn_jax.sim.mesh import Mesh, MeshSpec, roi
from pcmgn_jax.sim.static import recovered_von_mises
from pcmgn_jax.trajectory import Trajectory

__all__ = ["CCX_INSTALL", "CalculixNotFoundError", "CalculixRunError", "STRESS_READINGS", "ball_force",
           "ball_masses", "find_ccx", "frd_trajectory", "run_ccx", "run_scene", "static_fields"]

CCX_INSTALL = "apt install calculix-ccx"
STRESS_READINGS = ("recovered", "frd")


class CalculixNotFoundError(RuntimeError):
    """The CalculiX solver ``ccx`` is not installed (or not where it was said to be)."""


class CalculixRunError(RuntimeError):
    """ccx ran but failed: the message names the log file and its first error line."""


def find_ccx(ccx: str | None = None) -> str:
    """The path of the ``ccx`` executable (``ccx`` given, else ``ccx`` on PATH); CalculixNotFoundError
    saying how to install it."""
    name = ccx or "ccx"
    found = shutil.which(name)
    if found is None:
        raise CalculixNotFoundError(f"CalculiX solver {name!r} not found on PATH; install it with "
                                    f"`{CCX_INSTALL}` (Debian/Ubuntu) or give its path (--ccx)")
    return found


def run_ccx(inp: str | os.PathLike, *, ccx: str | None = None, threads: int = 1,
            timeout: float | None = None) -> dict[str, Any]:
    """Run ``ccx -i JOB`` for ``inp`` (JOB.inp) in its folder; return {"frd", "log", "wall_time_s"}."""
    exe = find_ccx(ccx)
    inp = Path(inp)
    if inp.suffix != ".inp" or not inp.is_file():
        raise CalculixRunError(f"{inp}: not an existing .inp file")
    job, folder = inp.stem, inp.parent
    log = folder / f"{job}.log"
    frd = folder / f"{job}.frd"
    frd.unlink(missing_ok=True)
    env = {**os.environ, "OMP_NUM_THREADS": str(int(threads)), "CCX_NPROC_EQUATION_SOLVER": str(int(threads))}
    t0 = time.perf_counter()
    try:
        with open(log, "w") as out:
            proc = subprocess.run([exe, "-i", job], cwd=folder, stdout=out, stderr=subprocess.STDOUT,
                                  env=env, timeout=timeout, check=False)
    except subprocess.TimeoutExpired:
        raise CalculixRunError(f"{inp}: ccx ran past {timeout} s (log: {log})") from None
    wall = time.perf_counter() - t0
    text = log.read_text(errors="replace")
    errors = [ln.strip() for ln in text.splitlines() if "*ERROR" in ln]
    if errors or proc.returncode != 0 or not frd.is_file():
        why = errors[0] if errors else f"exit status {proc.returncode}" + ("" if frd.is_file() else ", no .frd")
        raise CalculixRunError(f"{inp}: ccx failed: {why} (log: {log})")
    return {"frd": str(frd), "log": str(log), "wall_time_s": wall}


def ball_masses(scene: Scene, mesh: Mesh) -> np.ndarray:
    """(N,) row-sum lumped mass [kg] of the ball's cells on each node (zero off the ball)."""
    ball = mesh.cell_part == 0
    n = np.count_nonzero(ball)
    _, me, _ = fem.element_matrices(mesh.points, mesh.cells[ball], np.full(n, scene.ball.youngs),
                                    np.full(n, scene.ball.poisson), np.full(n, scene.ball.density),
                                    analysis=scene.analysis)
    mass = np.zeros(mesh.n_nodes)
    np.add.at(mass, mesh.cells[ball], me)
    return mass


def ball_force(velocity: np.ndarray, mass: np.ndarray, dt: float) -> np.ndarray:
    """(T-1,) mean upward force on the ball [N] over each frame interval, d(sum m v_y)/dt, from full-mesh
    velocities (T, N, 2) [m/s], masses (N,) [kg] (:func:`ball_masses`) and the frame interval [s]."""
    momentum = np.asarray(velocity)[..., 1] @ np.asarray(mass)
    return np.diff(momentum) / dt


def _face_rows(res: FrdResult, mesh: Mesh, half_angle: float, where: str) -> np.ndarray:
    """Rows of the .frd's node table holding the mesh's nodes on the wedge's +half_angle face (CalculiX node
    i + 1 = mesh node i), their coordinates checked against the mesh; InputFileError otherwise."""
    n = mesh.n_nodes
    index = np.full(int(res.node_ids.max()) + 1, -1, np.int64)
    index[res.node_ids] = np.arange(len(res.node_ids))
    if res.node_ids.max() < n or np.any(index[1:n + 1] < 0):
        raise InputFileError(f"{where}: nodes 1..{n} (the mesh's nodes on the wedge's face) are not all in the "
                             "file (was the deck written for this scene and preset?)")
    rows = index[1:n + 1]
    xyz = res.nodes[rows]
    worst = float(np.max(np.abs(np.stack([np.hypot(xyz[:, 0], xyz[:, 1]), xyz[:, 2]], 1) - mesh.points)))
    if worst > 1e-5 * max(float(np.ptp(mesh.points)), 1e-30):   # the .frd keeps 6 significant digits
        raise InputFileError(f"{where}: node coordinates differ from the scene's mesh by up to {worst:.3e} m "
                             "(another design or preset?)")
    return rows


def _planar(a: np.ndarray, half_angle: float) -> np.ndarray:
    """Global (x, y, z) vectors at angle +half_angle -> (radial, height)."""
    c, s = math.cos(half_angle), math.sin(half_angle)
    return np.stack([a[..., 0] * c + a[..., 1] * s, a[..., 2]], axis=-1)


def _full_fields(res: FrdResult, mesh: Mesh, half_angle: float, where: str) -> tuple[np.ndarray, ...]:
    """(times, u, v, stress) on the mesh's nodes, frame 0 excluded: the wedge's +half_angle face (CalculiX
    node i + 1 = mesh node i) turned back to the (radius, height) plane: u, v (T, N, 2); stress (T, N, 6) as
    (s_rr, s_zz, s_tt, s_rz, s_rt, s_tz) with z the height and t the hoop direction."""
    rows = _face_rows(res, mesh, half_angle, where)
    c, s = math.cos(half_angle), math.sin(half_angle)
    missing = [k for k in ("DISP", "VELO", "STRESS") if k not in res.results]
    if missing:
        raise InputFileError(f"{where}: no {missing} result blocks (the deck asks *NODE FILE U, V and "
                             "*EL FILE S)")
    u, v, st = (res.results[k][:, rows] for k in ("DISP", "VELO", "STRESS"))
    if not (np.isfinite(u).all() and np.isfinite(v).all() and np.isfinite(st).all()):
        raise InputFileError(f"{where}: a result block misses nodes or holds a non-finite value")
    sxx, syy, szz, sxy, syz, szx = (st[..., k] for k in range(6))
    srr = c * c * sxx + s * s * syy + 2 * c * s * sxy
    stt = s * s * sxx + c * c * syy - 2 * c * s * sxy
    srt = (syy - sxx) * c * s + sxy * (c * c - s * s)
    srz = c * szx + s * syz
    stz = c * syz - s * szx
    stress = np.stack([srr, szz, stt, srz, srt, stz], axis=-1)
    return res.times, _planar(u, half_angle), _planar(v, half_angle), stress


def frd_trajectory(frd: str | os.PathLike, scene: Scene, preset: str | MeshSpec, *, stress: str = "recovered",
                   crop: bool = True, meta: dict[str, Any] | None = None) -> tuple[Trajectory, dict[str, Any]]:
    """The .frd of ``scene`` at ``preset`` -> (trajectory [SI], extra) where extra holds the full-mesh
    ``force_N`` (T-1,) per frame interval (:func:`ball_force`) and both stress readings' full-mesh von Mises
    ``von_mises_full`` {reading: (T, N)}, the full ``mesh`` and the crop's ``node_map``. The frames must be the scene's
    (0, output_dt, ... n_frames x output_dt); InputFileError otherwise."""
    if stress not in STRESS_READINGS:
        raise ValueError(f"calculix: stress must be one of {STRESS_READINGS}, got {stress!r}")
    where = str(frd)
    mesh = calculix_mesh(scene, preset)
    half = math.radians(float((meta or {}).get("settings", {}).get("wedge_deg", CalculixSettings().wedge_deg))) / 2
    times, u, v, s = _full_fields(read_frd(frd), mesh, half, where)
    expect = np.arange(1, scene.n_frames + 1) * scene.output_dt
    if len(times) != len(expect) or not np.allclose(times, expect, rtol=1e-4, atol=0):
        raise InputFileError(f"{where}: {len(times)} output times {times[:3]}...; the scene's frames are "
                             f"{len(expect)} x {scene.output_dt:g} s")
    n = mesh.n_nodes
    v0 = np.zeros((1, n, 2))
    v0[0, np.unique(mesh.cells[mesh.cell_part == 0]), 1] = -scene.ball.velocity   # the solver's initial state
    u = np.concatenate([np.zeros((1, n, 2)), u])
    v = np.concatenate([v0, v])
    vms = {"recovered": recovered_von_mises(u, scene, mesh, CCX_COUNTERPART[ELEMENT_TYPE]),   # *DYNAMIC: C3D8
           "frd": np.concatenate([np.zeros((1, n)), von_mises_from_tensor(s)])}
    force = ball_force(v, ball_masses(scene, mesh), scene.output_dt)
    sub, node_map = roi(mesh, preset) if crop else (mesh, np.arange(n))
    info = {"units": dict(SI_UNITS), "analysis": scene.analysis, "scene": scene.to_dict(),
            "design": dict(zip(scene.design_layers, scene.design)), "output_dt": scene.output_dt,
            "source": "calculix", "part_names": list(scene.part_names), "energy": None,
            "solver": {"preset": preset if isinstance(preset, str) else "custom", "code": "ccx",
                       "full_mesh_nodes": n, "full_mesh_cells": int(len(mesh.cells)), "roi_nodes": sub.n_nodes,
                       "stress": stress, **(meta or {})}}
    traj = Trajectory(points=mesh.points[node_map], cells=sub.cells, cell_part=sub.cell_part,
                      node_part=sub.node_part, node_type=sub.node_type,
                      times=np.arange(scene.n_frames + 1) * scene.output_dt,
                      displacement=u[:, node_map], velocity=v[:, node_map], von_mises=vms[stress][:, node_map],
                      meta=info)
    traj.validate(where)
    return traj, {"force_N": force, "von_mises_full": vms, "mesh": mesh, "node_map": node_map}


def static_fields(frd: str | os.PathLike, scene: Scene, preset: str | MeshSpec, *,
                  wedge_deg: float = CalculixSettings().wedge_deg,
                  ccx_element: str = ELEMENT_TYPE) -> tuple[np.ndarray, np.ndarray]:
    """The .frd of a static deck (:func:`pcmgn_jax.data.exporters.calculix.static_inp_text`) of ``scene`` at
    ``preset`` -> (displacement (N, 2) [m], von Mises (N,) [Pa]) on the full mesh, the last (only) result; von
    Mises is the built-in solver's recovery applied to CalculiX's displacements (``stress="recovered"`` of
    :func:`frd_trajectory`) with the 2D counterpart of the deck's ``ccx_element`` (:data:`CCX_COUNTERPART`: ``q4``
    for C3D8, ``q4i`` for C3D8I)."""
    where = str(frd)
    mesh = calculix_mesh(scene, preset)
    res = read_frd(frd)
    rows = _face_rows(res, mesh, math.radians(wedge_deg) / 2, where)
    if "DISP" not in res.results:
        raise InputFileError(f"{where}: no DISP result block (the deck asks *NODE FILE U)")
    u = _planar(res.results["DISP"][-1, rows], math.radians(wedge_deg) / 2)
    if not np.isfinite(u).all():
        raise InputFileError(f"{where}: the DISP block misses nodes or holds a non-finite value")
    return u, recovered_von_mises(u[None], scene, mesh, CCX_COUNTERPART[ccx_element])[0]


def run_scene(scene: Scene, preset: str | MeshSpec, folder: str | os.PathLike, *,
              settings: CalculixSettings = CalculixSettings(), ccx: str | None = None, threads: int = 1,
              stress: str = "recovered", job: str = "job") -> tuple[Trajectory, dict[str, Any]]:
    """Write ``folder/JOB.inp``, run ccx, read ``JOB.frd``: (trajectory, extra) as :func:`frd_trajectory`,
    extra also holding the deck summary and the ccx wall time."""
    find_ccx(ccx)   # fail before writing anything
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    deck = write_inp(folder / f"{job}.inp", scene, preset, settings)
    run = run_ccx(folder / f"{job}.inp", ccx=ccx, threads=threads)
    meta = {"settings": dataclasses.asdict(settings), "inp": deck, "wall_time_s": run["wall_time_s"],
            "threads": int(threads)}
    traj, extra = frd_trajectory(run["frd"], scene, preset, stress=stress, meta=meta)
    return traj, {**extra, "deck": deck, "run": run}
