"""Importers: ANSYS Mechanical text exports, meshio meshes/time series, LS-DYNA d3plot -> Trajectory.

Every importer returns a validated :class:`~pcmgn_jax.trajectory.Trajectory` in SI units and writes
nothing (write it with ``trajectory_io.write_trajectory``, which is atomic). Bad input raises
:class:`InputFileError` (a ``ValueError``) naming the file and the line / node / element / column.

Parts
-----
Part ids are the positions in ``part_names`` (``scene.part_names`` when a scene is given:
0 = ball, 1..n = layers top to bottom). ``parts`` maps each part name to the mesh groups that form it::

    parts = {"ball": 1, "CG": 2, "OCA1": [3], ...}        # ints: ANSYS material number (cdb "mat"),
                                                          # LS-DYNA part id, or value of a meshio
                                                          # cell-data array (``part_field``)
    parts = {"ball": "BALL", "CG": "GLASS", ...}          # strs: ANSYS element component (CMBLOCK),
                                                          # meshio cell set, LS-DYNA part title
Default (``parts=None``): each part name is looked up as a component / cell set / part title of the
same name (case-insensitive). Every solid cell must belong to exactly one part; cells of unmapped
groups are an error unless ``ignore_unmapped=True`` (ANSYS contact/target/surface element types
169-178 and 151-154 are always skipped). ``node_part`` of a node shared by several parts is the
stiffest part (largest Young's modulus in the scene; without a scene: the smallest part id).
``node_type`` = ``node_part``, or ``len(part_names)`` for fixed nodes: ``fixed="bottom"`` (nodes at
the minimum height, the clamped plate bottom), a node component / node-set name, a sequence of node
numbers, or ``None``.

ANSYS Mechanical "Export -> Text File" results (``import_ansys_text``)
---------------------------------------------------------------------
One tab-separated nodal table per result per frame, as Mechanical writes it::

    Node Number<TAB>X Location (mm)<TAB>Y Location (mm)<TAB>Z Location (mm)<TAB>Directional Deformation (mm)

Units are read from the headers and converted to SI: lengths m, mm, µm/um, cm, in; velocity
<length>/<s|ms|µs>; stress Pa, kPa, MPa, GPa, psi, N/mm^2. Result columns: ``Directional
Deformation``, ``Directional Velocity`` (the X or Y orientation is chosen in Mechanical and not in
the header, so it comes from the file name) and ``Equivalent (von-Mises) Stress``. ``Z Location`` is
optional. X/Y locations are checked against the mesh (``location_tol`` [m]).

File naming convention inside the results folder (frames numbered 0..T-1, no gaps)::

    deformation_x_000.txt  deformation_y_000.txt  velocity_x_000.txt  velocity_y_000.txt  stress_000.txt
    deformation_x_001.txt  ...
    times.txt              optional: one frame time per line [s]; otherwise ``output_dt`` gives t_k = k*dt

or a manifest ``frames.json`` in the folder that lists the files (paths relative to the folder)::

    {"time_unit": "s", "frames": [{"time": 0.0, "deformation_x": "UX_0.txt", "deformation_y": "UY_0.txt",
                                   "velocity_x": "VX_0.txt", "velocity_y": "VY_0.txt", "stress": "S_0.txt"}, ...]}

Meshes (``read_mesh``)
----------------------
* ANSYS ``.cdb`` archives (``read_cdb``): NBLOCK nodes, EBLOCK elements (SOLID format, 4-node quads,
  e.g. PLANE182), CMBLOCK components, ET element types, ``/UNITS``. meshio has no .cdb reader, hence
  the small fixed-format parser here.
* Anything meshio reads (Abaqus .inp, Gmsh .msh, Nastran, VTU, ...): quads only (vertex/line cells
  are ignored); parts from cell sets or an integer cell-data array ``part_field``. ANSYS node numbers
  are the integer point-data array ``node_id_field`` if given, else meshio index + 1.

meshio time series (``import_meshio_series``): an XDMF time series or a list of per-frame files
(e.g. VTU), each with point data displacement (N,2|3), velocity (N,2|3) and von Mises (N,)
(names configurable), same mesh in every frame. LS-DYNA (``import_d3plot``): optional, needs
``pip install -e ".[dyna]"`` (lasso-python); 2D solids are shells in the d3plot.
"""
from __future__ import annotations

import json
import math
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

from pcmgn_jax.scene import Scene
from pcmgn_jax.trajectory import Trajectory
from pcmgn_jax.data.trajectory_io import SI_UNITS

__all__ = ["InputFileError", "Mesh", "import_ansys_text", "import_d3plot", "import_meshio_series",
           "read_ansys_table", "read_cdb", "read_mesh", "read_meshio_mesh"]


class InputFileError(ValueError):
    """Bad input file: the message names the file and the line / node / element / column."""


# ---- units --------------------------------------------------------------------------------------
LENGTH_UNITS = {"m": 1.0, "mm": 1e-3, "um": 1e-6, "\u00b5m": 1e-6, "\u03bcm": 1e-6, "cm": 1e-2,
                "nm": 1e-9, "in": 0.0254, "ft": 0.3048}
TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "\u00b5s": 1e-6, "\u03bcs": 1e-6}
STRESS_UNITS = {"pa": 1.0, "kpa": 1e3, "mpa": 1e6, "gpa": 1e9, "psi": 6894.757293168361,
                "n/m^2": 1.0, "n/m\u00b2": 1.0, "n/mm^2": 1e6, "n/mm\u00b2": 1e6}
ANSYS_UNIT_SYSTEMS = {"SI": "m", "MKS": "m", "MPA": "mm", "UMKS": "um", "CGS": "cm"}


def length_factor(unit: str, where: str) -> float:
    """SI factor of a length unit (m, mm, µm, ...); InputFileError naming ``where`` if unknown."""
    f = LENGTH_UNITS.get(unit.strip())
    if f is None:
        raise InputFileError(f"{where}: unknown length unit {unit!r}; known: {sorted(LENGTH_UNITS)}")
    return f


def _velocity_factor(unit: str, where: str) -> float:
    u = unit.strip()
    if "/" in u:
        num, den = u.split("/", 1)
        if num in LENGTH_UNITS and den in TIME_UNITS:
            return LENGTH_UNITS[num] / TIME_UNITS[den]
    raise InputFileError(f"{where}: unknown velocity unit {unit!r}; expected <length>/<time> with "
                         f"length in {sorted(LENGTH_UNITS)} and time in {sorted(TIME_UNITS)}")


def _stress_factor(unit: str, where: str) -> float:
    f = STRESS_UNITS.get(unit.strip().lower())
    if f is None:
        raise InputFileError(f"{where}: unknown stress unit {unit!r}; known: Pa, kPa, MPa, GPa, psi, N/mm^2")
    return f


