"""Graph builder and contact buffer on a hand-computed two-cell mesh."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from pcmgn_jax.mgn import contact, graphs
from pcmgn_jax.mgn.inputs import topology_from_trajectory

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
    k = next(i for i, (s, r) in enumerate(zip(topo.mesh_senders, topo.mesh_receivers)) if (s, r) == (4, 1))
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
    pts, cells, _cell_part = _two_body()
    cells = np.concatenate([cells, [[2, 3, 5, 4]]])       # a bridging cell makes 2-4, 3-5 mesh edges
    idx = contact.allocate(points=pts, cells=cells, cell_part=np.array([1, 0, 2]), radius=6e-6, capacity=8)
    e = contact.update(idx, jnp.asarray(pts, jnp.float32))
    assert int(e.count) == 0


def test_build_graph_jit_equals_eager(tiny_trajs):
    t = tiny_trajs[0]
    topo = topology_from_trajectory(t)
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
    from fixtures.helpers import drop_last_column, make_synthetic_trajectory
    from pcmgn_jax.mgn import batching
    trajs = [make_synthetic_trajectory(0.9), drop_last_column(make_synthetic_trajectory(1.2))]
    trajs = trajs + trajs[::-1]
    topos = [topology_from_trajectory(t) for t in trajs]
    assert all(np.all(np.diff(t.mesh_receivers) >= 0) for t in topos)
    idx = [contact.allocate(points=t.points, cells=t.cells, cell_part=t.cell_part, radius=20e-6, capacity=16)
           for t in trajs]
    b = batching.batch_graphs(topos, idx, [t.points for t in trajs])
    assert (~b.layout.edge_mask).any()  # padding edges present
    assert np.all(np.diff(b.topology.mesh_receivers) >= 0)


def _same_topology(a, b):
    assert a.n_node_types == b.n_node_types
    for k in ("node_type", "mesh_senders", "mesh_receivers", "fixed", "axis"):
        x, y = np.asarray(getattr(a, k)), np.asarray(getattr(b, k))
        assert x.dtype == y.dtype and np.array_equal(x, y), k
    if a.scene_features is None or b.scene_features is None:
        assert a.scene_features is None and b.scene_features is None
    else:
        x, y = np.asarray(a.scene_features), np.asarray(b.scene_features)
        assert x.dtype == y.dtype == np.float32 and np.array_equal(x, y)


def _same_index(a, b):
    assert a.radius == b.radius and a.capacity == b.capacity
    for k in ("ball_nodes", "panel_nodes", "allowed"):
        assert np.array_equal(np.asarray(getattr(a, k)), np.asarray(getattr(b, k))), k


def test_graph_inputs_are_what_training_surrogates_and_objectives_build():
    """mgn.inputs.graph_inputs (the one rule: mesh + scene -> topology, scene features, contact index) gives
    bit for bit what train.setup.prepare builds per trajectory (two meshes, auto radius, per-trajectory
    scene features), what MGNSurrogate._design builds on the reference and on another mesh, and the scene
    features the MGN objective traces with the design."""
    from types import SimpleNamespace

    from fixtures.helpers import drop_last_column, make_synthetic_trajectory, tiny_config
    from pcmgn_jax.mgn.inputs import graph_inputs, with_scene
    from pcmgn_jax.surrogates.inputs import design_of
    from pcmgn_jax.surrogates.mgn import MGNSurrogate
    from pcmgn_jax.train.setup import contact_positions, graph_for, prepare

    trajs = [make_synthetic_trajectory(0.9), drop_last_column(make_synthetic_trajectory(1.1)),
             make_synthetic_trajectory(1.0)]
    names = ("ball_radius", "layer_thickness")
    cfg = tiny_config(contact_radius=0.0, scene_features=",".join(names))
    setup = prepare(cfg, trajs, stats_max_frames=2)
    form = setup.spec.sim.formulation
    assert form.scene_features == names
    members = {0: [0, 2], 1: [1]}  # trajectories 0 and 2 share a mesh
    cap = setup.graphs[0].index.capacity
    for i, t in enumerate(trajs):
        g = members.get(i, members[0])
        inp = graph_inputs(t, t.meta["scene"], scene_features=names, radius=None,
                           positions=[contact_positions(form, trajs[j]) for j in g],
                           capacity_factor=cfg.contact_capacity_factor)
        _same_topology(inp.topology, setup.graphs[i].topology)
        if i in members:
            assert inp.index.radius == setup.radius
            _same_index(inp.index.replace(capacity=cap), setup.graphs[i].index)
        assert inp.points.dtype == np.float32 and np.array_equal(inp.points, np.asarray(t.points, np.float32))
        # graph_for (a trajectory outside the split): the same rule at the training radius and buffer
        d = graph_for(setup, t)
        want = graph_inputs(t, t.meta["scene"], scene_features=names, radius=setup.radius,
                            capacity=setup.sizes.capacity)
        _same_topology(d["topology"], want.topology)
        _same_index(d["index"], want.index)
        assert set(d) == {"topology", "index", "points"} and np.array_equal(d["points"], want.points)

    # the MGN surrogate: the model's topology / index on the reference mesh, its own on another mesh
    sur = MGNSurrogate.__new__(MGNSurrogate)
    sur.ref = trajs[0]
    sur.sim = SimpleNamespace(topology=setup.graphs[0].topology, index=setup.graphs[0].index, spec=setup.spec.sim)
    for i in (0, 1, 2):
        t = trajs[i]
        d = sur._design(t, t.displacement[0], t.velocity[0], t.von_mises[0], t.meta["scene"])
        _same_topology(d["topology"], setup.graphs[i].topology)
        own = graph_inputs(t, trajs[0].meta["scene"], radius=setup.radius, capacity=cap).index  # <= all pairs
        _same_index(d["index"], setup.graphs[i].index if i != 1 else own)
        _same_index(d["index"].replace(capacity=cap), setup.graphs[i].index)

    # the MGN objective: the reference topology with the scene features traced from the design
    traced = jax.jit(lambda x: with_scene(setup.graphs[0].topology, trajs[0].meta["scene"], names,
                                          design=x).scene_features)
    got = np.asarray(traced(jnp.asarray(design_of(trajs[2]), jnp.float32)))
    want = np.asarray(setup.graphs[2].topology.scene_features)
    assert got.dtype == want.dtype and np.array_equal(got, want)


def test_zero_shot_scenes_change_the_models_inputs_where_it_can_see_them():
    """A scene that changes a number training held fixed: a thicker cover glass or plate changes the MGN's
    inputs (the mesh, and the layer_thickness channels of the non-contact nodes); a layer's modulus changes
    them only through the ``material`` channel, and there only on that layer's own nodes (without the
    channel the model answers such a scene as if the modulus were unchanged)."""
    import dataclasses

    from pcmgn_jax.mgn.inputs import graph_inputs
    from pcmgn_jax.scene import default_scene
    from pcmgn_jax.sim.mesh import build_mesh

    def inputs(names=("layer_thickness",), **change):
        base = default_scene()
        layers = tuple(dataclasses.replace(lay, **change[lay.name]) if lay.name in change else lay
                       for lay in base.layers)
        scene = dataclasses.replace(base, layers=layers)
        g = graph_inputs(build_mesh(scene, "tiny"), scene.to_dict(), scene_features=names)
        return g.points, np.asarray(g.topology.scene_features), np.asarray(g.topology.node_type)

    p0, f0, _ = inputs()
    for change in ({"CG": {"thickness": 130e-6}}, {"PLATE": {"thickness": 1.5e-3}}):
        p, f, _ = inputs(**change)
        assert p.shape != p0.shape or not np.array_equal(p, p0)
        assert f.shape[0] != f0.shape[0] or not np.array_equal(f, f0)
    p, f, _ = inputs(OCA1={"youngs": 20e6})
    assert np.array_equal(p, p0) and np.array_equal(f, f0)
    names = ("layer_thickness", "material")
    _, m0, node_type = inputs(names)
    _, m, _ = inputs(names, OCA1={"youngs": 20e6})
    changed = np.any(m != m0, axis=1)
    oca1 = node_type == 2  # part 2: the second layer from the top (ball 0, CG 1)
    assert changed.any() and np.array_equal(changed, oca1)
    np.testing.assert_allclose(m[oca1, -3] - m0[oca1, -3], np.log10(2.0), rtol=1e-5)  # log10 E: a ratio


def test_material_rows_per_part_and_named_errors():
    """Each node carries its own part's [log10 E, nu, log10 rho]; fixed nodes the last layer's; a part
    without a property is named."""
    from pcmgn_jax.mgn.scene_features import across_part_channels, material_rows, scene_feature_rows
    from pcmgn_jax.scene import default_scene

    scene = default_scene().to_dict()
    n_parts = 1 + len(scene["layers"])
    rows = material_rows(scene, np.arange(n_parts + 1))
    np.testing.assert_allclose(rows[0], [np.log10(200e9), 0.30, np.log10(7850.0)], rtol=1e-6)
    np.testing.assert_allclose(rows[1], [np.log10(77e9), 0.21, np.log10(2500.0)], rtol=1e-6)
    np.testing.assert_array_equal(rows[-1], rows[-2])  # fixed nodes: the plate's
    got = scene_feature_rows(scene, ("ball_radius", "material"), np.array([0, 3]))
    assert got.shape == (2, 4) and got.dtype == np.float32 and np.array_equal(got[:, 1:], rows[[0, 3]])
    assert across_part_channels(scene, ("layer_thickness", "material", "ball_radius")) == \
        [len(scene["layers"]), len(scene["layers"]) + 1, len(scene["layers"]) + 2]
    bad = {**scene, "layers": [dict(scene["layers"][0], youngs=None)] + scene["layers"][1:]}
    with pytest.raises(ValueError, match="part 'CG' needs numbers youngs"):
        material_rows(bad, np.array([1]))
    with pytest.raises(ValueError, match="node types must lie in 0..7"):
        material_rows(scene, np.array([8]))


def test_material_identity_keeps_only_the_ball_and_fixed_one_hot_columns():
    """``identity='material'``: a layer's node sets no one-hot column (it is known by its material), the
    ball's and the fixed nodes' columns stay; the width is unchanged; the formulation asks for the
    channel it needs."""
    from pcmgn_jax.mgn.formulation import Formulation
    topo = graphs.make_topology(points=POINTS, cells=CELLS, node_type=np.array([0, 0, 2, 0, 1, 1]), n_parts=2)
    z = np.zeros((6, 2))
    by_type = np.asarray(graphs.node_features(topo, POINTS, z, z, "paper"))
    by_material = np.asarray(graphs.node_features(topo, POINTS, z, z, "paper", identity="material"))
    assert by_type.shape == by_material.shape
    np.testing.assert_array_equal(by_material[:, :3], by_type[:, :3] * [1, 0, 1])
    np.testing.assert_array_equal(by_material[:, 3:], by_type[:, 3:])
    with pytest.raises(ValueError, match="needs 'material' among scene_features"):
        Formulation(part_identity="material")


def test_contact_top_origin_measures_height_from_the_contact_layer_per_graph():
    """``origin='contact_top'`` / ``'support_top'``: node heights are measured from the contact layer's top
    / the plate's top, so a thicker plate leaves the cover glass's node features as they were (the mesh
    origin moves them by the change); in a union each graph has its own origin, and the padding graph's
    nodes stay finite."""
    import dataclasses

    from pcmgn_jax.mgn.batching import batch_graphs
    from pcmgn_jax.mgn.inputs import graph_inputs
    from pcmgn_jax.scene import default_scene
    from pcmgn_jax.sim.mesh import build_mesh

    def design(plate):
        base = default_scene()
        layers = tuple(dataclasses.replace(lay, thickness=plate) if lay.name == "PLATE" else lay
                       for lay in base.layers)
        scene = dataclasses.replace(base, layers=layers)
        return graph_inputs(build_mesh(scene, "tiny"), scene.to_dict())

    feats = {}
    for plate in (1.2e-3, 1.5e-3):
        g = design(plate)
        z = np.zeros_like(g.points)
        cg = np.asarray(g.topology.node_type) == 1
        for origin in ("mesh", "contact_top", "support_top"):
            f = np.asarray(graphs.node_features(g.topology, g.points, z, z, "strain", origin=origin))
            feats[plate, origin] = f[cg][:, g.topology.n_node_types:g.topology.n_node_types + 2]
        assert np.isclose(feats[plate, "contact_top"][:, 1].max(), 0.0, atol=1e-9)
    np.testing.assert_allclose(feats[1.5e-3, "contact_top"], feats[1.2e-3, "contact_top"], atol=1e-9)
    np.testing.assert_allclose(feats[1.5e-3, "support_top"], feats[1.2e-3, "support_top"], atol=1e-9)
    # support_top: the mesh's heights less the plate's top (1.2 mm here), a constant the normaliser removes
    np.testing.assert_allclose(feats[1.2e-3, "mesh"][:, 1] - feats[1.2e-3, "support_top"][:, 1], 1.2e-3, rtol=1e-5)
    np.testing.assert_allclose(feats[1.5e-3, "mesh"][:, 1] - feats[1.2e-3, "mesh"][:, 1], 0.3e-3, rtol=1e-4)
    # a union of both: each graph's own origin, as alone
    a, b = design(1.2e-3), design(1.5e-3)
    batch = batch_graphs([a.topology, b.topology], [a.index, b.index], [a.points, b.points])
    heights = np.asarray(graphs.origin_height(batch.topology, jnp.asarray(batch.points), "contact_top",
                                                batch.layout.node_graph))
    n_a, n_b = a.topology.n_node, b.topology.n_node
    np.testing.assert_allclose(heights[:n_a], a.points[np.asarray(a.topology.node_type) == 1, 1].max(), rtol=1e-6)
    np.testing.assert_allclose(heights[n_a:n_a + n_b], b.points[np.asarray(b.topology.node_type) == 1, 1].max(),
                               rtol=1e-6)
    assert np.all(np.isfinite(heights)) and np.all(heights[n_a + n_b:] == 0.0)


def test_stack_thickness_is_layer_thickness_on_every_node():
    """``stack_thickness`` gives the contact pair (ball, cover glass) the layers' thicknesses that
    ``layer_thickness`` hides from them; elsewhere the two are the same."""
    from pcmgn_jax.mgn.scene_features import scene_feature_rows
    from pcmgn_jax.scene import default_scene

    scene = default_scene().to_dict()
    node_type = np.array([0, 1, 2, 3, 6, 7])
    layer = scene_feature_rows(scene, ("layer_thickness",), node_type)
    stack = scene_feature_rows(scene, ("stack_thickness",), node_type)
    thick = np.array([la["thickness"] for la in scene["layers"]], np.float32)
    np.testing.assert_array_equal(stack, np.broadcast_to(thick, stack.shape))
    np.testing.assert_array_equal(layer[:2], 0.0)  # ball and cover glass
    np.testing.assert_array_equal(layer[2:], stack[2:])
