"""Trajectory datasets: design sampling, scene families, resumable batched generation with the solver.

The directory layout, the manifest format and the rule for what a directory is live in
:mod:`pcmgn_jax.data.layout` (re-exported here); reading splits for a run (``load_splits``, ``prepare_dataset``,
``load_directory``) in :mod:`pcmgn_jax.data.splits`, which builds on this module.

Designs are thicknesses of ``scene.design_layers`` in metres (the manifest also lists them in µm).
``train`` and ``test`` come from ONE seeded Latin hypercube of ``n_train + n_test`` points over
[low, high]^dim (the rows are in random order, so the first ``n_train`` rows are a random subset);
explicit designs (``--designs``) go into a named split (default ``extrap``).

Scene families (presets ``family`` and ``family_tiny``, :data:`FAMILIES`): the Latin hypercube runs over
the family's scene parameters (ball radius, drop speed, and the OCA1, OCA2 and polarizer thicknesses),
each scaled to its own range; every scene has its own mesh (the mesh preset of the same name sizes the
layers from their thickness) and is solved on its own. Each manifest entry and trajectory meta records
``scene_params`` ({parameter: SI value}); ``design_m`` holds the design-layer thicknesses as before.

Resuming: a trajectory is skipped when its files read back with a matching content hash
(``read_trajectory(verify=True)``) and its recorded design equals the requested one; anything else is
(re)generated. A manifest written for other settings (preset, scene, designs of a split) is an error,
never silently mixed. The solver never writes into a directory of trajectory files without a manifest
(an imported dataset).

Sharding (``shard=(K, N)``, ``merge=True``; the rule and the per-shard parts: :mod:`pcmgn_jax.data.shards`):
a shard solves its share of the batches and writes its own manifest part, never ``manifest.json``; the
merge verifies every trajectory and writes the manifest.
"""
from __future__ import annotations

import importlib
import os
import re
import time
from collections.abc import Callable, Sequence
from contextlib import ExitStack
from pathlib import Path
from typing import Any

import numpy as np

from pcmgn_jax.atomic import atomic_write_json
from pcmgn_jax.data import shards
from pcmgn_jax.data.designs import (
    DESIGN_HIGH,
    DESIGN_LOW,
    FAMILIES,
    SceneFamily,
    lhs_designs,
    origin_mismatch,
    parse_designs,
    parse_scene_params,
)
from pcmgn_jax.data.layout import (
    DATASET_FORMAT,
    GENERATE,
    IMPORTED,
    MANIFEST,
    SHARD_PARTS,
    DatasetError,
    check_element,
    dataset_source,
    entry_mismatch,
    has_shard_parts,
    has_trajectory_files,
    load_manifest,
    manifest_element,
    split_stems,
)
from pcmgn_jax.data.stack import StackFamily
from pcmgn_jax.data.trajectory_io import TrajectoryFileError, content_hash, read_trajectory, write_trajectory
from pcmgn_jax.lock import hold
from pcmgn_jax.presets import PRESET_NAMES
from pcmgn_jax.scene import Scene, default_scene
from pcmgn_jax.trajectory import Trajectory

__all__ = ["FAMILIES", "GENERATE", "IMPORTED", "MANIFEST", "DatasetError", "SceneFamily", "dataset_source",
           "ensure_dataset", "lhs_designs", "load_manifest", "parse_designs", "parse_scene_params", "split_stems"]

_SPLIT_RE = re.compile(r"^[A-Za-z][A-Za-z0-9_-]*$")


def _entry(split: str, i: int, design: np.ndarray, family: SceneFamily | None = None,
           base: Scene | None = None) -> dict[str, Any]:
    """A manifest entry; for a family, ``design`` is the scene-parameter vector (family order, SI) and
    the entry records it as ``scene_params`` beside the design-layer thicknesses."""
    name = f"{split}_{i:04d}"
    out: dict[str, Any] = {"name": name, "path": f"{split}/{name}"}
    if family is not None:
        params = {k: float(v) for k, v in zip(family.names, design)}
        out["scene_params"] = params
        one = family.scene(base, params)
        design = np.asarray(one.design)
        if isinstance(family, StackFamily):
            out["layers"] = [layer.name for layer in one.layers]     # the stack's layer list, top to bottom
    out.update({"design_m": [float(v) for v in design], "design_um": [round(float(v) * 1e6, 6) for v in design],
                "sha256": None, "wall_time_s": None})
    return out


