"""Markdown tables: one place for the rule every results page, study and task table writes its tables by.

* :func:`row`: one line, ``| a | b |``; a cell is rendered with ``str()``, an empty cell as ``| |``.
* :func:`table`: the header line, the ``|---|---|`` separator (one ``---`` a header cell) and one line per row.

Cells are written as given (no escaping of ``|``, no padding to a column width): a caller formats its numbers,
and the pages keep the bytes they had when each module wrote its tables by hand. Top-level and
dependency-free, so any layer can use it.
"""
from __future__ import annotations

from collections.abc import Iterable


def row(cells: Iterable) -> str:
    """One table line: ``| c1 | c2 |``, each cell ``str(c)``; an empty cell gives ``| |``."""
    return "|" + "".join(f" {s} |" if s else " |" for s in map(str, cells))


def table(head: Iterable, rows: Iterable[Iterable] = ()) -> list[str]:
    """The lines of a table: the header ``head``, the separator, then one line per row of ``rows``
    (:func:`row`). A row may have fewer or more cells than the header; it is written as given."""
    head = list(head)
    return [row(head), "|" + "---|" * len(head), *(row(r) for r in rows)]
