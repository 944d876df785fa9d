"""Mesh files: meshio-readable meshes (Abaqus .inp, Gmsh .msh, VTU, Nastran, ...) and the dispatch
``read_mesh`` (MAPDL archives / Workbench input files with an NBLOCK go to :func:`read_cdb`)."""
from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from pcmgn_jax.data.importers.cdb import has_nblock, read_cdb
from pcmgn_jax.data.importers.errors import InputFileError
from pcmgn_jax.data.importers.parts import ImportedMesh, assign_parts, finish_mesh, part_specs, resolve_part_names
from pcmgn_jax.data.importers.units import length_factor
from pcmgn_jax.scene import Scene

_LOWER_DIM = {"vertex", "line", "line3"}
# suffixes that may hold MAPDL commands (Workbench writes ds.dat / input.dat; .inp is also Abaqus)
_MAPDL_SUFFIXES = {".cdb", ".dat", ".inp", ".ans", ".mac", ".txt"}


def read_meshio_mesh(path: str | os.PathLike, *, scene: Scene | Mapping | None = None,
                     part_names: Sequence[str] | None = None, parts: Mapping[str, Any] | None = None,
                     part_field: str | None = None, node_id_field: str | None = None,
                     length_unit: str = "m", ignore_unmapped: bool = False, _mesh=None) -> ImportedMesh:
    """Read a 2D quad mesh with part groups through meshio (Abaqus .inp, Gmsh .msh, VTU, Nastran, ...).

    Parts come from ``mesh.cell_sets`` (str entries of ``parts``) or the integer cell-data array
    ``part_field`` (int entries). Node numbers: point-data ``node_id_field`` or index + 1.
    """
    import meshio

    path = Path(path)
    names, _ = resolve_part_names(scene, part_names)
    specs = part_specs(parts, names)
    if _mesh is None:
        try:
            m = meshio.read(path)
        except Exception as err:
            msg = " ".join(f"{type(err).__name__}: {err}".split())[:200]
            raise InputFileError(f"{path}: meshio cannot read it ({msg}); give a mesh in a format meshio "
                                 "reads, or an MAPDL archive (.cdb) / Workbench input file with an NBLOCK") from None
    else:
        m = _mesh
    where = str(path)
    keep_blocks = []
    for b, block in enumerate(m.cells):
        if block.type in _LOWER_DIM:
            continue
        if block.type != "quad":
            raise InputFileError(f"{where}: cell block {b} has {len(block.data)} '{block.type}' cells: "
                                 "not 4-node quads (only linear quads are supported)")
        keep_blocks.append(b)
    if not keep_blocks:
        raise InputFileError(f"{where}: no quad cells")
    cells = np.concatenate([m.cells[b].data for b in keep_blocks]).astype(np.int64)
    cell_ints = None
    if part_field is not None:
        if part_field not in m.cell_data:
            raise InputFileError(f"{where}: cell data {part_field!r} not found; have {sorted(m.cell_data)}")
        cell_ints = np.concatenate([np.asarray(m.cell_data[part_field][b]).reshape(-1)
                                    for b in keep_blocks]).astype(np.int64)
    groups = {}
    for name, per_block in (m.cell_sets or {}).items():
        mask = np.concatenate([np.isin(np.arange(len(m.cells[b].data)),
                                       np.asarray(per_block[b] if per_block[b] is not None else [], np.int64))
                               for b in keep_blocks])
        if mask.any():
            groups[name.lower()] = mask
    cell_part = assign_parts(where, names, specs, len(cells), cell_ints, f"cell data {part_field!r}", groups,
                             "cell set")
    pts = np.asarray(m.points, dtype=np.float64)
    if pts.shape[1] == 3:
        if np.any(pts[:, 2] != 0):
            k = int(np.argmax(pts[:, 2] != 0))
            raise InputFileError(f"{where}: node index {k} has z = {pts[k, 2]}; only 2D meshes are supported")
        pts = pts[:, :2]
    if not np.all(np.isfinite(pts)):
        k = int(np.argmax(~np.isfinite(pts).all(axis=1)))
        raise InputFileError(f"{where}: node index {k} has a non-finite coordinate")
    pts = pts * length_factor(length_unit, f"{where}: length_unit")
    if node_id_field is not None:
        if node_id_field not in m.point_data:
            raise InputFileError(f"{where}: point data {node_id_field!r} not found; have {sorted(m.point_data)}")
        node_ids = np.asarray(m.point_data[node_id_field]).reshape(-1).astype(np.int64)
        u, c = np.unique(node_ids, return_counts=True)
        if (c > 1).any():
            raise InputFileError(f"{where}: duplicate node number {int(u[c > 1][0])} in {node_id_field!r}")
    else:
        node_ids = np.arange(1, len(pts) + 1, dtype=np.int64)
    node_sets = {k.lower(): node_ids[np.asarray(v, np.int64)] for k, v in (m.point_sets or {}).items()}
    kept_nodes = np.unique(cells[cell_part >= 0])
    dropped = np.setdiff1d(node_ids[np.unique(cells[cell_part < 0])], node_ids[kept_nodes])
    return finish_mesh(where, node_ids, pts, cells, cell_part, np.arange(len(cells)), node_sets, names,
                       ignore_unmapped, cell_label="cell index", dropped_node_ids=dropped)


def is_mapdl_file(path: str | os.PathLike) -> bool:
    """``.cdb``, or a text file of MAPDL commands with an NBLOCK (e.g. Workbench's ``ds.dat``)."""
    suffix = Path(path).suffix.lower()
    return suffix == ".cdb" or (suffix in _MAPDL_SUFFIXES and has_nblock(path))


def read_mesh(path: str | os.PathLike, **kwargs) -> ImportedMesh:
    """``read_cdb`` for MAPDL archives / input files (see :func:`is_mapdl_file`), else ``read_meshio_mesh``
    (keyword arguments passed on; ``length_unit=None`` means m for meshio files)."""
    if not Path(path).is_file():
        raise InputFileError(f"{path}: mesh file not found")
    if is_mapdl_file(path):
        kwargs.pop("part_field", None)
        kwargs.pop("node_id_field", None)
        return read_cdb(path, **kwargs)
    if kwargs.get("length_unit", "m") is None:
        kwargs["length_unit"] = "m"
    return read_meshio_mesh(path, **kwargs)
