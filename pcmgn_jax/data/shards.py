"""Sharded generation: ``experiments.generate --shard K/N`` as one task of a scheduler's array job.

Which designs a shard solves. The run's design list (the splits in manifest order: ``train`` then
``test``, or the one explicit split) is cut into solver batches of ``batch`` designs, as one unsharded
run on an empty directory cuts it; shard ``K`` of ``N`` (0-based, ``0 <= K < N``, as
``SLURM_ARRAY_TASK_ID`` with ``--array=0-(N-1)``) solves the batches ``j`` with ``j % N == K``
(:func:`owner`). The batch is the unit because the solver's stable step is the minimum over a batch
and each trajectory records its batch: the same batches give the same trajectories, bit for bit, as
one process. No two shards write the same trajectory file, and each file is written atomically.

Who writes the manifest. Only one process writes ``OUT/manifest.json``. A shard writes its own part,
``OUT/.shards/PLAN-shard-KKKK-of-NNNN.json`` (PLAN = the first 12 hex digits of :func:`plan_digest`),
atomically, before its first solver batch and after each one::

    {"format": "pcmgn_jax.dataset.shard", "format_version": 1, "plan_sha256": "...",
     "shard": [K, N], "batch": 8, "preset": "paper", "splits": {"train": {"origin": {...}, "n": 105}, ...},
     "complete": true,                  # every design of the shard was written
     "trajectories": [{"name": "train_0003", "path": "train/train_0003", "sha256": "..." | null,
                       "wall_time_s": 1.9 | null, "error": "SolverError: ..."?}, ...]}

The merge (``--merge``) reads every trajectory back (hash-verified, design checked), writes the manifest
and deletes the parts of its plan; a design that is missing is a DatasetError naming it and its shard
(:func:`missing_report`), and nothing is written. An unsharded run into the same directory generates
what is missing and deletes the parts once it is complete. Parts of another plan that share a split
name, or of the same plan with another ``N`` or ``batch``, are an error before anything is solved.
"""
from __future__ import annotations

import hashlib
import json
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from pcmgn_jax.atomic import atomic_write_json
from pcmgn_jax.data.layout import MANIFEST, SHARD_PARTS, DatasetError, read_format_json
from pcmgn_jax.errors import SettingError

__all__ = ["PART_FORMAT", "adopt", "check_parts", "missing_report", "owner", "parse_shard", "plan_digest",
           "read_parts", "remove_parts", "write_part"]

PART_FORMAT = "pcmgn_jax.dataset.shard"
_SHARD_RE = re.compile(r"^\s*(\d+)\s*/\s*(\d+)\s*$")


def parse_shard(text: str) -> tuple[int, int]:
    """``"K/N"`` -> ``(K, N)``: shard K (0-based) of N, ``0 <= K < N``; ValueError naming the flag otherwise."""
    m = _SHARD_RE.match(text) if isinstance(text, str) else None
    if m is None:
        raise SettingError("shard", f"{text!r}: expected K/N, e.g. 3/8 (shard K of N, K counted from 0)")
    k, n = int(m.group(1)), int(m.group(2))
    if n < 1 or k >= n:
        raise SettingError("shard", f"{text}: K must be in 0..{max(n - 1, 0)} and N >= 1 (K counts from 0, as "
                         f"SLURM_ARRAY_TASK_ID with --array=0-{max(n - 1, 0)})")
    return k, n


