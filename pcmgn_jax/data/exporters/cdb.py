"""The MAPDL archive writer: :func:`write_cdb` (CDWRITE layout; see :mod:`pcmgn_jax.data.exporters.ansys`
for what is written and how the numbering maps)."""
from __future__ import annotations

import os
import re
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from pcmgn_jax.atomic import atomic_write_text
from pcmgn_jax.data.exporters.common import ExportError, export_errors
from pcmgn_jax.data.importers.units import ANSYS_UNIT_SYSTEMS, length_factor
from pcmgn_jax.trajectory import Trajectory

__all__ = ["ANALYSIS_KEYOPT3", "COMPONENT_RE", "write_cdb"]

ANALYSIS_KEYOPT3 = {"axisymmetric": 1, "plane_strain": 2}
COMPONENT_RE = re.compile(r"^[A-Za-z][A-Za-z0-9_]{0,31}$")   # a valid MAPDL component name


def _e21(x: float) -> str:
    """One ``e21.13e3`` field as MAPDL writes it: ' 1.2345678901234E-003'."""
    mant, exp = f"{float(x):.13E}".split("E")
    return f"{mant}E{int(exp):+04d}".rjust(21)


def _ranges(members: Sequence[int]) -> list[int]:
    """CMBLOCK items: sorted numbers with runs written as ``a, -b`` (a..b), as MAPDL writes them."""
    vals = sorted({int(v) for v in members})
    out: list[int] = []
    k = 0
    while k < len(vals):
        j = k
        while j + 1 < len(vals) and vals[j + 1] == vals[j] + 1:
            j += 1
        out += [vals[k], -vals[j]] if j > k else [vals[k]]
        k = j + 1
    return out


def _keyopt3(traj: Trajectory, keyopt3: int | None, where: str) -> int:
    if keyopt3 is not None:
        return int(keyopt3)
    meta = traj.meta or {}
    analysis = meta.get("analysis") or (meta.get("scene") or {}).get("analysis")
    if analysis not in ANALYSIS_KEYOPT3:
        raise ExportError(f"{where}: the trajectory's analysis is {analysis!r} (meta 'analysis' / 'scene'); "
                          f"give keyopt3= (1 axisymmetric, 2 plane strain)")
    return ANALYSIS_KEYOPT3[analysis]


def write_cdb(path: str | os.PathLike, traj: Trajectory, *, unit: str = "mm", units_line: bool = False,
              mats: Sequence[int] | None = None, node_ids: Sequence[int] | None = None,
              element_ids: Sequence[int] | None = None, keyopt3: int | None = None,
              components: Mapping[str, tuple[str, Sequence[int]]] | None = None,
              extra_types: Mapping[int, int] | None = None, extra_elements: str = "") -> np.ndarray:
    """Write ``traj``'s mesh as an MAPDL archive (CDWRITE layout); return the ANSYS node numbers (N,).

    ``unit``: length unit of the coordinates (m, mm, um, ...). ``units_line``: also write the matching
    ``/UNITS`` system (MPA for mm, SI for m, ...; CDWRITE writes none). ``mats``: material number per cell
    (default part id + 1). ``node_ids`` / ``element_ids``: ANSYS numbers (default 1..N / 1..E).
    ``keyopt3``: 1 axisymmetric, 2 plane strain (default: from the trajectory's meta analysis).
    ``components``: name -> ("ELEM" | "NODE", ANSYS numbers). ``extra_types``: more ET entries
    {type number: element type}, e.g. {2: 172} for CONTA172; ``extra_elements``: raw EBLOCK records
    appended to the element block (tests of the reader's skipping).
    """
    path = Path(path)
    where = str(path)
    n, e = traj.n_nodes, len(traj.cells)
    s = 1.0 / length_factor(unit, f"{where}: unit")
    ids = np.arange(1, n + 1) if node_ids is None else np.asarray(node_ids, dtype=np.int64)
    eids = np.arange(1, e + 1) if element_ids is None else np.asarray(element_ids, dtype=np.int64)
    mats = np.asarray(traj.cell_part, dtype=np.int64) + 1 if mats is None else np.asarray(mats, dtype=np.int64)
    if ids.shape != (n,) or len(np.unique(ids)) != n or ids.min() < 1:
        raise ExportError(f"{where}: node_ids must be {n} distinct numbers >= 1")
    if eids.shape != (e,) or len(np.unique(eids)) != e or eids.min() < 1:
        raise ExportError(f"{where}: element_ids must be {e} distinct numbers >= 1")
    if mats.shape != (e,) or mats.min() < 1:
        raise ExportError(f"{where}: mats must be {e} material numbers >= 1")
    k3 = _keyopt3(traj, keyopt3, where)
    lines = ["/COM,ANSYS RELEASE 2024 R1 (written by pcmgn_jax.data.exporters.ansys)"]
    if units_line:
        system = next((k for k, v in ANSYS_UNIT_SYSTEMS.items() if v == unit and k != "MKS"), None)
        if system is None:
            raise ExportError(f"{where}: no MAPDL /UNITS system has length unit {unit!r}; "
                              f"use units_line=False or one of {sorted(set(ANSYS_UNIT_SYSTEMS.values()))}")
        lines.append(f"/UNITS,{system}")
    lines += ["/PREP7", f"ET,{1:8d},182", f"KEYOP,{1:8d},{3:2d},{k3:9d}"]
    for itype, ename in sorted((extra_types or {}).items()):
        lines.append(f"ET,{int(itype):8d},{int(ename)}")
    lines += [f"NBLOCK,6,SOLID,{int(ids.max()):9d},{n:9d}", "(3i9,6e21.13e3)"]
    pts = np.asarray(traj.points, dtype=np.float64) * s
    for nid, (x, y) in zip(ids, pts):
        lines.append(f"{int(nid):9d}{0:9d}{0:9d}{_e21(x)}" + (_e21(y) if y != 0 else ""))
    lines += ["N,R5.3,LOC,       -1,"]
    lines += [f"EBLOCK,19,SOLID,{int(eids.max()):9d},{e:9d}", "(19i9)"]
    for eid, cell, mat in zip(eids, np.asarray(traj.cells), mats):
        f = [int(mat), 1, 1, 1, 0, 0, 0, 0, 4, 0, int(eid)] + [int(ids[c]) for c in cell]
        lines.append("".join(f"{v:9d}" for v in f))
    if extra_elements:
        lines.append(extra_elements.rstrip("\n"))
    lines.append(f"{-1:9d}")
    for name, (kind, members) in (components or {}).items():
        if not COMPONENT_RE.match(name):
            raise ExportError(f"{where}: component name {name!r} is not a valid MAPDL name "
                              "(a letter, then up to 31 letters, digits or _)")
        if kind.upper() not in ("ELEM", "NODE"):
            raise ExportError(f"{where}: component {name!r}: kind must be 'ELEM' or 'NODE', got {kind!r}")
        items = _ranges(members)
        lines += [f"CMBLOCK,{name:8s},{kind.upper()},{len(items):8d}  ! users component", "(8i10)"]
        for a in range(0, len(items), 8):
            lines.append("".join(f"{v:10d}" for v in items[a:a + 8]))
    lines.append("FINISH")
    with export_errors(path):
        atomic_write_text(path, "\n".join(lines) + "\n", parents=True)
    return ids


