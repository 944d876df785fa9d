"""A folder of ANSYS runs -> a folder of trajectory files: :func:`import_ansys_dataset`.

Layout read (what ``python -m experiments.export_ansys`` writes, and what to arrange your own exports as)::

    EXPORTS/<split>/<run>/model.cdb        the mesh (or the only *.cdb / *.dat in the folder, or run.json "mesh")
    EXPORTS/<split>/<run>/results/         Mechanical text tables (naming: see importers/__init__.py)
    EXPORTS/<split>/<run>/scene.json       optional: this run's scene (or scene.toml)
    EXPORTS/<split>/<run>/run.json         optional: {"mesh": ..., "results": ...,
                                                       "import": {"parts": "ball=1,...", "part_names": [...],
                                                                  "length_unit": "mm", "fixed": "FIXED",
                                                                  "output_dt": ..., "location_tol": ...,
                                                                  "ignore_unmapped": false},
                                                       "meta": {...}}   # copied into the trajectory's meta

Written: ``OUT/<split>/<run>.xdmf/.h5/.json`` (``write_trajectory``, atomic per run). Hidden folders
(names starting with ``.``) are skipped.

Settings per run: what the run folder says (its scene file, run.json ``import``) wins over the
arguments, which are the defaults for runs that say nothing. This way a dataset whose runs have
different scenes (ball radius, layer thicknesses) keeps each run's own scene. ``run.json`` ``meta``
keys (e.g. ``scene_params``) are added to the trajectory's meta unless the importer sets them itself.

Resumable: the trajectory's meta ``import.inputs_sha256`` is a hash of the run's input files (mesh,
every file in the results folder, scene, run.json) and the settings; a run whose output reads back
(hash-verified) with the same fingerprint is skipped. A run that fails is reported with a one-line
error naming its folder (and the file, line, ...), nothing is written for it, and the other runs go on.
"""
from __future__ import annotations

import hashlib
import json
import os
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

from pcmgn_jax.atomic import to_jsonable
from pcmgn_jax.data.importers.ansys_text import import_ansys_text
from pcmgn_jax.data.importers.errors import InputFileError
from pcmgn_jax.data.importers.meshes import read_mesh
from pcmgn_jax.data.importers.parts import parse_parts
from pcmgn_jax.data.trajectory_io import TrajectoryFileError, read_sidecar, read_trajectory, write_trajectory
from pcmgn_jax.errors import SettingError
from pcmgn_jax.geometry import RoiCropError
from pcmgn_jax.scene import Scene
from pcmgn_jax.trajectory import Trajectory, crop_trajectory

__all__ = ["ImportReport", "RUN_SETTINGS", "apply_roi", "find_runs", "import_ansys_dataset", "import_ansys_run",
           "run_settings"]

RUN_FILE = "run.json"            # names inside a run folder (the exporter writes the same, from here)
MESH_FILE = "model.cdb"
RESULTS_DIR = "results"
SCENE_FILES = ("scene.json", "scene.toml")
MESH_SUFFIXES = (".cdb", ".dat")
RUN_SETTINGS = ("parts", "part_names", "length_unit", "fixed", "output_dt", "location_tol", "ignore_unmapped")
ROI_PARAMS = ("radius", "depth", "ball_height")
# meta keys the importer sets; run.json "meta" cannot override them
OWN_META = frozenset({"units", "source", "analysis", "scene", "design", "output_dt", "solver", "energy",
                       "part_names", "node_ids", "import", "roi", "n_nodes_full", "node_map"})


def apply_roi(traj: Trajectory, roi: Mapping[str, float | None] | None) -> tuple[Trajectory, str | None]:
    """``traj`` cropped to the region of interest (``roi``: radius / depth / ball_height [m], None = no
    limit) and a note, or ``(traj, None)`` when no limit is given. Errors name the flag ``--roi_<param>``."""
    limits = {k: (roi or {}).get(k) for k in ROI_PARAMS}
    if all(v is None for v in limits.values()):
        return traj, None
    full = traj.n_nodes
    try:
        traj, _ = crop_trajectory(traj, **{k: float("inf") if v is None else v for k, v in limits.items()})
    except RoiCropError as err:
        raise SettingError(f"roi_{err.param}", f"{limits[err.param]}: {err}") from None
    return traj, f"region of interest: kept {traj.n_nodes} of {full} nodes"


