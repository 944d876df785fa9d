"""ANSYS Mechanical text exports into trajectory files: one run from its files (:func:`import_files`) or a
whole folder of run folders (:func:`import_exports`), as ``python -m experiments.import_ansys`` does.

Settings are the importers' (:data:`pcmgn_jax.data.importers.runs.RUN_SETTINGS`): ``parts`` (a part map,
:func:`pcmgn_jax.data.importers.parts.parse_parts`), ``part_names`` (names by part id, without a scene),
``length_unit`` of the mesh, ``fixed`` (bottom | none | a node component; default bottom), ``output_dt``
[s] (frame interval without times.txt), ``location_tol`` [m], ``ignore_unmapped``; ``roi``: crop limits
[m] (radius, depth, ball_height; None = no limit, :func:`pcmgn_jax.data.importers.runs.apply_roi`).
Errors are ``ValueError`` naming the flag or file.
"""
from __future__ import annotations

import sys
from typing import Mapping, Sequence

from pcmgn_jax.data.importers.ansys_text import import_ansys_text
from pcmgn_jax.data.importers.meshes import read_mesh
from pcmgn_jax.data.importers.runs import ImportReport, apply_roi, import_ansys_dataset
from pcmgn_jax.data.trajectory_io import write_trajectory
from pcmgn_jax.errors import SettingError
from pcmgn_jax.scene import Scene
from pcmgn_jax.trajectory import Trajectory


def import_files(mesh: str, results: str, out: str, *, scene: Scene | None = None,
                 part_names: Sequence[str] | None = None, parts: Mapping | None = None,
                 length_unit: str | None = None, fixed: str | None = None, output_dt: float | None = None,
                 location_tol: float | None = None, ignore_unmapped: bool = False,
                 roi: Mapping[str, float | None] | None = None) -> tuple[Trajectory, str]:
    """Import one run (``mesh``: .cdb, Workbench .dat or meshio-readable mesh; ``results``: the folder of
    exported tables) and write it atomically to OUT.xdmf/.h5/.json; notes (mesh, region of interest) go to
    stderr. Returns (trajectory, content sha256). Nothing is written unless the whole import succeeds."""
    imported = read_mesh(mesh, scene=scene, part_names=None if scene else part_names, parts=parts,
                         length_unit=length_unit, ignore_unmapped=ignore_unmapped)
    for note in imported.notes:
        print(f"note: {note}", file=sys.stderr)
    fixed = fixed or "bottom"
    traj = import_ansys_text(imported, results, scene=scene, part_names=part_names, output_dt=output_dt,
                             fixed=None if fixed == "none" else fixed, location_tol=location_tol)
    traj, note = apply_roi(traj, roi)
    if note:
        print(note, file=sys.stderr)
    return traj, write_trajectory(traj, out)


def import_exports(exports: str, out: str, *, scene: Scene | None = None, part_names: Sequence[str] | None = None,
                   parts: Mapping | None = None, length_unit: str | None = None, fixed: str | None = None,
                   output_dt: float | None = None, location_tol: float | None = None,
                   ignore_unmapped: bool = False, roi: Mapping[str, float | None] | None = None,
                   progress: bool = True) -> ImportReport:
    """Import every run folder EXPORTS/<split>/<run>/ into OUT/<split>/<run>.xdmf/.h5/.json
    (:func:`pcmgn_jax.data.importers.runs.import_ansys_dataset`); the settings are the defaults of the
    runs that set nothing in their own files. Raises ``ValueError`` without ``out``."""
    if not out:
        raise SettingError("out", "exports need an output folder (writes OUT/<split>/<run>.xdmf/.h5/.json)")
    defaults = {"parts": parts, "part_names": part_names, "length_unit": length_unit, "fixed": fixed,
                "output_dt": output_dt, "location_tol": location_tol, "ignore_unmapped": ignore_unmapped or None}
    return import_ansys_dataset(exports, out, defaults=defaults, scene=scene, roi=roi, progress=progress)
