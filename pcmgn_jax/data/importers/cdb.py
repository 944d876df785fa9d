"""MAPDL archives (CDWRITE ``.cdb``) and Workbench input files (``ds.dat``): NBLOCK, EBLOCK, ETBLOCK / ET /
KEYOPT, CMBLOCK, /UNITS, ``*SET`` parameters.

meshio has no reader for these, hence this small fixed-format parser. ``mapdl-archive`` (numpy only) reads
archives too, but it silently drops z and does not check element types, so it is used only as a
cross-check in the tests.

Element types (the ET / ETBLOCK table; the element's "type" field points into it):

* 2D structural solids are read: PLANE182 / PLANE42 / PLANE162 (4-node quads) and PLANE183 / PLANE82
  (8-node quads, reduced to their 4 corner nodes, see :func:`_corners`).
* Contact, target and surface elements (CONTA17x, TARGE169/170, SURF15x) and MESH200 are skipped with a note.
* Anything else (shells such as SHELL181, 3D solids, beams, thermal planes) is refused with a one-line
  error naming the file, the line that declares the type, the type and the fix.
* KEYOPT(3) of the 2D solids gives the analysis (1 axisymmetric, 2 plane strain, 0/3 plane stress, 5
  generalized plane strain); it must be the same for all read elements and match the scene's analysis.

The block readers (Fortran fixed formats, NBLOCK, EBLOCK, ...) are in :mod:`pcmgn_jax.data.importers.cdb_blocks`.
"""
from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pcmgn_jax.data.importers.cdb_blocks import (
    Archive,
    fixed_record,
    fortran_layout,
    scan,
)
from pcmgn_jax.data.importers.errors import InputFileError, read_text
from pcmgn_jax.data.importers.parts import (
    ImportedMesh,
    assign_parts,
    finish_mesh,
    part_specs,
    resolve_part_names,
)
from pcmgn_jax.data.importers.units import LENGTH_UNITS, length_factor
from pcmgn_jax.scene import ANALYSES, Scene

__all__ = [
    "KEYOPT3_ANALYSIS",
    "SKIPPED_TYPES",
    "SOLID_2D",
    "fixed_record",
    "fortran_layout",
    "has_nblock",
    "read_cdb",
    "type_name",
]

# ---- element-type catalogue ---------------------------------------------------------------------
SOLID_2D = {182: ("PLANE182", 4), 42: ("PLANE42", 4), 162: ("PLANE162", 4),
            183: ("PLANE183", 8), 82: ("PLANE82", 8)}
SKIPPED_TYPES = {151: "SURF151", 152: "SURF152", 153: "SURF153", 154: "SURF154", 169: "TARGE169",
                 170: "TARGE170", 171: "CONTA171", 172: "CONTA172", 173: "CONTA173", 174: "CONTA174",
                 175: "CONTA175", 176: "CONTA176", 177: "CONTA177", 178: "CONTA178", 200: "MESH200"}
_KNOWN = {181: ("SHELL181", "shell"), 281: ("SHELL281", "shell"), 208: ("SHELL208", "axisymmetric shell"),
          209: ("SHELL209", "axisymmetric shell"), 63: ("SHELL63", "shell"), 43: ("SHELL43", "shell"),
          93: ("SHELL93", "shell"), 131: ("SHELL131", "thermal shell"), 132: ("SHELL132", "thermal shell"),
          163: ("SHELL163", "explicit shell"), 41: ("SHELL41", "shell"), 28: ("SHELL28", "shell"),
          185: ("SOLID185", "3D solid"), 186: ("SOLID186", "3D solid"), 187: ("SOLID187", "3D solid"),
          285: ("SOLID285", "3D solid"), 45: ("SOLID45", "3D solid"), 95: ("SOLID95", "3D solid"),
          92: ("SOLID92", "3D solid"), 164: ("SOLID164", "3D solid"), 190: ("SOLSH190", "solid shell"),
          188: ("BEAM188", "beam"), 189: ("BEAM189", "beam"), 180: ("LINK180", "link"),
          21: ("MASS21", "point mass"), 14: ("COMBIN14", "spring"), 55: ("PLANE55", "2D thermal solid"),
          77: ("PLANE77", "2D thermal solid"), 13: ("PLANE13", "2D coupled-field solid"),
          223: ("PLANE223", "2D coupled-field solid"), 25: ("PLANE25", "axisymmetric-harmonic solid"),
          83: ("PLANE83", "axisymmetric-harmonic solid")}
