"""The solver search's trace against the surrogate searches: best solver-checked objective so far against wall
time and evaluations, beside each other result's solver-checked optimum and wall time (issue 50).

  python -m experiments.optimize_trace --files 'RUN/optimize/solver_slsqp.json,RUN/optimize/*_ga.json' \
      --train_seconds mgn_ga=5400 --out results/optimize/trace

Each file is a result JSON of ``experiments.optimize``, named by its file stem. A result with a ``trace``
(``--surrogate solver``: every evaluation a solver run) is drawn as its best value so far against the search's
wall time [s] and its evaluations; every other result is a horizontal line at its solver-checked optimum and, on
the time axis, a point at its search time plus its training time (``--train_seconds NAME=S ...``: the wall time
[s] spent training the surrogate of the result NAME, e.g. the MGN's). Writes OUT.png and OUT.md (the table:
pcmgn_jax/opt/table.py ``trace_rows``, with the evaluations and time after which the trace is within 0.5 % of
each other result).
"""
from __future__ import annotations

import glob
import sys
from dataclasses import dataclass
from pathlib import Path

from pcmgn_jax import cli


@dataclass(frozen=True)
class TraceArgs:
    files: str = ""                        # comma-separated paths or globs (quote them) of optimize JSONs
    out: str = "results/optimize/trace"    # writes OUT.png and OUT.md
    train_seconds: tuple[str, ...] = ()    # NAME=S ..., space-separated after one --train_seconds: training [s]


def load(files: str) -> dict:
    """{file stem: result} of the comma-separated paths / globs ``files``; ValueError naming a file that is no
    optimize result (:func:`pcmgn_jax.opt.table.read_result`), two files of one stem, or no file at all."""
    from pcmgn_jax.opt.table import read_result
    out, where = {}, {}
    for item in (s.strip() for s in files.split(",") if s.strip()):
        for p in sorted(glob.glob(item)) if any(c in item for c in "*?[") else [item]:
            d = read_result(p, required=("surrogate", "method", "optimum_um", "search_seconds"))
            stem = Path(p).stem
            if stem in where and where[stem] != p:
                raise ValueError(f"{p} and {where[stem]}: two results named {stem!r} (copy one under another name)")
            out[stem], where[stem] = d, p
    if not out:
        raise ValueError(f"--files {files!r}: no result file")
    return out


def main(argv=None) -> int:
    args = cli.parse(TraceArgs, argv, description=__doc__, prog="python -m experiments.optimize_trace")
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import NullFormatter

    from pcmgn_jax.atomic import atomic_write_text
    from pcmgn_jax.opt.table import best_so_far, trace_rows

    results = load(args.files)
    train = {}
    for item in args.train_seconds:
        name, eq, sec = item.partition("=")
        if not eq or name not in results:
            raise ValueError(f"--train_seconds {item!r}: give NAME=S with NAME one of {sorted(results)}")
        train[name] = float(sec)
    if not any("trace" in d for d in results.values()):
        raise ValueError(f"--files: none of {sorted(results)} holds a solver trace (optimize --surrogate solver)")
    fig, (ax_t, ax_n) = plt.subplots(1, 2, figsize=(11, 4.2), sharey=True)
    for i, (name, d) in enumerate(results.items()):
        colour = f"C{i}"
        if "trace" in d:
            c = best_so_far(d["trace"])
            ax_t.step([p["seconds"] for p in c], [p["best_mpa"] for p in c], where="post", color=colour, marker="o",
                      ms=3, label=f"{name} (best so far)")
            ax_n.step([p["evals"] for p in c], [p["best_mpa"] for p in c], where="post", color=colour, marker="o",
                      ms=3, label=name)
        elif d.get("solver_mpa") is not None:
            total = d["search_seconds"] + train.get(name, 0.0)
            for ax in (ax_t, ax_n):
                ax.axhline(d["solver_mpa"], color=colour, ls="--", lw=1)
            ax_t.plot([total], [d["solver_mpa"]], "s", color=colour,
                      label=f"{name}: search{' + training' if name in train else ''}")
            ax_n.plot([], [], "--", color=colour, label=f"{name} ({d['n_evals']:,} surrogate evaluations)")
    ax_t.set(xscale="log", xlabel="wall time [s]", ylabel="solver-checked objective [MPa]")
    ax_t.xaxis.set_minor_formatter(NullFormatter())     # the log axis's minor labels overlap
    ax_n.set(xlabel="solver runs (a value and gradient each; a screened value counts one)")
    for ax in (ax_t, ax_n):
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out.with_suffix(".png"), dpi=130)
    plt.close(fig)
    lines = trace_rows(results, train)
    command = cli.command_line("experiments.optimize_trace", argv)
    atomic_write_text(out.with_suffix(".md"), "\n".join(lines + ["", f"Command: `{command}`"]) + "\n")
    print("\n".join(lines))
    print(f"wrote {out.with_suffix('.png')} and {out.with_suffix('.md')}")
    return 0


if __name__ == "__main__":
    sys.exit(cli.run(main))
