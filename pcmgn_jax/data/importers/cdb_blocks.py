"""Block readers of MAPDL archives / Workbench input files: the Fortran fixed formats and one reader per
block kind (/UNITS, ``*SET`` parameters, ET / KEYOPT / ETBLOCK element types, NBLOCK nodes, EBLOCK elements,
CMBLOCK components). :func:`scan` runs them over the file's lines into one :class:`Archive`; the checks and
the mesh are built from it in :mod:`pcmgn_jax.data.importers.cdb`.
"""
from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

from pcmgn_jax.data.importers.errors import InputFileError
from pcmgn_jax.data.importers.units import ANSYS_UNIT_SYSTEMS


@dataclass
class _EType:
    ename: int
    line: int            # 1-based line of the ET / ETBLOCK record declaring it
    keyopt3: int = 0


# ---- Fortran fixed formats ----------------------------------------------------------------------
_FMT_ITEM = re.compile(r"(\d*)([iaefgd])(\d+)(?:\.\d+)?(?:e\d+)?", re.IGNORECASE)
_FMT_SKIP = re.compile(r"(\d*)x", re.IGNORECASE)


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


def fixed_record(line: str, layout: Sequence[tuple[str, int]],
                 where: str) -> tuple[list[int | None], list[float | None]]:
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


_PARAM = re.compile(r"^\s*(?:\*set\s*,\s*([A-Za-z_]\w*)\s*,\s*([-+0-9.eE]+)"
                    r"|([A-Za-z_]\w*)\s*=\s*([-+0-9.eE]+))\s*(?:!.*)?$", re.IGNORECASE)


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


@dataclass
class Archive:
    """What :func:`scan` reads from a file, in file units (lengths as written, before /UNITS scaling).

    nodes:      [(node id, x, y, z, line)] in file order
    elems:      [(element id, material, type, node ids, line)] of EBLOCKs in SOLID form
    comps_elem, comps_node: element / node components (CMBLOCK), lower-case name -> ids
    et:         element type number -> its declaration (ET / ETBLOCK)
    keyopt3:    element type number -> KEYOPT(3)
    params:     ``*SET`` / ``NAME = value`` parameters, upper-case name -> value
    notes:      what was skipped or assumed, one line each
    file_unit:  the /UNITS length unit name, or None
    """

    nodes: list[tuple[int, float, float, float, int]] = field(default_factory=list)
    elems: list[tuple[int, int, int, list[int], int]] = field(default_factory=list)
    comps_elem: dict[str, set[int]] = field(default_factory=dict)
    comps_node: dict[str, set[int]] = field(default_factory=dict)
    et: dict[int, _EType] = field(default_factory=dict)
    keyopt3: dict[int, int] = field(default_factory=dict)
    params: dict[str, float] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    file_unit: str | None = None


def _layout_after(lines: Sequence[str], i: int, path) -> list[tuple[str, int]]:
    """The Fortran format on the line after the block header at index ``i``."""
    return fortran_layout(lines[i + 1] if i + 1 < len(lines) else "", f"{path}:{i + 2}")


def _read_units(arc: Archive, fields: list[str], path, i: int) -> None:
    sysname = fields[1].upper() if len(fields) > 1 else ""
    if sysname not in ANSYS_UNIT_SYSTEMS:
        raise InputFileError(f"{path}:{i + 1}: unsupported unit system {sysname!r} in /UNITS; "
                             f"give the length unit: --length_unit mm (length_unit= in Python)")
    arc.file_unit = ANSYS_UNIT_SYSTEMS[sysname]


def _read_param(arc: Archive, m: re.Match) -> None:
    name, val = (m.group(1), m.group(2)) if m.group(1) else (m.group(3), m.group(4))
    try:
        arc.params[name.upper()] = float(val)
    except ValueError:
        pass


def _read_et(arc: Archive, fields: list[str], line: str, path, i: int) -> None:
    """ET,itype,ename[,KOP1,KOP2,KOP3]: an element type and its KEYOPT(3)."""
    itype = _int_arg(fields[1], arc.params) if len(fields) > 1 else None
    ename = _int_arg(fields[2], arc.params) if len(fields) > 2 else None
    if itype is None or ename is None:
        arc.notes.append(f"{path}:{i + 1}: ET line not understood, ignored: {line.strip()[:60]!r}")
        return
    arc.et[itype] = _EType(ename, i + 1)
    if len(fields) > 5 and fields[5]:
        k3 = _int_arg(fields[5], arc.params)
        if k3 is not None:
            arc.keyopt3[itype] = k3


