"""Exact objective gradients at a generated dataset's designs, one JSON file that a gradient-enhanced
surrogate reads (the differentiable solver, :mod:`pcmgn_jax.sim.differentiable`).

    doc = design_gradients("data/family", "train", n=25, out="grads.json")   # resumable: done rows are kept
    G = aligned_gradients(doc, designs)       # {parameter: (B,) [Pa per its unit]}, rows matched

Each design's scene is the dataset's base scene (its manifest's ``scene``) at the design's row
(``design.scene(base)``: a stack design has its own layers); its objective ``reading`` [Pa] and the derivative
with respect to every parameter of the row are computed in float64 at the design's own stable step held fixed
(a derivative at fixed dt; a scene family's mesh pinned at the design's element counts,
:func:`pcmgn_jax.sim.mesh.pinned_spec`), each design compiled on its own mesh. A row parameter's derivative
comes from the solver's parameters (:mod:`pcmgn_jax.sim.parameters`) by :func:`solver_parameters`: a layer
name (a scene family's row) and a stack row's ``<slot>.thickness`` [m] are that layer's thickness;
``<slot>.log10_youngs`` [log10 Pa] is its modulus E by the chain rule, dF/dlog10 E = dF/dE * E * ln 10;
``ball.radius`` and ``ball.velocity`` are themselves. A stack row's ``<slot>.present`` flag is discrete (a
layer is there or not): not differentiable, its derivative recorded as 0; so are the numbers of a slot absent
from the design's stack, which do not enter its scene. The ball's radius is differentiated on the ball mesh
scaled about its pole (:mod:`pcmgn_jax.sim.parameters`), where the generator re-grades the ball: a derivative
of a slightly different discrete problem. Any other row name is refused by name.

Cost is what a gradient-enhanced surrogate is charged: every record holds the wall time of value and
gradient, and every ``time_every``-th also of the value alone (each after its own compilation), so the
file states the measured cost of a gradient in solves (:func:`cost_in_solves`).
"""
from __future__ import annotations

import math
import os
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pcmgn_jax.atomic import atomic_write_json
from pcmgn_jax.data.family import Design
from pcmgn_jax.data.layout import DatasetError, load_manifest, read_format_json
from pcmgn_jax.data.splits import split_designs
from pcmgn_jax.data.stack import SLOT_NAMES
from pcmgn_jax.scene import SCENE_PARAMETERS, Scene

GRADIENTS_FORMAT = "pcmgn_jax.design_gradients"
UNITS = {"objective_pa": "Pa", "gradient": "Pa per unit of the row parameter (SI; log10 Pa for a log10 modulus)",
         "solver_gradient": "Pa per SI unit of the solver parameter", "wall": "s"}
STACK_FIELDS = ("thickness", "log10_youngs", "present")   # a stack row's per-slot numbers (data/stack.py)


def solver_parameters(names: Sequence[str], scene: Scene) -> dict[str, tuple[str, float] | None]:
    """How each row parameter's derivative comes from the solver's (module docstring), at ``scene`` (the
    design's own scene): {row parameter: (solver parameter, factor)}, d objective / d row parameter = factor x
    d objective / d solver parameter; None where it is 0 (a ``<slot>.present`` flag, not differentiable, and
    every number of a stack slot absent from ``scene``, which does not enter it). ValueError naming a row
    parameter that maps to nothing."""
    layers = {layer.name: layer for layer in scene.layers}
    out: dict[str, tuple[str, float] | None] = {}
    for name in names:
        part, _, field = name.partition(".")
        if name in SCENE_PARAMETERS:
            out[name] = (name, 1.0)
        elif name in layers:
            out[name] = (f"{name}.thickness", 1.0)
        elif field in STACK_FIELDS and part in layers:
            out[name] = {"thickness": (name, 1.0), "present": None,
                         "log10_youngs": (f"{part}.youngs", layers[part].youngs * math.log(10.0))}[field]
        elif field in STACK_FIELDS and part in SLOT_NAMES:
            out[name] = None
        else:
            raise ValueError(f"design gradients: row parameter {name!r} has no solver parameter (a layer name "
                             f"{list(layers)}, one of {list(SCENE_PARAMETERS)}, or a stack slot's "
                             f"<slot>.{{{','.join(STACK_FIELDS)}}})")
    return out


def differentiated(terms: dict[str, tuple[str, float] | None]) -> list[str]:
    """The solver parameters ``terms`` (:func:`solver_parameters`) read, once each, in the row's order."""
    return list(dict.fromkeys(t[0] for t in terms.values() if t is not None))


def row_gradient(terms: dict[str, tuple[str, float] | None], solver_gradient: dict[str, float]) -> dict[str, float]:
    """{row parameter: d objective / d it} from ``solver_gradient`` {solver parameter: d objective / d it}
    (every one :func:`differentiated` names) by ``terms`` (:func:`solver_parameters`): factor x the solver's
    derivative, 0.0 where the term is None."""
    return {name: 0.0 if t is None else t[1] * solver_gradient[t[0]] for name, t in terms.items()}


def _header(root: Path, man: dict[str, Any], split: str, reading: str, names: Sequence[str]) -> dict[str, Any]:
    return {"format": GRADIENTS_FORMAT, "format_version": 1, "dataset": str(root), "preset": man["preset"],
            "element": man.get("element"), "scene": man["scene"], "split": split, "reading": reading,
            "names": list(names), "units": UNITS, "records": []}