# ---- mesh ---------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Mesh:
    """A 2D quad mesh with parts, as read from a mesh file.

    node_ids: (N,) int64 external node numbers (unique); points: (N, 2) float64 [m];
    cells: (E, 4) int64 indices into points; cell_part: (E,) int32 part ids; cell_ids: (E,) int64
    external element numbers; node_sets: name -> external node numbers (components / node sets);
    part_names: names indexed by part id; source: the file.
    """

    node_ids: np.ndarray
    points: np.ndarray
    cells: np.ndarray
    cell_part: np.ndarray
    cell_ids: np.ndarray
    node_sets: Mapping[str, np.ndarray]
    part_names: tuple[str, ...]
    source: str

    def compact(self) -> "Mesh":
        """Drop nodes used by no cell (renumbering cells)."""
        used = np.zeros(len(self.node_ids), dtype=bool)
        used[self.cells.reshape(-1)] = True
        if used.all():
            return self
        new = -np.ones(len(used), dtype=np.int64)
        new[used] = np.arange(used.sum())
        return Mesh(self.node_ids[used], self.points[used], new[self.cells], self.cell_part, self.cell_ids,
                    self.node_sets, self.part_names, self.source)


def _resolve_part_names(scene: Scene | Mapping | None, part_names: Sequence[str] | None) -> tuple[
        tuple[str, ...], Scene | None]:
    if isinstance(scene, Mapping):
        scene = Scene.from_dict(scene)
    if scene is not None:
        names = scene.part_names
        if part_names is not None and tuple(part_names) != names:
            raise ValueError(f"part_names {tuple(part_names)} disagree with the scene's {names}")
        return names, scene
    if not part_names:
        raise ValueError("give a scene or part_names (part name -> part id mapping by position)")
    names = tuple(part_names)
    if len(set(names)) != len(names):
        raise ValueError(f"part_names must be unique, got {names}")
    return names, None


def _part_specs(parts: Mapping[str, Any] | None, names: Sequence[str]) -> dict[str, list]:
    if parts is None:
        return {n: [n] for n in names}
    unknown = sorted(set(parts) - set(names))
    if unknown:
        raise ValueError(f"parts: unknown part name(s) {unknown}; part names are {list(names)}")
    out = {}
    for n, spec in parts.items():
        items = list(spec) if isinstance(spec, (list, tuple)) else [spec]
        for it in items:
            if not isinstance(it, (int, np.integer, str)) or isinstance(it, bool):
                raise ValueError(f"parts[{n!r}]: entries must be ints or strings, got {it!r}")
        out[n] = items
    return out


def parse_parts(text: str) -> dict[str, list]:
    """Parse a CLI part map ``"ball=1,CG=2+7,OCA1=OCA_1"`` (int = material/part id, str = group name)."""
    out: dict[str, list] = {}
    for item in filter(None, (s.strip() for s in text.split(","))):
        if "=" not in item:
            raise ValueError(f"--parts: {item!r} is not NAME=GROUP")
        name, groups = (s.strip() for s in item.split("=", 1))
        out[name] = [int(g) if re.fullmatch(r"-?\d+", g) else g for g in groups.split("+")]
    return out


def _assign_parts(where: str, names: Sequence[str], specs: Mapping[str, list], n_cells: int,
                  cell_ints: np.ndarray | None, int_label: str, cell_groups: Mapping[str, np.ndarray],
                  group_label: str) -> np.ndarray:
    """(E,) part id per cell, -1 where unmapped. cell_groups: lower-case name -> bool mask (E,)."""
    part = -np.ones(n_cells, dtype=np.int32)
    for pid, name in enumerate(names):
        for item in specs.get(name, []):
            if isinstance(item, str):
                mask = cell_groups.get(item.lower())
                if mask is None:
                    raise InputFileError(f"{where}: part {name!r}: no {group_label} named {item!r}; "
                                         f"have {sorted(cell_groups)}")
            else:
                if cell_ints is None:
                    raise InputFileError(f"{where}: part {name!r}: integer group {item} given but the mesh "
                                         f"has no {int_label}")
                mask = cell_ints == int(item)
                if not mask.any():
                    raise InputFileError(f"{where}: part {name!r}: no cells with {int_label} {item}")
            clash = mask & (part >= 0) & (part != pid)
            if clash.any():
                i = int(np.argmax(clash))
                raise InputFileError(f"{where}: cell {i} belongs to parts {names[part[i]]!r} and {name!r}")
            part[mask] = pid
    return part


def _finish_mesh(where: str, node_ids, points, cells, cell_part, cell_ids, node_sets, names,
                 ignore_unmapped: bool, cell_label: str = "element") -> Mesh:
    unmapped = cell_part < 0
    if unmapped.any() and not ignore_unmapped:
        bad = cell_ids[unmapped][:5].tolist()
        raise InputFileError(f"{where}: {int(unmapped.sum())} {cell_label}(s) belong to no part, e.g. "
                             f"{cell_label} {bad}; map them in `parts` or pass ignore_unmapped=True")
    keep = ~unmapped
    mesh = Mesh(np.asarray(node_ids, np.int64), np.asarray(points, np.float64),
                np.asarray(cells, np.int64)[keep], cell_part[keep].astype(np.int32),
                np.asarray(cell_ids, np.int64)[keep], dict(node_sets), tuple(names), where).compact()
    if len(mesh.cells) == 0:
        raise InputFileError(f"{where}: no quad cells left after part mapping")
    return mesh


# ---- ANSYS .cdb ---------------------------------------------------------------------------------
_CONTACT_TYPES = {151, 152, 153, 154, 169, 170, 171, 172, 173, 174, 175, 177, 178}
_INT_FMT = re.compile(r"(\d+)i(\d+)", re.I)
_FLT_FMT = re.compile(r"(\d+)e(\d+)\.\d+", re.I)


def _fortran_widths(fmt: str, where: str) -> tuple[int, int, int, int]:
    """(n_int, int_width, n_float, float_width) of '(3i9,6e21.13e3)' style formats."""
    mi, mf = _INT_FMT.search(fmt), _FLT_FMT.search(fmt)
    if not mi:
        raise InputFileError(f"{where}: cannot parse Fortran format {fmt.strip()!r}")
    return int(mi.group(1)), int(mi.group(2)), (int(mf.group(1)) if mf else 0), (int(mf.group(2)) if mf else 0)


