"""The four-task table (issue 24): the MGN beside every baseline on each task, the winner per metric named.

  python -m experiments.tasks_table --task a=runs/cpu/eval/metrics.json,runs/cpu_seed1/eval/metrics.json \
      b=runs/family/eval/metrics.json c=runs/cpu/eval/extrap/metrics.json --out docs/results/tasks.md

Each ``T=FILES`` after ``--task`` gives evaluate()'s metrics.json files of task T (a | b | c | d, see
pcmgn_jax.eval.tasks.TASKS), one per MGN seed; a task not given is listed as not measured.
"""
import shlex
import sys
from dataclasses import dataclass, field
from pathlib import Path

from pcmgn_jax import cli


@dataclass(frozen=True)
class TasksArgs:
    task: tuple[str, ...] = ()     # T=metrics.json[,metrics.json...] ... (T: a | b | c | d, or T.VARIANT such as d.cg_thin), space-separated after one --task
    out: str = ""                  # Markdown file to write ("" = print only)
    note: tuple[str, ...] = field(default_factory=tuple)   # lines to put under the title (budgets, what is missing)


def main(argv=None) -> int:
    args = cli.parse(TasksArgs, argv, description=__doc__, prog="python -m experiments.tasks_table")
    from pcmgn_jax.atomic import atomic_write_text
    from pcmgn_jax.eval.tasks import code_note, summary_table, task_rows, task_table
    runs = cli.keyed_json_files(args.task, "task")
    seeds = {task: len(files) for task, files in runs.items()}
    command = "python -m experiments.tasks_table " + " ".join(shlex.quote(a) for a in (argv or sys.argv[1:]))
    rows = task_rows(runs)
    text = "\n".join(["# Four tasks: the MGN beside the response surfaces", "", f"`{command}`", "",
                      *[x for n in args.note for x in (n, "")], code_note(runs), "",
                      "**At a glance** (mean over the MGN's seeds; bold where the MGN is at least as accurate):", "",
                      summary_table(rows), "", task_table(rows, seeds=seeds)])
    print(text)
    if args.out:
        atomic_write_text(Path(args.out), text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(cli.run(main))
