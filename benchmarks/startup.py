"""Start-up: seconds from launching a command to its first training step, first rollout and first solver call,
with an empty (cold) and a filled (warm) persistent compilation cache (issue 42).

    python -m benchmarks.startup [--preset cpu] [--data DIR] [--json PATH] [--md PATH] [--budget_s 900]

Each figure is measured in a fresh process of the real entry point, from just before the process is started
(so Python's start, the imports, reading the data, building the graphs, initialising the model and compiling
all count) to the end of the event, read from the compile notes (:mod:`pcmgn_jax.compile_notes`: the unix
time at which the first call of each compiled computation returned):

- ``train``: ``python -m experiments.train --preset P --dataset_dir DATA --num_steps=1 --steps_per_dispatch=1``
  in a new run folder: **first training step** = the end of the first (one-step) training call; **first
  rollout** = the end of the validation rollout that follows it (the run's ``n_val`` trajectories);
- ``solver``: ``python -m experiments.generate --preset P --n_train 1 --n_test 0`` into a new folder:
  **first solver call** = the end of the first solver call (one design, the scene's whole trajectory).

Three conditions (``--conditions``), in this order, each a new process, command by command (training first,
then the solver; each command with a cache folder of its own): ``off`` (``PCMGN_JAX_CACHE=0``), ``cold`` (an
empty cache folder) and ``warm`` (the same folder, filled by the cold run). Before the first, one untimed training
process (cache off; ``--no_prime``: none) builds the dataset's read cache and warms the OS file cache. The XLA compile
seconds of each first call are reported beside (``xla_s``; ~0 when the program came from the cache). ``--data``: a
dataset folder of the preset (made with the solver when missing; default a temporary folder). The JSON is rewritten
after every measurement; ``--budget_s`` skips what is not started in time, saying so.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from benchmarks import common
from pcmgn_jax import cli
from pcmgn_jax.eval import bench
from pcmgn_jax.presets import PresetName

ROOT = Path(__file__).resolve().parents[1]
CONDITIONS = ("off", "cold", "warm")


@dataclass(frozen=True)
class StartupArgs(common.Outputs):
    preset: PresetName = "cpu"            # training preset (its data preset is generated if missing)
    data: str = ""                        # the preset's dataset folder (default: a temporary one)
    conditions: str = ",".join(CONDITIONS)  # comma list of off, cold, warm (in this order; warm needs cold before it)
    # one untimed training process first (the dataset's read cache; --no_prime when a run has trained on --data already)
    prime: bool = True
    budget_s: float = 900.0               # seconds for the whole benchmark


def _notes(path: Path) -> list[dict]:
    if not path.exists():
        return []
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def _first(notes: list[dict], label: str) -> dict | None:
    return next((n for n in notes if n["compile"] == label), None)


def launch(cmd: list[str], env: dict, timeout: float) -> tuple[float, subprocess.CompletedProcess | None]:
    """(unix time just before the start, the finished process or None when killed at ``timeout``)."""
    t0 = time.time()
    try:
        run = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=max(1.0, timeout))
    except subprocess.TimeoutExpired:
        return t0, None
    return t0, run


def measure(kind: str, a, data: Path, work: Path, env: dict, timeout: float) -> dict:
    """One process of ``kind`` (train | solver): its events' seconds from launch."""
    folder = Path(tempfile.mkdtemp(prefix=f"{kind}-", dir=work))
    log = folder / "compile.jsonl"
    if kind == "train":
        run_dir = folder / "run"
        cmd = [sys.executable, "-m", "experiments.train", "--preset", a.preset, "--dataset_dir", str(data),
               "--workdir", str(run_dir), "--num_steps=1", "--steps_per_dispatch=1", "--log_every=1",
               "--ckpt_every=1", "--val_every=1", "--no_progress"]
        log = run_dir / "compile.jsonl"
        events = {"first_training_step": "the training step", "first_rollout": "the validation rollout"}
    else:
        cmd = [sys.executable, "-m", "experiments.generate", "--preset", _data_preset(a.preset), "--n_train", "1",
               "--n_test", "0", "--out", str(folder / "data"), "--no_progress"]
        events = {"first_solver_call": "the solver"}
    t0, run = launch(cmd, {**env, "PCMGN_COMPILE_LOG": str(log)}, timeout)
    out: dict = {"command": cli.command_line(cmd[2], cmd[3:]), "process_s": time.time() - t0}
    if run is None or run.returncode != 0:
        why = "killed at the budget" if run is None else f"exit {run.returncode}: " + " | ".join(
            (run.stderr or run.stdout).strip().splitlines()[-3:])
        return {**out, "error": why}
    notes = _notes(log)
    for name, label in events.items():
        n = _first(notes, label)
        out[name] = None if n is None else {"s": n["time"] - t0, "first_call_s": n["seconds"],
                                            "xla_s": n["xla_seconds"]}
    return out