def _fixed_fields(line: str, width: int, where: str, *, convert=int, what: str = "{field!r} is not an integer",
                  start: int = 0) -> list:
    """Non-blank fixed-width fields of ``line`` from ``start``, converted; a bad field raises
    InputFileError naming ``where`` and the field (``what`` is the message template)."""
    line = line.rstrip("\r\n")
    out = []
    for a in range(start, len(line), width):
        field = line[a:a + width].strip()
        if field:
            try:
                out.append(convert(field))
            except ValueError:
                raise InputFileError(f"{where}: " + what.format(field=field)) from None
    return out


def _fixed_ints(line: str, width: int, where: str) -> list[int]:
    return _fixed_fields(line, width, where)


def read_cdb(path: str | os.PathLike, *, scene: Scene | Mapping | None = None,
             part_names: Sequence[str] | None = None, parts: Mapping[str, Any] | None = None,
             length_unit: str | None = None, ignore_unmapped: bool = False) -> Mesh:
    """Read a 2D quad mesh from an ANSYS ``.cdb`` archive (NBLOCK / EBLOCK / CMBLOCK / ET / /UNITS).

    Coordinates are converted to m using ``length_unit`` or the archive's ``/UNITS`` (default m).
    ``parts`` ints are material numbers ("mat" field of EBLOCK), strs element components.
    """
    path = Path(path)
    names, _ = _resolve_part_names(scene, part_names)
    specs = _part_specs(parts, names)
    lines = _read_text(path).splitlines()
    node_rows: list[tuple[int, float, float, float, int]] = []
    elems: list[tuple[int, int, int, list[int], int]] = []   # (id, mat, type, nodes, line)
    comps_elem: dict[str, set[int]] = {}
    comps_node: dict[str, set[int]] = {}
    et: dict[int, int] = {}
    file_unit = None
    i = 0
    while i < len(lines):
        line = lines[i]
        head = line.strip().upper()
        if head.startswith("/UNITS"):
            sysname = line.split(",")[1].strip().upper() if "," in line else ""
            if sysname not in ANSYS_UNIT_SYSTEMS:
                raise InputFileError(f"{path}:{i + 1}: unsupported unit system {sysname!r} in /UNITS; "
                                     f"pass length_unit= explicitly")
            file_unit = ANSYS_UNIT_SYSTEMS[sysname]
        elif head.startswith("ET,"):
            f = [s.strip() for s in line.split(",")]
            try:
                et[int(f[1])] = int(float(f[2]))
            except (IndexError, ValueError):
                pass
        elif head.startswith("NBLOCK"):
            n_int, wi, n_flt, wf = _fortran_widths(lines[i + 1], f"{path}:{i + 2}")
            i += 2
            while i < len(lines):
                raw = lines[i].rstrip("\r\n")
                if raw.strip().upper().startswith("N,") or raw.strip() == "-1" or not raw.strip():
                    break
                where = f"{path}:{i + 1}"
                ints = _fixed_ints(raw[: n_int * wi], wi, where)
                vals = _fixed_fields(raw, wf, where, convert=float, start=n_int * wi,
                                     what="node coordinate {field!r} is not a number")
                vals += [0.0] * (3 - len(vals))
                if not ints:
                    raise InputFileError(f"{where}: NBLOCK line has no node number")
                if not all(math.isfinite(v) for v in vals[:3]):
                    raise InputFileError(f"{where}: node {ints[0]} has a non-finite coordinate")
                node_rows.append((ints[0], vals[0], vals[1], vals[2], i + 1))
                i += 1
        elif head.startswith("EBLOCK"):
            if "SOLID" not in head:
                raise InputFileError(f"{path}:{i + 1}: only EBLOCK in SOLID format is supported, got {line.strip()!r}")
            _, wi, _, _ = _fortran_widths(lines[i + 1], f"{path}:{i + 2}")
            i += 2
            while i < len(lines):
                where = f"{path}:{i + 1}"
                ints = _fixed_ints(lines[i], wi, where)
                if not ints or ints[0] == -1:
                    break
                if len(ints) < 11:
                    raise InputFileError(f"{where}: EBLOCK record has {len(ints)} fields, expected >= 11")
                n_nodes, eid = ints[8], ints[10]
                nodes = ints[11:]
                start = i + 1
                while len(nodes) < n_nodes and i + 1 < len(lines):   # continuation line(s)
                    i += 1
                    nodes += _fixed_ints(lines[i], wi, f"{path}:{i + 1}")
                elems.append((eid, ints[0], ints[1], nodes[:n_nodes], start))
                i += 1
        elif head.startswith("CMBLOCK"):
            f = [s.strip() for s in line.split("!")[0].split(",")]
            if len(f) < 4:
                raise InputFileError(f"{path}:{i + 1}: malformed CMBLOCK header")
            cname, ctype, count = f[1], f[2].upper(), int(f[3])
            _, wi, _, _ = _fortran_widths(lines[i + 1], f"{path}:{i + 2}")
            vals: list[int] = []
            i += 2
            while len(vals) < count and i < len(lines):
                vals += _fixed_ints(lines[i], wi, f"{path}:{i + 1}")
                i += 1
            members: set[int] = set()
            for k, v in enumerate(vals):
                if v < 0:
                    members.update(range(vals[k - 1], -v + 1))
                else:
                    members.add(v)
            (comps_elem if ctype == "ELEM" else comps_node)[cname.lower()] = members
            continue
        i += 1
    if not node_rows:
        raise InputFileError(f"{path}: no NBLOCK (nodes) found")
    if not elems:
        raise InputFileError(f"{path}: no EBLOCK (elements) found")
    if length_unit is not None and file_unit is not None and LENGTH_UNITS.get(length_unit) != LENGTH_UNITS[file_unit]:
        raise InputFileError(f"{path}: /UNITS says {file_unit!r} but length_unit={length_unit!r} was given")
    scale = length_factor(length_unit or file_unit or "m", f"{path}: length_unit")
    node_ids = np.array([r[0] for r in node_rows], dtype=np.int64)
    order = np.argsort(node_ids, kind="stable")
    dup = np.nonzero(np.diff(node_ids[order]) == 0)[0]
    if len(dup):
        nid = int(node_ids[order][dup[0]])
        lines_ = [r[4] for r in node_rows if r[0] == nid]
        raise InputFileError(f"{path}:{lines_[1]}: duplicate node number {nid} (first on line {lines_[0]})")
    for r in node_rows:
        if r[3] != 0.0:
            raise InputFileError(f"{path}:{r[4]}: node {r[0]} has z = {r[3]}; only 2D (z = 0) meshes are supported")
    points = np.array([[r[1], r[2]] for r in node_rows], dtype=np.float64) * scale
    sorted_ids = node_ids[order]

    # elements: skip contact/target/surface types, keep the rest for part mapping
    kept = [e for e in elems if et.get(e[2], 0) not in _CONTACT_TYPES]
    eids = np.array([e[0] for e in kept], dtype=np.int64)
    if len(np.unique(eids)) != len(eids):
        u, c = np.unique(eids, return_counts=True)
        raise InputFileError(f"{path}: duplicate element number {int(u[c > 1][0])}")
    mats = np.array([e[1] for e in kept], dtype=np.int64)
    groups = {name: np.isin(eids, sorted(m)) for name, m in comps_elem.items()}
    cell_part = _assign_parts(str(path), names, specs, len(kept), mats, "material number", groups, "element component")
    cells = np.zeros((len(kept), 4), dtype=np.int64)
    for k, (eid, mat, etype, nodes, ln) in enumerate(kept):
        if cell_part[k] < 0:
            continue
        where = f"{path}:{ln}"
        if len(nodes) != 4 or len(set(nodes)) != 4:
            raise InputFileError(f"{where}: element {eid} (part {names[cell_part[k]]!r}) has nodes {nodes}: "
                                 "not a 4-node quad (only linear quads, e.g. PLANE182, are supported)")
        pos = np.searchsorted(sorted_ids, nodes)
        for nd, p in zip(nodes, pos):
            if p >= len(sorted_ids) or sorted_ids[p] != nd:
                raise InputFileError(f"{where}: element {eid} refers to node {nd}, which is not in the NBLOCK")
        cells[k] = order[pos]
    node_sets = {name: np.array(sorted(m), dtype=np.int64) for name, m in comps_node.items()}
    return _finish_mesh(str(path), node_ids, points, cells, cell_part, eids, node_sets, names, ignore_unmapped)