def _is_done(root: Path, entry: dict[str, Any], layers: Sequence[str], element: str) -> bool:
    try:
        traj = read_trajectory(root / entry["path"], verify=True)
    except TrajectoryFileError:
        return False
    digest = content_hash(traj)
    if entry.get("sha256") not in (None, digest):
        return False
    if entry_mismatch(entry, traj.meta, layers, element) is not None:
        return False
    entry["sha256"] = digest
    if entry.get("wall_time_s") is None and traj.meta.get("wall_time_s") is not None:
        entry["wall_time_s"] = float(traj.meta["wall_time_s"])
    return True


def default_batch() -> int:
    """Designs per solver batch when none is given: 8 (a manifest save every 8 designs), or the solver's
    designs per compiled call where that is larger (an accelerator, :func:`pcmgn_jax.sim.solver.designs_per_call`)."""
    return max(8, importlib.import_module("pcmgn_jax.sim.solver").designs_per_call())


def _solver(solve_fn):
    """(solve_designs or ``solve_fn`` if given, (SolverError,)); the solver (JAX) is imported lazily,
    through ``sys.modules`` (``import_module``), so a test can substitute the module."""
    solver = importlib.import_module("pcmgn_jax.sim.solver")
    return (solve_fn or solver.solve_designs), (solver.SolverError,)


