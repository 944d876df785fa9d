"""Trajectory datasets: design sampling, scene families, resumable batched generation with the solver.

The directory layout, the manifest format and the rule for what a directory is live in
:mod:`pcmgn_jax.data.layout` (re-exported here); reading splits for a run (``load_splits``, ``prepare_dataset``,
``load_directory``) in :mod:`pcmgn_jax.data.splits`, which builds on this module.

Designs are thicknesses of ``scene.design_layers`` in metres (the manifest also lists them in µm).
``train`` and ``test`` come from ONE seeded Latin hypercube of ``n_train + n_test`` points over
[low, high]^dim (the rows are in random order, so the first ``n_train`` rows are a random subset);
explicit designs (``--designs``) go into a named split (default ``extrap``).

Scene families (:class:`pcmgn_jax.data.family.Family`; presets ``family``, ``family_tiny``, ``stack``,
``stack_tiny``, :data:`FAMILIES`): the family samples its rows of scene parameters (SI); every scene has its
own mesh (the mesh preset of the same name sizes the layers from their thickness) and is solved on its own.
Each manifest entry and trajectory meta records ``scene_params`` ({parameter: SI value}); ``design_m``
holds the design-layer thicknesses as before. What each split holds: :func:`pcmgn_jax.data.designs.sampled_splits`.

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
from collections.abc import Callable, Mapping, Sequence
from contextlib import ExitStack
from dataclasses import dataclass
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
    SplitPlan,
    explicit_split,
    lhs_designs,
    origin_mismatch,
    parse_designs,
    parse_scene_params,
    sampled_splits,
)
from pcmgn_jax.data.family import Design, Family
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
from pcmgn_jax.data.trajectory_io import TrajectoryFileError, content_hash, read_trajectory, write_trajectory
from pcmgn_jax.lock import hold
from pcmgn_jax.presets import PRESET_NAMES
from pcmgn_jax.scene import Scene, default_scene
from pcmgn_jax.trajectory import Trajectory

__all__ = ["FAMILIES", "GENERATE", "IMPORTED", "MANIFEST", "DatasetError", "Design", "Family", "SceneFamily",
           "SplitPlan", "dataset_source", "ensure_dataset", "lhs_designs", "load_manifest", "parse_designs",
           "parse_scene_params", "split_stems"]

_SPLIT_RE = re.compile(r"^[A-Za-z][A-Za-z0-9_-]*$")


@dataclass(frozen=True)
class _Job:
    """How :func:`ensure_dataset` generates, once its arguments are checked (see there)."""

    root: Path
    scene: Scene                   # the family's base scene, or the scene whose design layers vary
    family: Family | None
    preset: str
    batch: int
    progress: bool
    solve_fn: Callable[..., list[Trajectory]] | None
    shard: tuple[int, int] | None
    merge: bool

    @property
    def tag(self) -> str:
        return "" if self.shard is None else f" shard {self.shard[0]}/{self.shard[1]}"


# ---- top to bottom: check, plan the splits, lock, open the manifest, record, pick the work, solve --
def ensure_dataset(out_dir: str | os.PathLike, *, preset: str = "cpu", n_train: int = 100,
                   n_test: int = 50, seed: int = 0, designs: np.ndarray | None = None,
                   split: str | None = None, scene: Scene | None = None, batch: int = 0,
                   progress: bool = True, low: float = DESIGN_LOW, high: float = DESIGN_HIGH,
                   solve_fn: Callable[..., list[Trajectory]] | None = None, shard: tuple[int, int] | None = None,
                   merge: bool = False, stack_split: str | None = None, family: Family | None = None) -> Path:
    """Generate the missing trajectories of a dataset with the solver; return ``Path(out_dir)``.

    designs=None: splits ``train``/``test`` from one seeded LHS of n_train + n_test designs [m] in [low, high].
    designs=(B, n_design) [m]: only the split ``split`` (default ``'extrap'``) with these designs; for a
    scene family (B, n_parameters): scene-parameter rows in the family's order (SI), which may lie outside
    its box (:func:`parse_scene_params`).
    ``family``: a :class:`pcmgn_jax.data.family.Family` (default the preset's, :data:`FAMILIES`, if any):
    its :meth:`~pcmgn_jax.data.family.Family.sample_splits` draws train and test, each scene is meshed
    (``preset``) and solved on its own, and each trajectory records its row (meta['scene_params']).
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
    ``stack_split``: a family's split plan (its ``plans``; the stack's e1 | e2 | e3,
    :data:`pcmgn_jax.data.stack.PLANS`): how its train and test scenes are drawn (a family of one plan
    ignores it); None: the plan in OUT's manifest (so training, which generates what is missing, resumes a
    dataset of any plan), else the family's first.
    """
    root = Path(out_dir)
    _check_request(root, preset=preset, batch=batch, shard=shard, merge=merge)
    family = family if family is not None else FAMILIES.get(preset)
    scene = scene if scene is not None else default_scene()
    job = _Job(root, scene if family is None else family.base(scene), family, preset, batch or default_batch(),
               progress, solve_fn, shard, merge)
    if designs is None:
        if split is not None:
            raise DatasetError("split is only used with explicit designs")
        if family is not None and family.plans and stack_split is None:     # the plan OUT records
            train = (load_manifest(root) or {}).get("splits", {}).get("train") or {}
            stack_split = (train.get("origin") or {}).get("plan")
        plan = sampled_splits(job.scene, family, n_train=n_train, n_test=n_test, seed=seed, low=low, high=high,
                              plan=stack_split)
    else:
        plan = [explicit_split(job.scene, family, designs, split or "extrap", preset=preset)]
    for sp in plan:
        if not _SPLIT_RE.match(sp.name):
            raise DatasetError(f"split name {sp.name!r} must match {_SPLIT_RE.pattern}")
    with _dataset_lock(root, shard):
        return _generate(job, plan)


def _check_request(root: Path, *, preset: str, batch: int, shard, merge: bool) -> None:
    """DatasetError for a request that cannot run, before anything is planned or written."""
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


def _dataset_lock(root: Path, shard: tuple[int, int] | None) -> ExitStack:
    """One writer per dataset (:mod:`pcmgn_jax.lock`): a shard holds the dataset's lock shared and its part's
    exclusively."""
    locks = ExitStack()
    if shard is None:
        locks.enter_context(hold(root, "generate"))
    else:
        locks.enter_context(hold(root, "generate --shard", shared=True))
        locks.enter_context(hold(root / SHARD_PARTS, f"generate --shard {shard[0]}/{shard[1]}",
                                 name=f".lock-shard-{shard[0]}-of-{shard[1]}"))
    return locks


def _generate(job: _Job, plan: Sequence[SplitPlan]) -> Path:
    """:func:`ensure_dataset` once its arguments are checked and the dataset's lock is held."""
    man = _open_manifest(job)
    designs = _record_splits(job, man, plan)
    names = tuple(sp.name for sp in plan)
    digest = shards.plan_digest(man, names)
    parts = shards.check_parts(job.root, digest=digest, splits=names, batch=job.batch, shard=job.shard)
    planned = [e for sp in plan for e in man["splits"][sp.name]["trajectories"]]
    shards.adopt(planned, parts)
    own, batches, missing = _pick_work(job, man, planned)
    if job.merge and missing:
        raise DatasetError(shards.missing_report(job.root, missing, len(planned), parts, batch=job.batch))
    for name in names:
        (job.root / name).mkdir(parents=True, exist_ok=True)

    def save(complete: bool = False) -> None:
        if job.shard is None:
            atomic_write_json(job.root / MANIFEST, man)
        else:
            shards.write_part(job.root, man, names, own, digest=digest, shard=job.shard, batch=job.batch,
                              complete=complete)

    save(complete=not batches)
    if batches:
        _solve_batches(job, batches, designs, save)
    if job.shard is None:
        shards.remove_parts(parts)
    elif batches:
        save(complete=True)
    return job.root