def _data_preset(preset: str) -> str:
    from pcmgn_jax.config import TrainConfig
    return TrainConfig.from_preset(preset).data_preset


def main(argv=None) -> dict:
    a = cli.parse(StartupArgs, argv, description=__doc__, prog="python -m benchmarks.startup")
    from pcmgn_jax.atomic import atomic_write_text

    base_env = {k: v for k, v in os.environ.items() if k not in ("PCMGN_JAX_CACHE", "PCMGN_JAX_CACHE_DIR")}
    os.environ["JAX_PLATFORMS"] = "cpu"    # this process never takes the device (a GPU's memory) from the runs
    t_start = time.perf_counter()
    path = Path(a.json) if a.json else common.RESULTS / "startup.json"
    md_path = Path(a.md) if a.md else path.with_suffix(".md")
    work = Path(tempfile.mkdtemp(prefix="pcmgn-startup-"))
    data = Path(a.data) if a.data else work / "data"
    base_env["PYTHONPATH"] = os.pathsep.join(
        [str(ROOT)] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p])
    result: dict = {"config": {"preset": a.preset, "data": str(data), "budget_s": a.budget_s,
                               "command": cli.command_line("benchmarks.startup", argv)},
                    "machine": {**bench.machine_info(), "jax_backend": "(not used by the measuring process)"},
                    "runs": {}, "skipped": []}

    def left() -> float:
        return a.budget_s - (time.perf_counter() - t_start)

    def save():
        result["total_s"] = time.perf_counter() - t_start
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(path, json.dumps(common.clean(result), indent=1, allow_nan=False) + "\n")
        atomic_write_text(md_path, table(result))

    if not (data / "manifest.json").exists():          # the dataset first (not timed here)
        t0 = time.perf_counter()
        cmd = [sys.executable, "-m", "experiments.generate", "--preset", _data_preset(a.preset), "--out", str(data),
               "--no_progress"]
        _, run = launch(cmd, {**base_env, "PCMGN_JAX_CACHE": "0"}, left())
        result["data_generation_s"] = time.perf_counter() - t0
        if run is None or run.returncode != 0:
            result["skipped"].append({"what": "everything", "why": "the dataset could not be generated in the budget"
                                      if run is None else (run.stderr or run.stdout)[-500:]})
            save()
            print(json.dumps(result["skipped"]))
            return result
    conditions = [c for c in CONDITIONS if c in a.conditions.split(",")]
    result["config"]["conditions"] = conditions
    # command by command (its cold run, then its warm one: on a GPU lent for minutes the warm figure comes
    # right after the cold one); each command has its own cache folder, so its cold run starts empty
    for kind in ("train", "solver"):
        cache = work / f"jax-cache-{kind}"
        for cond in conditions:
            env = dict(base_env)
            if cond == "off":
                env["PCMGN_JAX_CACHE"] = "0"
            else:
                env["PCMGN_JAX_CACHE_DIR"] = str(cache)
            # prime: the dataset's read cache, the OS file cache
            if a.prime and cond == conditions[0] and kind == "train":
                measure(kind, a, data, work, {**env, "PCMGN_JAX_CACHE": "0"}, left())
            if left() < 5:
                result["skipped"].append({"what": f"{cond} {kind}",
                                          "why": f"{max(left(), 0):.0f} s of the budget left"})
                save()
                continue
            r = measure(kind, a, data, work, env, left())
            result["runs"].setdefault(cond, {})[kind] = r
            save()
            print(f"{cond:5s} {kind:6s} " + ", ".join(
                f"{k} {v['s']:.1f} s (XLA {v['xla_s']:.1f} s)" for k, v in r.items()
                if isinstance(v, dict)) + (f" error: {r['error']}" if "error" in r else ""), flush=True)
        result.setdefault("cache_bytes", {})[kind] = (sum(p.stat().st_size for p in cache.rglob("*") if p.is_file())
                                                      if cache.exists() else 0)
    save()
    print(table(result))
    print(f"wrote {path} and {md_path}")
    return result


def table(result: dict) -> str:
    rows = []
    for kind, event in (("train", "first_training_step"), ("train", "first_rollout"), ("solver", "first_solver_call")):
        row = [event.replace("_", " ")]
        for cond in CONDITIONS:
            v = result["runs"].get(cond, {}).get(kind, {}).get(event)
            row.append("—" if not v else f"{v['s']:.1f} s (XLA {v['xla_s']:.1f} s)")
        rows.append(row)
    cmd = result["config"]["command"]
    return (f"## Start-up, seconds from launch (`{cmd}`)\n\n"
            + common.md_table(["event", "cache off", "cold cache", "warm cache"], rows))


if __name__ == "__main__":
    common.run(main)
