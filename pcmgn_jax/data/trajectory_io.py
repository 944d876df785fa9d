"""Trajectory files: ``NAME.xdmf`` + ``NAME.h5`` (meshio XDMF time series) + ``NAME.json`` sidecar.

This is the one interchange format of the project (docs/design.md §4). All values are SI (m, s, m/s, Pa).

XDMF/HDF5 content (opens in ParaView with the "XDMF Reader"):
  geometry:  reference points, written as (N, 3) float64 with z = 0 (x = radius/width, y = height)
  topology:  one block of quads (E, 4) int64
  per frame (``Time`` = the frame time [s]):
    point data  displacement (N, 3) [m], velocity (N, 3) [m/s]  (z = 0; ParaView wants 3-vectors,
                so "Warp By Vector" on ``displacement`` shows the deformed shape),
                von_mises (N,) [Pa], node_part (N,), node_type (N,)
    cell data   part (E,)
  Arrays keep the Trajectory's dtypes (float32 or float64), so a write -> read round trip is exact.

JSON sidecar (written LAST; it is the commit marker): the trajectory's ``meta`` dict plus the reserved
keys ``format``, ``format_version``, ``n_nodes``, ``n_cells``, ``n_frames``, ``times``, ``dtypes``,
``files`` and ``sha256`` (content hash over all arrays, see :func:`content_hash`). Standard keys
``units``, ``analysis``, ``scene``, ``design``, ``output_dt``, ``source``, ``solver``, ``energy``,
``part_names`` are always present (``null`` when the producer did not supply them).

Atomicity (:func:`pcmgn_jax.atomic.atomic_dir`): every file is first written into a temporary
directory next to the target (``.NAME.tmp-XXXX/``, under its final name, because the XDMF refers to
its HDF5 file by base name), fsynced, then moved in with ``os.replace``: first an old sidecar is
removed, then the HDF5 and XDMF are replaced, then the sidecar. A run killed at any point leaves
either no sidecar or a sidecar whose hash does not match, and :func:`read_trajectory` refuses both. The XDMF refers to
the HDF5 file by a relative name, so a folder of trajectories can be moved or copied freely.

Note on meshio: ``meshio.xdmf.TimeSeriesWriter`` opens its HDF5 file as ``Path(filename).stem + ".h5"``
relative to the *current working directory*, not next to the XDMF file; :class:`_XdmfWriter` fixes
that so writes never depend on (or change) the working directory.
"""
from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from pcmgn_jax.atomic import atomic_dir, to_jsonable
from pcmgn_jax.trajectory import Trajectory

__all__ = [
    "ARRAY_FIELDS",
    "FORMAT",
    "FORMAT_VERSION",
    "TrajectoryFileError",
    "content_hash",
    "read_sidecar",
    "read_trajectory",
    "trajectory_paths",
    "write_trajectory",
    "write_xdmf_series",
]

FORMAT = "pcmgn_jax.trajectory"
FORMAT_VERSION = 1
# Hashed / stored arrays, in hashing order.
ARRAY_FIELDS = ("points", "cells", "cell_part", "node_part", "node_type", "times",
                "displacement", "velocity", "von_mises")
RESERVED_KEYS = frozenset({"format", "format_version", "n_nodes", "n_cells", "n_frames", "times",
                           "dtypes", "files", "sha256"})
STANDARD_KEYS = ("units", "analysis", "scene", "design", "output_dt", "source", "solver", "energy",
                 "part_names")
SI_UNITS = {"length": "m", "time": "s", "velocity": "m/s", "stress": "Pa"}
SUFFIXES = (".xdmf", ".h5", ".json")
_KINDS = {  # field -> allowed numpy dtype kinds
    "points": "f", "cells": "iu", "cell_part": "iu", "node_part": "iu", "node_type": "iu",
    "times": "f", "displacement": "f", "velocity": "f", "von_mises": "f",
}


class TrajectoryFileError(ValueError):
    """A trajectory file is missing, incomplete, inconsistent or corrupt (message names file and field)."""


# ---- paths, hashing, JSON helpers ---------------------------------------------------------------
def trajectory_paths(path_stem: str | os.PathLike) -> tuple[Path, Path, Path]:
    """``(NAME.xdmf, NAME.h5, NAME.json)`` for ``dir/NAME`` (a trailing .xdmf/.h5/.json is dropped)."""
    stem = Path(path_stem)
    if stem.suffix in SUFFIXES:
        stem = stem.with_suffix("")
    return stem.with_name(stem.name + ".xdmf"), stem.with_name(stem.name + ".h5"), \
        stem.with_name(stem.name + ".json")


