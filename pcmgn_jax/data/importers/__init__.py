"""Importers: ANSYS Mechanical text exports, meshio meshes/time series, LS-DYNA d3plot -> Trajectory
(CalculiX ``.frd`` results: :mod:`pcmgn_jax.data.importers.frd` and :mod:`pcmgn_jax.data.calculix`).

Every importer returns a validated :class:`~pcmgn_jax.trajectory.Trajectory` in SI units and writes
nothing (write it with ``trajectory_io.write_trajectory``, which is atomic). Bad input raises
:class:`InputFileError` (a ``ValueError``) naming the file and the line / node / element / column.

Parts
-----
Part ids are the positions in ``part_names`` (``scene.part_names`` when a scene is given:
0 = ball, 1..n = layers top to bottom). ``parts`` maps each part name to the mesh groups that form it::

    parts = {"ball": 1, "CG": 2, "OCA1": [3], ...}        # ints: ANSYS material number (cdb "mat"),
                                                          # LS-DYNA part id, or value of a meshio
                                                          # cell-data array (``part_field``)
    parts = {"ball": "BALL", "CG": "GLASS", ...}          # strs: ANSYS element component (CMBLOCK),
                                                          # meshio cell set, LS-DYNA part title
Default (``parts=None``): each part name is looked up as a component / cell set / part title of the
same name (case-insensitive). Every solid cell must belong to exactly one part; cells of unmapped
groups are an error unless ``ignore_unmapped=True`` (ANSYS contact/target/surface element types
169-178, 151-154 and MESH200 are always skipped, with a note). ``node_part`` of a node shared by several parts is the
stiffest part (largest Young's modulus in the scene; without a scene: the smallest part id).
``node_type`` = ``node_part``, or ``len(part_names)`` for fixed nodes: ``fixed="bottom"`` (nodes at
the minimum height, the clamped plate bottom), a node component / node-set name, a sequence of node
numbers, or ``None``.

ANSYS Mechanical "Export -> Text File" results (``import_ansys_text``)
---------------------------------------------------------------------
One tab-separated nodal table per result per frame, as Mechanical writes it::

    Node Number<TAB>X Location (mm)<TAB>Y Location (mm)<TAB>Z Location (mm)<TAB>Directional Deformation (mm)

Units are read from the headers and converted to SI: lengths m, mm, µm/um, cm, in; velocity
<length>/<s|ms|µs>; stress Pa, kPa, MPa, GPa, psi, N/mm^2. Result columns: ``Directional
Deformation``, ``Directional Velocity`` (the X or Y orientation is chosen in Mechanical and not in
the header, so it comes from the file name) and ``Equivalent (von-Mises) Stress``. ``Z Location`` is
optional. X/Y locations are checked against the mesh (``location_tol`` [m]).

File naming convention inside the results folder (frames numbered 0..T-1, no gaps)::

    deformation_x_000.txt  deformation_y_000.txt  velocity_x_000.txt  velocity_y_000.txt  stress_000.txt
    deformation_x_001.txt  ...
    times.txt              optional: one frame time per line [s]; otherwise ``output_dt`` gives t_k = k*dt

or a manifest ``frames.json`` in the folder that lists the files (paths relative to the folder)::

    {"time_unit": "s", "frames": [{"time": 0.0, "deformation_x": "UX_0.txt", "deformation_y": "UY_0.txt",
                                   "velocity_x": "VX_0.txt", "velocity_y": "VY_0.txt", "stress": "S_0.txt"}, ...]}

Meshes (``read_mesh``)
----------------------
* MAPDL ``.cdb`` archives and Workbench input files (``ds.dat``; any ``.dat``/``.inp``/... holding an
  NBLOCK) through ``read_cdb`` (module ``cdb``): NBLOCK nodes (any Fortran format), EBLOCK elements
  in SOLID form (non-SOLID EBLOCKs, i.e. surface/contact elements, are skipped with a note),
  ETBLOCK / ET / KEYOPT element types (2D structural solids PLANE182/42/162 and PLANE183/82, the
  8-node quads reduced to their corners; shells and other types refused; KEYOPT(3) must match the
  scene's analysis), CMBLOCK components, ``/UNITS``. A file without ``/UNITS`` needs ``length_unit``
  (CLI ``--length_unit``).
* Anything meshio reads (Abaqus .inp, Gmsh .msh, Nastran, VTU, ...): quads only (vertex/line cells
  are ignored); parts from cell sets or an integer cell-data array ``part_field``. ANSYS node numbers
  are the integer point-data array ``node_id_field`` if given, else meshio index + 1.

meshio time series (``import_meshio_series``): an XDMF time series or a list of per-frame files
(e.g. VTU), each with point data displacement (N,2|3), velocity (N,2|3) and von Mises (N,)
(names configurable), same mesh in every frame. LS-DYNA (``import_d3plot``): optional, needs
``pip install -e ".[dyna]"`` (lasso-python); 2D solids are shells in the d3plot.

A folder of runs (``EXPORTS/<split>/<run>/model.cdb + results/ [+ scene.json, run.json]``, what
``pcmgn_jax.data.exporters`` / ``python -m experiments.export_ansys`` write) -> ``OUT/<split>/<run>``
trajectory files: ``import_ansys_dataset`` (module ``runs``; CLI ``python -m experiments.import_ansys
--exports EXPORTS --out OUT``), atomic per run, resumable, one-line errors naming the run folder.

Region of interest: crop an imported trajectory around the contact with
``pcmgn_jax.trajectory.crop_trajectory`` (CLI ``--roi_radius`` / ``--roi_depth`` / ``--roi_ball_height``,
metres); the rule is ``pcmgn_jax.geometry.roi_crop``, shared with the generator's mesh.

Modules: ``units`` (unit factors), ``parts`` (ImportedMesh, part mapping), ``cdb`` (MAPDL archives and
input files), ``meshes`` (meshio meshes, ``read_mesh`` dispatch), ``ansys_text`` (Mechanical text tables,
frame discovery, node matching), ``series`` (meshio time series), ``d3plot`` (LS-DYNA), ``build``
(node parts / types, Trajectory assembly), ``errors`` (InputFileError, text reading), ``runs`` (folders of runs -> a
dataset folder).
"""
from __future__ import annotations