# ---- generation ---------------------------------------------------------------------------------
def ensure_dataset(out_dir: str | os.PathLike, *, preset: str = "cpu", n_train: int = 100,
                   n_test: int = 50, seed: int = 0, designs: np.ndarray | None = None,
                   split: str | None = None, scene: Scene | None = None, batch: int = 0,
                   progress: bool = True, low: float = DESIGN_LOW, high: float = DESIGN_HIGH,
                   solve_fn: Callable[..., list[Trajectory]] | None = None, shard: tuple[int, int] | None = None,
                   merge: bool = False, stack_split: str | None = None) -> Path:
    """Generate the missing trajectories of a dataset with the solver; return ``Path(out_dir)``.

    designs=None: splits ``train``/``test`` from one seeded LHS of n_train + n_test designs [m].
    designs=(B, n_design) [m]: only the split ``split`` (default ``'extrap'``) with these designs; for a
    scene family (B, n_parameters): scene-parameter rows in the family's order (SI), which may lie outside
    its box (:func:`parse_scene_params`).
    Resumable: valid trajectories (hash-verified, same design) are skipped. The solver is called as
    ``solve_fn(scene, designs (b, n_design) [m], preset=preset) -> list[Trajectory]`` in batches of
    ``batch`` designs (default ``pcmgn_jax.sim.solver.solve_designs``; ``batch`` 0: :func:`default_batch`,
    8 on CPU, the solver's designs per call on an accelerator; give it explicitly when shards run on
    different devices, since the shards' plan depends on it). Designs that raise ``SolverError`` are
    retried one by one, recorded in the manifest with their error, and reported in a DatasetError
    raised after everything else has been written.

    ``shard=(K, N)`` (0-based): solve only the batches ``j % N == K`` of the design list cut into batches
    of ``batch`` (:func:`pcmgn_jax.data.shards.owner`) and write the part ``OUT/.shards/...-shard-K-of-N.json``
    instead of the manifest, so N shards can run at once into one directory. ``merge=True``: solve nothing;
    verify every trajectory, write the manifest and delete the parts, or raise a DatasetError naming each
    missing design and its shard (nothing written). An unsharded run also deletes the parts once complete.
    ``stack_split``: a stack family's split plan (e1 | e2 | e3, :data:`pcmgn_jax.data.stack.PLANS`): how its
    train and test scenes are drawn (other presets ignore it); None: the plan in OUT's manifest (so training,
    which generates what is missing, resumes a dataset of any plan), else e1.
    """
    root = Path(out_dir)
    scene = scene if scene is not None else default_scene()
    if shard is not None and merge:
        raise DatasetError(f"{root}: shard={shard!r} and merge=True exclude each other: solve the shards, then "
                           "merge once")
    if shard is not None and not (isinstance(shard, tuple) and len(shard) == 2 and 0 <= shard[0] < shard[1]):
        raise DatasetError(f"shard must be (K, N) with 0 <= K < N, got {shard!r}")
    if root.is_dir() and load_manifest(root) is None and not has_shard_parts(root) and has_trajectory_files(root):
        raise DatasetError(f"{root}: holds trajectory files in train/ or test/ but no {MANIFEST} (an imported "
                           "dataset?); the solver does not write into it: use another --out")
    if preset not in PRESET_NAMES:
        raise DatasetError(f"preset must be one of {PRESET_NAMES}, got {preset!r}")
    if not isinstance(batch, int) or batch < 0:
        raise DatasetError(f"batch must be an integer >= 0 (0: the device's default), got {batch!r}")
    batch = batch or default_batch()
    family = FAMILIES.get(preset)
    if family is not None:
        scene = family.base(scene)
    # explicit rows: design-layer thicknesses [m], or for a family its scene parameters (family order, SI:
    # e.g. scenes outside the family's box, experiments.generate --scene_params)
    n_design = len(scene.design_layers) if family is None else len(family.names)
    plan: dict[str, tuple[np.ndarray, dict[str, Any]]] = {}
    if designs is None:
        if split is not None:
            raise DatasetError("split is only used with explicit designs")
        if n_train < 0 or n_test < 0 or n_train + n_test == 0:
            raise DatasetError(f"need n_train + n_test > 0, got n_train={n_train}, n_test={n_test}")
        if family is None:
            lhs = lhs_designs(n_train + n_test, seed=seed, low=low, high=high, dim=n_design)
            origin = {"kind": "lhs", "seed": int(seed), "n_total": n_train + n_test, "low_m": low, "high_m": high}
        elif isinstance(family, StackFamily):
            if stack_split is None:
                origin = ((load_manifest(root) or {}).get("splits", {}).get("train") or {}).get("origin") or {}
                stack_split = origin.get("plan", "e1")
            try:
                lhs = np.concatenate(family.sample_splits(n_train, n_test, seed, stack_split))
            except ValueError as err:
                raise DatasetError(str(err)) from None
            origin = {"kind": "stack", "plan": stack_split, "seed": int(seed), "n_total": n_train + n_test,
                      "parameters": [list(p) for p in family.parameters]}
        else:
            lows, highs = (np.array([p[i] for p in family.parameters]) for i in (1, 2))
            lhs = lhs_designs(n_train + n_test, seed=seed, low=lows, high=highs, dim=len(lows))
            origin = {"kind": "lhs", "seed": int(seed), "n_total": n_train + n_test,
                      "parameters": [list(p) for p in family.parameters]}
        plan["train"] = (lhs[:n_train], {**origin, "rows": [0, n_train]})
        plan["test"] = (lhs[n_train:], {**origin, "rows": [n_train, n_train + n_test]})
    else:
        designs = np.asarray(designs, dtype=np.float64)
        split = split or "extrap"
        what = list(scene.design_layers) if family is None else list(family.names)
        if designs.ndim != 2 or designs.shape[1] != n_design or len(designs) == 0:
            raise DatasetError(f"designs must have shape (B>0, {n_design}) for {what}, got {designs.shape}"
                               + ("" if family is None else f" (preset {preset!r} is a scene family: give its "
                                                            "scene parameters, --scene_params)"))
        if not np.all(np.isfinite(designs)) or np.any(designs < 0 if isinstance(family, StackFamily) else designs <= 0):
            raise DatasetError(f"designs must be finite values > 0 (SI; >= 0 in a stack's padded row) for {what}")
        plan[split] = (designs, {"kind": "explicit"})
        for i, row in enumerate(designs if family is not None else ()):   # every scene made once, before the lock
            try:
                family.scene(scene, dict(zip(family.names, row)))
            except ValueError as err:
                raise DatasetError(f"scene {i + 1} of {len(designs)}: {err}") from None
    for name in plan:
        if not _SPLIT_RE.match(name):
            raise DatasetError(f"split name {name!r} must match {_SPLIT_RE.pattern}")
    # one writer per dataset (pcmgn_jax.lock): a shard holds the dataset's lock shared and its part's exclusively
    with ExitStack() as locks:
        if shard is None:
            locks.enter_context(hold(root, "generate"))
        else:
            locks.enter_context(hold(root, "generate --shard", shared=True))
            locks.enter_context(hold(root / SHARD_PARTS, f"generate --shard {shard[0]}/{shard[1]}",
                                     name=f".lock-shard-{shard[0]}-of-{shard[1]}"))
        return _generate(root, plan, scene=scene, family=family, preset=preset, batch=batch, progress=progress,
                         solve_fn=solve_fn, shard=shard, merge=merge)


