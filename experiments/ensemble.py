"""Trust: an ensemble of trained MGNs, and whether its spread (and kriging's) ranks the real error (issue 26).

  python -m experiments.ensemble --members runs/cpu_a,runs/cpu_b,runs/cpu_c,runs/cpu_d --extrap data/cpu/extrap
  python -m experiments.ensemble --train 4 --base runs/ens --train_flags "--formulation=realtime"
  python -m experiments.ensemble --members runs/family                      # one model: kriging, residual GP

--train K trains K members (seeds 0..K-1) into BASE/m0..m{K-1} with experiments.train and the given
--train_flags (a member whose run is finished is kept; a killed one resumes), then evaluates them.
The members must share one dataset. Sets: the runs' test split, plus --extrap (a folder of trajectories
with truth, e.g. the paper's extrapolation designs). Writes --out (default BASE or the first member's
folder /ensemble.json) and a markdown table beside it (pcmgn_jax/eval/ensemble.py has the definitions).
"""
from __future__ import annotations

import shlex
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

from pcmgn_jax import cli


@dataclass(frozen=True)
class EnsembleArgs:
    # cli.check_bounds: {flag: (lowest value, inclusive[, highest])}
    BOUNDS: ClassVar[dict] = {"train": (0, True)}
    members: str = ""          # comma-separated run directories (trained, same dataset)
    train: int = 0             # train this many members first (seeds 0..K-1) under --base
    base: str = "runs/ensemble"  # --train: the members' parent folder
    train_flags: str = "--formulation=realtime"  # --train: flags for experiments.train (besides --workdir, --seed)
    extrap: str = ""           # optional folder of trajectories (with truth) to score too
    out: str = ""              # result JSON (default <base or first member>/ensemble.json)


def _finished(w: Path) -> bool:
    """A run is finished when its log's last line is at the config's num_steps."""
    import json
    try:
        steps = json.loads((w / "config.json").read_text())["num_steps"]
        last = (w / "metrics.jsonl").read_text().strip().splitlines()[-1]
        return json.loads(last)["step"] >= steps
    except (OSError, KeyError, IndexError, ValueError):
        return False


def _train_members(args) -> list[str]:
    dirs = []
    for k in range(args.train):
        w = Path(args.base) / f"m{k}"
        if not _finished(w):
            flags = ["--workdir", str(w), "--seed", str(k), *shlex.split(args.train_flags)]
            if (w / "config.json").exists():
                flags = ["--workdir", str(w), "--resume"]
            print("train member:", " ".join(flags), flush=True)
            subprocess.run([sys.executable, "-m", "experiments.train", *flags], check=True)
        dirs.append(str(w))
    return dirs


def main(argv: list[str] | None = None) -> int:
    args = cli.parse(EnsembleArgs, argv, description=__doc__, prog="python -m experiments.ensemble")
    from pcmgn_jax.atomic import atomic_write_json, atomic_write_text
    from pcmgn_jax.config import TrainConfig
    from pcmgn_jax.data.splits import load_directory
    from pcmgn_jax.eval.ensemble import ensemble_report, report_markdown
    from pcmgn_jax.surrogates.mgn import run_splits

    members = [m for m in args.members.split(",") if m] + (_train_members(args) if args.train else [])
    if not members:
        raise ValueError("--members or --train: no ensemble members given")
    cfgs = [TrainConfig.load(Path(m) / "config.json") for m in members]
    data = {str(Path(c.resolved_dataset_dir).resolve()) for c in cfgs}
    if len(data) > 1:
        raise ValueError(f"ensemble members must share one dataset, got {sorted(data)}")
    _, train, _, test = run_splits(members[0])
    sets = {"test": test}
    if args.extrap:
        sets["extrap"] = load_directory(args.extrap)
    rep = ensemble_report(members, sets, train)
    command = cli.command_line("experiments.ensemble", argv)
    rep["command"] = command
    out = Path(args.out or (Path(args.base) if args.train else Path(members[0])) / "ensemble.json")
    atomic_write_json(out, rep)
    md = report_markdown(rep, command)
    atomic_write_text(out.with_suffix(".md"), md)
    print(md)
    print(f"wrote {out} and {out.with_suffix('.md')}")
    return 0


if __name__ == "__main__":
    sys.exit(cli.run(main))