from pcmgn_jax.data.importers.ansys_text import (
                                                 FRAME_KEYS,
                                                 RESULT_KINDS,
                                                 AnsysTable,
                                                 import_ansys_text,
                                                 read_ansys_table,
)
from pcmgn_jax.data.importers.build import build_trajectory, fixed_mask, node_part
from pcmgn_jax.data.importers.cdb import fortran_layout, read_cdb
from pcmgn_jax.data.importers.d3plot import (
                                                 D3plotPart,
                                                 d3plot_parts,
                                                 decode_title,
                                                 import_d3plot,
                                                 read_d3plot_mesh,
                                                 von_mises_from_tensor,
)
from pcmgn_jax.data.importers.errors import InputFileError
from pcmgn_jax.data.importers.meshes import is_mapdl_file, read_mesh, read_meshio_mesh
from pcmgn_jax.data.importers.parts import ImportedMesh, Mesh, parse_parts
from pcmgn_jax.data.importers.runs import (
                                                 ImportReport,
                                                 apply_roi,
                                                 find_runs,
                                                 import_ansys_dataset,
                                                 import_ansys_run,
                                                 run_settings,
)
from pcmgn_jax.data.importers.series import import_meshio_series
from pcmgn_jax.data.importers.units import (
                                                 ANSYS_UNIT_SYSTEMS,
                                                 LENGTH_UNITS,
                                                 STRESS_UNITS,
                                                 TIME_UNITS,
                                                 length_factor,
                                                 stress_factor,
                                                 time_factor,
                                                 velocity_factor,
)

__all__ = ["ANSYS_UNIT_SYSTEMS", "AnsysTable", "D3plotPart", "FRAME_KEYS", "ImportReport", "ImportedMesh",
           "InputFileError", "apply_roi", "find_runs", "import_ansys_dataset", "import_ansys_run", "run_settings",
           "LENGTH_UNITS", "Mesh", "RESULT_KINDS", "STRESS_UNITS", "TIME_UNITS", "build_trajectory",
           "d3plot_parts", "decode_title", "fixed_mask", "fortran_layout", "import_ansys_text", "import_d3plot",
           "import_meshio_series", "is_mapdl_file", "length_factor", "node_part", "parse_parts",
           "read_ansys_table", "read_cdb", "read_d3plot_mesh", "read_mesh", "read_meshio_mesh",
           "stress_factor", "time_factor", "velocity_factor", "von_mises_from_tensor"]
