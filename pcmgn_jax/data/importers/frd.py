"""Read CalculiX ASCII result files (``.frd``) with NumPy: nodes, elements and nodal result blocks.

The layout (CalculiX GraphiX "frd" format, as ``ccx`` 2.x writes it for ``*NODE FILE`` / ``*EL FILE``):

* ``    1C`` header, ``    1U...`` user records (``1UMAT    1NAME``: material numbers and names);
* ``    2C  <n>`` node block: one ``" -1" I10 3E12.5`` record per node (number, x, y, z), closed by ``" -3"``;
* ``    3C  <n>`` element block: per element a ``" -1" I10 I5 I5 I5`` record (number, type, group,
  material) and ``" -2"`` records of I10 node numbers (frd type 9 = 4-node quad), closed by ``" -3"``;
* per output time and result: ``    1PSTEP`` then ``  100CL  <set> <time E12.5> <n nodes> ...``, a
  ``" -4  NAME  <ncomp>"`` record (``DISP``, ``VELO``, ``STRESS``, ``ERROR`` ...), ``" -5"`` records naming
  the components (STRESS: SXX, SYY, SZZ, SXY, SYZ, SZX), then ``" -1" I10 <ncomp>E12.5`` records (a long
  record continues on ``" -2"`` lines), closed by ``" -3"``; ``9999`` ends the file.

Values are fixed-width (E12.5: 6 significant digits; a negative value has no blank before it), so the
records are cut by column, never split on blanks. Nodal stresses are CalculiX's: extrapolated from the
integration points and averaged over every element at the node (across materials). Errors are
:class:`~pcmgn_jax.data.importers.errors.InputFileError` naming the file and line.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pcmgn_jax.data.importers.errors import InputFileError

__all__ = ["FrdResult", "read_frd"]

_W = 12   # E12.5 field width
_NODE = slice(3, 13)   # I10 node / element number after the 3-character record key


@dataclass
class FrdResult:
    """One .frd file: ``node_ids`` (N,) int64 and ``nodes`` (N, 3) float64 [file units, m for our decks]
    in file order; ``elements`` {number: node numbers}; ``materials`` {number: name}; ``times`` (T,) [s]
    of the output steps; ``results`` {NAME: (T, N, ncomp) float64} in the node order of ``node_ids``
    (NaN where a step wrote no value for a node); ``components`` {NAME: [component names]}."""

    path: str
    node_ids: np.ndarray
    nodes: np.ndarray
    elements: dict[int, tuple[int, ...]] = field(default_factory=dict)
    materials: dict[int, str] = field(default_factory=dict)
    times: np.ndarray = field(default_factory=lambda: np.zeros(0))
    results: dict[str, np.ndarray] = field(default_factory=dict)
    components: dict[str, list[str]] = field(default_factory=dict)


def _floats(line: str, start: int, n: int, where: str) -> list[float]:
    try:
        return [float(line[start + k * _W:start + (k + 1) * _W]) for k in range(n)]
    except ValueError:
        raise InputFileError(f"{where}: expected {n} numbers of 12 characters from column {start + 1}, "
                             f"got {line[start:].rstrip()!r}") from None


def read_frd(path: str | os.PathLike) -> FrdResult:
    """Parse an ASCII .frd (see the module docstring). InputFileError on a binary or truncated file."""
    path = Path(path)
    try:
        text = path.read_text(encoding="ascii")
    except UnicodeDecodeError:
        raise InputFileError(f"{path}: not an ASCII .frd (binary output? use *NODE FILE / *EL FILE, not "
                             "*NODE OUTPUT)") from None
    except OSError as err:
        raise InputFileError(f"{path}: cannot read: {err.strerror or err}") from None
    lines = text.splitlines()
    if not lines or not lines[0].startswith("    1C"):
        raise InputFileError(f"{path}:1: not a CalculiX .frd file (expected '    1C' on the first line)")
    node_ids: list[int] = []
    coords: list[list[float]] = []
    elements: dict[int, tuple[int, ...]] = {}
    materials: dict[int, str] = {}
    steps: list[tuple[float, str, list[int], list[list[float]]]] = []
    components: dict[str, list[str]] = {}
    i, n = 0, len(lines)
    while i < n:
        line = lines[i]
        where = f"{path}:{i + 1}"
        key = line[:6]
        if line.startswith("    1UMAT"):
            try:
                materials[int(line[9:14])] = line[14:].strip()
            except ValueError:
                raise InputFileError(f"{where}: cannot read the material record {line!r}") from None
        elif key == "    2C":
            i += 1
            while i < n and lines[i].startswith(" -1"):
                node_ids.append(int(lines[i][_NODE]))
                coords.append(_floats(lines[i], 13, 3, f"{path}:{i + 1}"))
                i += 1
            if i >= n or not lines[i].startswith(" -3"):
                raise InputFileError(f"{path}:{i + 1}: node block not closed by ' -3' (truncated file?)")
        elif key == "    3C":
            i += 1
            while i < n and lines[i].startswith(" -1"):
                num = int(lines[i][_NODE])
                conn: list[int] = []
                i += 1
                while i < n and lines[i].startswith(" -2"):
                    rec = lines[i][3:].rstrip()
                    conn += [int(rec[k:k + 10]) for k in range(0, len(rec), 10)]
                    i += 1
                elements[num] = tuple(conn)
            if i >= n or not lines[i].startswith(" -3"):
                raise InputFileError(f"{path}:{i + 1}: element block not closed by ' -3' (truncated file?)")
        elif line.startswith("  100C"):
            try:
                time = float(line[12:24])
            except ValueError:
                raise InputFileError(f"{where}: cannot read the step time from {line!r}") from None
            i += 1
            if i >= n or not lines[i].startswith(" -4"):
                raise InputFileError(f"{path}:{i + 1}: expected the ' -4  NAME' record of a result block")
            name = lines[i].split()[1]
            comps = []
            i += 1
            while i < n and lines[i].startswith(" -5"):
                comps.append(lines[i].split()[1])
                i += 1
            # the header's count includes derived components (DISP's 'ALL' magnitude) that are not
            # written: the components are the -5 names without 'ALL', their values the record's
            comps = [c for c in comps if c != "ALL"]
            ncomp = len(comps)
            components.setdefault(name, comps)
            ids: list[int] = []
            vals: list[list[float]] = []
            while i < n and lines[i].startswith(" -1"):
                rec = lines[i]
                ids.append(int(rec[_NODE]))
                row = _floats(rec, 13, min(ncomp, 6), f"{path}:{i + 1}")
                i += 1
                while len(row) < ncomp and i < n and lines[i].startswith(" -2"):
                    more = min(ncomp - len(row), 6)
                    row += _floats(lines[i], 13, more, f"{path}:{i + 1}")
                    i += 1
                vals.append(row)
            if i >= n or not lines[i].startswith(" -3"):
                raise InputFileError(f"{path}:{i + 1}: result block {name} not closed by ' -3' (truncated file?)")
            steps.append((time, name, ids, vals))
        elif line.startswith(" 9999"):
            break
        i += 1
    if not node_ids:
        raise InputFileError(f"{path}: no node block ('    2C') in the file")
    ids_arr = np.asarray(node_ids, np.int64)
    index = np.full(int(ids_arr.max()) + 1, -1, np.int64)
    index[ids_arr] = np.arange(len(ids_arr))
    times = sorted({t for t, *_ in steps})
    t_index = {t: k for k, t in enumerate(times)}
    results: dict[str, np.ndarray] = {}
    for time, name, ids, vals in steps:
        arr = results.setdefault(name, np.full((len(times), len(ids_arr), len(components[name])), np.nan))
        rows = np.asarray(ids, np.int64)
        if rows.size and (rows.max() >= len(index) or np.any(index[rows] < 0)):
            raise InputFileError(f"{path}: result {name} at t = {time:g} s names a node not in the node block")
        arr[t_index[time], index[rows]] = np.asarray(vals, np.float64)
    return FrdResult(path=str(path), node_ids=ids_arr, nodes=np.asarray(coords, np.float64), elements=elements,
                     materials=materials, times=np.asarray(times, np.float64), results=results,
                     components=components)