# ---- meshio meshes ------------------------------------------------------------------------------
_LOWER_DIM = {"vertex", "line", "line3"}


def read_meshio_mesh(path: str | os.PathLike, *, scene: Scene | Mapping | None = None,
                     part_names: Sequence[str] | None = None, parts: Mapping[str, Any] | None = None,
                     part_field: str | None = None, node_id_field: str | None = None,
                     length_unit: str = "m", ignore_unmapped: bool = False, _mesh=None) -> Mesh:
    """Read a 2D quad mesh with part groups through meshio (Abaqus .inp, Gmsh .msh, VTU, Nastran, ...).

    Parts come from ``mesh.cell_sets`` (str entries of ``parts``) or the integer cell-data array
    ``part_field`` (int entries). Node numbers: point-data ``node_id_field`` or index + 1.
    """
    import meshio

    path = Path(path)
    names, _ = _resolve_part_names(scene, part_names)
    specs = _part_specs(parts, names)
    if _mesh is None:
        try:
            m = meshio.read(path)
        except Exception as err:
            raise InputFileError(f"{path}: meshio cannot read it: {type(err).__name__}: {err}") from None
    else:
        m = _mesh
    where = str(path)
    keep_blocks = []
    for b, block in enumerate(m.cells):
        if block.type in _LOWER_DIM:
            continue
        if block.type != "quad":
            raise InputFileError(f"{where}: cell block {b} has {len(block.data)} '{block.type}' cells: "
                                 "not 4-node quads (only linear quads are supported)")
        keep_blocks.append(b)
    if not keep_blocks:
        raise InputFileError(f"{where}: no quad cells")
    cells = np.concatenate([m.cells[b].data for b in keep_blocks]).astype(np.int64)
    cell_ints = None
    if part_field is not None:
        if part_field not in m.cell_data:
            raise InputFileError(f"{where}: cell data {part_field!r} not found; have {sorted(m.cell_data)}")
        cell_ints = np.concatenate([np.asarray(m.cell_data[part_field][b]).reshape(-1)
                                    for b in keep_blocks]).astype(np.int64)
    groups = {}
    for name, per_block in (m.cell_sets or {}).items():
        mask = np.concatenate([np.isin(np.arange(len(m.cells[b].data)),
                                       np.asarray(per_block[b] if per_block[b] is not None else [], np.int64))
                               for b in keep_blocks])
        if mask.any():
            groups[name.lower()] = mask
    cell_part = _assign_parts(where, names, specs, len(cells), cell_ints, f"cell data {part_field!r}", groups, "cell set")
    pts = np.asarray(m.points, dtype=np.float64)
    if pts.shape[1] == 3:
        if np.any(pts[:, 2] != 0):
            k = int(np.argmax(pts[:, 2] != 0))
            raise InputFileError(f"{where}: node index {k} has z = {pts[k, 2]}; only 2D meshes are supported")
        pts = pts[:, :2]
    if not np.all(np.isfinite(pts)):
        k = int(np.argmax(~np.isfinite(pts).all(axis=1)))
        raise InputFileError(f"{where}: node index {k} has a non-finite coordinate")
    pts = pts * length_factor(length_unit, f"{where}: length_unit")
    if node_id_field is not None:
        if node_id_field not in m.point_data:
            raise InputFileError(f"{where}: point data {node_id_field!r} not found; have {sorted(m.point_data)}")
        node_ids = np.asarray(m.point_data[node_id_field]).reshape(-1).astype(np.int64)
        u, c = np.unique(node_ids, return_counts=True)
        if (c > 1).any():
            raise InputFileError(f"{where}: duplicate node number {int(u[c > 1][0])} in {node_id_field!r}")
    else:
        node_ids = np.arange(1, len(pts) + 1, dtype=np.int64)
    node_sets = {k.lower(): node_ids[np.asarray(v, np.int64)] for k, v in (m.point_sets or {}).items()}
    return _finish_mesh(where, node_ids, pts, cells, cell_part, np.arange(len(cells)), node_sets, names,
                        ignore_unmapped, cell_label="cell index")


def read_mesh(path: str | os.PathLike, **kwargs) -> Mesh:
    """``read_cdb`` for ``.cdb`` files, else ``read_meshio_mesh`` (keyword arguments passed on)."""
    if Path(path).suffix.lower() == ".cdb":
        kwargs.pop("part_field", None)
        kwargs.pop("node_id_field", None)
        return read_cdb(path, **kwargs)
    return read_meshio_mesh(path, **kwargs)


# ---- node parts / types / meta ------------------------------------------------------------------
def _node_part(mesh: Mesh, scene: Scene | None) -> np.ndarray:
    n = len(mesh.points)
    n_parts = len(mesh.part_names)
    if scene is not None:
        stiff = np.array([scene.ball.youngs] + [l.youngs for l in scene.layers])
        rank = np.argsort(np.argsort(-stiff, kind="stable"), kind="stable")   # 0 = stiffest
    else:
        rank = np.arange(n_parts)
    best = np.full(n, n_parts, dtype=np.int64)
    cell_rank = rank[mesh.cell_part]
    for c in range(4):
        np.minimum.at(best, mesh.cells[:, c], cell_rank)
    inv = np.argsort(rank)
    return inv[best].astype(np.int32)


