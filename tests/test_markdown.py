"""pcmgn_jax/markdown.py: the one markdown-table helper writes the bytes the pages were written with by hand."""
from pcmgn_jax import markdown


def test_table_byte_for_byte():
    lines = markdown.table(("predictor", "position MAE [µm]", "stress MAE [MPa]"),
                           [("MGN", "0.296", 2.22), ("rom", 0.0657, "0.382")])
    assert "\n".join(lines) == ("| predictor | position MAE [µm] | stress MAE [MPa] |\n"
                                "|---|---|---|\n"
                                "| MGN | 0.296 | 2.22 |\n"
                                "| rom | 0.0657 | 0.382 |")


def test_empty_cell_is_one_space():
    # evaluate's summary_table and the study tables write "| | |" for an empty cell, never "|  |"
    assert markdown.row(("ground truth", "", "", 0.03)) == "| ground truth | | | 0.03 |"
    assert markdown.row(("", "x")) == "| | x |"


def test_cells_by_str_and_no_rows():
    # a cell is str(cell): None, 0 and False are cells like any other, not empty ones
    assert markdown.row((None, 0, False, "–")) == "| None | 0 | False | – |"
    assert markdown.table(["a", "b"]) == ["| a | b |", "|---|---|"]
    assert markdown.table(iter(["a"]), iter([iter(["1"])])) == ["| a |", "|---|", "| 1 |"]