KEYOPT3_ANALYSIS = {0: "plane_stress", 1: "axisymmetric", 2: "plane_strain", 3: "plane_stress",
                    5: "generalized_plane_strain", 6: "axisymmetric"}
_FIX_TYPES = ("fix: mesh the 2D cross-section with PLANE182 or PLANE183 (KEYOPT(3)=1 axisymmetric or 2 "
              "plane strain), or leave these elements out of the export")


def type_name(ename: int) -> tuple[str, str]:
    """(name, category) of an MAPDL element-type number."""
    if ename in SOLID_2D:
        return SOLID_2D[ename][0], "2D structural solid"
    if ename in SKIPPED_TYPES:
        return SKIPPED_TYPES[ename], "contact/target/surface"
    return _KNOWN.get(ename, (f"element type #{ename}", "not a 2D structural solid"))


def _corners(nodes: list[int]) -> tuple[list[int], list[int]]:
    """(corner nodes, midside nodes) of a 4- or 8-node quad record (MAPDL lists I J K L first).

    Why corners rather than four sub-quads per 8-node quad: a PLANE183 has no centre node, so a split
    would invent one (and its results, by interpolation) without an ANSYS node number, while Mechanical's
    nodal exports hold results only at real nodes; the sub-quads would also leave hanging nodes where a
    PLANE183 region meets a PLANE182 region. Corners keep every graph node a real node with exported
    results; the price is a 2x coarser graph (mesh with PLANE182 at half the size if that matters).
    """
    if len(nodes) == 8:
        return nodes[:4], nodes[4:]
    return nodes, []


def _read_lines(path: Path) -> list[str]:
    """The file's lines; refuses NUL bytes (a truncated or corrupt archive) naming the line."""
    text = read_text(path)
    nul = text.find("\x00")
    if nul >= 0:
        ln = text.count("\n", 0, nul) + 1
        raise InputFileError(f"{path}:{ln}: NUL bytes in a text archive: the file is truncated or corrupt; "
                             "re-export it (CDWRITE,DB in MAPDL or 'Write Input File' in Workbench)")
    return text.splitlines()


