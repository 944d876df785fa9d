"""pcmgn_jax.geometry on a hand-computed two-cell mesh.

    3 ---- 4 ---- 5      y = 1   cell 1 (part 1, stiff):  1 2 5 4  (counter-clockwise)
    |  c0  |  c1  |              cell 0 (part 0, soft):   0 3 4 1  (clockwise)
    0 ---- 1 ---- 2      y = 0   node 6: in no cell
"""
import numpy as np
import pytest

from pcmgn_jax import geometry

POINTS = np.array([[0, 0], [1, 0], [2, 0], [0, 1], [1, 1], [2, 1], [5, 5]], float)
CELLS = np.array([[0, 3, 4, 1], [1, 2, 5, 4]])
CELL_PART = np.array([0, 1])


def test_cell_sides():
    a, b, owner = geometry.cell_sides(CELLS)
    assert a.tolist() == [0, 3, 4, 1, 1, 2, 5, 4]
    assert b.tolist() == [3, 4, 1, 0, 2, 5, 4, 1]
    assert owner.tolist() == [0, 0, 0, 0, 1, 1, 1, 1]


def test_quad_sides_unique_sorted():
    # 8 sides, the shared side 1-4 once: 7 unique
    assert geometry.quad_sides(CELLS).tolist() == [[0, 1], [0, 3], [1, 2], [1, 4], [2, 5], [3, 4], [4, 5]]
    # a collapsed quad (triangle 0 1 4, node 4 repeated) has no side 4-4
    assert geometry.quad_sides(np.array([[0, 1, 4, 4]])).tolist() == [[0, 1], [0, 4], [1, 4]]
    with pytest.raises(ValueError):
        geometry.quad_sides(np.zeros((3, 3), int))


def test_boundary_sides():
    a, b, owner = geometry.boundary_sides(CELLS)
    # every side but the shared 4-1 / 1-4, in cell order
    assert list(zip(a.tolist(), b.tolist())) == [(0, 3), (3, 4), (1, 0), (1, 2), (2, 5), (5, 4)]
    assert owner.tolist() == [0, 0, 0, 1, 1, 1]
    # one part alone: its four sides
    a, _, _ = geometry.boundary_sides(CELLS[CELL_PART == 1])
    assert a.tolist() == [1, 2, 5, 4]


def test_outward_normals_either_orientation():
    a, b, owner = geometry.boundary_sides(CELLS)
    n = geometry.outward_normals(POINTS, CELLS, a, b, owner)
    expected = [[-1, 0], [0, 1], [0, -1], [0, -1], [1, 0], [0, 1]]   # 0-3 left, 3-4 top, 1-0 bottom, ...
    np.testing.assert_allclose(n, expected, atol=1e-15)


def test_surface_nodes():
    up = geometry.surface_nodes(POINTS, CELLS, CELL_PART, 0, facing="up")
    down = geometry.surface_nodes(POINTS, CELLS, CELL_PART, 1, facing="down")
    assert up.tolist() == [3, 4] and up.dtype == np.int32
    assert down.tolist() == [1, 2]
    # both cells as one part: top row, bottom row
    assert geometry.surface_nodes(POINTS, CELLS, None, 0, facing="up").tolist() == [3, 4, 5]
    assert geometry.surface_nodes(POINTS, CELLS, None, 0, facing="down").tolist() == [0, 1, 2]
    with pytest.raises(ValueError):
        geometry.surface_nodes(POINTS, CELLS, CELL_PART, 0, facing="left")
    with pytest.raises(ValueError):
        geometry.surface_nodes(POINTS, CELLS, CELL_PART, 7, facing="up")


def test_surface_nodes_visible_only_drops_hidden_step():
    # an L of three cells: the side shared by the lower-left and the upper cell is not a boundary
    pts = np.array([[0, 0], [1, 0], [2, 0], [0, 1], [1, 1], [2, 1], [0, 2], [1, 2]], float)
    cells = np.array([[0, 1, 4, 3], [1, 2, 5, 4], [3, 4, 7, 6]])
    assert geometry.surface_nodes(pts, cells, None, 0, facing="up").tolist() == [4, 5, 6, 7]
    # a facing-down side hidden above another: two stacked cells with a hole between them
    pts2 = np.array([[0, 0], [1, 0], [0, 1], [1, 1], [0, 2], [1, 2], [0, 3], [1, 3]], float)
    cells2 = np.array([[0, 1, 3, 2], [4, 5, 7, 6]])
    down = geometry.surface_nodes(pts2, cells2, None, 0, facing="down")
    assert down.tolist() == [0, 1, 4, 5]
    assert geometry.surface_nodes(pts2, cells2, None, 0, facing="down", visible_only=True).tolist() == [0, 1]


def test_stiffest_adjacent_part():
    # part 1 stiffer: interface nodes 1 and 4 take part 1; node 6 is in no cell
    part = geometry.stiffest_adjacent_part(CELLS, CELL_PART, [1.0, 5.0], n_nodes=7)
    assert part.tolist() == [0, 1, 1, 0, 1, 1, -1] and part.dtype == np.int32
    # part 0 stiffer
    assert geometry.stiffest_adjacent_part(CELLS, CELL_PART, [5.0, 1.0], n_nodes=6).tolist() == [0, 0, 1, 0, 0, 1]
    # a tie goes to the smaller part id
    assert geometry.stiffest_adjacent_part(CELLS, CELL_PART, [2.0, 2.0], n_nodes=6).tolist() == [0, 0, 1, 0, 0, 1]
