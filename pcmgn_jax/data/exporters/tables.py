"""Mechanical "Export -> Text File" result tables: :func:`write_results` (one nodal table per result per
frame, plus ``times.txt``; see :mod:`pcmgn_jax.data.exporters.ansys` for the layout and units)."""
from __future__ import annotations

import os
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pcmgn_jax.data.exporters.common import ExportError, atomic_folder
from pcmgn_jax.data.importers.ansys_text import FRAME_KEYS
from pcmgn_jax.data.importers.units import length_factor, stress_factor, velocity_factor
from pcmgn_jax.trajectory import Trajectory

__all__ = ["RESULT_COLUMNS", "format_table", "result_file", "unit_scales", "write_results"]

RESULT_COLUMNS = {"deformation": ("Directional Deformation", "length"),
                  "velocity": ("Directional Velocity", "velocity"),
                  "stress": ("Equivalent (von-Mises) Stress", "stress")}


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


def unit_scales(length_unit: str, velocity_unit: str, stress_unit: str) -> dict[str, float]:
    """{"length" | "velocity" | "stress": factor from SI to the given unit}; ValueError for an unknown unit."""
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
        scales = unit_scales(length_unit, velocity_unit, stress_unit)
    except ValueError as err:
        raise ExportError(f"{folder}: {err}") from None
    units = {"length": length_unit, "velocity": velocity_unit, "stress": stress_unit}
    ids = np.arange(1, traj.n_nodes + 1) if node_ids is None else np.asarray(node_ids)
    if len(ids) != traj.n_nodes:
        raise ExportError(f"{folder}: {len(ids)} node numbers for {traj.n_nodes} nodes")
    fields = {"deformation": np.asarray(traj.displacement), "velocity": np.asarray(traj.velocity),
              "stress": np.asarray(traj.von_mises)}
    with atomic_folder(folder) as tmp:
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


