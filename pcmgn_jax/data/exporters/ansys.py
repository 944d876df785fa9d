"""Write trajectories in the ANSYS formats the importers read: an MAPDL archive (``model.cdb``) and
Mechanical "Export -> Text File" result tables (``results/``).

What is written (the layouts the readers in :mod:`pcmgn_jax.data.importers` parse, as ANSYS writes them):

* ``write_cdb``: like MAPDL's ``CDWRITE,DB``: ``/PREP7``, ``ET`` (PLANE182) with ``KEYOP`` KEYOPT(3)
  (1 axisymmetric, 2 plane strain, from the trajectory's analysis), ``NBLOCK,6,SOLID`` in
  ``(3i9,6e21.13e3)`` (14 significant digits; a zero y is omitted as CDWRITE omits trailing zeros),
  ``EBLOCK,19,SOLID`` in ``(19i9)`` (material number, type 1, real 1, section 1, 4 nodes, element
  number, the 4 corner nodes counter-clockwise), and ``CMBLOCK`` components in ``(8i10)`` with ranges
  (``a, -b`` = a..b). No ``/UNITS`` line unless ``units_line=True`` (CDWRITE writes none), so the
  importer must be told the unit (``--length_unit``).
* ``write_results``: one tab-separated nodal table per result per frame, named as the importer's
  convention says (``deformation_x_000.txt``, ``deformation_y_000.txt``, ``velocity_x_000.txt``,
  ``velocity_y_000.txt``, ``stress_000.txt``, then ``_001`` ...) plus ``times.txt`` (one frame time per
  line [s]). Header ``Node Number / X Location (mm) / Y Location (mm) / Z Location (mm) / <result> (<unit>)``;
  values are written with ``repr`` (shortest exact float64 text), so the only round-trip error is the
  unit conversion (~1e-16 relative). Units default to Mechanical's (mm, mm/s, MPa).

Numbering (``export_trajectory``): ANSYS node ``i + 1`` = trajectory node ``i`` (the NBLOCK is in
trajectory order, and the importer keeps NBLOCK order, so a round trip gives the same node order);
element ``e + 1`` = cell ``e``; material number = part id + 1 (``ball=1``, first layer ``=2``, ...);
element components named after the parts (upper case) and a node component ``FIXED`` (the fixed nodes).

Every writer is atomic: files are written into a temporary sibling (``.NAME.tmp-XXXX``) and renamed
into place, so a failed or killed export leaves no half-written file or folder. Errors are
:class:`ExportError` (a ``ValueError``) naming the path.
"""
from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Callable, Iterator, Mapping, Sequence

import numpy as np

from pcmgn_jax.atomic import atomic_write_text
from pcmgn_jax.data.importers.units import (ANSYS_UNIT_SYSTEMS, length_factor, stress_factor,
                                            velocity_factor)
from pcmgn_jax.data.importers.ansys_text import FRAME_KEYS
from pcmgn_jax.data.importers.runs import MESH_FILE, OWN_META, RESULTS_DIR, RUN_FILE, SCENE_FILES
from pcmgn_jax.data.trajectory_io import read_sidecar, read_trajectory, to_jsonable
from pcmgn_jax.trajectory import Trajectory

__all__ = ["ANALYSIS_KEYOPT3", "EXPORT_FORMAT", "ExportError", "MESH_FILE", "RESULTS_DIR", "RUN_FILE", "find_trajectories",
           "SCENE_FILE", "FIXED_COMPONENT", "export_dataset", "export_trajectory", "format_table",
           "part_map", "parts_string", "result_file", "write_cdb", "write_results"]

EXPORT_FORMAT = "pcmgn_jax.ansys_export"
SCENE_FILE = SCENE_FILES[0]
FIXED_COMPONENT = "FIXED"
ANALYSIS_KEYOPT3 = {"axisymmetric": 1, "plane_strain": 2}
RESULT_COLUMNS = {"deformation": ("Directional Deformation", "length"),
                  "velocity": ("Directional Velocity", "velocity"),
                  "stress": ("Equivalent (von-Mises) Stress", "stress")}
_COMPONENT_RE = re.compile(r"^[A-Za-z][A-Za-z0-9_]{0,31}$")