def _generate(root: Path, plan: dict[str, tuple[np.ndarray, dict[str, Any]]], *, scene: Scene,
              family: SceneFamily | None, preset: str, batch: int, progress: bool, solve_fn, shard,
              merge: bool) -> Path:
    """:func:`ensure_dataset` once its arguments are checked and the dataset's lock is held."""
    man = load_manifest(root)
    manifest_path = root / MANIFEST
    if man is None:
        from pcmgn_jax.sim.fem import DEFAULT_ELEMENT

        man = {"format": DATASET_FORMAT, "format_version": 1, "preset": preset, "element": DEFAULT_ELEMENT,
               "scene": scene.to_dict(),
               "family": None if family is None else {"parameters": [list(p) for p in family.parameters]},
               "design_layers": list(scene.design_layers),
               "units": {"design_m": "m", "design_um": "µm", "wall_time_s": "s"}, "splits": {}}
    else:
        if man.get("preset") != preset:
            raise DatasetError(f"{manifest_path}: dataset was generated with preset {man.get('preset')!r}, "
                               f"not {preset!r}; use another folder")
        if man.get("scene") != scene.to_dict():
            raise DatasetError(f"{manifest_path}: dataset was generated for a different scene; use another folder")
        check_element(root, man)
    for name, (des, origin) in plan.items():
        old = man["splits"].get(name)
        entries = [_entry(name, i, d, family, scene) for i, d in enumerate(des)]
        if old is not None:
            key = "design_m" if family is None else "scene_params"
            old_d = np.asarray([e[key] if family is None else list(e[key].values()) for e in old["trajectories"]],
                               dtype=np.float64).reshape(len(old["trajectories"]), -1)
            if old_d.shape != des.shape or not np.allclose(old_d, des, rtol=1e-12, atol=0):
                why = origin_mismatch(old.get("origin") or {}, len(old_d), origin, len(des))
                raise DatasetError(f"{manifest_path}: split {name!r} {why}; use another dataset folder (or split name)")
            for e, o in zip(entries, old["trajectories"]):
                e["sha256"], e["wall_time_s"] = o.get("sha256"), o.get("wall_time_s")
        man["splits"][name] = {"origin": origin, "trajectories": entries}

    digest = shards.plan_digest(man, tuple(plan))
    parts = shards.check_parts(root, digest=digest, splits=tuple(plan), batch=batch, shard=shard)
    planned = [(name, e) for name in plan for e in man["splits"][name]["trajectories"]]
    shards.adopt([e for _, e in planned], parts)
    layers = scene.design_layers
    todo: list[tuple[str, dict[str, Any]]] = []
    chunks: dict[int, list[tuple[str, dict[str, Any]]]] = {}      # a shard's batches, by batch index
    own: list[dict[str, Any]] = []
    missing: list[tuple[int, dict[str, Any]]] = []
    for pos, (name, e) in enumerate(planned):
        if shard is not None and shards.owner(pos, batch=batch, n=shard[1]) != shard[0]:
            continue
        own.append(e)
        if not _is_done(root, e, layers, manifest_element(man)):
            e["sha256"], e["wall_time_s"] = None, None
            todo.append((name, e))
            chunks.setdefault(pos // batch, []).append((name, e))
            missing.append((pos, e))
    if merge and missing:
        raise DatasetError(shards.missing_report(root, missing, len(planned), parts, batch=batch))
    for name in plan:
        (root / name).mkdir(parents=True, exist_ok=True)

    def save(complete: bool = False) -> None:
        if shard is None:
            atomic_write_json(manifest_path, man)
        else:
            shards.write_part(root, man, tuple(plan), own, digest=digest, shard=shard, batch=batch,
                              complete=complete)

    save(complete=not todo)
    if not todo:
        if shard is None:
            shards.remove_parts(parts)
        return root

    solve, solver_errors = _solver(solve_fn)
    call_size = importlib.import_module("pcmgn_jax.sim.solver").call_size
    from tqdm.auto import tqdm

    failures: list[str] = []
    tag = "" if shard is None else f" shard {shard[0]}/{shard[1]}"
    bar = tqdm(total=len(todo), unit="design", desc=f"generate {root.name}{tag}", disable=not progress,
               dynamic_ncols=True)
    batches = ([todo[i:i + batch] for i in range(0, len(todo), batch)] if shard is None
               else list(chunks.values()))                    # a shard keeps the unsharded run's batches
    try:
        for chunk in batches:
            groups = [chunk]
            # a short last batch is padded with copies of its last design (results dropped) where the solver
            # would compile a call of another size for it (an accelerator); one batch alone is not
            pad = (batch - len(chunk)
                   if family is None and len(batches) > 1 and call_size(len(chunk)) != call_size(batch) else 0)
            t0 = time.perf_counter()
            try:
                results = [_solve_checked(solve, scene, chunk, preset, family, pad=pad)]
            except solver_errors:
                groups = [[item] for item in chunk]     # isolate the failing design(s)
                results = []
                for item in groups:
                    try:
                        results.append(_solve_checked(solve, scene, item, preset, family))
                    except solver_errors as err:
                        results.append(None)
                        item[0][1]["error"] = f"{type(err).__name__}: {err}"
                        failures.append(f"{item[0][1]['name']} design_um={item[0][1]['design_um']}: {err}")
            elapsed = time.perf_counter() - t0
            for group, trajs in zip(groups, results):
                if trajs is None:
                    continue
                for (_, e), traj in zip(group, trajs):
                    e["sha256"] = write_trajectory(traj, root / e["path"])
                    wall = traj.meta.get("wall_time_s")
                    e["wall_time_s"] = float(wall) if wall is not None else elapsed / len(chunk)
                    e.pop("error", None)
            save()
            bar.update(len(chunk))
    finally:
        bar.close()
    if failures:
        where = manifest_path if shard is None else f"{root}{tag}"
        raise DatasetError(f"{where}: {len(failures)} design(s) failed in the solver "
                           "(rerun to retry):\n  " + "\n  ".join(failures))
    if shard is None:
        shards.remove_parts(parts)
    else:
        save(complete=True)
    return root


def _solve_checked(solve, scene: Scene, items, preset: str, family: SceneFamily | None = None,
                   pad: int = 0) -> list[Trajectory]:
    """Solve the entries ``items``: one batched call over the design layers (``pad`` more copies of the last
    design, whose trajectories are dropped), or for a scene family one call per scene (each scene has its
    own mesh), its parameters recorded in meta['scene_params']."""
    if family is not None:
        trajs = []
        for _, e in items:
            one = family.scene(scene, e["scene_params"])
            (traj,) = _solve_checked(solve, one, [(None, e)], preset)
            traj.meta["scene_params"] = dict(e["scene_params"])
            traj.meta["family"] = preset
            trajs.append(traj)
        return trajs
    des = np.asarray([e["design_m"] for _, e in items] + [items[-1][1]["design_m"]] * pad, dtype=np.float64)
    trajs = list(solve(scene, des, preset=preset))
    if len(trajs) != len(des):
        raise DatasetError(f"solver returned {len(trajs)} trajectories for {len(des)} designs")
    return trajs[:len(items)]