def _node_table(path: Path, node_rows) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(node ids (N,) int64 in file order, argsort of the ids (N,), points (N, 2) in file units) of the
    NBLOCK rows; refuses duplicate node numbers and z != 0."""
    node_ids = np.array([r[0] for r in node_rows], dtype=np.int64)
    order = np.argsort(node_ids, kind="stable")
    dup = np.nonzero(np.diff(node_ids[order]) == 0)[0]
    if len(dup):
        nid = int(node_ids[order][dup[0]])
        lines_ = [r[4] for r in node_rows if r[0] == nid]
        raise InputFileError(f"{path}:{lines_[1]}: duplicate node number {nid} (first on line {lines_[0]})")
    for r in node_rows:
        if r[3] != 0.0:
            raise InputFileError(f"{path}:{r[4]}: node {r[0]} has z = {r[3]}; only 2D (z = 0) meshes are "
                                 "supported: export the 2D model")
    points = np.array([[r[1], r[2]] for r in node_rows], dtype=np.float64)
    return node_ids, order, points


def _split_elements(path: Path, arc: Archive) -> tuple[list, list]:
    """(skipped contact/target/surface elements, kept elements), with notes for both kinds of doubt."""
    def ename_of(itype: int) -> int | None:
        return arc.et[itype].ename if itype in arc.et else None

    skipped = [e for e in arc.elems if ename_of(e[2]) in SKIPPED_TYPES]
    if skipped:
        kinds = sorted({SKIPPED_TYPES[ename_of(e[2])] for e in skipped})
        arc.notes.append(f"{path}: skipped {len(skipped)} contact/target/surface element(s) ({', '.join(kinds)})")
    kept = [e for e in arc.elems if ename_of(e[2]) not in SKIPPED_TYPES]
    undeclared = sorted({e[2] for e in kept if e[2] not in arc.et})
    if undeclared:
        arc.notes.append(f"{path}: element type(s) {undeclared} have no ET / ETBLOCK declaration; read as 2D "
                         "solids by their node count")
    return skipped, kept


def _type_analysis(path: Path, arc: Archive, itype: int, subset) -> str:
    """The analysis KEYOPT(3) of element type ``itype`` declares; refuses a type that is not a 2D
    structural solid or an analysis other than axisymmetric / plane strain."""
    t = arc.et[itype]
    if t.ename not in SOLID_2D:
        name, category = type_name(t.ename)
        users = [e[0] for e in subset if e[2] == itype]
        raise InputFileError(
            f"{path}:{t.line}: element type {itype} is {name} ({category}), used by {len(users)} "
            f"element(s), e.g. {users[0]}: only 2D structural solids are read (PLANE182, PLANE183, "
            f"PLANE42, PLANE82, PLANE162); {_FIX_TYPES}")
    k3 = arc.keyopt3.get(itype, 0)
    analysis = KEYOPT3_ANALYSIS.get(k3, f"KEYOPT(3)={k3}")
    if analysis not in ANALYSES:
        raise InputFileError(
            f"{path}:{t.line}: element type {itype} ({SOLID_2D[t.ename][0]}) has KEYOPT(3)={k3} "
            f"({analysis.replace('_', ' ')}): only axisymmetric (KEYOPT(3)=1) and plane strain "
            "(KEYOPT(3)=2) models are supported; set KEYOPT(3) in ANSYS and re-export")
    return analysis


def _check_types(path: Path, arc: Archive, subset, scene_obj: Scene | None) -> str | None:
    """Refuse non-2D-solid types among the elements ``subset``; the one analysis their KEYOPT(3) declares
    (None if no type is declared), which must match the scene's."""
    analyses: dict[str, int] = {}
    for itype in sorted({e[2] for e in subset}):
        if itype in arc.et:
            analyses.setdefault(_type_analysis(path, arc, itype, subset), itype)
    if len(analyses) > 1:
        (a1, t1), (a2, t2) = list(analyses.items())[:2]
        raise InputFileError(f"{path}:{arc.et[t2].line}: element type {t2} is {a2.replace('_', ' ')} but type "
                             f"{t1} is {a1.replace('_', ' ')} (KEYOPT(3)): one analysis per model; "
                             "set the same KEYOPT(3) on every 2D solid type")
    analysis = next(iter(analyses), None)
    if analysis is not None and scene_obj is not None and analysis != scene_obj.analysis:
        t = analyses[analysis]
        raise InputFileError(
            f"{path}:{arc.et[t].line}: element type {t} is {analysis.replace('_', ' ')} (KEYOPT(3)="
            f"{arc.keyopt3.get(t, 0)}) but the scene's analysis is {scene_obj.analysis!r}: use a scene with "
            f"analysis = {analysis!r} or set KEYOPT(3) in ANSYS and re-export")
    return analysis


def _quad_cells(path: Path, kept, cell_part, names, node_ids, order) -> tuple[np.ndarray, set[int], set[int], int]:
    """(cells (E, 4) int64 row indices into the NBLOCK order (zero rows for unmapped elements), midside
    node ids, corner node ids, number of 8-node quads reduced to corners) of the kept elements."""
    sorted_ids = node_ids[order]
    cells = np.zeros((len(kept), 4), dtype=np.int64)
    midside: set[int] = set()
    corner_ids: set[int] = set()
    n_reduced = 0
    for k, (eid, _mat, _etype, nodes, ln) in enumerate(kept):
        if cell_part[k] < 0:
            continue
        where = f"{path}:{ln}"
        corners, mids = _corners(nodes)
        if len(corners) != 4 or len(set(corners)) != 4:
            shape = " (a degenerate quad: triangle)" if len(corners) == 4 else ""
            raise InputFileError(f"{where}: element {eid} (part {names[cell_part[k]]!r}) has nodes {nodes}{shape}: "
                                 "not a 4-node quad or an 8-node quad (PLANE182 / PLANE183); remesh with "
                                 "quadrilaterals only")
        if mids:
            n_reduced += 1
            midside.update(mids)
        corner_ids.update(corners)
        pos = np.searchsorted(sorted_ids, corners)
        for nd, p in zip(corners, pos):
            if p >= len(sorted_ids) or sorted_ids[p] != nd:
                raise InputFileError(f"{where}: element {eid} refers to node {nd}, which is not in the NBLOCK")
        cells[k] = order[pos]
    return cells, midside, corner_ids, n_reduced


