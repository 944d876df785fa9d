"""ANSYS Mechanical "Export -> Text File" nodal tables: parsing, frame discovery, node matching, and
:func:`import_ansys_text` (tables + a mesh -> Trajectory)."""
from __future__ import annotations

import json
import math
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

from pcmgn_jax.data.importers.build import build_trajectory
from pcmgn_jax.data.importers.errors import InputFileError, read_text
from pcmgn_jax.data.importers.meshes import read_mesh
from pcmgn_jax.data.importers.parts import ImportedMesh, resolve_part_names
from pcmgn_jax.data.importers.units import TIME_UNITS, length_factor, stress_factor, velocity_factor
from pcmgn_jax.scene import Scene
from pcmgn_jax.trajectory import Trajectory

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
    lines = read_text(path).splitlines()
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
        factors[k] = {"length": length_factor, "velocity": velocity_factor,
                      "stress": stress_factor}[label](unit, where)
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
            raise InputFileError(f"{path}:{ln + 1}: column 'Node Number': "
                                 f"{fields[i_node]!r} is not an integer") from None
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
                             "(see the naming convention in pcmgn_jax/data/importers/__init__.py)")
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
        for ln, row in enumerate(read_text(times_file).splitlines(), 1):
            if row.strip():
                try:
                    vals.append(float(row.split()[-1]))
                except ValueError:
                    raise InputFileError(f"{times_file}:{ln}: {row.strip()!r} is not a time [s]") from None
        t = np.asarray(vals, np.float64)
    return out, t


def _drop_rows(tab: AnsysTable, ids: np.ndarray) -> AnsysTable:
    """``tab`` without the rows of node numbers ``ids``."""
    if len(ids) == 0:
        return tab
    keep = ~np.isin(tab.node_ids, ids)
    if keep.all():
        return tab
    return AnsysTable(tab.path, tab.node_ids[keep], tab.locations[keep], tab.values[keep], tab.lines[keep],
                      tab.column)


def _match_nodes(tab: AnsysTable, mesh: ImportedMesh, ref_ids: np.ndarray | None, ref_file: Path | None,
                 location_tol: float) -> np.ndarray:
    """Indices into the mesh of the table rows; checks membership, node-set equality, locations.
    Rows of nodes the mesh dropped on purpose (midside nodes of 8-node quads) must already be removed
    (:func:`_drop_rows`)."""
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
            f"differs from the mesh {mesh.points[idx[k]].tolist()} m by {err[k]:.3g} m (> location_tol); "
            "if the mesh's length unit is wrong, pass --length_unit (length_unit=), e.g. mm")
    return idx


def import_ansys_text(mesh: str | os.PathLike | ImportedMesh, results: str | os.PathLike, *,
                      scene: Scene | Mapping | None = None, part_names: Sequence[str] | None = None,
                      parts: Mapping[str, Any] | None = None, output_dt: float | None = None,
                      times: Sequence[float] | None = None, fixed: Any = "bottom",
                      location_tol: float | None = None, ignore_unmapped: bool = False,
                      design: Mapping[str, float] | None = None, **mesh_kwargs) -> Trajectory:
    """ANSYS Mechanical nodal text exports in folder ``results`` + a mesh -> Trajectory (source 'ansys-text').

    ``mesh``: a ``.cdb`` / meshio-readable path or an :class:`ImportedMesh`. Frame times [s] come from
    ``times``, ``frames.json``/``times.txt`` in ``results``, or ``output_dt`` (t_k = k * output_dt).
    ``location_tol`` [m] (default 1e-5 x the mesh extent) bounds |X/Y Location - mesh coordinate|.
    Returns displacement (T,N,2) [m], velocity (T,N,2) [m/s], von_mises (T,N) [Pa].
    """
    results = Path(results)
    names, scene_obj = resolve_part_names(scene, part_names)
    if not isinstance(mesh, ImportedMesh):
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
            tab = _drop_rows(read_ansys_table(fr[key], kind), mesh.dropped_node_ids)
            idx = _match_nodes(tab, mesh, ref_ids, ref_file, tol)
            if ref_ids is None:
                ref_ids, ref_file = np.sort(tab.node_ids), tab.path
            columns.setdefault(key, tab.column)
            if kind == "stress":
                vm[k, idx] = tab.values
            else:
                (disp if kind == "deformation" else vel)[k, idx, "xy".index(comp)] = tab.values
    return build_trajectory(mesh, scene_obj, fixed, t, disp, vel, vm, "ansys-text",
                  {"mesh": mesh.source, "results": str(results), "columns": columns}, design)
