"""Exporters: trajectories -> other solvers' file formats (the inverse of :mod:`pcmgn_jax.data.importers`).

``ansys``: an MAPDL archive (``.cdb``, CDWRITE layout) and Mechanical "Export -> Text File" result tables
in the naming convention the ANSYS text importer reads; :func:`export_dataset` writes a whole dataset
as run folders ``OUT/<split>/<run>/{model.cdb, results/, scene.json, run.json}`` that
:func:`pcmgn_jax.data.importers.import_ansys_dataset` (CLI ``python -m experiments.import_ansys
--exports OUT --out DIR``) reads back. It is how the project makes "your own ANSYS data" from its own
solver runs, and the round trip is tested (tests/data/test_ansys_export.py).

``calculix`` (imported by name, not re-exported here): a scene on the project's mesh as a CalculiX deck
(``write_inp``); :mod:`pcmgn_jax.data.calculix` runs ``ccx`` and reads its ``.frd`` back
(:mod:`pcmgn_jax.data.importers.frd`) into a trajectory (tests/data/test_calculix.py).
"""
from __future__ import annotations

from pcmgn_jax.data.exporters.ansys import (
    EXPORT_FORMAT,
    FIXED_COMPONENT,
    MESH_FILE,
    RESULTS_DIR,
    RUN_FILE,
    SCENE_FILE,
    ExportError,
    export_dataset,
    export_trajectory,
    find_trajectories,
    format_table,
    part_map,
    parts_string,
    result_file,
    write_cdb,
    write_results,
)

__all__ = ["EXPORT_FORMAT", "FIXED_COMPONENT", "MESH_FILE", "RESULTS_DIR", "RUN_FILE", "SCENE_FILE", "ExportError",
           "export_dataset", "export_trajectory", "find_trajectories", "format_table", "part_map",
           "parts_string", "result_file", "write_cdb", "write_results"]