def _read_keyopt(arc: Archive, fields: list[str]) -> None:
    """KEYOPT,itype,knum,value: only KEYOPT(3) is kept."""
    if len(fields) > 3:
        itype, knum, val = (_int_arg(f, arc.params) for f in fields[1:4])
        if itype is not None and knum == 3 and val is not None:
            arc.keyopt3[itype] = val


def _read_etblock(arc: Archive, lines: Sequence[str], i: int, path) -> int:
    """ETBLOCK at line index ``i``; returns the index of the line after its terminator."""
    layout = _layout_after(lines, i, path)
    i += 2
    while i < len(lines):
        ints, _ = fixed_record(lines[i], layout, f"{path}:{i + 1}")
        if not ints or ints[0] is None or ints[0] == -1:
            break
        if len(ints) < 2 or ints[1] is None:
            raise InputFileError(f"{path}:{i + 1}: ETBLOCK record without an element type number")
        arc.et[ints[0]] = _EType(ints[1], i + 1)
        if len(ints) > 4 and ints[4] is not None:
            arc.keyopt3[ints[0]] = ints[4]
        i += 1
    return i + 1


def _read_nblock(arc: Archive, lines: Sequence[str], i: int, path) -> int:
    """NBLOCK at line index ``i`` (nodes, file units); returns the index of the line after its end."""
    layout = _layout_after(lines, i, path)
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
        arc.nodes.append((ints[0], xyz[0], xyz[1], xyz[2], i + 1))
        i += 1
    return i + 1


def _skip_eblock(arc: Archive, lines: Sequence[str], i: int, path, wi: int) -> int:
    """An EBLOCK in non-SOLID form (surface / contact elements in Workbench files) at line index ``i``:
    skipped with a note; returns the index of the line after its terminator."""
    header, start_block = lines[i], i + 1
    i += 2
    n_skip = 0
    while i < len(lines):
        ints = _fixed_ints(lines[i], wi, f"{path}:{i + 1}")
        if not ints or ints[0] == -1:
            break
        n_skip += 1
        i += 1
    arc.notes.append(f"{path}:{start_block}: skipped an EBLOCK in non-SOLID form ({header.strip()!r}, "
                     f"{n_skip} record(s)): surface/contact elements")
    return i + 1


def _read_eblock(arc: Archive, lines: Sequence[str], i: int, path, fields: list[str]) -> int:
    """EBLOCK at line index ``i``; returns the index of the line after its terminator."""
    wi = _int_width(_layout_after(lines, i, path), f"{path}:{i + 2}")
    if not (len(fields) > 2 and fields[2].upper() == "SOLID"):
        return _skip_eblock(arc, lines, i, path, wi)
    i += 2
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
        arc.elems.append((eid, ints[0], ints[1], nodes[:n_nodes], start))
        i += 1
    return i + 1


def _read_cmblock(arc: Archive, lines: Sequence[str], i: int, path, fields: list[str]) -> int:
    """CMBLOCK at line index ``i`` (a node or element component; negative ids close a range);
    returns the index of the first line after its records."""
    if len(fields) < 4:
        raise InputFileError(f"{path}:{i + 1}: malformed CMBLOCK header")
    cname, ctype = fields[1], fields[2].upper()
    try:
        count = int(fields[3])
    except ValueError:
        raise InputFileError(f"{path}:{i + 1}: CMBLOCK count {fields[3]!r} is not an integer") from None
    wi = _int_width(_layout_after(lines, i, path), f"{path}:{i + 2}")
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
    (arc.comps_elem if ctype == "ELEM" else arc.comps_node)[cname.lower()] = members
    return i


def scan(lines: Sequence[str], path) -> Archive:
    """Run the block readers over ``lines`` of file ``path`` (named in errors); unknown lines are skipped."""
    arc = Archive()
    i = 0
    while i < len(lines):
        line = lines[i]
        head = line.strip().upper()
        cmd = head.split(",", 1)[0].strip()
        fields = [s.strip() for s in line.split("!")[0].split(",")]
        if head.startswith("/UNITS"):
            _read_units(arc, fields, path, i)
        elif (m := _PARAM.match(line)) is not None:
            _read_param(arc, m)
        elif cmd == "ET":
            _read_et(arc, fields, line, path, i)
        elif cmd in ("KEYOP", "KEYOPT", "KEYO"):
            _read_keyopt(arc, fields)
        elif cmd == "ETBLOCK":
            i = _read_etblock(arc, lines, i, path)
            continue
        elif cmd == "NBLOCK":
            i = _read_nblock(arc, lines, i, path)
            continue
        elif cmd == "EBLOCK":
            i = _read_eblock(arc, lines, i, path, fields)
            continue
        elif cmd == "CMBLOCK":
            i = _read_cmblock(arc, lines, i, path, fields)
            continue
        i += 1
    return arc
