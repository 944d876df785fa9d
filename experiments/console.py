"""One console command for every entry point: ``pcmgn NAME [flags]`` runs ``experiments.NAME.main(flags)``.

  pcmgn --help                       # the subcommands, one line each
  pcmgn train --preset tiny          # the same as: python -m experiments.train --preset tiny
  pcmgn evaluate --help              # that command's own flags

Installed as the ``pcmgn`` script (pyproject.toml ``[project.scripts]``); ``python -m experiments.console``
is the same command. A subcommand's module is imported only when it runs, so ``pcmgn --help`` reads each
description (the first sentence of the module's docstring) from the file and imports no jax. Names take
hyphens or underscores (``optimize-table`` = ``optimize_table``). Related commands are grouped where a user
looks for them (:data:`GROUPS`): ``pcmgn calculix check`` = ``pcmgn calculix_check``, ``pcmgn calculix run``
= ``pcmgn calculix``. An unknown name exits with status 2.
"""
from __future__ import annotations

import ast
import difflib
import importlib
import importlib.util
import re
import sys
from typing import Sequence

# every module in experiments/ with a main(argv), in the order a user meets them
COMMANDS = ("generate", "train", "evaluate", "report", "explore", "optimize", "optimize_table", "optimize_trace",
            "active", "ensemble", "tasks_table", "learning_curve", "error_budget", "compute_curve", "onepass",
            "export", "import_ansys", "export_ansys", "study", "ablation", "objective_convergence",
            "panel_report", "hertz_check", "reach", "calculix", "calculix_check", "mesh_series", "calculix_locking",
            "gradient", "gradient_curve")
PACKAGE = "experiments"
# ``pcmgn GROUP SUB`` runs COMMANDS' ``GROUPS[GROUP][SUB]``; ``pcmgn GROUP`` followed by anything else runs
# the command of the group's own name (``pcmgn calculix --preset tiny``, as before the groups)
GROUPS = {"calculix": {"run": "calculix", "check": "calculix_check", "locking": "calculix_locking"},
          "optimize": {"run": "optimize", "table": "optimize_table", "trace": "optimize_trace"},
          "gradient": {"run": "gradient", "curve": "gradient_curve"}}


def _spec(name: str):
    try:
        return importlib.util.find_spec(f"{PACKAGE}.{name}")
    except ModuleNotFoundError:     # the experiments package itself is not importable
        return None


def describe(name: str) -> str | None:
    """The one-line description of ``experiments.NAME``: its docstring's first sentence, without a trailing
    command example; None when the module is not there."""
    spec = _spec(name)
    if spec is None or not spec.origin:
        return None
    with open(spec.origin, encoding="utf-8") as f:
        doc = ast.get_docstring(ast.parse(f.read())) or ""
    para = " ".join(doc.strip().split("\n\n")[0].replace("``", "").split())
    first = re.split(r"(?<=[.!?])\s", para, maxsplit=1)[0]
    first = re.split(r":\s*python -m", first)[0]          # "Train the MeshGraphNet: ``python -m ...``."
    first = first.rstrip(". :")
    return first if len(first) <= 110 else first[:107].rstrip() + "..."


def usage() -> str:
    """The ``pcmgn --help`` text: every subcommand with its description."""
    width = max(map(len, COMMANDS))
    lines = ["usage: pcmgn COMMAND [flags]     (pcmgn COMMAND --help: that command's flags)", "",
             "Every command is also `python -m experiments.COMMAND`, run from the repository root.", "",
             "commands:"]
    for name in COMMANDS:
        text = describe(name)
        lines.append(f"  {name:<{width}}  " + (text if text is not None else
                                                f"(not in this checkout: experiments/{name}.py is missing)"))
    lines += ["", "groups (the same commands where a user looks for them):"]
    pairs = [(f"{group} {sub}", name) for group, subs in GROUPS.items() for sub, name in subs.items()]
    lines += [f"  pcmgn {pair:<{width}}  = pcmgn {name}" for pair, name in pairs]
    return "\n".join(lines)


def resolve(argv: Sequence[str]) -> tuple[str, list[str]]:
    """(command name, its flags) of ``pcmgn ARGV``: a group's subcommand (:data:`GROUPS`) or a command's name,
    hyphens read as underscores."""
    name, rest = argv[0].replace("-", "_"), list(argv[1:])
    subs = GROUPS.get(name, {})
    if rest and rest[0].replace("-", "_") in subs:
        return subs[rest[0].replace("-", "_")], rest[1:]
    return name, rest


def _error(message: str) -> int:
    print(f"error: {message}", file=sys.stderr)
    return 2


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``pcmgn COMMAND [flags]`` (``argv`` default ``sys.argv[1:]``) and return the exit status."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] in ("-h", "--help", "help"):
        print(usage())
        return 0
    if not argv or argv[0].startswith("-"):
        print(usage(), file=sys.stderr)
        return _error("no command given" if not argv else f"{argv[0]}: give a command first")
    name, rest = resolve(argv)
    if name not in COMMANDS:
        close = difflib.get_close_matches(name, COMMANDS, n=1)
        return _error(f"unknown command {argv[0]!r}" + (f" (did you mean {close[0]!r}?)" if close else "")
                      + "; `pcmgn --help` lists the commands")
    if _spec(name) is None:
        if _spec("train") is None:
            return _error(f"cannot import the {PACKAGE} package: install the project (pip install -e .) "
                          "or run `python -m experiments.console` from the repository root")
        return _error(f"pcmgn {name}: experiments/{name}.py is not in this checkout")
    from pcmgn_jax import cli  # imports jax: only when a command runs, not for --help
    module = importlib.import_module(f"{PACKAGE}.{name}")
    # the entry points read sys.argv[1:] where argv is empty (to record their command): give them their own
    saved, sys.argv = sys.argv, [f"pcmgn {name}", *rest]
    try:
        return cli.run(module.main, rest)
    finally:
        sys.argv = saved


if __name__ == "__main__":
    sys.exit(main())
