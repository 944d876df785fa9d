"""The imported mesh type and the part mapping (part names -> mesh groups -> per-cell part ids).

Why a second mesh type next to :class:`pcmgn_jax.sim.mesh.Mesh`: the solver's mesh carries what only
the generator knows (per-dof Dirichlet mask, the ball and panel contact surfaces, node parts after the
stiffness rule), while a foreign file defines none of that and instead carries external numbering
that the importers need: ANSYS / LS-DYNA node and element numbers (result tables are matched by node
number), node components / node sets (fixed nodes), and the midside nodes dropped from 8-node quads.
Neither is a subset of the other; what they share is exactly what :class:`~pcmgn_jax.trajectory.Trajectory`
holds (points, cells, cell_part, node_part, node_type), and that is the one type both produce.
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field, replace
from typing import Any, Mapping, Sequence

import numpy as np

from pcmgn_jax.data.importers.errors import InputFileError
from pcmgn_jax.errors import SettingError
from pcmgn_jax.scene import Scene


@dataclass(frozen=True)
class ImportedMesh:
    """A 2D quad mesh with parts and external numbering, as read from a mesh file.

    node_ids: (N,) int64 external node numbers (unique); points: (N, 2) float64 [m];
    cells: (E, 4) int64 indices into points; cell_part: (E,) int32 part ids; cell_ids: (E,) int64
    external element numbers; node_sets: name -> external node numbers (components / node sets);
    part_names: names indexed by part id; source: the file; dropped_node_ids: external numbers of
    nodes dropped on purpose (midside nodes of 8-node quads, nodes only of skipped or unmapped
    elements): result tables may list them and they are ignored there; analysis: 'axisymmetric' | 'plane_strain' | None
    as declared by the file (MAPDL KEYOPT(3)); notes: what was skipped or assumed, one line each.
    """

    node_ids: np.ndarray
    points: np.ndarray
    cells: np.ndarray
    cell_part: np.ndarray
    cell_ids: np.ndarray
    node_sets: Mapping[str, np.ndarray]
    part_names: tuple[str, ...]
    source: str
    dropped_node_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    analysis: str | None = None
    notes: tuple[str, ...] = ()

    def compact(self) -> "ImportedMesh":
        """Drop nodes used by no cell (renumbering cells)."""
        used = np.zeros(len(self.node_ids), dtype=bool)
        used[self.cells.reshape(-1)] = True
        if used.all():
            return self
        new = -np.ones(len(used), dtype=np.int64)
        new[used] = np.arange(used.sum())
        return replace(self, node_ids=self.node_ids[used], points=self.points[used], cells=new[self.cells])


Mesh = ImportedMesh   # the name this type had before the split; kept for callers


def resolve_part_names(scene: Scene | Mapping | None, part_names: Sequence[str] | None) -> tuple[
        tuple[str, ...], Scene | None]:
    if isinstance(scene, Mapping):
        scene = Scene.from_dict(scene)
    if scene is not None:
        names = scene.part_names
        if part_names is not None and tuple(part_names) != names:
            raise ValueError(f"part_names {tuple(part_names)} disagree with the scene's {names}")
        return names, scene
    if not part_names:
        raise ValueError("give a scene or part_names (part name -> part id mapping by position)")
    names = tuple(part_names)
    if len(set(names)) != len(names):
        raise ValueError(f"part_names must be unique, got {names}")
    return names, None


def part_specs(parts: Mapping[str, Any] | None, names: Sequence[str]) -> dict[str, list]:
    if parts is None:
        return {n: [n] for n in names}
    unknown = sorted(set(parts) - set(names))
    if unknown:
        raise ValueError(f"parts: unknown part name(s) {unknown}; part names are {list(names)}")
    out = {}
    for n, spec in parts.items():
        items = list(spec) if isinstance(spec, (list, tuple)) else [spec]
        for it in items:
            if not isinstance(it, (int, np.integer, str)) or isinstance(it, bool):
                raise ValueError(f"parts[{n!r}]: entries must be ints or strings, got {it!r}")
        out[n] = items
    return out


def parse_parts(text: str) -> dict[str, list]:
    """Parse a CLI part map ``"ball=1,CG=2+7,OCA1=OCA_1"`` (int = material/part id, str = group name)."""
    out: dict[str, list] = {}
    for item in filter(None, (s.strip() for s in text.split(","))):
        if "=" not in item:
            raise SettingError("parts", f"{item!r} is not NAME=GROUP")
        name, groups = (s.strip() for s in item.split("=", 1))
        out[name] = [int(g) if re.fullmatch(r"-?\d+", g) else g for g in groups.split("+")]
    return out


def assign_parts(where: str, names: Sequence[str], specs: Mapping[str, list], n_cells: int,
                 cell_ints: np.ndarray | None, int_label: str, cell_groups: Mapping[str, np.ndarray],
                 group_label: str) -> np.ndarray:
    """(E,) part id per cell, -1 where unmapped. cell_groups: lower-case name -> bool mask (E,)."""
    part = -np.ones(n_cells, dtype=np.int32)
    for pid, name in enumerate(names):
        for item in specs.get(name, []):
            if isinstance(item, str):
                mask = cell_groups.get(item.lower())
                if mask is None:
                    raise InputFileError(f"{where}: part {name!r}: no {group_label} named {item!r}; "
                                         f"have {sorted(cell_groups)} (map parts with --parts / parts=)")
            else:
                if cell_ints is None:
                    raise InputFileError(f"{where}: part {name!r}: integer group {item} given but the mesh "
                                         f"has no {int_label}")
                mask = cell_ints == int(item)
                if not mask.any():
                    raise InputFileError(f"{where}: part {name!r}: no cells with {int_label} {item}")
            clash = mask & (part >= 0) & (part != pid)
            if clash.any():
                i = int(np.argmax(clash))
                raise InputFileError(f"{where}: cell {i} belongs to parts {names[part[i]]!r} and {name!r}")
            part[mask] = pid
    return part


def finish_mesh(where: str, node_ids, points, cells, cell_part, cell_ids, node_sets, names,
                ignore_unmapped: bool, cell_label: str = "element", **extra) -> ImportedMesh:
    """Drop unmapped cells (or refuse them), then unused nodes. ``extra``: optional ImportedMesh fields."""
    unmapped = cell_part < 0
    if unmapped.any() and not ignore_unmapped:
        bad = np.asarray(cell_ids)[unmapped][:5].tolist()
        raise InputFileError(f"{where}: {int(unmapped.sum())} {cell_label}(s) belong to no part, e.g. "
                             f"{cell_label} {bad}; map them in `parts` or pass ignore_unmapped=True")
    keep = ~unmapped
    mesh = ImportedMesh(np.asarray(node_ids, np.int64), np.asarray(points, np.float64),
                        np.asarray(cells, np.int64)[keep], cell_part[keep].astype(np.int32),
                        np.asarray(cell_ids, np.int64)[keep], dict(node_sets), tuple(names), where,
                        **extra).compact()
    if len(mesh.cells) == 0:
        raise InputFileError(f"{where}: no quad cells left after part mapping")
    return mesh