def _open_manifest(job: _Job) -> dict[str, Any]:
    """OUT's manifest, or a new one; DatasetError when it was written for another preset, scene or element."""
    man = load_manifest(job.root)
    if man is None:
        from pcmgn_jax.sim.fem import DEFAULT_ELEMENT

        family = job.family
        return {"format": DATASET_FORMAT, "format_version": 1, "preset": job.preset, "element": DEFAULT_ELEMENT,
                "scene": job.scene.to_dict(),
                "family": None if family is None else {"parameters": [list(p) for p in family.parameters]},
                "design_layers": list(job.scene.design_layers),
                "units": {"design_m": "m", "design_um": "µm", "wall_time_s": "s"}, "splits": {}}
    where = job.root / MANIFEST
    if man.get("preset") != job.preset:
        raise DatasetError(f"{where}: dataset was generated with preset {man.get('preset')!r}, "
                           f"not {job.preset!r}; use another folder")
    if man.get("scene") != job.scene.to_dict():
        raise DatasetError(f"{where}: dataset was generated for a different scene; use another folder")
    check_element(job.root, man)
    return man


def _record_splits(job: _Job, man: dict[str, Any], plan: Sequence[SplitPlan]) -> dict[str, Design]:
    """Write the planned splits' entries into ``man`` (a recorded split must hold the same designs: its
    hashes and wall times carry over); {entry name: its design}."""
    out = {}
    for sp in plan:
        old = man["splits"].get(sp.name)
        entries = [_entry(sp.name, i, d, job.scene) for i, d in enumerate(sp.designs)]
        if old is not None:
            olds = old["trajectories"]
            old_d = np.asarray([e["design_m"] if job.family is None else list(e["scene_params"].values())
                                for e in olds], dtype=np.float64).reshape(len(olds), -1)
            rows = sp.rows
            if old_d.shape != rows.shape or not np.allclose(old_d, rows, rtol=1e-12, atol=0):
                why = origin_mismatch(old.get("origin") or {}, len(old_d), sp.origin, len(rows))
                raise DatasetError(f"{job.root / MANIFEST}: split {sp.name!r} {why}; use another dataset folder "
                                   "(or split name)")
            for e, o in zip(entries, olds):
                e["sha256"], e["wall_time_s"] = o.get("sha256"), o.get("wall_time_s")
        man["splits"][sp.name] = {"origin": sp.origin, "trajectories": entries}
        out.update({e["name"]: d for e, d in zip(entries, sp.designs)})
    return out