class ExportError(ValueError):
    """An export could not be written (one line naming the path and the cause)."""


# ---- atomic file / folder writes ------------------------------------------------------------------
def _write_text_atomic(path: Path, text: str) -> None:
    """:func:`pcmgn_jax.atomic.atomic_write_text`, creating the folder, with a failure as :class:`ExportError`."""
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(path, text)
    except OSError as err:
        raise ExportError(f"{path}: cannot write: {err.strerror or err}") from None


@contextmanager
def _atomic_dir(final: Path) -> Iterator[Path]:
    """Yield a temporary folder beside ``final``; on success it replaces ``final`` (an old folder of that
    name is moved aside first and deleted after), on failure it is deleted and ``final`` is untouched."""
    final = Path(final)
    try:
        final.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{final.name}.tmp-", dir=final.parent))
    except OSError as err:
        raise ExportError(f"{final}: cannot write: {err.strerror or err}") from None
    try:
        try:
            yield tmp
        except ExportError as err:   # name the final path, not the temporary folder
            raise ExportError(str(err).replace(str(tmp), str(final))) from None
        old = None
        if final.exists():
            if not final.is_dir():
                raise ExportError(f"{final}: exists and is not a folder; remove it or choose another output")
            old = Path(tempfile.mkdtemp(prefix=f".{final.name}.old-", dir=final.parent))
            os.replace(final, old / final.name)
        try:
            os.replace(tmp, final)
        except OSError:
            if old is not None:          # put the old folder back
                os.replace(old / final.name, final)
                shutil.rmtree(old, ignore_errors=True)
            raise
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
    except OSError as err:
        raise ExportError(f"{final}: cannot write: {err.strerror or err}") from None
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


# ---- the archive ----------------------------------------------------------------------------------
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
        if not _COMPONENT_RE.match(name):
            raise ExportError(f"{where}: component name {name!r} is not a valid MAPDL name "
                              "(a letter, then up to 31 letters, digits or _)")
        if kind.upper() not in ("ELEM", "NODE"):
            raise ExportError(f"{where}: component {name!r}: kind must be 'ELEM' or 'NODE', got {kind!r}")
        items = _ranges(members)
        lines += [f"CMBLOCK,{name:8s},{kind.upper()},{len(items):8d}  ! users component", "(8i10)"]
        for a in range(0, len(items), 8):
            lines.append("".join(f"{v:10d}" for v in items[a:a + 8]))
    lines.append("FINISH")
    _write_text_atomic(path, "\n".join(lines) + "\n")
    return ids


# ---- the result tables ----------------------------------------------------------------------------
def result_file(key: str, frame: int) -> str:
    """File name of result ``key`` (one of FRAME_KEYS) in frame ``frame``: ``deformation_x_000.txt``."""
    if key not in FRAME_KEYS:
        raise ValueError(f"result key {key!r} is not one of {FRAME_KEYS}")
    return f"{key}_{frame:03d}.txt"


def format_table(node_ids: Sequence[int], points: np.ndarray, values: np.ndarray, *, column: str,
                 length_unit: str = "mm", value_scale: float = 1.0, order: Sequence[int] | None = None,
                 with_z: bool = True) -> str:
    """One Mechanical nodal text table: header, then one row per node (in ``order``, default as given).

    ``points`` [m] are written in ``length_unit``; ``values`` (SI) are multiplied by ``value_scale``.
    ``column`` is the full result header, e.g. ``'Directional Deformation (mm)'``."""
    s = 1.0 / length_factor(length_unit, "length_unit")
    head = ["Node Number", f"X Location ({length_unit})", f"Y Location ({length_unit})"]
    head += [f"Z Location ({length_unit})"] if with_z else []
    rows = ["\t".join(head + [column])]
    pts = np.asarray(points, dtype=np.float64)
    vals = np.asarray(values, dtype=np.float64)
    for k in (range(len(node_ids)) if order is None else order):
        f = [str(int(node_ids[k])), repr(float(pts[k, 0] * s)), repr(float(pts[k, 1] * s))]
        f += ["0."] if with_z else []
        rows.append("\t".join(f + [repr(float(vals[k] * value_scale))]))
    return "\n".join(rows) + "\n"


