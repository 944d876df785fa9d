"""Graph builder and contact buffer on a hand-computed two-cell mesh."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from pcmgn_jax.mgn import contact
from pcmgn_jax.mgn import graphs
#   3 --- 4 --- 5          y = 1e-5
#   |  0  |  1  |
#   0 --- 1 --- 2          y = 0
H = 1e-5
POINTS = np.array([[0, 0], [H, 0], [2 * H, 0], [0, H], [H, H], [2 * H, H]], float)
CELLS = np.array([[0, 1, 4, 3], [1, 2, 5, 4]])


def test_two_cell_mesh_edges_and_features():
    topo = graphs.make_topology(points=POINTS, cells=CELLS, node_type=np.array([0, 0, 2, 0, 1, 1]), n_parts=2)
    pairs = set(zip(topo.mesh_senders.tolist(), topo.mesh_receivers.tolist()))
    und = {(0, 1), (1, 4), (4, 3), (3, 0), (1, 2), (2, 5), (5, 4)}  # 7 unique sides, shared 1-4 once
    assert pairs == und | {(b, a) for a, b in und}
    assert len(topo.mesh_senders) == 14
    assert topo.fixed.tolist() == [False, False, True, False, False, False]
    assert topo.axis.tolist() == [True, False, False, True, False, False]

    u = np.zeros((6, 2))
    u[4] = [1e-6, -2e-6]
    v = np.arange(12, dtype=float).reshape(6, 2)
    edges = contact.empty_edges(4)
    g = graphs.build_graph(topo, points=POINTS, displacement=u, velocity=v, contact=edges)
    assert g.nodes.shape == (6, 3 + 4)
    np.testing.assert_allclose(g.nodes[4], [0, 1, 0, H + 1e-6, H - 2e-6, 8, 9], rtol=1e-6)
    k = [i for i, (s, r) in enumerate(zip(topo.mesh_senders, topo.mesh_receivers)) if (s, r) == (4, 1)][0]
    # u_41 = X4 - X1 = (0, H); x_41 = (1e-6, H - 2e-6)
    expect = [0, H, H, 1e-6, H - 2e-6, np.hypot(1e-6, H - 2e-6)]
    np.testing.assert_allclose(g.edges["mesh"].features[k], expect, rtol=1e-5, atol=1e-12)
    assert g.senders is not None and np.array_equal(g.senders, g.edges["mesh"].senders)
    assert g.edges["contact"].features.shape == (4, 3)
    assert not np.any(g.edges["contact"].features)


def _two_body():
    # ball block (part 0) above a CG block (part 1), separated by a 5 µm gap
    pts = np.array([[0, 0], [H, 0], [0, H], [H, H],                         # CG cell
                    [0, H + 5e-6], [H, H + 5e-6], [0, 2 * H + 5e-6], [H, 2 * H + 5e-6]])  # ball cell
    cells = np.array([[0, 1, 3, 2], [4, 5, 7, 6]])
    return pts, cells, np.array([1, 0])


def test_contact_candidates_radius_and_overflow():
    pts, cells, cell_part = _two_body()
    idx = contact.allocate(points=pts, cells=cells, cell_part=cell_part, radius=6e-6, positions=[pts[None]],
                           min_capacity=2, capacity_factor=1.0)
    assert idx.ball_nodes.tolist() == [4, 5] and idx.panel_nodes.tolist() == [2, 3]
    assert idx.capacity == 8  # 16-rounded, clipped to all candidate pairs (2 x 2 x 2 directions)
    idx = idx.replace(capacity=4)
    e = jax.jit(contact.update)(idx, jnp.asarray(pts, jnp.float32))
    got = {(int(s), int(r)) for s, r, m in zip(e.senders, e.receivers, e.mask) if m}
    assert got == {(4, 2), (2, 4), (5, 3), (3, 5)}
    assert not bool(e.overflow)
    # push the ball down: 4 pairs in range (8 directed) > capacity 4 -> overflow reported, count exact
    moved = pts.copy()
    moved[4:, 1] -= 4e-6
    e2 = contact.update(idx.replace(radius=1.2 * H), jnp.asarray(moved, jnp.float32))
    assert bool(e2.overflow) and int(e2.count) == 8
    bigger = contact.grow(idx, int(e2.count))
    e3 = contact.update(bigger.replace(radius=1.2 * H), jnp.asarray(moved, jnp.float32))
    assert not bool(e3.overflow) and int(e3.mask.sum()) == 8


def test_contact_excludes_mesh_edges():
    pts, cells, cell_part = _two_body()
    cells = np.concatenate([cells, [[2, 3, 5, 4]]])       # a bridging cell makes 2-4, 3-5 mesh edges
    idx = contact.allocate(points=pts, cells=cells, cell_part=np.array([1, 0, 2]), radius=6e-6, capacity=8)
    e = contact.update(idx, jnp.asarray(pts, jnp.float32))
    assert int(e.count) == 0


def test_build_graph_jit_equals_eager(tiny_trajs):
    t = tiny_trajs[0]
    topo = graphs.topology_from_trajectory(t)
    idx = contact.allocate(points=t.points, cells=t.cells, cell_part=t.cell_part, radius=20e-6,
                           positions=[t.positions])

    def f(topo, idx, u, v):
        e = contact.update(idx, jnp.asarray(t.points, jnp.float32) + u)
        return graphs.build_graph(topo, points=t.points, displacement=u, velocity=v, contact=e)

    u, v = jnp.asarray(t.displacement[6], jnp.float32), jnp.asarray(t.velocity[6], jnp.float32)
    a, b = f(topo, idx, u, v), jax.jit(f)(topo, idx, u, v)
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b)):
        np.testing.assert_allclose(np.asarray(x, float), np.asarray(y, float), rtol=1e-6, atol=1e-12)


def test_bad_inputs_raise():
    with pytest.raises(ValueError):
        graphs.quad_edges(np.zeros((3, 3), int))
    with pytest.raises(ValueError):
        contact.allocate(points=POINTS, cells=CELLS, cell_part=np.array([0, 1]), radius=-1.0)


def test_mesh_receivers_sorted_alone_and_in_a_union():
    """The model sums mesh messages with indices_are_sorted=True: quad_edges and the padded disjoint
    union (offset designs, padding edges on the padding node) keep the mesh receivers ascending."""
    from conftest import drop_last_column, make_synthetic_trajectory
    from pcmgn_jax.mgn import batching
    trajs = [make_synthetic_trajectory(0.9), drop_last_column(make_synthetic_trajectory(1.2))]
    trajs = trajs + trajs[::-1]
    topos = [graphs.topology_from_trajectory(t) for t in trajs]
    assert all(np.all(np.diff(t.mesh_receivers) >= 0) for t in topos)
    idx = [contact.allocate(points=t.points, cells=t.cells, cell_part=t.cell_part, radius=20e-6, capacity=16)
           for t in trajs]
    b = batching.batch_graphs(topos, idx, [t.points for t in trajs])
    assert (~b.layout.edge_mask).any()  # padding edges present
    assert np.all(np.diff(b.topology.mesh_receivers) >= 0)
