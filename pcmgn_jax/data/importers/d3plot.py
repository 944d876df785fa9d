"""LS-DYNA d3plot (through lasso-python, the optional ``dyna`` extra) -> ImportedMesh / Trajectory.

2D solids (plane strain / axisymmetric) are stored as 4-node shells in a d3plot. Part titles come back
from lasso as ``bytes`` padded with blanks; they are decoded here (``str(b'...')`` never matched a title).
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from pcmgn_jax.data.importers.build import build_trajectory
from pcmgn_jax.data.importers.errors import InputFileError
from pcmgn_jax.data.importers.parts import ImportedMesh, assign_parts, finish_mesh, part_specs, resolve_part_names
from pcmgn_jax.data.importers.units import length_factor, stress_factor, time_factor
from pcmgn_jax.scene import Scene
from pcmgn_jax.trajectory import Trajectory


def _lasso():
    try:
        from lasso.dyna import ArrayType, D3plot
    except ImportError:
        raise ImportError("import_d3plot needs lasso-python: pip install -e \".[dyna]\" "
                          "(or pip install lasso-python)") from None
    return D3plot, ArrayType


def decode_title(raw: Any) -> str:
    """A d3plot part title as text: lasso returns blank- or NUL-padded ``bytes``."""
    if isinstance(raw, (bytes, bytearray, np.bytes_)):
        raw = bytes(raw).decode("utf-8", errors="replace")
    return str(raw).replace("\x00", " ").strip()


def von_mises_from_tensor(s: np.ndarray) -> np.ndarray:
    """Von Mises stress of (..., 6) tensors ordered xx, yy, zz, xy, yz, xz."""
    sxx, syy, szz, sxy, syz, sxz = (s[..., i] for i in range(6))
    return np.sqrt(0.5 * ((sxx - syy) ** 2 + (syy - szz) ** 2 + (szz - sxx) ** 2)
                   + 3.0 * (sxy ** 2 + syz ** 2 + sxz ** 2))


@dataclass(frozen=True)
class D3plotPart:
    """One part of a d3plot: LS-DYNA part id, decoded title, its shell count and node count."""

    part_id: int
    title: str
    n_shells: int
    n_nodes: int


def _open(path: Path):
    D3plot, AT = _lasso()
    try:
        d = D3plot(str(path))
    except Exception as err:
        msg = " ".join(f"{type(err).__name__}: {err}".split())[:200]
        raise InputFileError(f"{path}: lasso cannot read the d3plot ({msg}); give the first file of the "
                             "d3plot family (d3plot, not d3plot01)") from None
    return d.arrays, AT


def _parts_of(arr, AT) -> tuple[np.ndarray, dict[int, str]]:
    part_idx = np.asarray(arr.get(AT.element_shell_part_indexes, np.zeros(0, np.int64)), np.int64)
    n_parts = int(part_idx.max()) + 1 if len(part_idx) else 0
    pids = np.asarray(arr.get(AT.part_ids, np.arange(n_parts) + 1), np.int64)
    titles = {int(t): decode_title(x) for t, x in zip(np.asarray(arr.get(AT.part_titles_ids, [])).tolist(),
                                                      list(arr.get(AT.part_titles, [])))}
    return pids, titles


def d3plot_parts(path: str | os.PathLike) -> list[D3plotPart]:
    """The parts of a d3plot (ids, decoded titles, shell and node counts): what ``parts`` can refer to."""
    path = Path(path)
    arr, AT = _open(path)
    pids, titles = _parts_of(arr, AT)
    cells = np.asarray(arr.get(AT.element_shell_node_indexes, np.zeros((0, 4))), np.int64)
    part_idx = np.asarray(arr.get(AT.element_shell_part_indexes, np.zeros(0)), np.int64)
    ids = sorted(set(pids.tolist()) | set(titles))
    out = []
    for pid in ids:
        mask = pids[part_idx] == pid if len(part_idx) else np.zeros(0, bool)
        out.append(D3plotPart(pid, titles.get(pid, ""), int(mask.sum()), len(np.unique(cells[mask]))))
    return out


def _mesh_from_arrays(path: Path, arr, AT, names, specs, length_unit: str, ignore_unmapped: bool) -> ImportedMesh:
    for key in (AT.node_coordinates, AT.node_ids):
        if key not in arr:
            raise InputFileError(f"{path}: d3plot has no {key!r} array: not a complete d3plot")
    cells = np.asarray(arr.get(AT.element_shell_node_indexes, np.zeros((0, 4))), np.int64)
    if len(cells) == 0:
        kinds = [k for k, key in (("beams", AT.element_beam_node_indexes), ("solids", AT.element_solid_node_indexes),
                                  ("thick shells", AT.element_tshell_node_indexes))
                 if len(np.asarray(arr.get(key, []))) > 0]
        raise InputFileError(f"{path}: d3plot has no shell elements (it has {', '.join(kinds) or 'no elements'}): "
                             "2D solids (plane strain / axisymmetric) are stored as shells; export a 2D model")
    lf = length_factor(length_unit, f"{path}: length_unit")
    coords = np.asarray(arr[AT.node_coordinates], np.float64)
    node_ids = np.asarray(arr[AT.node_ids], np.int64)
    if np.any(coords[:, 2] != 0):
        k = int(np.argmax(coords[:, 2] != 0))
        raise InputFileError(f"{path}: node {int(node_ids[k])} has z = {coords[k, 2]}; only 2D models are supported")
    part_idx = np.asarray(arr[AT.element_shell_part_indexes], np.int64)
    pids, titles = _parts_of(arr, AT)
    cell_pid = pids[part_idx]
    groups = {title.lower(): cell_pid == tid for tid, title in titles.items() if title}
    cell_part = assign_parts(str(path), names, specs, len(cells), cell_pid, "LS-DYNA part id", groups, "part title")
    eids = np.asarray(arr.get(AT.element_shell_ids, np.arange(1, len(cells) + 1)), np.int64)
    degenerate = np.array([len(set(c)) != 4 for c in cells.tolist()])
    if np.any(degenerate & (cell_part >= 0)):
        k = int(np.argmax(degenerate & (cell_part >= 0)))
        n_bad = int((degenerate & (cell_part >= 0)).sum())
        raise InputFileError(f"{path}: element {eids[k]} (part {names[cell_part[k]]!r}, LS-DYNA part "
                             f"{int(cell_pid[k])}) is a degenerate quad (triangle), {n_bad} such element(s): "
                             "only 4-node quads are supported; remesh the part with quadrilaterals only")
    return finish_mesh(str(path), node_ids, coords[:, :2] * lf, cells, cell_part, eids, {}, names, ignore_unmapped)


def read_d3plot_mesh(path: str | os.PathLike, *, scene: Scene | Mapping | None = None,
                     part_names: Sequence[str] | None = None, parts: Mapping[str, Any] | None = None,
                     length_unit: str = "m", ignore_unmapped: bool = False) -> ImportedMesh:
    """The 2D quad mesh of a d3plot (shells) with parts; ``parts`` ints are LS-DYNA part ids, strs part titles."""
    path = Path(path)
    names, _ = resolve_part_names(scene, part_names)
    arr, AT = _open(path)
    return _mesh_from_arrays(path, arr, AT, names, part_specs(parts, names), length_unit, ignore_unmapped)


def import_d3plot(path: str | os.PathLike, *, scene: Scene | Mapping | None = None,
                  part_names: Sequence[str] | None = None, parts: Mapping[str, Any] | None = None,
                  length_unit: str = "m", time_unit: str = "s", stress_unit: str = "Pa",
                  fixed: Any = "bottom", ignore_unmapped: bool = False,
                  design: Mapping[str, float] | None = None) -> Trajectory:
    """LS-DYNA d3plot of a 2D (plane strain / axisymmetric) model -> Trajectory (source 'd3plot').

    Needs lasso-python. 2D solids are stored as 4-node shells; ``parts`` ints are LS-DYNA part ids,
    strs part titles (default: the part names). lasso's ``node_displacement`` holds current coordinates
    (displacement = node_displacement - node_coordinates). Nodal von Mises = mean over the adjacent
    elements of the element von Mises (averaged over integration layers). Units via ``length_unit`` /
    ``time_unit`` / ``stress_unit`` (LS-DYNA is unit-consistent; e.g. mm, ms, GPa).
    """
    path = Path(path)
    names, scene_obj = resolve_part_names(scene, part_names)
    specs = part_specs(parts, names)
    arr, AT = _open(path)
    mesh = _mesh_from_arrays(path, arr, AT, names, specs, length_unit, ignore_unmapped)
    for key in (AT.node_displacement, AT.node_velocity, AT.global_timesteps):
        if key not in arr:
            raise InputFileError(f"{path}: d3plot has no {key!r} array: write displacements and velocities "
                                 "(*DATABASE_EXTENT_BINARY) and run again")
    lf = length_factor(length_unit, "length_unit")
    tf = time_factor(time_unit, "time_unit")
    sf = stress_factor(stress_unit, "stress_unit")
    all_ids = np.asarray(arr[AT.node_ids], np.int64)
    order = np.argsort(all_ids)
    used = order[np.searchsorted(all_ids[order], mesh.node_ids)]
    pos = np.asarray(arr[AT.node_displacement], np.float64)[:, used, :2] * lf
    disp = pos - mesh.points[None]
    vel = np.asarray(arr[AT.node_velocity], np.float64)[:, used, :2] * (lf / tf)
    t = np.asarray(arr[AT.global_timesteps], np.float64) * tf
    T, n = len(t), len(mesh.points)
    vm = np.zeros((T, n))
    if AT.element_shell_stress in arr:
        cells_all = np.asarray(arr[AT.element_shell_node_indexes], np.int64)
        eids_all = np.asarray(arr.get(AT.element_shell_ids, np.arange(1, len(cells_all) + 1)), np.int64)
        keep = np.isin(eids_all, mesh.cell_ids)
        evm = von_mises_from_tensor(np.asarray(arr[AT.element_shell_stress], np.float64)).mean(axis=2)
        if evm.shape[1] != len(cells_all):
            raise InputFileError(f"{path}: stress is stored for {evm.shape[1]} of {len(cells_all)} shells "
                                 "(rigid parts?); model every part as deformable")
        evm = evm[:, keep] * sf
        count = np.zeros(n)
        for c in range(4):
            np.add.at(vm, (slice(None), mesh.cells[:, c]), evm)
            np.add.at(count, mesh.cells[:, c], 1.0)
        vm /= np.maximum(count, 1.0)[None]
    for name, a in (("displacement", disp), ("velocity", vel), ("von_mises", vm)):
        if not np.all(np.isfinite(a)):
            k = np.argwhere(~np.isfinite(a))[0]
            raise InputFileError(f"{path}: {name}: non-finite value at state {k[0]}, node {mesh.node_ids[k[1]]}")
    return build_trajectory(mesh, scene_obj, fixed, t, disp, vel, vm, "d3plot",
                            {"mesh": str(path), "results": str(path)}, design)