def _entry(split: str, i: int, design: Design, base: Scene) -> dict[str, Any]:
    """A manifest entry; a family's design records its row as ``scene_params`` beside the design-layer
    thicknesses of its scene (and, for a padded row, the scene's layer list, top to bottom)."""
    name = f"{split}_{i:04d}"
    out: dict[str, Any] = {"name": name, "path": f"{split}/{name}"}
    values = design.values
    if design.family is not None:
        out["scene_params"] = design.row
        one = design.scene(base)
        values = one.design
        if design.family.padded:
            out["layers"] = [layer.name for layer in one.layers]
    out.update({"design_m": [float(v) for v in values], "design_um": [round(float(v) * 1e6, 6) for v in values],
                "sha256": None, "wall_time_s": None})
    return out


def _pick_work(job: _Job, man: dict[str, Any], planned: Sequence[dict[str, Any]]):
    """(this run's entries, its batches of entries still to solve, [(position, entry)] of those): an
    unsharded run cuts what is missing into batches of ``batch``; a shard keeps the unsharded run's batches
    of the whole design list and solves those it owns (:func:`pcmgn_jax.data.shards.owner`)."""
    own: list[dict[str, Any]] = []
    chunks: dict[int, list[dict[str, Any]]] = {}        # a shard's batches, by batch index
    missing: list[tuple[int, dict[str, Any]]] = []
    for pos, e in enumerate(planned):
        if job.shard is not None and shards.owner(pos, batch=job.batch, n=job.shard[1]) != job.shard[0]:
            continue
        own.append(e)
        if not _is_done(job.root, e, job.scene.design_layers, manifest_element(man)):
            e["sha256"], e["wall_time_s"] = None, None
            chunks.setdefault(pos // job.batch, []).append(e)
            missing.append((pos, e))
    todo = [e for _, e in missing]
    batches = ([todo[i:i + job.batch] for i in range(0, len(todo), job.batch)] if job.shard is None
               else list(chunks.values()))
    return own, batches, missing


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


def _solve_batches(job: _Job, batches: Sequence[Sequence[dict[str, Any]]], designs: Mapping[str, Design],
                   save: Callable[[], None]) -> None:
    """Solve and write every batch, saving the manifest (or the shard's part) after each; a batch that raises
    ``SolverError`` is retried design by design. DatasetError listing the designs that failed, at the end."""
    solver = importlib.import_module("pcmgn_jax.sim.solver")      # lazily, so a test can substitute it
    solve, solver_errors = job.solve_fn or solver.solve_designs, (solver.SolverError,)
    from tqdm.auto import tqdm

    failures: list[str] = []
    bar = tqdm(total=sum(map(len, batches)), unit="design", desc=f"generate {job.root.name}{job.tag}",
               disable=not job.progress, dynamic_ncols=True)
    try:
        for chunk in batches:
            groups = [chunk]
            # a short last batch is padded with copies of its last design (results dropped) where the solver
            # would compile a call of another size for it (an accelerator); one batch alone is not
            pad = (job.batch - len(chunk) if job.family is None and len(batches) > 1
                   and solver.call_size(len(chunk)) != solver.call_size(job.batch) else 0)
            t0 = time.perf_counter()
            try:
                results = [_solve_checked(solve, job, chunk, designs, pad=pad)]
            except solver_errors:
                groups = [[e] for e in chunk]     # isolate the failing design(s)
                results = []
                for group in groups:
                    try:
                        results.append(_solve_checked(solve, job, group, designs))
                    except solver_errors as err:
                        results.append(None)
                        group[0]["error"] = f"{type(err).__name__}: {err}"
                        failures.append(f"{group[0]['name']} design_um={group[0]['design_um']}: {err}")
            elapsed = time.perf_counter() - t0
            for group, trajs in zip(groups, results):
                for e, traj in zip(group, trajs or ()):
                    e["sha256"] = write_trajectory(traj, job.root / e["path"])
                    wall = traj.meta.get("wall_time_s")
                    e["wall_time_s"] = float(wall) if wall is not None else elapsed / len(chunk)
                    e.pop("error", None)
            save()
            bar.update(len(chunk))
    finally:
        bar.close()
    if failures:
        where = job.root / MANIFEST if job.shard is None else f"{job.root}{job.tag}"
        raise DatasetError(f"{where}: {len(failures)} design(s) failed in the solver "
                           "(rerun to retry):\n  " + "\n  ".join(failures))


def _solve_checked(solve, job: _Job, entries, designs: Mapping[str, Design], pad: int = 0) -> list[Trajectory]:
    """Solve ``entries``: one batched call over the design layers (``pad`` more copies of the last design,
    whose trajectories are dropped), or for a family one call per scene (each scene has its own mesh), its
    row recorded in meta['scene_params'] and the family's name in meta['family']."""
    if job.family is not None:
        trajs = []
        for e in entries:
            one = designs[e["name"]].scene(job.scene)
            (traj,) = _solve(solve, one, [e["design_m"]], job.preset)
            traj.meta["scene_params"] = dict(e["scene_params"])
            traj.meta["family"] = job.family.name
            trajs.append(traj)
        return trajs
    return _solve(solve, job.scene, [e["design_m"] for e in entries] + [entries[-1]["design_m"]] * pad,
                  job.preset)[:len(entries)]


def _solve(solve, scene: Scene, rows, preset: str) -> list[Trajectory]:
    """``solve(scene, rows (b, n_design) [m], preset=preset)``; DatasetError when it returns another count."""
    des = np.asarray(rows, dtype=np.float64)
    trajs = list(solve(scene, des, preset=preset))
    if len(trajs) != len(des):
        raise DatasetError(f"solver returned {len(trajs)} trajectories for {len(des)} designs")
    return trajs