def _unit_scales(length_unit: str, velocity_unit: str, stress_unit: str) -> dict[str, float]:
    return {"length": 1.0 / length_factor(length_unit, "length_unit"),
            "velocity": 1.0 / velocity_factor(velocity_unit, "velocity_unit"),
            "stress": 1.0 / stress_factor(stress_unit, "stress_unit")}


def write_results(folder: str | os.PathLike, traj: Trajectory, node_ids: Sequence[int] | None = None, *,
                  length_unit: str = "mm", velocity_unit: str = "mm/s", stress_unit: str = "MPa",
                  times_file: bool = True,
                  table_options: Callable[[str, int], Mapping[str, Any]] | None = None) -> None:
    """Write ``traj``'s fields as Mechanical text tables into ``folder`` (replaced atomically as a whole).

    One file per result per frame (:func:`result_file` names), plus ``times.txt`` [s] unless
    ``times_file=False``. ``node_ids``: ANSYS node numbers (default 1..N). ``table_options(key, frame)``
    may return per-table overrides of :func:`format_table` (``order=`` a row permutation, ``with_z=``),
    e.g. to test the reader on shuffled rows; Mechanical itself writes rows by node number.
    """
    folder = Path(folder)
    try:
        scales = _unit_scales(length_unit, velocity_unit, stress_unit)
    except ValueError as err:
        raise ExportError(f"{folder}: {err}") from None
    units = {"length": length_unit, "velocity": velocity_unit, "stress": stress_unit}
    ids = np.arange(1, traj.n_nodes + 1) if node_ids is None else np.asarray(node_ids)
    if len(ids) != traj.n_nodes:
        raise ExportError(f"{folder}: {len(ids)} node numbers for {traj.n_nodes} nodes")
    fields = {"deformation": np.asarray(traj.displacement), "velocity": np.asarray(traj.velocity),
              "stress": np.asarray(traj.von_mises)}
    with _atomic_dir(folder) as tmp:
        for k in range(traj.n_frames):
            for key in FRAME_KEYS:
                kind, _, comp = key.partition("_")
                label, quantity = RESULT_COLUMNS[kind]
                values = fields[kind][k] if kind == "stress" else fields[kind][k, :, "xy".index(comp)]
                opts = dict(table_options(key, k) or {}) if table_options else {}
                text = format_table(ids, traj.points, values, column=f"{label} ({units[quantity]})",
                                    length_unit=length_unit, value_scale=scales[quantity], **opts)
                (tmp / result_file(key, k)).write_text(text)
        if times_file:
            (tmp / "times.txt").write_text("\n".join(repr(float(t)) for t in np.asarray(traj.times)) + "\n")


# ---- one trajectory -> one run folder, a dataset -> a folder of run folders ------------------------
def part_map(part_names: Sequence[str]) -> dict[str, int]:
    """Part name -> MAPDL material number (part id + 1)."""
    return {name: pid + 1 for pid, name in enumerate(part_names)}


def parts_string(part_names: Sequence[str]) -> str:
    """The ``--parts`` value that maps the exported material numbers back: ``"ball=1,CG=2,..."``."""
    return ",".join(f"{name}={mat}" for name, mat in part_map(part_names).items())


# meta keys the importer sets itself (and the solver's wall time); everything else is carried over in
# run.json "meta"
_IMPORTER_KEYS = OWN_META | {"wall_time_s"}


def _options(length_unit, velocity_unit, stress_unit, units_line) -> dict[str, Any]:
    return {"length_unit": length_unit, "velocity_unit": velocity_unit, "stress_unit": stress_unit,
            "units_line": bool(units_line)}


