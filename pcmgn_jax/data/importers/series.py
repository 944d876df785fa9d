"""meshio time series (an XDMF time series or per-frame files such as VTU) -> Trajectory."""
from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from pcmgn_jax.data.importers.build import build_trajectory
from pcmgn_jax.data.importers.errors import InputFileError
from pcmgn_jax.data.importers.meshes import read_meshio_mesh
from pcmgn_jax.data.importers.parts import resolve_part_names
from pcmgn_jax.data.importers.units import length_factor, stress_factor, velocity_factor
from pcmgn_jax.scene import Scene
from pcmgn_jax.trajectory import Trajectory


def import_meshio_series(files: str | os.PathLike | Sequence[str | os.PathLike], *,
                         scene: Scene | Mapping | None = None, part_names: Sequence[str] | None = None,
                         parts: Mapping[str, Any] | None = None, part_field: str | None = None,
                         times: Sequence[float] | None = None, output_dt: float | None = None,
                         fields: Mapping[str, str] | None = None, length_unit: str = "m",
                         velocity_unit: str = "m/s", stress_unit: str = "Pa", fixed: Any = "bottom",
                         ignore_unmapped: bool = False, design: Mapping[str, float] | None = None) -> Trajectory:
    """A meshio time series -> Trajectory (source 'meshio').

    ``files``: one XDMF time series (frame times from the file) or a list of per-frame mesh files
    (VTU, ...; times from ``times`` or ``output_dt``). ``fields`` maps 'displacement', 'velocity',
    'von_mises' to point-data names (default: the same names). Units given by the ``*_unit`` args.
    """
    import meshio

    fields = {"displacement": "displacement", "velocity": "velocity", "von_mises": "von_mises",
              **(fields or {})}
    names, scene_obj = resolve_part_names(scene, part_names)
    frames: list[tuple[str, float | None, Any, dict]] = []   # (where, t, mesh, point_data)
    if isinstance(files, (str, os.PathLike)) and Path(files).suffix.lower() == ".xdmf":
        src = Path(files)
        try:
            with meshio.xdmf.TimeSeriesReader(src) as r:
                pts, cells = r.read_points_cells()
                for k in range(r.num_steps):
                    tk, pd, cd = r.read_data(k)
                    frames.append((f"{src} (frame {k})", tk, meshio.Mesh(pts, cells, cell_data=cd), pd))
        except InputFileError:
            raise
        except Exception as err:
            raise InputFileError(f"{src}: cannot read XDMF time series: {type(err).__name__}: {err}") from None
        first_path = src
    else:
        paths = [Path(files)] if isinstance(files, (str, os.PathLike)) else [Path(p) for p in files]
        if not paths:
            raise InputFileError("import_meshio_series: no files given")
        for p in paths:
            try:
                m = meshio.read(p)
            except Exception as err:
                raise InputFileError(f"{p}: meshio cannot read it: {type(err).__name__}: {err}") from None
            frames.append((str(p), None, m, m.point_data))
        first_path = paths[0]
    if times is not None:
        t = np.asarray(times, np.float64)
    elif all(f[1] is not None for f in frames):
        t = np.asarray([f[1] for f in frames], np.float64)
    elif output_dt is not None:
        t = np.arange(len(frames)) * float(output_dt)
    else:
        raise InputFileError(f"{first_path}: frame times unknown: give times or output_dt")
    if t.shape != (len(frames),) or not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
        raise InputFileError(f"{first_path}: need {len(frames)} finite, strictly increasing frame times")
    m0 = frames[0][2]
    mesh = read_meshio_mesh(first_path, scene=scene_obj, part_names=None if scene_obj else names, parts=parts,
                            part_field=part_field, length_unit=length_unit,
                            ignore_unmapped=ignore_unmapped, _mesh=m0)
    # mesh.compact() may drop unused points: map original point index -> trajectory index
    keep = np.asarray(mesh.node_ids - 1, dtype=np.int64)
    lf = length_factor(length_unit, "length_unit")
    vf = velocity_factor(velocity_unit, "velocity_unit")
    sf = stress_factor(stress_unit, "stress_unit")
    T, n = len(frames), len(keep)
    disp, vel, vm = np.zeros((T, n, 2)), np.zeros((T, n, 2)), np.zeros((T, n))
    for k, (where, _, m, pd) in enumerate(frames):
        if len(m.points) != len(m0.points) or not np.array_equal(np.asarray(m.points), np.asarray(m0.points)):
            raise InputFileError(f"{where}: points differ from frame 0 ({len(m.points)} vs {len(m0.points)} "
                                 "nodes): frames have different node sets")
        if len(m.cells) != len(m0.cells) or any(
                a.type != b.type or not np.array_equal(a.data, b.data) for a, b in zip(m.cells, m0.cells)):
            raise InputFileError(f"{where}: cells differ from frame 0")
        for key, target in (("displacement", disp), ("velocity", vel), ("von_mises", vm)):
            name = fields[key]
            if name not in pd:
                raise InputFileError(f"{where}: point data {name!r} ({key}) missing; have {sorted(pd)}")
            arr = np.asarray(pd[name], dtype=np.float64)
            if key == "von_mises":
                arr = arr.reshape(len(m.points), -1)
                if arr.shape[1] != 1:
                    raise InputFileError(f"{where}: point data {name!r} has shape {arr.shape}, expected (N,)")
                arr = arr[:, 0]
            elif arr.ndim != 2 or arr.shape[1] not in (2, 3) or arr.shape[0] != len(m.points):
                raise InputFileError(f"{where}: point data {name!r} has shape {arr.shape}, expected (N, 2|3)")
            if not np.all(np.isfinite(arr)):
                bad = np.argwhere(~np.isfinite(arr))[0]
                raise InputFileError(f"{where}: point data {name!r}: non-finite value at node index {bad[0]}")
            arr = arr[keep]
            if key == "von_mises":
                target[k] = arr * sf
            else:
                target[k] = arr[:, :2] * (lf if key == "displacement" else vf)
    return build_trajectory(mesh, scene_obj, fixed, t, disp, vel, vm, "meshio",
                  {"mesh": str(first_path), "results": str(first_path), "fields": dict(fields)}, design)
