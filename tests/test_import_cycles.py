"""No import cycle inside the library: the import graph of ``pcmgn_jax`` (every import statement, module level
and inside functions, as grimp reads them with ``ast``) has no strongly connected component of two or more
modules. The check is shown to fail on a cycle planted in a tiny temporary package.

grimp comes with import-linter (the dev extra), as for tests/test_architecture.py.
"""
from __future__ import annotations

import textwrap
from collections import deque
from typing import NamedTuple

import grimp


class Cycle(NamedTuple):
    modules: list[str]   # a strongly connected component of two or more modules, sorted
    chain: list[str]     # a shortest closed chain of imports through its first module: [a, b, ..., a]


def import_cycles(package: str) -> list[Cycle]:
    """The import cycles of ``package``: one per strongly connected component of its module graph with two or
    more modules (Tarjan), with a shortest closed chain through the component's first module, so a reader sees
    which imports to break. Empty when the package is acyclic."""
    graph = grimp.build_graph(package, cache_dir=None)
    edges = {m: sorted(graph.find_modules_directly_imported_by(m)) for m in sorted(graph.modules)}
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    components: list[list[str]] = []

    def connect(v: str) -> None:   # recursive Tarjan: the package's import depth is small
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in edges[v]:
            if w not in index:
                connect(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                components.append(sorted(comp))

    for module in edges:
        if module not in index:
            connect(module)
    return [Cycle(comp, _closed_chain(comp, edges)) for comp in sorted(components)]


def _closed_chain(component: list[str], edges: dict[str, list[str]]) -> list[str]:
    """A shortest chain of imports inside ``component`` from its first module back to itself (BFS)."""
    start, inside = component[0], set(component)
    parent: dict[str, str] = {}
    queue = deque([start])
    while queue:
        v = queue.popleft()
        for w in edges[v]:
            if w == start:
                chain = [v]
                while chain[-1] != start:
                    chain.append(parent[chain[-1]])
                return [*reversed(chain), start]
            if w in inside and w not in parent:
                parent[w] = v
                queue.append(w)
    raise AssertionError(f"{component}: not a cycle")   # cannot happen for a strongly connected component


def _report(cycles: list[Cycle]) -> str:
    return "\n".join(f"{' -> '.join(c.chain)}   ({len(c.modules)} modules: {', '.join(c.modules)})"
                     for c in cycles)


def test_library_has_no_import_cycle():
    cycles = import_cycles("pcmgn_jax")
    assert not cycles, f"import cycles inside pcmgn_jax (break one import of each):\n{_report(cycles)}"


def test_planted_cycle_is_reported(tmp_path, monkeypatch):
    pkg = tmp_path / "cyclepkg"
    pkg.mkdir()
    files = {
        "__init__.py": "",
        "a.py": "from cyclepkg import b\n",
        "b.py": "def f():\n    from cyclepkg.c import g   # inside a function: still an import\n    return g\n",
        "c.py": "import cyclepkg.a\n\ndef g():\n    return 1\n",
        "d.py": "from cyclepkg import a\n",          # imports into the cycle, not part of it
        "e.py": "from cyclepkg import f\n", "f.py": "from cyclepkg import e\n",   # a second, separate cycle
    }
    for name, text in files.items():
        (pkg / name).write_text(textwrap.dedent(text))
    monkeypatch.syspath_prepend(str(tmp_path))
    cycles = import_cycles("cyclepkg")
    assert [c.chain for c in cycles] == [["cyclepkg.a", "cyclepkg.b", "cyclepkg.c", "cyclepkg.a"],
                                         ["cyclepkg.e", "cyclepkg.f", "cyclepkg.e"]], _report(cycles)
    assert cycles[0].modules == ["cyclepkg.a", "cyclepkg.b", "cyclepkg.c"]
    (pkg / "c.py").write_text("def g():\n    return 1\n")        # break both cycles: nothing is reported
    (pkg / "f.py").write_text("")
    assert import_cycles("cyclepkg") == []