def _fixed_mask(mesh: Mesh, fixed: Any) -> np.ndarray:
    n = len(mesh.points)
    if fixed is None:
        return np.zeros(n, dtype=bool)
    if isinstance(fixed, str) and fixed == "bottom":
        y = mesh.points[:, 1]
        tol = 1e-9 * max(float(np.ptp(mesh.points)), 1e-30)
        return y <= y.min() + tol
    if isinstance(fixed, str):
        ids = mesh.node_sets.get(fixed.lower())
        if ids is None:
            raise InputFileError(f"{mesh.source}: fixed-node set {fixed!r} not found; have {sorted(mesh.node_sets)}")
    else:
        ids = np.asarray(list(fixed), dtype=np.int64)
    missing = np.setdiff1d(ids, mesh.node_ids)
    if len(missing) and not isinstance(fixed, str):
        raise InputFileError(f"{mesh.source}: fixed node {int(missing[0])} is not in the mesh")
    return np.isin(mesh.node_ids, ids)


def _build(mesh: Mesh, scene: Scene | None, fixed: Any, times: np.ndarray, disp: np.ndarray,
           vel: np.ndarray, vm: np.ndarray, source: str, extra: Mapping[str, Any],
           design: Mapping[str, float] | None) -> Trajectory:
    node_part = _node_part(mesh, scene)
    node_type = node_part.copy()
    node_type[_fixed_mask(mesh, fixed)] = len(mesh.part_names)
    dt = np.diff(times)
    uniform = len(dt) > 0 and np.allclose(dt, dt[0], rtol=1e-9, atol=0)
    if design is None and scene is not None and scene.design_layers:
        design = dict(zip(scene.design_layers, scene.design))
    meta = {"units": dict(SI_UNITS), "source": source,
            "analysis": scene.analysis if scene is not None else None,
            "scene": scene.to_dict() if scene is not None else None,
            "design": dict(design) if design is not None else None,
            "output_dt": float(dt[0]) if uniform else None, "solver": None, "energy": None,
            "part_names": list(mesh.part_names), "node_ids": mesh.node_ids.tolist(), "import": dict(extra)}
    traj = Trajectory(points=mesh.points, cells=mesh.cells, cell_part=mesh.cell_part, node_part=node_part,
                      node_type=node_type, times=np.asarray(times, np.float64), displacement=disp,
                      velocity=vel, von_mises=vm, meta=meta)
    try:
        traj.validate(f"import from {extra.get('results', mesh.source)}")
    except ValueError as err:
        raise InputFileError(str(err)) from None
    return traj


def _read_text(path: Path) -> str:
    try:
        raw = path.read_bytes()
    except OSError as err:
        raise InputFileError(f"{path}: cannot read: {err.strerror}") from None
    if raw.startswith((b"\xff\xfe", b"\xfe\xff")):
        return raw.decode("utf-16")
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        return raw.decode("cp1252", errors="replace")


# ---- ANSYS text tables --------------------------------------------------------------------------
RESULT_KINDS = {   # key -> (accepted column-name prefixes, quantity)
    "deformation": (("directional deformation",), "length"),
    "velocity": (("directional velocity",), "velocity"),
    "stress": (("equivalent (von-mises) stress", "equivalent stress"), "stress"),
}
FRAME_KEYS = ("deformation_x", "deformation_y", "velocity_x", "velocity_y", "stress")
_HEADER_RE = re.compile(r"^(.*?)\s*\(([^()]*)\)\s*$")


def _split_header(col: str) -> tuple[str, str | None]:
    m = _HEADER_RE.match(col.strip())
    if m and m.group(1):
        return " ".join(m.group(1).lower().split()), m.group(2).strip()
    return " ".join(col.lower().split()), None


@dataclass(frozen=True)
class AnsysTable:
    """One parsed nodal table: node_ids (M,), locations (M, 2) [m], values (M,) [SI], lines (M,) 1-based."""

    path: Path
    node_ids: np.ndarray
    locations: np.ndarray
    values: np.ndarray
    lines: np.ndarray
    column: str


def read_ansys_table(path: str | os.PathLike, kind: str) -> AnsysTable:
    """Parse one ANSYS Mechanical text export of result ``kind`` ('deformation'|'velocity'|'stress')."""
    path = Path(path)
    prefixes, quantity = RESULT_KINDS[kind]
    lines = _read_text(path).splitlines()
    start = next((k for k, ln in enumerate(lines) if ln.strip()), None)
    if start is None:
        raise InputFileError(f"{path}: empty file")
    header = lines[start].rstrip("\r\n").split("\t")
    cols = [_split_header(c) for c in header]
    names = [c[0] for c in cols]

    def find(label: str, accepted: Iterable[str]) -> int:
        for k, nm in enumerate(names):
            if any(nm == a or nm.startswith(a) for a in accepted):
                return k
        raise InputFileError(f"{path}:{start + 1}: missing column {label!r}; found columns {header}")

    i_node = find("Node Number", ("node number",))
    i_x = find("X Location (<length unit>)", ("x location",))
    i_y = find("Y Location (<length unit>)", ("y location",))
    i_v = find(f"{RESULT_KINDS[kind][0][0].title()} (<unit>)", prefixes)
    factors = {}
    for k, label in ((i_x, "length"), (i_y, "length"), (i_v, quantity)):
        unit = cols[k][1]
        where = f"{path}:{start + 1}: column {header[k].strip()!r}"
        if unit is None:
            raise InputFileError(f"{where}: no unit in the header (expected e.g. '(mm)')")
        factors[k] = {"length": length_factor, "velocity": _velocity_factor,
                      "stress": _stress_factor}[label](unit, where)
    ids, xs, ys, vs, lns = [], [], [], [], []
    ncol = len(header)
    for ln in range(start + 1, len(lines)):
        row = lines[ln]
        if not row.strip():
            continue
        fields = row.rstrip("\r\n").split("\t")
        if len(fields) != ncol:
            raise InputFileError(f"{path}:{ln + 1}: {len(fields)} tab-separated fields, header has {ncol}")
        try:
            nid = int(fields[i_node])
        except ValueError:
            raise InputFileError(f"{path}:{ln + 1}: column 'Node Number': {fields[i_node]!r} is not an integer") from None
        vals = []
        for k in (i_x, i_y, i_v):
            try:
                v = float(fields[k])
            except ValueError:
                raise InputFileError(f"{path}:{ln + 1}: node {nid}: column {header[k].strip()!r}: "
                                     f"{fields[k]!r} is not a number") from None
            if not math.isfinite(v):
                raise InputFileError(f"{path}:{ln + 1}: node {nid}: column {header[k].strip()!r}: "
                                     f"non-finite value {fields[k]!r}")
            vals.append(v)
        ids.append(nid)
        xs.append(vals[0])
        ys.append(vals[1])
        vs.append(vals[2])
        lns.append(ln + 1)
    if not ids:
        raise InputFileError(f"{path}: no data rows")
    node_ids = np.array(ids, dtype=np.int64)
    lines_arr = np.array(lns, dtype=np.int64)
    order = np.argsort(node_ids, kind="stable")
    dup = np.nonzero(np.diff(node_ids[order]) == 0)[0]
    if len(dup):
        a, b = order[dup[0]], order[dup[0] + 1]
        raise InputFileError(f"{path}:{lines_arr[b]}: duplicate node number {node_ids[a]} "
                             f"(first on line {lines_arr[a]})")
    loc = np.stack([np.array(xs) * factors[i_x], np.array(ys) * factors[i_y]], axis=1)
    return AnsysTable(path, node_ids, loc, np.array(vs) * factors[i_v], lines_arr, header[i_v].strip())


