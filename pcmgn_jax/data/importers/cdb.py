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
"""
from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from pcmgn_jax.data.importers.errors import InputFileError, read_text
from pcmgn_jax.data.importers.parts import (ImportedMesh, assign_parts, finish_mesh, part_specs,
                                            resolve_part_names)
from pcmgn_jax.data.importers.units import ANSYS_UNIT_SYSTEMS, LENGTH_UNITS, length_factor
from pcmgn_jax.scene import ANALYSES, Scene

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


@dataclass
class _EType:
    ename: int
    line: int            # 1-based line of the ET / ETBLOCK record declaring it
    keyopt3: int = 0


# ---- Fortran fixed formats ----------------------------------------------------------------------
_FMT_ITEM = re.compile(r"(\d*)([iaefgd])(\d+)(?:\.\d+)?(?:e\d+)?", re.I)
_FMT_SKIP = re.compile(r"(\d*)x", re.I)


def fortran_layout(fmt: str, where: str) -> list[tuple[str, int]]:
    """Fields of a Fortran format line such as ``(3i9,6e21.13e3)`` or ``(1i7,2i9,6e21.13)``, every group
    expanded: [(kind, width)], kind 'i' (integer), 'a' (text), 'f' (real), 'x' (skipped columns)."""
    s = fmt.strip()
    if not (s.startswith("(") and s.endswith(")")):
        raise InputFileError(f"{where}: expected a Fortran format line such as '(3i9,6e21.13e3)', got {s[:40]!r}")
    out: list[tuple[str, int]] = []
    for item in s[1:-1].split(","):
        item = item.strip()
        m = _FMT_ITEM.fullmatch(item)
        if m:
            kind = m.group(2).lower()
            kind = "f" if kind in "efgd" else kind
            out += [(kind, int(m.group(3)))] * int(m.group(1) or 1)
            continue
        m = _FMT_SKIP.fullmatch(item)
        if m:
            out.append(("x", int(m.group(1) or 1)))
            continue
        raise InputFileError(f"{where}: cannot parse Fortran format {s!r} (group {item!r})")
    if not out:
        raise InputFileError(f"{where}: empty Fortran format {s!r}")
    return out


def _show(field: str) -> str:
    return repr(field if len(field) <= 24 else field[:24] + "...")


def fixed_record(line: str, layout: Sequence[tuple[str, int]], where: str) -> tuple[list[int | None], list[float | None]]:
    """Split ``line`` by ``layout``: (integer fields, real fields) in order, None where blank or past the end."""
    line = line.rstrip("\r\n")
    ints: list[int | None] = []
    reals: list[float | None] = []
    a = 0
    for kind, w in layout:
        field = line[a:a + w].strip()
        a += w
        if kind == "x":
            continue
        if kind in "ia":
            if not field:
                ints.append(None)
                continue
            try:
                ints.append(int(field))
            except ValueError:
                raise InputFileError(f"{where}: field {_show(field)} (columns {a - w + 1}-{a}) is not an "
                                     "integer: corrupt or hand-edited record; re-export the file") from None
        else:
            if not field:
                reals.append(None)
                continue
            try:
                v = float(field)
            except ValueError:
                try:   # Fortran exponents without 'E' (1.0-3) and 'D' exponents
                    v = float(re.sub(r"(?<=\d)([+-]\d+)$", r"E\1", field.replace("D", "E").replace("d", "e")))
                except ValueError:
                    raise InputFileError(f"{where}: node coordinate {_show(field)} (columns {a - w + 1}-{a}) is "
                                         "not a number: corrupt or truncated record; re-export the file") from None
            reals.append(v)
    return ints, reals


def _fixed_ints(line: str, width: int, where: str) -> list[int]:
    """Non-blank integer fields of width ``width`` (EBLOCK / CMBLOCK records, any number of fields)."""
    n = max(1, -(-len(line.rstrip("\r\n")) // width))
    return [v for v in fixed_record(line, [("i", width)] * n, where)[0] if v is not None]


def _int_width(layout: Sequence[tuple[str, int]], where: str) -> int:
    widths = {w for k, w in layout if k in "ia"}
    if len(widths) != 1:
        raise InputFileError(f"{where}: expected one integer field width in the format, got {sorted(widths)}")
    return widths.pop()


# ---- the parser ---------------------------------------------------------------------------------
_PARAM = re.compile(r"^\s*(?:\*set\s*,\s*([A-Za-z_]\w*)\s*,\s*([-+0-9.eE]+)|([A-Za-z_]\w*)\s*=\s*([-+0-9.eE]+))\s*(?:!.*)?$",
                    re.I)


def _int_arg(text: str, params: Mapping[str, float]) -> int | None:
    """An integer command argument: a number, a ``*SET`` parameter name, or a name such as PLANE182."""
    t = text.strip()
    if not t:
        return None
    try:
        return int(float(t))
    except ValueError:
        pass
    if t.upper() in params:
        return int(params[t.upper()])
    m = re.fullmatch(r"[A-Za-z]+(\d+)", t)
    return int(m.group(1)) if m else None


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
    text = read_text(path)
    nul = text.find("\x00")
    if nul >= 0:
        ln = text.count("\n", 0, nul) + 1
        raise InputFileError(f"{path}:{ln}: NUL bytes in a text archive: the file is truncated or corrupt; "
                             "re-export it (CDWRITE,DB in MAPDL or 'Write Input File' in Workbench)")
    lines = text.splitlines()
    node_rows: list[tuple[int, float, float, float, int]] = []
    elems: list[tuple[int, int, int, list[int], int]] = []   # (id, mat, type, nodes, line)
    comps_elem: dict[str, set[int]] = {}
    comps_node: dict[str, set[int]] = {}
    et: dict[int, _EType] = {}
    keyopt3: dict[int, int] = {}
    params: dict[str, float] = {}
    notes: list[str] = []
    file_unit = None
    i = 0
    while i < len(lines):
        line = lines[i]
        head = line.strip().upper()
        cmd = head.split(",", 1)[0].strip()
        fields = [s.strip() for s in line.split("!")[0].split(",")]
        if head.startswith("/UNITS"):
            sysname = fields[1].upper() if len(fields) > 1 else ""
            if sysname not in ANSYS_UNIT_SYSTEMS:
                raise InputFileError(f"{path}:{i + 1}: unsupported unit system {sysname!r} in /UNITS; "
                                     f"give the length unit: --length_unit mm (length_unit= in Python)")
            file_unit = ANSYS_UNIT_SYSTEMS[sysname]
        elif (m := _PARAM.match(line)) is not None:
            name, val = (m.group(1), m.group(2)) if m.group(1) else (m.group(3), m.group(4))
            try:
                params[name.upper()] = float(val)
            except ValueError:
                pass
        elif cmd == "ET":
            itype = _int_arg(fields[1], params) if len(fields) > 1 else None
            ename = _int_arg(fields[2], params) if len(fields) > 2 else None
            if itype is None or ename is None:
                notes.append(f"{path}:{i + 1}: ET line not understood, ignored: {line.strip()[:60]!r}")
            else:
                et[itype] = _EType(ename, i + 1)
                if len(fields) > 5 and fields[5]:
                    k3 = _int_arg(fields[5], params)
                    if k3 is not None:
                        keyopt3[itype] = k3
        elif cmd in ("KEYOP", "KEYOPT", "KEYO"):
            if len(fields) > 3:
                itype, knum, val = (_int_arg(f, params) for f in fields[1:4])
                if itype is not None and knum == 3 and val is not None:
                    keyopt3[itype] = val
        elif cmd == "ETBLOCK":
            layout = fortran_layout(lines[i + 1] if i + 1 < len(lines) else "", f"{path}:{i + 2}")
            i += 2
            while i < len(lines):
                ints, _ = fixed_record(lines[i], layout, f"{path}:{i + 1}")
                if not ints or ints[0] is None or ints[0] == -1:
                    break
                if len(ints) < 2 or ints[1] is None:
                    raise InputFileError(f"{path}:{i + 1}: ETBLOCK record without an element type number")
                et[ints[0]] = _EType(ints[1], i + 1)
                if len(ints) > 4 and ints[4] is not None:
                    keyopt3[ints[0]] = ints[4]
                i += 1
        elif cmd == "NBLOCK":
            layout = fortran_layout(lines[i + 1] if i + 1 < len(lines) else "", f"{path}:{i + 2}")
            i += 2
            while i < len(lines):
                raw = lines[i]
                s = raw.strip()
                if not s or s == "-1" or s.upper().startswith("N,"):
                    break
                where = f"{path}:{i + 1}"
                ints, vals = fixed_record(raw, layout, where)
                if not ints or ints[0] is None:
                    raise InputFileError(f"{where}: NBLOCK record has no node number: corrupt record; re-export the file")
                xyz = [(v if v is not None else 0.0) for v in vals[:3]] + [0.0] * (3 - len(vals[:3]))
                if not all(math.isfinite(v) for v in xyz):
                    raise InputFileError(f"{where}: node {ints[0]} has a non-finite coordinate")
                node_rows.append((ints[0], xyz[0], xyz[1], xyz[2], i + 1))
                i += 1
        elif cmd == "EBLOCK":
            layout = fortran_layout(lines[i + 1] if i + 1 < len(lines) else "", f"{path}:{i + 2}")
            wi = _int_width(layout, f"{path}:{i + 2}")
            solid = len(fields) > 2 and fields[2].upper() == "SOLID"
            start_block = i + 1
            i += 2
            if not solid:   # non-SOLID form (surface / contact elements in Workbench files): skip it
                n_skip = 0
                while i < len(lines):
                    ints = _fixed_ints(lines[i], wi, f"{path}:{i + 1}")
                    if not ints or ints[0] == -1:
                        break
                    n_skip += 1
                    i += 1
                notes.append(f"{path}:{start_block}: skipped an EBLOCK in non-SOLID form ({line.strip()!r}, "
                             f"{n_skip} record(s)): surface/contact elements")
                i += 1
                continue
            while i < len(lines):
                where = f"{path}:{i + 1}"
                ints = _fixed_ints(lines[i], wi, where)
                if not ints or ints[0] == -1:
                    break
                if len(ints) < 11:
                    raise InputFileError(f"{where}: EBLOCK record has {len(ints)} fields, expected >= 11: "
                                         "corrupt record; re-export the file")
                n_nodes, eid = ints[8], ints[10]
                nodes = ints[11:]
                start = i + 1
                while len(nodes) < n_nodes and i + 1 < len(lines):   # continuation line(s)
                    i += 1
                    nodes += _fixed_ints(lines[i], wi, f"{path}:{i + 1}")
                elems.append((eid, ints[0], ints[1], nodes[:n_nodes], start))
                i += 1
        elif cmd == "CMBLOCK":
            if len(fields) < 4:
                raise InputFileError(f"{path}:{i + 1}: malformed CMBLOCK header")
            cname, ctype = fields[1], fields[2].upper()
            try:
                count = int(fields[3])
            except ValueError:
                raise InputFileError(f"{path}:{i + 1}: CMBLOCK count {fields[3]!r} is not an integer") from None
            wi = _int_width(fortran_layout(lines[i + 1] if i + 1 < len(lines) else "", f"{path}:{i + 2}"),
                            f"{path}:{i + 2}")
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
        raise InputFileError(f"{path}: no NBLOCK (nodes) found: not an MAPDL archive / input file with a mesh")
    if not elems:
        raise InputFileError(f"{path}: no EBLOCK in SOLID form (elements) found")
    if length_unit is not None and file_unit is not None and LENGTH_UNITS.get(length_unit) != LENGTH_UNITS[file_unit]:
        raise InputFileError(f"{path}: /UNITS says {file_unit!r} but length_unit={length_unit!r} was given "
                             "(--length_unit): drop it or make it agree")
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
    points = np.array([[r[1], r[2]] for r in node_rows], dtype=np.float64)   # file unit; scaled below
    sorted_ids = node_ids[order]

    # element types: skip contact/target/surface, refuse what is not a 2D structural solid
    def ename_of(itype: int) -> int | None:
        return et[itype].ename if itype in et else None

    skipped = [e for e in elems if ename_of(e[2]) in SKIPPED_TYPES]
    if skipped:
        kinds = sorted({SKIPPED_TYPES[ename_of(e[2])] for e in skipped})
        notes.append(f"{path}: skipped {len(skipped)} contact/target/surface element(s) ({', '.join(kinds)})")
    kept = [e for e in elems if ename_of(e[2]) not in SKIPPED_TYPES]
    undeclared = sorted({e[2] for e in kept if e[2] not in et})
    if undeclared:
        notes.append(f"{path}: element type(s) {undeclared} have no ET / ETBLOCK declaration; read as 2D solids "
                     "by their node count")

    def check_types(subset) -> str | None:
        """Refuse non-2D-solid types among ``subset``; the analysis their KEYOPT(3) declares."""
        analyses: dict[str, int] = {}
        for itype in sorted({e[2] for e in subset}):
            if itype not in et:
                continue
            t = et[itype]
            if t.ename not in SOLID_2D:
                name, category = type_name(t.ename)
                users = [e[0] for e in subset if e[2] == itype]
                raise InputFileError(
                    f"{path}:{t.line}: element type {itype} is {name} ({category}), used by {len(users)} "
                    f"element(s), e.g. {users[0]}: only 2D structural solids are read (PLANE182, PLANE183, "
                    f"PLANE42, PLANE82, PLANE162); {_FIX_TYPES}")
            k3 = keyopt3.get(itype, 0)
            analysis = KEYOPT3_ANALYSIS.get(k3, f"KEYOPT(3)={k3}")
            if analysis not in ANALYSES:
                raise InputFileError(
                    f"{path}:{t.line}: element type {itype} ({SOLID_2D[t.ename][0]}) has KEYOPT(3)={k3} "
                    f"({analysis.replace('_', ' ')}): only axisymmetric (KEYOPT(3)=1) and plane strain "
                    "(KEYOPT(3)=2) models are supported; set KEYOPT(3) in ANSYS and re-export")
            analyses.setdefault(analysis, itype)
        if len(analyses) > 1:
            (a1, t1), (a2, t2) = list(analyses.items())[:2]
            raise InputFileError(f"{path}:{et[t2].line}: element type {t2} is {a2.replace('_', ' ')} but type "
                                 f"{t1} is {a1.replace('_', ' ')} (KEYOPT(3)): one analysis per model; "
                                 "set the same KEYOPT(3) on every 2D solid type")
        analysis = next(iter(analyses), None)
        if analysis is not None and scene_obj is not None and analysis != scene_obj.analysis:
            t = analyses[analysis]
            raise InputFileError(
                f"{path}:{et[t].line}: element type {t} is {analysis.replace('_', ' ')} (KEYOPT(3)="
                f"{keyopt3.get(t, 0)}) but the scene's analysis is {scene_obj.analysis!r}: use a scene with "
                f"analysis = {analysis!r} or set KEYOPT(3) in ANSYS and re-export")
        return analysis

    if not ignore_unmapped:
        check_types(kept)
    if length_unit is None and file_unit is None:
        raise InputFileError(f"{path}: no /UNITS line, so the length unit is unknown (CDWRITE writes none): "
                             "pass --length_unit mm (or m, um, ...; length_unit= in Python)")
    points = points * length_factor(length_unit or file_unit, f"{path}: length_unit (--length_unit)")
    eids = np.array([e[0] for e in kept], dtype=np.int64)
    if len(np.unique(eids)) != len(eids):
        u, c = np.unique(eids, return_counts=True)
        raise InputFileError(f"{path}: duplicate element number {int(u[c > 1][0])}")
    mats = np.array([e[1] for e in kept], dtype=np.int64)
    groups = {name: np.isin(eids, sorted(m)) for name, m in comps_elem.items()}
    cell_part = assign_parts(str(path), names, specs, len(kept), mats, "material number", groups, "element component")
    analysis = check_types([e for e, p in zip(kept, cell_part) if p >= 0])
    cells = np.zeros((len(kept), 4), dtype=np.int64)
    midside: set[int] = set()
    corner_ids: set[int] = set()
    n_reduced = 0
    for k, (eid, mat, etype, nodes, ln) in enumerate(kept):
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
    # nodes whose result rows are ignored: midside nodes, and nodes only of skipped or unmapped elements
    others = {n for (_, _, _, nodes, _), p in zip(kept, cell_part) if p < 0 for n in nodes}
    others.update(n for e in skipped for n in e[3])
    dropped = np.array(sorted((midside | others) - corner_ids), dtype=np.int64)
    if n_reduced:
        notes.append(f"{path}: {n_reduced} 8-node quad(s) reduced to their corner nodes; {len(dropped)} midside "
                     "node(s) dropped (their rows in result tables are ignored)")
    node_sets = {name: np.array(sorted(m), dtype=np.int64) for name, m in comps_node.items()}
    return finish_mesh(str(path), node_ids, points, cells, cell_part, eids, node_sets, names, ignore_unmapped,
                       dropped_node_ids=dropped, analysis=analysis, notes=tuple(notes))


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