def find_runs(exports: str | os.PathLike) -> dict[str, list[Path]]:
    """{split: sorted run folders} of ``EXPORTS/<split>/<run>/`` (hidden folders skipped)."""
    root = Path(exports)
    if not root.is_dir():
        raise InputFileError(f"{root}: exports folder not found (expected {root}/<split>/<run>/model.cdb + results/)")
    out: dict[str, list[Path]] = {}
    for split in sorted(p for p in root.iterdir() if p.is_dir() and not p.name.startswith(".")):
        runs = sorted(p for p in split.iterdir() if p.is_dir() and not p.name.startswith("."))
        if runs:
            out[split.name] = runs
    if not out:
        raise InputFileError(f"{root}: no run folders (expected {root}/<split>/<run>/model.cdb + results/)")
    return out


def _read_json(path: Path) -> dict[str, Any]:
    try:
        data = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise InputFileError(f"{path}: cannot read JSON: {err}") from None
    if not isinstance(data, dict):
        raise InputFileError(f"{path}: expected a JSON object")
    return data


def run_settings(run_dir: str | os.PathLike, defaults: Mapping[str, Any] | None = None,
                 scene: Scene | None = None) -> dict[str, Any]:
    """The resolved settings of one run folder: ``mesh``, ``results`` (paths), ``scene`` (Scene | None),
    ``scene_file``, ``meta`` and the :data:`RUN_SETTINGS` (run.json ``import`` over ``defaults``)."""
    run_dir = Path(run_dir)
    run_path = run_dir / RUN_FILE
    run = _read_json(run_path) if run_path.is_file() else {}
    own = run.get("import") or {}
    if not isinstance(own, dict):
        raise InputFileError(f"{run_path}: 'import' must be an object with keys {list(RUN_SETTINGS)}")
    unknown = sorted(set(own) - set(RUN_SETTINGS))
    if unknown:
        raise InputFileError(f"{run_path}: unknown key(s) {unknown} in 'import'; known: {list(RUN_SETTINGS)}")
    out: dict[str, Any] = {k: (defaults or {}).get(k) for k in RUN_SETTINGS}
    out.update({k: v for k, v in own.items() if v is not None})
    if isinstance(out["parts"], str):
        out["parts"] = parse_parts(out["parts"])
    # the mesh
    if run.get("mesh"):
        mesh = run_dir / run["mesh"]
    else:
        named = [run_dir / MESH_FILE] if (run_dir / MESH_FILE).is_file() else []
        cands = named or sorted(p for p in run_dir.iterdir() if p.is_file() and p.suffix.lower() in MESH_SUFFIXES)
        if len(cands) != 1:
            what = "no mesh file" if not cands else f"{len(cands)} mesh files {[p.name for p in cands]}"
            raise InputFileError(f"{run_dir}: {what}; put the archive there as model.cdb "
                                 f"(or name it in {RUN_FILE} \"mesh\")")
        mesh = cands[0]
    if not mesh.is_file():
        raise InputFileError(f"{mesh}: mesh file not found (named by {run_path} \"mesh\")")
    results = run_dir / run.get("results", RESULTS_DIR)
    if not results.is_dir():
        raise InputFileError(f"{results}: results folder not found (run folder {run_dir}; the text tables "
                             f"go into {run_dir}/results/)")
    # the scene: the run's own file wins over the default
    scene_file = next((run_dir / n for n in SCENE_FILES if (run_dir / n).is_file()), None)
    if scene_file is not None:
        try:
            scene = Scene.load(scene_file)
        except (OSError, ValueError, KeyError, TypeError) as err:
            raise InputFileError(f"{scene_file}: invalid scene: {err}") from None
    meta = run.get("meta") or {}
    if not isinstance(meta, dict):
        raise InputFileError(f"{run_path}: 'meta' must be an object")
    out.update({"mesh": mesh, "results": results, "scene": scene, "scene_file": scene_file, "meta": meta,
                "run_file": run_path if run_path.is_file() else None})
    return out


def _fingerprint(s: Mapping[str, Any], roi: Mapping[str, Any] | None) -> str:
    h = hashlib.sha256()

    def add_file(p: Path) -> None:
        h.update(f"{p.name}|{p.stat().st_size}|".encode())
        with open(p, "rb") as f:
            for block in iter(lambda: f.read(1 << 20), b""):
                h.update(block)

    add_file(s["mesh"])
    for p in sorted(s["results"].iterdir()):
        if p.is_file():
            add_file(p)
    for p in (s["scene_file"], s["run_file"]):
        if p is not None:
            add_file(p)
    settings = {k: s[k] for k in RUN_SETTINGS}
    settings["scene"] = s["scene"].to_dict() if s["scene"] is not None else None
    settings["roi"] = {k: (roi or {}).get(k) for k in ROI_PARAMS}
    h.update(json.dumps(to_jsonable(settings), sort_keys=True).encode())
    return h.hexdigest()