def _frame_files(results: Path) -> tuple[list[dict[str, Path]], np.ndarray | None]:
    manifest = results / "frames.json"
    if manifest.exists():
        try:
            spec = json.loads(manifest.read_text())
            frames = spec["frames"]
            tscale = TIME_UNITS[spec.get("time_unit", "s")]
        except (json.JSONDecodeError, KeyError, TypeError) as err:
            raise InputFileError(f"{manifest}: invalid frames manifest ({type(err).__name__}: {err})") from None
        out, times = [], []
        for k, fr in enumerate(frames):
            miss = [key for key in FRAME_KEYS if key not in fr]
            if miss:
                raise InputFileError(f"{manifest}: frame {k} is missing key(s) {miss}")
            out.append({key: results / fr[key] for key in FRAME_KEYS})
            times.append(fr.get("time"))
        t = None if any(v is None for v in times) else np.asarray(times, np.float64) * tscale
        return out, t
    found: dict[str, dict[int, Path]] = {key: {} for key in FRAME_KEYS}
    pat = re.compile(r"^(" + "|".join(FRAME_KEYS) + r")_(\d+)\.txt$")
    for p in sorted(results.iterdir()):
        m = pat.match(p.name)
        if m:
            k = int(m.group(2))
            if k in found[m.group(1)]:
                raise InputFileError(f"{p}: frame {k} of {m.group(1)} also in {found[m.group(1)][k].name}")
            found[m.group(1)][k] = p
    nums = sorted(found["deformation_x"])
    if not nums:
        raise InputFileError(f"{results}: no 'deformation_x_NNN.txt' files and no frames.json "
                             "(see the naming convention in pcmgn_jax/data/importers.py)")
    if nums != list(range(len(nums))):
        gap = next(k for k, n in enumerate(nums) if n != k)
        raise InputFileError(f"{results}: frame numbers must be 0..{len(nums) - 1} without gaps; "
                             f"deformation_x frame {gap} is missing")
    out = []
    for key in FRAME_KEYS:
        extra = sorted(set(found[key]) - set(nums))
        if extra:
            raise InputFileError(f"{found[key][extra[0]]}: frame {extra[0]} has no deformation_x file")
    for k in nums:
        fr = {}
        for key in FRAME_KEYS:
            if k not in found[key]:
                raise InputFileError(f"{results / f'{key}_{k:03d}.txt'}: file missing (frame {k}, result {key})")
            fr[key] = found[key][k]
        out.append(fr)
    times_file = results / "times.txt"
    t = None
    if times_file.exists():
        vals = []
        for ln, row in enumerate(_read_text(times_file).splitlines(), 1):
            if row.strip():
                try:
                    vals.append(float(row.split()[-1]))
                except ValueError:
                    raise InputFileError(f"{times_file}:{ln}: {row.strip()!r} is not a time [s]") from None
        t = np.asarray(vals, np.float64)
    return out, t


def _match_nodes(tab: AnsysTable, mesh: Mesh, ref_ids: np.ndarray | None, ref_file: Path | None,
                 location_tol: float) -> np.ndarray:
    """Indices into the mesh of the table rows; checks membership, node-set equality, locations."""
    sorted_order = np.argsort(mesh.node_ids)
    sorted_ids = mesh.node_ids[sorted_order]
    pos = np.clip(np.searchsorted(sorted_ids, tab.node_ids), 0, len(sorted_ids) - 1)
    found = sorted_ids[pos] == tab.node_ids
    if not found.all():
        k = int(np.argmax(~found))
        raise InputFileError(f"{tab.path}:{tab.lines[k]}: node {tab.node_ids[k]} is not in the mesh {mesh.source}"
                             " (or not on a quad cell of a mapped part)")
    idx = sorted_order[pos]
    if ref_ids is not None and not np.array_equal(np.sort(tab.node_ids), ref_ids):
        extra = np.setdiff1d(tab.node_ids, ref_ids)
        if len(extra):
            k = int(np.nonzero(tab.node_ids == extra[0])[0][0])
            raise InputFileError(f"{tab.path}:{tab.lines[k]}: node {extra[0]} is not in {ref_file.name} "
                                 "(frames/results have different node sets)")
        missing = np.setdiff1d(ref_ids, tab.node_ids)
        raise InputFileError(f"{tab.path}: node {missing[0]} of {ref_file.name} is missing "
                             "(frames/results have different node sets)")
    if len(idx) != len(mesh.node_ids):
        missing = np.setdiff1d(mesh.node_ids, tab.node_ids)
        raise InputFileError(f"{tab.path}: node {missing[0]} of the mesh {mesh.source} has no value "
                             f"({len(missing)} mesh node(s) missing)")
    err = np.abs(tab.locations - mesh.points[idx]).max(axis=1)
    if np.any(err > location_tol):
        k = int(np.argmax(err > location_tol))
        raise InputFileError(
            f"{tab.path}:{tab.lines[k]}: node {tab.node_ids[k]}: X/Y Location {tab.locations[k].tolist()} m "
            f"differs from the mesh {mesh.points[idx[k]].tolist()} m by {err[k]:.3g} m (> location_tol)")
    return idx