def export_trajectory(traj: Trajectory, run_dir: str | os.PathLike, *, length_unit: str = "mm",
                      velocity_unit: str = "mm/s", stress_unit: str = "MPa", units_line: bool = False,
                      source: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """Write one run folder (atomically): ``model.cdb``, ``results/``, ``scene.json`` (when the trajectory's
    meta has a scene) and ``run.json``; return the run.json dict.

    run.json: ``format``, the export ``options`` (units), ``import`` (the importer settings that give the
    trajectory back: ``parts`` string, ``length_unit``, ``fixed`` = the FIXED node component,
    ``part_names``), ``materials`` {part: material number}, ``components``, ``node_numbers``, ``meta`` (the
    trajectory's meta keys the importer does not set, e.g. ``scene_params``) and ``source``."""
    run_dir = Path(run_dir)
    where = str(run_dir)
    meta = dict(traj.meta or {})
    names = meta.get("part_names")
    if not names and meta.get("scene"):
        from pcmgn_jax.scene import Scene
        names = Scene.from_dict(meta["scene"]).part_names
    if not names:
        raise ExportError(f"{where}: the trajectory's meta has no 'part_names' (or 'scene'); "
                          "cannot name the materials")
    names = list(names)
    try:
        traj.validate(where)
    except ValueError as err:
        raise ExportError(str(err)) from None
    comps: dict[str, tuple[str, list[int]]] = {}
    for pid, name in enumerate(names):
        cname = name.upper()
        if _COMPONENT_RE.match(cname):
            comps[cname] = ("ELEM", (np.nonzero(np.asarray(traj.cell_part) == pid)[0] + 1).tolist())
    fixed = np.nonzero(np.asarray(traj.node_type) == len(names))[0] + 1
    if len(fixed):
        comps[FIXED_COMPONENT] = ("NODE", fixed.tolist())
    run = {
        "format": EXPORT_FORMAT, "format_version": 1,
        "mesh": MESH_FILE, "results": RESULTS_DIR,
        "options": _options(length_unit, velocity_unit, stress_unit, units_line),
        "import": {"parts": parts_string(names), "part_names": names, "length_unit": length_unit,
                   "fixed": FIXED_COMPONENT if len(fixed) else "none"},
        "materials": part_map(names),
        "components": {name: c for name, c in zip(names, (n.upper() for n in names)) if c in comps},
        "node_numbers": "ANSYS node i + 1 = trajectory node i; element e + 1 = cell e",
        "analysis": meta.get("analysis") or (meta.get("scene") or {}).get("analysis"),
        "n_nodes": traj.n_nodes, "n_cells": int(len(traj.cells)), "n_frames": traj.n_frames,
        "meta": {k: v for k, v in meta.items() if k not in _IMPORTER_KEYS},
        "source": dict(source or {}),
    }
    run = to_jsonable(run, f"{run_dir / RUN_FILE}")
    with _atomic_dir(run_dir) as tmp:
        write_cdb(tmp / MESH_FILE, traj, unit=length_unit, units_line=units_line, components=comps)
        write_results(tmp / RESULTS_DIR, traj, length_unit=length_unit, velocity_unit=velocity_unit,
                      stress_unit=stress_unit)
        if meta.get("scene"):
            (tmp / SCENE_FILE).write_text(json.dumps(to_jsonable(meta["scene"]), indent=1))
        (tmp / RUN_FILE).write_text(json.dumps(run, indent=1))   # last: marks a complete run folder
    return run


def find_trajectories(data_dir: str | os.PathLike) -> dict[str, list[Path]]:
    """{split: sorted trajectory stems} of a dataset folder: every ``DIR/<split>/NAME.json`` that is a
    trajectory sidecar (hidden folders such as ``.cache`` are skipped)."""
    root = Path(data_dir)
    if not root.is_dir():
        raise ExportError(f"{root}: not a folder (give the dataset folder that holds <split>/NAME.json)")
    out: dict[str, list[Path]] = {}
    for split in sorted(p for p in root.iterdir() if p.is_dir() and not p.name.startswith(".")):
        stems = []
        for side in sorted(split.glob("*.json")):
            try:
                read_sidecar(side.with_suffix(""))
            except ValueError:
                continue
            stems.append(side.with_suffix(""))
        if stems:
            out[split.name] = stems
    if not out:
        raise ExportError(f"{root}: no trajectories in {root}/<split>/ (NAME.json + NAME.xdmf/.h5)")
    return out


def _file_sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _export_done(run_dir: Path, sha: str, options: Mapping[str, Any]) -> bool:
    try:
        run = json.loads((run_dir / RUN_FILE).read_text())
    except (OSError, ValueError):
        return False
    return (run.get("format") == EXPORT_FORMAT and run.get("source", {}).get("sha256") == sha
            and run.get("options") == dict(options) and (run_dir / MESH_FILE).is_file()
            and (run_dir / RESULTS_DIR).is_dir())


def _readme(splits: Mapping[str, list[Path]], out: Path, parts: str, length_unit: str) -> str:
    n = sum(len(v) for v in splits.values())
    return f"""# ANSYS-format export of a trajectory dataset

Written by `python -m experiments.export_ansys` ({n} trajectories; splits: {", ".join(splits)}).
Layout: `<split>/<run>/model.cdb` (MAPDL archive, CDWRITE layout, no /UNITS line: length unit
{length_unit}), `<split>/<run>/results/` (Mechanical "Export -> Text File" tables,
`deformation_x_000.txt` ..., `times.txt` [s]), `scene.json` (that run's scene) and `run.json`
(importer settings, materials, source hash).

Materials: {parts} (material number = part id + 1); element components named after the
parts (upper case); node component FIXED = the fixed nodes. ANSYS node i + 1 = trajectory node i.

Import all runs back (resumable; run.json and scene.json of each run give --parts, --length_unit,
--fixed and the scene):

    python -m experiments.import_ansys --exports {out} --out DIR
"""


def export_dataset(data_dir: str | os.PathLike, out_dir: str | os.PathLike, *, length_unit: str = "mm",
                   velocity_unit: str = "mm/s", stress_unit: str = "MPa", units_line: bool = False,
                   splits: Sequence[str] | None = None, progress: bool = True) -> dict[str, int]:
    """Export every trajectory of ``data_dir/<split>/`` to ``out_dir/<split>/<stem>/`` (a run folder each,
    see :func:`export_trajectory`) and write ``out_dir/README.md`` + ``out_dir/export.json``.

    Resumable: a run folder whose run.json records the same source hash and options is kept.
    Returns {"exported": n, "skipped": m}."""
    from tqdm.auto import tqdm

    out = Path(out_dir)
    found = find_trajectories(data_dir)
    if splits:
        missing = sorted(set(splits) - set(found))
        if missing:
            raise ExportError(f"{data_dir}: no split(s) {missing}; have {sorted(found)}")
        found = {k: v for k, v in found.items() if k in splits}
    options = _options(length_unit, velocity_unit, stress_unit, units_line)
    try:
        _unit_scales(length_unit, velocity_unit, stress_unit)
    except ValueError as err:
        raise ExportError(f"{out}: {err}") from None
    names_seen: list[str] | None = None
    counts = {"exported": 0, "skipped": 0}
    items = [(split, stem) for split, stems in found.items() for stem in stems]
    for split, stem in tqdm(items, desc=f"export {out.name}", unit="traj", disable=not progress,
                            dynamic_ncols=True):
        side = read_sidecar(stem)
        run_dir = out / split / stem.name
        names = side.get("part_names")
        if names_seen is None:
            names_seen = names
        elif names != names_seen:
            raise ExportError(f"{stem}.json: part names {names} differ from the dataset's {names_seen}")
        if _export_done(run_dir, side["sha256"], options):
            counts["skipped"] += 1
            continue
        traj = read_trajectory(stem)
        export_trajectory(traj, run_dir, length_unit=length_unit, velocity_unit=velocity_unit,
                          stress_unit=stress_unit, units_line=units_line,
                          source={"trajectory": str(stem), "sha256": side["sha256"]})
        counts["exported"] += 1
    parts = parts_string(names_seen or [])
    summary = {"format": EXPORT_FORMAT, "format_version": 1, "source": str(data_dir), "options": options,
               "parts": parts, "part_names": names_seen, "materials": part_map(names_seen or []),
               "splits": {k: [s.name for s in v] for k, v in found.items()},
               "import_command": f"python -m experiments.import_ansys --exports {out} --out DIR"}
    _write_text_atomic(out / "export.json", json.dumps(to_jsonable(summary), indent=1) + "\n")
    _write_text_atomic(out / "README.md", _readme(found, out, parts, length_unit))
    return counts