def owner(position: int, *, batch: int, n: int) -> int:
    """The shard (0-based, of ``n``) that solves the design at ``position`` of the run's design list."""
    return (position // batch) % n


def plan_digest(man: Mapping[str, Any], splits: Sequence[str]) -> str:
    """sha256 over what a run generates: preset, scene, family, design layers, and for each of ``splits``
    its origin and designs (names, ``design_m``, ``scene_params``); not hashes or timings."""
    plan = {k: man.get(k) for k in ("preset", "scene", "family", "design_layers")}
    plan["splits"] = {s: {"origin": man["splits"][s]["origin"],
                          "designs": [[e["name"], e["design_m"], e.get("scene_params")]
                                      for e in man["splits"][s]["trajectories"]]} for s in splits}
    return hashlib.sha256(json.dumps(plan, sort_keys=True).encode()).hexdigest()


def _part_path(root: Path, digest: str, k: int, n: int) -> Path:
    return root / SHARD_PARTS / f"{digest[:12]}-shard-{k:04d}-of-{n:04d}.json"


def read_parts(root: Path) -> list[dict[str, Any]]:
    """Every shard part in ``root/.shards`` (each with its file under ``"_path"``), sorted by file name."""
    folder = root / SHARD_PARTS
    if not folder.is_dir():
        return []
    parts = []
    for path in sorted(folder.glob("*-shard-*-of-*.json")):
        part = read_format_json(path, PART_FORMAT, "shard part")
        part["_path"] = path
        parts.append(part)
    return parts


def check_parts(root: Path, *, digest: str, splits: Sequence[str], batch: int,
                shard: tuple[int, int] | None) -> list[dict[str, Any]]:
    """The parts of this plan (``digest``); DatasetError for a part of another plan that writes one of
    ``splits``, or (``shard`` given) a part of this plan with another N or ``batch``."""
    mine = []
    for part in read_parts(root):
        if part.get("plan_sha256") == digest:
            if shard is not None and (part["shard"][1] != shard[1] or part["batch"] != batch):
                raise DatasetError(
                    f"{part['_path']}: written by --shard {part['shard'][0]}/{part['shard'][1]} with --batch "
                    f"{part['batch']}; this run is --shard {shard[0]}/{shard[1]} with --batch {batch}. Every shard "
                    f"of a sweep needs the same N and --batch (or delete {root / SHARD_PARTS} and start over)")
            mine.append(part)
        elif set(part.get("splits", {})) & set(splits):
            common = sorted(set(part["splits"]) & set(splits))
            raise DatasetError(
                f"{part['_path']}: a shard of another run (other preset, scene, seed, sizes or designs; split "
                f"{common[0]!r} origin {part['splits'][common[0]]['origin']}) writes into this directory. Give "
                "every shard and the merge the same flags, or use another --out")
    return mine


def adopt(entries: Sequence[dict[str, Any]], parts: Sequence[Mapping[str, Any]]) -> None:
    """Take ``sha256`` and ``wall_time_s`` of ``entries`` (manifest entries) from the parts that wrote them
    (a part is newer than the manifest it was run against); the files are verified afterwards anyway."""
    recorded = {t["name"]: t for part in parts for t in part["trajectories"] if t.get("sha256")}
    for e in entries:
        t = recorded.get(e["name"])
        if t is not None:
            e["sha256"], e["wall_time_s"] = t["sha256"], t.get("wall_time_s")


def write_part(root: Path, man: Mapping[str, Any], splits: Sequence[str], own: Sequence[Mapping[str, Any]], *,
               digest: str, shard: tuple[int, int], batch: int, complete: bool) -> None:
    """Write (atomically) the part of shard ``shard`` = (K, N): its entries ``own`` as they stand now."""
    keys = ("name", "path", "sha256", "wall_time_s", "error")
    part = {"format": PART_FORMAT, "format_version": 1, "plan_sha256": digest, "shard": list(shard),
            "batch": batch, "preset": man["preset"],
            "splits": {s: {"origin": man["splits"][s]["origin"], "n": len(man["splits"][s]["trajectories"])}
                       for s in splits},
            "complete": bool(complete), "trajectories": [{k: e[k] for k in keys if k in e} for e in own]}
    path = _part_path(root, digest, *shard)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_json(path, part)


def remove_parts(parts: Sequence[Mapping[str, Any]]) -> None:
    """Delete merged parts (and the ``.shards`` folder once it is empty, the shards' lock files with it: the
    caller holds the dataset's lock exclusively, so no shard runs)."""
    for part in parts:
        Path(part["_path"]).unlink(missing_ok=True)
    if parts:
        for f in Path(parts[0]["_path"]).parent.glob(".lock-shard-*"):
            f.unlink(missing_ok=True)
        try:
            Path(parts[0]["_path"]).parent.rmdir()
        except OSError:
            pass       # other plans' parts (or a shard's temp file) are still there


def missing_report(root: Path, missing: Sequence[tuple[int, Mapping[str, Any]]], n_total: int,
                   parts: Sequence[Mapping[str, Any]], *, batch: int) -> str:
    """The merge's error: every missing design ``(position, entry)`` with the shard that owns it and what
    that shard's part says (none written, not finished, failed in the solver, or a file that does not verify)."""
    by_shard = {part["shard"][0]: part for part in parts}
    n = parts[0]["shard"][1] if parts else None
    b = parts[0]["batch"] if parts else batch
    lines = []
    for pos, e in missing:
        what = f"{e['name']} design_um={e['design_um']}"
        if n is None:
            lines.append(f"{what}: no shard part records it")
            continue
        k = owner(pos, batch=b, n=n)
        part = by_shard.get(k)
        rec = {t["name"]: t for t in part["trajectories"]} if part is not None else {}
        t = rec.get(e["name"], {})
        if part is None:
            why = "wrote no part (not started, or killed before its first batch)"
        elif t.get("error"):
            why = f"failed in the solver: {t['error']}"
        elif t.get("sha256"):
            why = "recorded it, but the file is missing or does not verify"
        else:
            why = "has not finished (still running, or killed)"
        lines.append(f"{what}: shard {k}/{n} {why}")
    shown = lines[:40] + ([f"... and {len(lines) - 40} more"] if len(lines) > 40 else [])
    return (f"{root}: {len(missing)} of {n_total} trajectories missing or invalid; {MANIFEST} not written. "
            "Run the shards named below again (same flags), then --merge:\n  " + "\n  ".join(shown))