def import_ansys_text(mesh: str | os.PathLike | Mesh, results: str | os.PathLike, *,
                      scene: Scene | Mapping | None = None, part_names: Sequence[str] | None = None,
                      parts: Mapping[str, Any] | None = None, output_dt: float | None = None,
                      times: Sequence[float] | None = None, fixed: Any = "bottom",
                      location_tol: float | None = None, ignore_unmapped: bool = False,
                      design: Mapping[str, float] | None = None, **mesh_kwargs) -> Trajectory:
    """ANSYS Mechanical nodal text exports in folder ``results`` + a mesh -> Trajectory (source 'ansys-text').

    ``mesh``: a ``.cdb`` / meshio-readable path or a :class:`Mesh`. Frame times [s] come from
    ``times``, ``frames.json``/``times.txt`` in ``results``, or ``output_dt`` (t_k = k * output_dt).
    ``location_tol`` [m] (default 1e-5 x the mesh extent) bounds |X/Y Location - mesh coordinate|.
    Returns displacement (T,N,2) [m], velocity (T,N,2) [m/s], von_mises (T,N) [Pa].
    """
    results = Path(results)
    names, scene_obj = _resolve_part_names(scene, part_names)
    if not isinstance(mesh, Mesh):
        mesh = read_mesh(mesh, scene=scene_obj, part_names=None if scene_obj else names, parts=parts,
                         ignore_unmapped=ignore_unmapped, **mesh_kwargs)
    if not results.is_dir():
        raise InputFileError(f"{results}: results folder not found")
    frames, file_times = _frame_files(results)
    if times is not None:
        t = np.asarray(times, np.float64)
    elif file_times is not None:
        t = file_times
    elif output_dt is not None:
        t = np.arange(len(frames)) * float(output_dt)
    else:
        raise InputFileError(f"{results}: frame times unknown: give output_dt, times, or a times.txt / "
                             "frames.json with times")
    if t.shape != (len(frames),):
        raise InputFileError(f"{results}: {len(t)} frame times for {len(frames)} frames")
    if not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
        raise InputFileError(f"{results}: frame times must be finite and strictly increasing")
    tol = location_tol if location_tol is not None else 1e-5 * max(float(np.ptp(mesh.points)), 1e-12)
    n = len(mesh.points)
    T = len(frames)
    disp = np.zeros((T, n, 2))
    vel = np.zeros((T, n, 2))
    vm = np.zeros((T, n))
    ref_ids = ref_file = None
    columns = {}
    for k, fr in enumerate(frames):
        for key in FRAME_KEYS:
            kind, _, comp = key.partition("_")
            tab = read_ansys_table(fr[key], kind)
            idx = _match_nodes(tab, mesh, ref_ids, ref_file, tol)
            if ref_ids is None:
                ref_ids, ref_file = np.sort(tab.node_ids), tab.path
            columns.setdefault(key, tab.column)
            if kind == "stress":
                vm[k, idx] = tab.values
            else:
                (disp if kind == "deformation" else vel)[k, idx, "xy".index(comp)] = tab.values
    return _build(mesh, scene_obj, fixed, t, disp, vel, vm, "ansys-text",
                  {"mesh": mesh.source, "results": str(results), "columns": columns}, design)


# ---- meshio time series -------------------------------------------------------------------------
def import_meshio_series(files: str | os.PathLike | Sequence[str | os.PathLike], *,
                         scene: Scene | Mapping | None = None, part_names: Sequence[str] | None = None,
                         parts: Mapping[str, Any] | None = None, part_field: str | None = None,
                         times: Sequence[float] | None = None, output_dt: float | None = None,
                         fields: Mapping[str, str] | None = None, length_unit: str = "m",
                         velocity_unit: str = "m/s", stress_unit: str = "Pa", fixed: Any = "bottom",
                         ignore_unmapped: bool = False, design: Mapping[str, float] | None = None) -> Trajectory:
    """A meshio time series -> Trajectory (source 'meshio').

    ``files``: one XDMF time series (frame times from the file) or a list of per-frame mesh files
    (VTU, ...; times from ``times`` or ``output_dt``). ``fields`` maps 'displacement', 'velocity',
    'von_mises' to point-data names (default: the same names). Units given by the ``*_unit`` args.
    """
    import meshio

    fields = {"displacement": "displacement", "velocity": "velocity", "von_mises": "von_mises",
              **(fields or {})}
    names, scene_obj = _resolve_part_names(scene, part_names)
    frames: list[tuple[str, float | None, Any, dict]] = []   # (where, t, mesh, point_data)
    if isinstance(files, (str, os.PathLike)) and Path(files).suffix.lower() == ".xdmf":
        src = Path(files)
        try:
            with meshio.xdmf.TimeSeriesReader(src) as r:
                pts, cells = r.read_points_cells()
                for k in range(r.num_steps):
                    tk, pd, cd = r.read_data(k)
                    frames.append((f"{src} (frame {k})", tk, meshio.Mesh(pts, cells, cell_data=cd), pd))
        except InputFileError:
            raise
        except Exception as err:
            raise InputFileError(f"{src}: cannot read XDMF time series: {type(err).__name__}: {err}") from None
        first_path = src
    else:
        paths = [Path(files)] if isinstance(files, (str, os.PathLike)) else [Path(p) for p in files]
        if not paths:
            raise InputFileError("import_meshio_series: no files given")
        for p in paths:
            try:
                m = meshio.read(p)
            except Exception as err:
                raise InputFileError(f"{p}: meshio cannot read it: {type(err).__name__}: {err}") from None
            frames.append((str(p), None, m, m.point_data))
        first_path = paths[0]
    if times is not None:
        t = np.asarray(times, np.float64)
    elif all(f[1] is not None for f in frames):
        t = np.asarray([f[1] for f in frames], np.float64)
    elif output_dt is not None:
        t = np.arange(len(frames)) * float(output_dt)
    else:
        raise InputFileError(f"{first_path}: frame times unknown: give times or output_dt")
    if t.shape != (len(frames),) or not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
        raise InputFileError(f"{first_path}: need {len(frames)} finite, strictly increasing frame times")
    m0 = frames[0][2]
    mesh = read_meshio_mesh(first_path, scene=scene_obj, part_names=None if scene_obj else names, parts=parts,
                            part_field=part_field, length_unit=length_unit,
                            ignore_unmapped=ignore_unmapped, _mesh=m0)
    # mesh.compact() may drop unused points: map original point index -> trajectory index
    keep = np.asarray(mesh.node_ids - 1, dtype=np.int64)
    lf = length_factor(length_unit, "length_unit")
    vf = _velocity_factor(velocity_unit, "velocity_unit")
    sf = _stress_factor(stress_unit, "stress_unit")
    T, n = len(frames), len(keep)
    disp, vel, vm = np.zeros((T, n, 2)), np.zeros((T, n, 2)), np.zeros((T, n))
    for k, (where, _, m, pd) in enumerate(frames):
        if len(m.points) != len(m0.points) or not np.array_equal(np.asarray(m.points), np.asarray(m0.points)):
            raise InputFileError(f"{where}: points differ from frame 0 ({len(m.points)} vs {len(m0.points)} "
                                 "nodes): frames have different node sets")
        if len(m.cells) != len(m0.cells) or any(
                a.type != b.type or not np.array_equal(a.data, b.data) for a, b in zip(m.cells, m0.cells)):
            raise InputFileError(f"{where}: cells differ from frame 0")
        for key, target in (("displacement", disp), ("velocity", vel), ("von_mises", vm)):
            name = fields[key]
            if name not in pd:
                raise InputFileError(f"{where}: point data {name!r} ({key}) missing; have {sorted(pd)}")
            arr = np.asarray(pd[name], dtype=np.float64)
            if key == "von_mises":
                arr = arr.reshape(len(m.points), -1)
                if arr.shape[1] != 1:
                    raise InputFileError(f"{where}: point data {name!r} has shape {arr.shape}, expected (N,)")
                arr = arr[:, 0]
            elif arr.ndim != 2 or arr.shape[1] not in (2, 3) or arr.shape[0] != len(m.points):
                raise InputFileError(f"{where}: point data {name!r} has shape {arr.shape}, expected (N, 2|3)")
            if not np.all(np.isfinite(arr)):
                bad = np.argwhere(~np.isfinite(arr))[0]
                raise InputFileError(f"{where}: point data {name!r}: non-finite value at node index {bad[0]}")
            arr = arr[keep]
            if key == "von_mises":
                target[k] = arr * sf
            else:
                target[k] = arr[:, :2] * (lf if key == "displacement" else vf)
    return _build(mesh, scene_obj, fixed, t, disp, vel, vm, "meshio",
                  {"mesh": str(first_path), "results": str(first_path), "fields": dict(fields)}, design)