def _canonical(arr: np.ndarray) -> np.ndarray:
    arr = np.asarray(arr)
    if arr.dtype.byteorder == ">":
        arr = arr.astype(arr.dtype.newbyteorder("<"))
    return np.ascontiguousarray(arr)


def content_hash(traj: Trajectory) -> str:
    """sha256 (hex) over every array field: name, dtype, shape and little-endian C-order bytes.

    The hash changes with the dtype, so float32 and float64 copies of the same numbers differ.
    """
    h = hashlib.sha256()
    for name in ARRAY_FIELDS:
        arr = _canonical(getattr(traj, name))
        h.update(f"{name}|{arr.dtype.str}|{arr.shape}|".encode())
        h.update(memoryview(arr).cast("B"))
    return h.hexdigest()


# ---- writing ------------------------------------------------------------------------------------
def _xdmf_writer_class():
    import meshio

    class _XdmfWriter(meshio.xdmf.TimeSeriesWriter):
        """TimeSeriesWriter that puts the HDF5 file next to the XDMF file (meshio uses the CWD)."""

        def __enter__(self):
            import h5py

            self.h5_filename = str(self.filename.with_suffix(".h5"))
            self.h5_file = h5py.File(self.h5_filename, "w")
            return self

    return _XdmfWriter


def _check_dtypes(traj: Trajectory, where: str) -> None:
    for name in ARRAY_FIELDS:
        arr = np.asarray(getattr(traj, name))
        if arr.dtype.kind not in _KINDS[name]:
            raise ValueError(f"{where}: field {name!r} has dtype {arr.dtype}, expected kind {_KINDS[name]!r}")


def _pad3(a: np.ndarray) -> np.ndarray:
    out = np.zeros(a.shape[:-1] + (3,), dtype=a.dtype)
    out[..., :2] = a
    return out


def write_xdmf_series(xdmf_path: Path, points: np.ndarray, cells: np.ndarray, times: np.ndarray, *,
                      frame_data: Mapping[str, np.ndarray],
                      static_point_data: Mapping[str, np.ndarray] | None = None,
                      cell_data: Mapping[str, np.ndarray] | None = None) -> None:
    """Low-level: write a quad-mesh XDMF+HDF5 time series (HDF5 beside the XDMF, same stem).

    points (N, 2|3) [m]; cells (E, 4); times (T,) [s]; frame_data name -> (T, N) or (T, N, 2|3)
    (2-vectors are padded to 3 with z = 0); static_point_data name -> (N, ...) and cell_data
    name -> (E,) are repeated in every frame. Not atomic: callers write into a temporary directory.
    """
    writer_cls = _xdmf_writer_class()
    pts = np.asarray(points)
    pts = _pad3(pts) if pts.shape[1] == 2 else pts
    static_point_data = dict(static_point_data or {})
    cell_data = dict(cell_data or {})
    with writer_cls(Path(xdmf_path)) as writer:
        writer.write_points_cells(pts, [("quad", np.asarray(cells))])
        for k in range(len(times)):
            pdata = {}
            for name, arr in frame_data.items():
                frame = np.asarray(arr[k])
                if frame.ndim == 2 and frame.shape[1] == 2:
                    frame = _pad3(frame)
                pdata[name] = np.ascontiguousarray(frame)
            for name, arr in static_point_data.items():
                pdata[name] = np.ascontiguousarray(arr)
            cdata = {name: [np.ascontiguousarray(arr)] for name, arr in cell_data.items()}
            writer.write_data(float(times[k]), point_data=pdata, cell_data=cdata)


def _sidecar(traj: Trajectory, digest: str, name: str) -> dict[str, Any]:
    meta = dict(traj.meta or {})
    clash = sorted(RESERVED_KEYS & set(meta))
    if clash:
        raise ValueError(f"trajectory {name!r}: meta uses reserved sidecar key(s) {clash}")
    units = meta.get("units", SI_UNITS)
    if units != SI_UNITS:
        raise ValueError(f"trajectory {name!r}: meta 'units' must be SI {SI_UNITS}, got {units!r}")
    side: dict[str, Any] = {"format": FORMAT, "format_version": FORMAT_VERSION}
    for key in STANDARD_KEYS:
        side[key] = meta.pop(key, SI_UNITS if key == "units" else None)
    side.update(meta)
    side.update({
        "n_nodes": traj.n_nodes, "n_cells": int(traj.cells.shape[0]), "n_frames": traj.n_frames,
        "times": [float(t) for t in np.asarray(traj.times)],
        "dtypes": {f: np.asarray(getattr(traj, f)).dtype.str for f in ARRAY_FIELDS},
        "files": {"xdmf": name + ".xdmf", "h5": name + ".h5"},
        "sha256": digest,
    })
    return to_jsonable(side, f"{name}.json")