def import_ansys_run(run_dir: str | os.PathLike, *, defaults: Mapping[str, Any] | None = None,
                     scene: Scene | None = None, roi: Mapping[str, float | None] | None = None,
                     settings: Mapping[str, Any] | None = None) -> tuple[Trajectory, list[str]]:
    """One run folder -> (Trajectory, notes). ``defaults``: :data:`RUN_SETTINGS` for what the folder does
    not set; ``scene``: the default scene. Writes nothing."""
    s = dict(settings) if settings is not None else run_settings(run_dir, defaults, scene)
    scene = s["scene"]
    names = s["part_names"]
    if scene is None and not names:
        raise InputFileError(f"{run_dir}: no scene (scene.json / scene.toml in the folder or --scene) and no "
                             f"part names (--part_names or {RUN_FILE} import.part_names)")
    fixed = s["fixed"] or "bottom"
    mesh = read_mesh(s["mesh"], scene=scene, part_names=None if scene else names, parts=s["parts"],
                     length_unit=s["length_unit"], ignore_unmapped=bool(s["ignore_unmapped"]))
    notes = [f"note: {n}" for n in mesh.notes]
    traj = import_ansys_text(mesh, s["results"], scene=scene, part_names=None if scene else names,
                             output_dt=s["output_dt"], fixed=None if fixed == "none" else fixed,
                             location_tol=s["location_tol"])
    for k, v in s["meta"].items():
        if k not in OWN_META:
            traj.meta[k] = v
    traj.meta["import"]["run"] = str(run_dir)
    traj, note = apply_roi(traj, roi)
    if note:
        notes.append(note)
    return traj, notes


@dataclass
class ImportReport:
    """What :func:`import_ansys_dataset` did: output stems imported / skipped, and (run folder, message)
    of every failed run."""

    imported: list[Path] = field(default_factory=list)
    skipped: list[Path] = field(default_factory=list)
    failed: list[tuple[Path, str]] = field(default_factory=list)


def _done(stem: Path, fingerprint: str) -> bool:
    try:
        side = read_sidecar(stem)
        if (side.get("import") or {}).get("inputs_sha256") != fingerprint:
            return False
        read_trajectory(stem, verify=True)
    except TrajectoryFileError:
        return False
    return True


def import_ansys_dataset(exports: str | os.PathLike, out: str | os.PathLike, *,
                         defaults: Mapping[str, Any] | None = None, scene: Scene | None = None,
                         roi: Mapping[str, float | None] | None = None, splits: Sequence[str] | None = None,
                         progress: bool = True, log: Callable[[str], None] | None = None) -> ImportReport:
    """Import every run folder ``EXPORTS/<split>/<run>/`` into ``OUT/<split>/<run>.xdmf/.h5/.json``.

    ``defaults`` (:data:`RUN_SETTINGS`) and ``scene`` apply to runs whose folder does not set them;
    ``roi``: crop limits [m] (radius, depth, ball_height). Valid finished runs with the same inputs are
    skipped; a failing run is logged (``log``, default stderr) as one line naming its folder and the
    others go on. Returns an :class:`ImportReport`; the caller decides what a failure means."""
    from tqdm.auto import tqdm

    found = find_runs(exports)
    if splits:
        missing = sorted(set(splits) - set(found))
        if missing:
            raise InputFileError(f"{exports}: no split(s) {missing}; have {sorted(found)}")
        found = {k: v for k, v in found.items() if k in splits}
    items = [(split, run) for split, runs in found.items() for run in runs]
    report = ImportReport()
    out = Path(out)
    bar = tqdm(items, desc=f"import {Path(exports).name}", unit="run", disable=not progress, dynamic_ncols=True)
    say = log or (lambda msg: tqdm.write(msg, file=sys.stderr))
    for split, run in bar:
        stem = out / split / run.name
        try:
            s = run_settings(run, defaults, scene)
            fp = _fingerprint(s, roi)
            if _done(stem, fp):
                report.skipped.append(stem)
                continue
            traj, notes = import_ansys_run(run, roi=roi, settings=s)
            traj.meta["import"]["inputs_sha256"] = fp
            write_trajectory(traj, stem)
        except (ValueError, OSError) as err:
            msg = str(err) if not isinstance(err, OSError) else f"{err.strerror or err}"
            msg = " ".join(msg.split("\n"))
            if str(run) not in msg:
                msg = f"{run}: {msg}"
            report.failed.append((run, msg))
            say(f"error: {msg}")
            continue
        for n in notes:
            say(f"{run}: {n}")
        report.imported.append(stem)
    return report