# ---- LS-DYNA d3plot (optional) ------------------------------------------------------------------
def _lasso():
    try:
        from lasso.dyna import ArrayType, D3plot
    except ImportError:
        raise ImportError("import_d3plot needs lasso-python: pip install -e \".[dyna]\" "
                          "(or pip install lasso-python)") from None
    return D3plot, ArrayType


def von_mises_from_tensor(s: np.ndarray) -> np.ndarray:
    """Von Mises stress of (..., 6) tensors ordered xx, yy, zz, xy, yz, xz."""
    sxx, syy, szz, sxy, syz, sxz = (s[..., i] for i in range(6))
    return np.sqrt(0.5 * ((sxx - syy) ** 2 + (syy - szz) ** 2 + (szz - sxx) ** 2)
                   + 3.0 * (sxy ** 2 + syz ** 2 + sxz ** 2))


def import_d3plot(path: str | os.PathLike, *, scene: Scene | Mapping | None = None,
                  part_names: Sequence[str] | None = None, parts: Mapping[str, Any] | None = None,
                  length_unit: str = "m", time_unit: str = "s", stress_unit: str = "Pa",
                  fixed: Any = "bottom", ignore_unmapped: bool = False,
                  design: Mapping[str, float] | None = None) -> Trajectory:
    """LS-DYNA d3plot of a 2D (plane strain / axisymmetric) model -> Trajectory (source 'd3plot').

    Needs lasso-python. 2D solids are stored as 4-node shells; ``parts`` ints are LS-DYNA part ids,
    strs part titles. lasso's ``node_displacement`` holds current coordinates (displacement =
    node_displacement - node_coordinates). Nodal von Mises = mean over the adjacent elements of the
    element von Mises (averaged over integration layers). Units via ``length_unit``/``time_unit``/
    ``stress_unit`` (LS-DYNA is unit-consistent; e.g. mm, ms, GPa).
    """
    D3plot, AT = _lasso()
    path = Path(path)
    names, scene_obj = _resolve_part_names(scene, part_names)
    specs = _part_specs(parts, names)
    try:
        d = D3plot(str(path))
    except Exception as err:
        raise InputFileError(f"{path}: lasso cannot read the d3plot: {type(err).__name__}: {err}") from None
    arr = d.arrays
    for key in (AT.node_coordinates, AT.node_ids, AT.node_displacement, AT.node_velocity,
                AT.global_timesteps, AT.element_shell_node_indexes, AT.element_shell_part_indexes):
        if key not in arr:
            raise InputFileError(f"{path}: d3plot has no {key!r} array (need 2D solids as shells, "
                                 "displacements and velocities in the output)")
    lf = length_factor(length_unit, "length_unit")
    tf = TIME_UNITS[time_unit]
    sf = _stress_factor(stress_unit, "stress_unit")
    coords = np.asarray(arr[AT.node_coordinates], np.float64)
    if np.any(coords[:, 2] != 0):
        k = int(np.argmax(coords[:, 2] != 0))
        raise InputFileError(f"{path}: node {int(arr[AT.node_ids][k])} has z != 0; only 2D models are supported")
    cells = np.asarray(arr[AT.element_shell_node_indexes], np.int64)
    part_idx = np.asarray(arr[AT.element_shell_part_indexes], np.int64)
    pids = np.asarray(arr.get(AT.part_ids, np.arange(part_idx.max() + 1) + 1))
    titles = [str(x).strip() for x in arr.get(AT.part_titles, [])]
    title_ids = list(np.asarray(arr.get(AT.part_titles_ids, [])))
    groups = {}
    for tid, title in zip(title_ids, titles):
        groups[title.lower()] = pids[part_idx] == tid
    cell_part = _assign_parts(str(path), names, specs, len(cells), pids[part_idx], "LS-DYNA part id", groups, "part title")
    eids = np.asarray(arr.get(AT.element_shell_ids, np.arange(1, len(cells) + 1)), np.int64)
    degenerate = np.array([len(set(c)) != 4 for c in cells])
    if np.any(degenerate & (cell_part >= 0)):
        k = int(np.argmax(degenerate & (cell_part >= 0)))
        raise InputFileError(f"{path}: element {eids[k]} is a degenerate quad (triangle): not a 4-node quad")
    mesh = _finish_mesh(str(path), np.asarray(arr[AT.node_ids], np.int64), coords[:, :2] * lf, cells,
                        cell_part, eids, {}, names, ignore_unmapped)
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
        keep = cell_part >= 0
        evm = von_mises_from_tensor(np.asarray(arr[AT.element_shell_stress], np.float64)).mean(axis=2)
        if evm.shape[1] != len(cells):
            raise InputFileError(f"{path}: stress is stored for {evm.shape[1]} of {len(cells)} shells "
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
    return _build(mesh, scene_obj, fixed, t, disp, vel, vm, "d3plot", {"mesh": str(path), "results": str(path)},
                  design)
