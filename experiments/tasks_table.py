"""The task tables: the MGN beside every baseline on each task, the winner per metric named.

  python -m experiments.tasks_table --manifest results/tasks.toml --out docs/results/tasks.md
  python -m experiments.tasks_table --task a=runs/cpu/eval/metrics.json,runs/cpu_seed1/eval/metrics.json \
      b=runs/family/eval/metrics.json --out /tmp/t.md

The manifest (TOML) has one ``[tasks]`` table: each key a task (a | b | c | d, see
pcmgn_jax.eval.tasks.TASKS) or ``T.VARIANT``, each value the list of evaluate()'s metrics.json files, one
per MGN seed; ``--task T=FILES`` gives the same on the command line (both may be used; a key given twice is
an error). An optional ``[baselines]`` table, ``"T" = "metrics.json"``, lends a task whose files were evaluated
with ``--no_baselines`` the baselines of another evaluation of the same test split (checked: the test designs'
true objectives must be identical). A task not given is listed as not measured. When ``--out`` exists and holds the line
:data:`KEEP_MARKER`, everything from that line on (the hand-written reading) is kept below the new tables.
"""
import sys
import textwrap
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from pcmgn_jax import cli


@dataclass(frozen=True)
class TasksArgs:
    # TOML file with a [tasks] table: "T" = ["metrics.json", ...] (e.g. results/tasks.toml)
    manifest: str = ""
    # T=metrics.json[,metrics.json...] ... (T: a | b | c | d, or T.VARIANT such as d.cg_thin), space-separated after
    # one --task
    task: tuple[str, ...] = ()
    out: str = ""                  # Markdown file to write ("" = print only)
    note: tuple[str, ...] = field(default_factory=tuple)   # lines to put under the title (budgets, what is missing)


KEEP_MARKER = "<!-- hand-written below this line: kept when the tables are regenerated -->"


def manifest(path: str) -> tuple[list[str], dict[str, str]]:
    """A TOML manifest, read once: its ``[tasks]`` table as ``--task`` specs (``T=a.json,b.json``) and its optional
    ``[baselines]`` table ({task: the metrics.json whose baselines it borrows}); ValueError naming the file and the
    key for a missing file, bad TOML, a missing table or a value that is not a list of paths (one path)."""
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"--manifest: {p} does not exist")
    try:
        doc = tomllib.loads(p.read_text())
    except tomllib.TOMLDecodeError as err:
        raise ValueError(f"--manifest: {p} is not TOML ({err})") from None
    tasks = doc.get("tasks")
    if not isinstance(tasks, dict) or not tasks:
        raise ValueError(f"--manifest: {p} has no [tasks] table of TASK = [metrics.json, ...]")
    specs = []
    for key, files in tasks.items():
        if not (isinstance(files, list) and files and all(isinstance(f, str) and f for f in files)):
            raise ValueError(f"--manifest {p}: tasks.{key} must be a non-empty list of metrics.json paths")
        specs.append(f"{key}={','.join(files)}")
    table = doc.get("baselines", {})
    bad = [k for k, v in table.items() if not (isinstance(v, str) and v)] if isinstance(table, dict) else ["(table)"]
    if bad:
        raise ValueError(f"--manifest {p}: baselines.{bad[0]} must be one metrics.json path")
    return specs, table


def main(argv=None) -> int:
    args = cli.parse(TasksArgs, argv, description=__doc__, prog="python -m experiments.tasks_table")
    from pcmgn_jax.atomic import atomic_write_text
    from pcmgn_jax.eval.tasks import code_note, lend_baselines, summary_table, task_rows, task_table
    specs, lent = manifest(args.manifest) if args.manifest else ([], {})
    specs = specs + list(args.task)
    if not specs:
        raise ValueError("give --manifest FILE.toml or --task T=metrics.json[,...]")
    runs = cli.keyed_json_files(specs, "task")
    for task, path in lent.items():
        if task not in runs:
            raise ValueError(f"--manifest {args.manifest}: baselines.{task} names a task the [tasks] table lacks")
        source = cli.keyed_json_files([f"{task}={path}"], "manifest")[task][0]
        runs[task] = lend_baselines(runs[task], source, name=path)
    seeds = {task: len(files) for task, files in runs.items()}
    command = cli.command_line("experiments.tasks_table", argv)
    rows = task_rows(runs)
    text = "\n".join(["# The tasks: the MGN beside the response surfaces", "", f"`{command}`", "",
                      *[x for n in args.note for x in (n, "")], textwrap.fill(code_note(runs), 120), "",
                      "**At a glance** (mean over the MGN's seeds; bold where the MGN is at least as accurate):", "",
                      summary_table(rows), "", task_table(rows, seeds=seeds)])
    print(text)
    if args.out:
        out = Path(args.out)
        old = out.read_text() if out.is_file() else ""
        kept = old[old.index(KEEP_MARKER):] if KEEP_MARKER in old else ""
        atomic_write_text(out, text + "\n" + ("\n" + kept if kept else ""))
    return 0


if __name__ == "__main__":
    sys.exit(cli.run(main))