def _check_blocks(path: Path, arc: Archive, length_unit: str | None) -> None:
    """Refuse a file without nodes or SOLID elements, or whose /UNITS disagrees with ``length_unit``."""
    if not arc.nodes:
        raise InputFileError(f"{path}: no NBLOCK (nodes) found: not an MAPDL archive / input file with a mesh")
    if not arc.elems:
        raise InputFileError(f"{path}: no EBLOCK in SOLID form (elements) found")
    if (length_unit is not None and arc.file_unit is not None
            and LENGTH_UNITS.get(length_unit) != LENGTH_UNITS[arc.file_unit]):
        raise InputFileError(f"{path}: /UNITS says {arc.file_unit!r} but length_unit={length_unit!r} was given "
                             "(--length_unit): drop it or make it agree")


def read_cdb(path: str | os.PathLike, *, scene: Scene | Mapping | None = None,
             part_names: Sequence[str] | None = None, parts: Mapping[str, Any] | None = None,
             length_unit: str | None = None, ignore_unmapped: bool = False) -> ImportedMesh:
    """Read a 2D quad mesh from an MAPDL archive (``.cdb``) or a Workbench input file (``.dat``).

    Coordinates are converted to m with ``length_unit`` or the file's ``/UNITS``; a file with neither is
    refused (CDWRITE writes no /UNITS, and a silent default of m made mm meshes 1000x too large).
    ``parts`` ints are material numbers ("mat" field of EBLOCK), strs element components.
    """
    path = Path(path)
    names, scene_obj = resolve_part_names(scene, part_names)
    specs = part_specs(parts, names)
    arc = scan(_read_lines(path), path)
    _check_blocks(path, arc, length_unit)
    node_ids, order, points = _node_table(path, arc.nodes)
    skipped, kept = _split_elements(path, arc)
    if not ignore_unmapped:
        _check_types(path, arc, kept, scene_obj)
    if length_unit is None and arc.file_unit is None:
        raise InputFileError(f"{path}: no /UNITS line, so the length unit is unknown (CDWRITE writes none): "
                             "pass --length_unit mm (or m, um, ...; length_unit= in Python)")
    points = points * length_factor(length_unit or arc.file_unit, f"{path}: length_unit (--length_unit)")
    eids = np.array([e[0] for e in kept], dtype=np.int64)
    if len(np.unique(eids)) != len(eids):
        u, c = np.unique(eids, return_counts=True)
        raise InputFileError(f"{path}: duplicate element number {int(u[c > 1][0])}")
    mats = np.array([e[1] for e in kept], dtype=np.int64)
    groups = {name: np.isin(eids, sorted(m)) for name, m in arc.comps_elem.items()}
    cell_part = assign_parts(str(path), names, specs, len(kept), mats, "material number", groups, "element component")
    analysis = _check_types(path, arc, [e for e, p in zip(kept, cell_part) if p >= 0], scene_obj)
    cells, midside, corner_ids, n_reduced = _quad_cells(path, kept, cell_part, names, node_ids, order)
    # nodes whose result rows are ignored: midside nodes, and nodes only of skipped or unmapped elements
    others = {n for (_, _, _, nodes, _), p in zip(kept, cell_part) if p < 0 for n in nodes}
    others.update(n for e in skipped for n in e[3])
    dropped = np.array(sorted((midside | others) - corner_ids), dtype=np.int64)
    if n_reduced:
        arc.notes.append(f"{path}: {n_reduced} 8-node quad(s) reduced to their corner nodes; {len(dropped)} "
                         "midside node(s) dropped (their rows in result tables are ignored)")
    node_sets = {name: np.array(sorted(m), dtype=np.int64) for name, m in arc.comps_node.items()}
    return finish_mesh(str(path), node_ids, points, cells, cell_part, eids, node_sets, names, ignore_unmapped,
                       dropped_node_ids=dropped, analysis=analysis, notes=tuple(arc.notes))


def has_nblock(path: str | os.PathLike) -> bool:
    """Whether a text file holds an MAPDL NBLOCK (Workbench ``ds.dat`` / ``input.dat``, archives)."""
    try:
        with open(path, "rb") as f:
            for raw in f:
                if raw.lstrip()[:6].upper() == b"NBLOCK":
                    return True
    except OSError:
        return False
    return False
