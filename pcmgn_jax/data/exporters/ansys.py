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
into place (:mod:`pcmgn_jax.atomic`), so a failed or killed export leaves no half-written file or folder.
Errors are :class:`ExportError` (a ``ValueError``) naming the path.

Modules: ``cdb.py`` (the archive), ``tables.py`` (the result tables), ``common.py`` (ExportError, atomic
writes); this one writes run folders and datasets and re-exports the writers.
"""
from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pcmgn_jax.atomic import atomic_write_text, to_jsonable
from pcmgn_jax.data.exporters.cdb import ANALYSIS_KEYOPT3, COMPONENT_RE, write_cdb
from pcmgn_jax.data.exporters.common import ExportError, atomic_folder, export_errors
from pcmgn_jax.data.exporters.tables import (
    format_table,
    result_file,
    unit_scales,
    write_results,
)
from pcmgn_jax.data.importers.runs import (
    MESH_FILE,
    OWN_META,
    RESULTS_DIR,
    RUN_FILE,
    SCENE_FILES,
)
from pcmgn_jax.data.trajectory_io import read_sidecar, read_trajectory
from pcmgn_jax.trajectory import Trajectory

__all__ = ["ANALYSIS_KEYOPT3", "EXPORT_FORMAT", "FIXED_COMPONENT", "MESH_FILE", "RESULTS_DIR", "RUN_FILE",
           "SCENE_FILE", "ExportError", "export_dataset", "export_trajectory", "find_trajectories",
           "format_table", "part_map", "parts_string", "result_file", "write_cdb", "write_results"]

EXPORT_FORMAT = "pcmgn_jax.ansys_export"
SCENE_FILE = SCENE_FILES[0]
FIXED_COMPONENT = "FIXED"


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
        if COMPONENT_RE.match(cname):
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
        "n_nodes": traj.n_nodes, "n_cells": len(traj.cells), "n_frames": traj.n_frames,
        "meta": {k: v for k, v in meta.items() if k not in _IMPORTER_KEYS},
        "source": dict(source or {}),
    }
    run = to_jsonable(run, f"{run_dir / RUN_FILE}")
    with atomic_folder(run_dir) as tmp:
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
        unit_scales(length_unit, velocity_unit, stress_unit)
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
    for name, text in (("export.json", json.dumps(to_jsonable(summary), indent=1) + "\n"),
                       ("README.md", _readme(found, out, parts, length_unit))):
        with export_errors(out / name):
            atomic_write_text(out / name, text, parents=True)
    return counts