def design_gradients(dataset_dir: str | os.PathLike, split: str, *, n: int | None, out: str | os.PathLike,
                     reading: str = "area_mean", time_every: int = 5,
                     progress: Callable[[str], None] | None = print) -> dict[str, Any]:
    """The objective and its gradient at the first ``n`` designs (None: every one) of ``split`` of a generated
    dataset, written to ``out`` after each design (atomic; a rerun keeps the records already there and adds the
    rest; an ``out`` of another dataset, split or reading is refused by name). Returns the document."""
    import jax

    from pcmgn_jax.sim import differentiable as dsim  # jax: imported by who computes, not who reads the file

    root, out = Path(dataset_dir), Path(out)
    man = load_manifest(root)
    if man is None:
        raise DatasetError(f"{root}: no generated dataset (manifest.json) here")
    designs = split_designs(root, split)
    n = len(designs) if n is None else n
    designs = designs[:n]
    if len(designs) < n:
        raise DatasetError(f"{root}: split {split!r} holds {len(designs)} designs, {n} asked for")
    base = Scene.from_dict(man["scene"], where=f"{root}/manifest.json scene")
    names = designs[0].names
    scenes = [design.scene(base) for design in designs]       # each design's own (a stack's own layers)
    terms = [solver_parameters(names, scene) for scene in scenes]   # refused by name before any solve
    doc = _header(root, man, split, reading, names)
    if out.exists():
        old = read_format_json(out, GRADIENTS_FORMAT, "design gradients")
        for key in ("dataset", "preset", "element", "scene", "split", "reading", "names"):
            if old.get(key) != doc[key]:
                raise DatasetError(f"{out}: holds gradients of another {key} ({old.get(key)!r}, not {doc[key]!r}); "
                                   "use another --out")
        doc["records"] = old["records"]
    done = {r["index"] for r in doc["records"]}
    for i, design in enumerate(designs):
        if i in done:
            continue
        t0 = time.perf_counter()
        with jax.enable_x64(True):
            params = differentiated(terms[i])
            gs = dsim.setup([scenes[i]], man["preset"], names=params, reading=reading)
            both = dsim.value_and_grad_fn(gs)
            jax.block_until_ready(both(gs.theta))          # compile (each design has its own mesh)
            t1 = time.perf_counter()
            v, g = jax.block_until_ready(both(gs.theta))
            solver = dict(zip(params, map(float, np.asarray(g)[0])))
            rec = {"index": i, "label": design.label(), "row": design.row, "objective_pa": float(np.asarray(v)[0]),
                   "gradient": row_gradient(terms[i], solver), "solver_gradient": solver,
                   "wall_value_and_grad_s": time.perf_counter() - t1, "dt_s": gs.dt, "n_substeps_per_frame": gs.n_sub}
            if i % time_every == 0:
                value = dsim.value_fn(gs)
                jax.block_until_ready(value(gs.theta))
                t2 = time.perf_counter()
                jax.block_until_ready(value(gs.theta))
                rec["wall_value_s"] = time.perf_counter() - t2
        rec["wall_total_s"] = time.perf_counter() - t0
        doc["records"] = sorted(doc["records"] + [rec], key=lambda r: r["index"])
        atomic_write_json(out, doc, parents=True)
        if progress is not None:
            progress(f"gradient {len(doc['records'])}/{n} ({design.label()}): "
                     f"{rec['objective_pa'] * 1e-6:.4f} MPa, {rec['wall_total_s']:.1f} s")
    return doc


def cost_in_solves(doc: dict[str, Any]) -> float:
    """The median of wall(value and gradient) / wall(value) over the records timed both ways: what one
    design's gradient costs, counted in solves of that design (value included). ValueError when no record
    was timed both ways."""
    ratios = [r["wall_value_and_grad_s"] / r["wall_value_s"] for r in doc["records"] if r.get("wall_value_s")]
    if not ratios:
        raise ValueError(f"{doc.get('dataset')}: no record timed the value alone (time_every)")
    return float(np.median(ratios))


def aligned_gradients(doc: dict[str, Any], designs: Sequence[Design], *,
                      rtol: float = 1e-9) -> dict[str, np.ndarray]:
    """{row parameter: (B,) [Pa per its unit]}: the gradients of ``designs``, each found by its row (named
    columns: a surface orders them as its inputs); DatasetError naming the first design without one."""
    names = doc["names"]
    rows = np.array([[r["row"][k] for k in names] for r in doc["records"]])
    out = []
    for d in designs:
        x = np.array([d.row[k] for k in names])
        hit = np.flatnonzero(np.all(np.isclose(rows, x, rtol=rtol, atol=0), axis=1)) if len(rows) else []
        if not len(hit):
            raise DatasetError(f"{doc.get('dataset')}: no gradient of the design {d.label()} in the file "
                               f"({len(rows)} records)")
        out.append([doc["records"][hit[0]]["gradient"][k] for k in names])
    cols = np.array(out, np.float64).reshape(len(out), len(names))
    return {k: cols[:, j] for j, k in enumerate(names)}


def load_gradients(path: str | os.PathLike) -> dict[str, Any]:
    """A design-gradients file (:func:`design_gradients`), its format checked; DatasetError naming it."""
    return read_format_json(Path(path), GRADIENTS_FORMAT, "design gradients")