def write_trajectory(traj: Trajectory, path_stem: str | os.PathLike) -> str:
    """Write ``traj`` atomically as ``path_stem``.{xdmf,h5,json}; return its content hash (sha256 hex).

    An existing trajectory of the same name is replaced. Raises ValueError (naming the field) for an
    invalid trajectory or a meta dict that is not JSON-serialisable; nothing is written then.
    """
    xdmf, h5, side_path = trajectory_paths(path_stem)
    name = xdmf.stem
    where = str(xdmf.with_suffix(""))
    traj.validate(where)
    _check_dtypes(traj, where)
    digest = content_hash(traj)
    side = _sidecar(traj, digest, name)
    with atomic_dir(xdmf.parent, files=(h5.name, xdmf.name, side_path.name)) as tmpdir:   # sidecar last
        write_xdmf_series(
            tmpdir / xdmf.name, traj.points, traj.cells, traj.times,
            frame_data={"displacement": traj.displacement, "velocity": traj.velocity,
                        "von_mises": traj.von_mises},
            static_point_data={"node_part": traj.node_part, "node_type": traj.node_type},
            cell_data={"part": traj.cell_part})
        (tmpdir / side_path.name).write_text(json.dumps(side, indent=1, allow_nan=False))
    return digest


# ---- reading ------------------------------------------------------------------------------------
def read_sidecar(path_stem: str | os.PathLike) -> dict[str, Any]:
    """The parsed JSON sidecar; TrajectoryFileError if missing, unparsable or not a trajectory sidecar."""
    _, _, side_path = trajectory_paths(path_stem)
    if not side_path.is_file():
        raise TrajectoryFileError(
            f"{side_path}: sidecar missing (trajectory not written completely, or not a trajectory)")
    try:
        side = json.loads(side_path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise TrajectoryFileError(f"{side_path}: cannot parse sidecar JSON: {err}") from None
    if not isinstance(side, dict) or side.get("format") != FORMAT:
        raise TrajectoryFileError(f"{side_path}: field 'format' is not {FORMAT!r}")
    if side.get("format_version") != FORMAT_VERSION:
        raise TrajectoryFileError(
            f"{side_path}: field 'format_version' is {side.get('format_version')!r}, expected {FORMAT_VERSION}")
    for key in ("n_nodes", "n_cells", "n_frames", "times", "dtypes", "sha256"):
        if key not in side:
            raise TrajectoryFileError(f"{side_path}: field {key!r} is missing")
    return side


def read_trajectory(path_stem: str | os.PathLike, *, verify: bool = True) -> Trajectory:
    """Read a trajectory written by :func:`write_trajectory` (exact round trip, dtypes preserved).

    ``verify`` recomputes the content hash and compares it with the sidecar's. Shapes, frame count
    and times are always checked against the sidecar. Raises TrajectoryFileError naming file and field.
    """
    import meshio

    xdmf, h5, side_path = trajectory_paths(path_stem)
    side = read_sidecar(path_stem)
    for p in (xdmf, h5):
        if not p.is_file():
            raise TrajectoryFileError(f"{p}: file missing (sidecar {side_path.name} refers to it)")
    dtypes = side["dtypes"]
    try:
        with meshio.xdmf.TimeSeriesReader(xdmf) as reader:
            points, blocks = reader.read_points_cells()
            if len(blocks) != 1 or blocks[0].type != "quad":
                raise TrajectoryFileError(
                    f"{xdmf}: field 'cells' must be one block of quads, got {[b.type for b in blocks]}")
            cells = np.asarray(blocks[0].data)
            n_steps = reader.num_steps
            if n_steps != side["n_frames"]:
                raise TrajectoryFileError(
                    f"{xdmf}: field 'times' has {n_steps} frames, sidecar says n_frames={side['n_frames']}")
            frames: dict[str, list[np.ndarray]] = {"displacement": [], "velocity": [], "von_mises": []}
            xtimes = []
            node_part = node_type = cell_part = None
            for k in range(n_steps):
                t, pdata, cdata = reader.read_data(k)
                xtimes.append(t)
                for key in ("displacement", "velocity", "von_mises", "node_part", "node_type"):
                    if key not in pdata:
                        raise TrajectoryFileError(f"{xdmf}: field {key!r} missing in frame {k}")
                if "part" not in cdata:
                    raise TrajectoryFileError(f"{xdmf}: field 'part' (cell data) missing in frame {k}")
                for key in ("displacement", "velocity"):
                    vec = np.asarray(pdata[key])
                    if vec.ndim != 2 or vec.shape[1] not in (2, 3):
                        raise TrajectoryFileError(f"{xdmf}: field {key!r} has shape {vec.shape} in frame {k}")
                    if vec.shape[1] == 3 and np.any(vec[:, 2] != 0):
                        raise TrajectoryFileError(f"{xdmf}: field {key!r} has non-zero z in frame {k}")
                    frames[key].append(vec[:, :2])
                frames["von_mises"].append(np.asarray(pdata["von_mises"]).reshape(-1))
                if k == 0:
                    node_part = np.asarray(pdata["node_part"]).reshape(-1)
                    node_type = np.asarray(pdata["node_type"]).reshape(-1)
                    cell_part = np.asarray(cdata["part"][0]).reshape(-1)
    except TrajectoryFileError:
        raise
    except Exception as err:  # noqa: BLE001 (h5py / XML / meshio raise many types; all become one error)
        raise TrajectoryFileError(f"{xdmf}: cannot read XDMF/HDF5 data: {type(err).__name__}: {err}") from None

    points = np.asarray(points)
    if points.ndim != 2 or points.shape[1] not in (2, 3):
        raise TrajectoryFileError(f"{xdmf}: field 'points' has shape {points.shape}")
    if points.shape[1] == 3:
        if np.any(points[:, 2] != 0):
            raise TrajectoryFileError(f"{xdmf}: field 'points' has non-zero z coordinates")
        points = points[:, :2]
    n = points.shape[0]
    if n != side["n_nodes"] or cells.shape[0] != side["n_cells"]:
        raise TrajectoryFileError(
            f"{side_path}: field 'n_nodes'/'n_cells' ({side['n_nodes']}, {side['n_cells']}) disagrees with "
            f"{xdmf.name} ({n}, {cells.shape[0]})")
    times = np.asarray(side["times"], dtype=np.float64)
    if times.shape != (n_steps,) or np.any(times != np.asarray(xtimes, dtype=np.float64)):
        raise TrajectoryFileError(f"{side_path}: field 'times' disagrees with the frame times in {xdmf.name}")
    arrays = {
        "points": points, "cells": cells, "cell_part": cell_part, "node_part": node_part,
        "node_type": node_type, "times": times,
        "displacement": np.stack(frames["displacement"]) if n_steps else np.zeros((0, n, 2)),
        "velocity": np.stack(frames["velocity"]) if n_steps else np.zeros((0, n, 2)),
        "von_mises": np.stack(frames["von_mises"]) if n_steps else np.zeros((0, n)),
    }
    for name, arr in arrays.items():
        want = dtypes.get(name)
        if want is None:
            raise TrajectoryFileError(f"{side_path}: field 'dtypes.{name}' is missing")
        if name == "times":
            arrays[name] = arr.astype(np.dtype(want))
            if np.any(arrays[name].astype(np.float64) != arr):
                raise TrajectoryFileError(f"{side_path}: field 'times' is not representable as {want}")
        elif arr.dtype != np.dtype(want):
            raise TrajectoryFileError(
                f"{xdmf}: field {name!r} has dtype {arr.dtype}, sidecar {side_path.name} says {want}")
    meta = {k: v for k, v in side.items() if k not in RESERVED_KEYS}
    traj = Trajectory(**arrays, meta=meta)
    try:
        traj.validate(str(xdmf))
    except ValueError as err:
        raise TrajectoryFileError(str(err)) from None
    if verify:
        digest = content_hash(traj)
        if digest != side["sha256"]:
            raise TrajectoryFileError(
                f"{side_path}: field 'sha256' does not match the data in {xdmf.name}/{h5.name} "
                f"(recorded {side['sha256'][:12]}..., computed {digest[:12]}...): corrupt or partial write")
    return traj
