"""Disjoint-union batching: designs of different meshes roll out together exactly as alone, padding
changes nothing, and another mesh in the same size bucket does not recompile."""
import jax
import numpy as np
import pytest

from fixtures.helpers import CompileCounter, drop_last_column, make_synthetic_trajectory
from pcmgn_jax.mgn import batching, contact as contact_lib, rollout as rl
from pcmgn_jax.mgn.formulation import FORMULATIONS
from pcmgn_jax.mgn.inputs import topology_from_trajectory
from pcmgn_jax.mgn.model import EncodeProcessDecode
from pcmgn_jax.mgn.normalization import normalize_graph

N_STEPS = 8


def design(t, capacity: int = 16) -> dict:
    topo = topology_from_trajectory(t)
    index = contact_lib.allocate(points=t.points, cells=t.cells, cell_part=t.cell_part, radius=20e-6,
                                 capacity=capacity)
    return dict(topology=topo, index=index, points=t.points, u0=t.displacement[0], v0=t.velocity[0],
                vm0=t.von_mises[0])


def simulator(formulation: str, ref: dict):
    """A small random-parameter model with statistics from the training-time statistics code."""
    from pcmgn_jax.train.setup import compute_stats
    form = FORMULATIONS[formulation]
    model = EncodeProcessDecode(output_size=form.output_size, latent_size=16, mlp_layers=2,
                                message_passing_steps=2)
    spec = rl.Spec(model=model, formulation=form, dt=4e-6)
    topo, index = ref["topology"], ref["index"]
    trajs = [make_synthetic_trajectory(d) for d in (0.9, 1.1)]
    stats = compute_stats(spec, trajs, topo, index, np.zeros(topo.n_node, np.float32), max_frames=12)
    g, _ = rl.input_graph(form, topo, index, ref["points"], ref["u0"], ref["v0"])
    params = model.init(jax.random.PRNGKey(1), normalize_graph(stats, g, topo.node_type))
    return spec, params, stats


@pytest.fixture(scope="module")
def designs():
    """Two different meshes (40 and 36 nodes): the synthetic scene, and the same without a column."""
    return [design(make_synthetic_trajectory(0.9)), design(drop_last_column(make_synthetic_trajectory(1.2)))]


def test_bucket_sizes():
    sizes = [batching.bucket_size(n, 1) for n in range(1, 5000)]
    assert all(s >= n and s <= max(1.125 * n, 8) for n, s in zip(range(1, 5000), sizes))
    assert len(set(sizes)) <= 8 * 10 and all(s % 2 == 0 for s in sizes if s >= 16)
    assert [batching.design_slots(b) for b in (1, 2, 3, 5, 8, 9)] == [1, 2, 4, 8, 8, 16]
    with pytest.raises(ValueError):
        batching.design_slots(0)


def test_union_layout_and_masks(designs):
    b = batching.batch_graphs([d["topology"] for d in designs], [d["index"] for d in designs],
                              [d["points"] for d in designs])
    n0, n1 = (d["topology"].n_node for d in designs)
    assert b.n_node.tolist() == [n0, n1] and int(b.n_designs) == 2
    lay, topo = b.layout, b.topology
    assert lay.node_mask.sum() == n0 + n1 and not lay.node_mask[n0 + n1:].any()
    assert lay.node_graph[:n0].tolist() == [0] * n0 and lay.node_graph[n0:n0 + n1].tolist() == [1] * n1
    assert topo.fixed[~lay.node_mask].all() and (topo.node_type[~lay.node_mask] == topo.n_node_types - 1).all()
    # real mesh edges stay inside their design; padding edges touch padding nodes only
    e_real = lay.edge_mask
    graph_of = lay.node_graph
    assert (graph_of[topo.mesh_senders[e_real]] == graph_of[topo.mesh_receivers[e_real]]).all()
    assert not lay.node_mask[topo.mesh_senders[~e_real]].any()
    # contact candidates of slot g are nodes of design g
    for g in range(2):
        allowed = b.index.allowed[g]
        assert (graph_of[b.index.ball_nodes[g][allowed.any(1)]] == g).all()
        assert (graph_of[b.index.panel_nodes[g][allowed.any(0)]] == g).all()
    parts = batching.split(b, np.arange(b.points.shape[0]))
    assert [len(p) for p in parts] == [n0, n1]
    with pytest.raises(ValueError):
        batching.to_union(b, [designs[0]["u0"], designs[0]["u0"]])  # design 1 has another node count


@pytest.mark.slow  # ~46 s for default, ~15 s for paper (the default suite's 10-minute budget)
@pytest.mark.parametrize("formulation", ["default", "paper"])
def test_union_equals_each_design_alone(designs, formulation):
    """Two meshes of different topology in one padded union: the same fields, overflow flags and contact
    counts as rolling each design out alone (rigid ball pooled per graph, contact searched per graph),
    and the same again in a larger bucket (padding invariance)."""
    spec, params, stats = simulator(formulation, designs[0])
    alone = [rl.rollout_checked(spec, N_STEPS, params, stats, d["topology"], d["index"], d["points"], d["u0"],
                                d["v0"], d["vm0"])[0] for d in designs]
    assert max(int(np.max(r.contact_count)) for r in alone) > 0  # the contact search is exercised
    small = rl.rollout_designs(spec, N_STEPS, params, stats, designs).rollouts
    big = []
    for d in designs:  # padding invariance: the same designs in a bucket of 8 slots, many padding nodes
        b = batching.batch_graphs([d["topology"]], [d["index"]], [d["points"]], min_nodes=300, min_edges=900,
                                  min_slots=8, min_capacity=64)
        init = [batching.to_union(b, [d[k]]) for k in ("u0", "v0", "vm0")]
        res, b = rl.rollout_union_checked(spec, N_STEPS, params, stats, b, *init)
        assert b.points.shape[0] == 320 and b.layout.n_node.shape[0] == 9
        big.extend(rl.unbatch(b, res))
    for one, u, p in zip(alone, small, big):
        for got in (u, p):
            for k in ("displacement", "velocity", "von_mises"):  # float32 round-off, relative to the field
                want = np.asarray(getattr(one, k))
                np.testing.assert_allclose(getattr(got, k), want, rtol=1e-4, atol=1e-5 * np.abs(want).max())
            np.testing.assert_array_equal(got.contact_count, one.contact_count)
            np.testing.assert_array_equal(got.overflow, one.overflow)


@pytest.mark.slow  # ~32 s (the default suite's 10-minute budget, 2026-12-03)
def test_union_grows_contact_buffer_per_graph(designs):
    spec, params, stats = simulator("default", designs[0])
    tight = [dict(d, index=d["index"].replace(capacity=2)) for d in designs]
    out = rl.rollout_designs(spec, N_STEPS, params, stats, tight)
    need = max(int(np.max(r.contact_count)) for r in out.rollouts)
    assert need > 2 and out.capacity >= need
    assert not any(np.any(r.overflow) for r in out.rollouts)


@pytest.mark.slow  # ~23 s (the 10-minute budget, 2026-12-03); test_rollout.py::test_rollout_no_recompilation stays
def test_same_bucket_other_mesh_does_not_recompile(designs):
    """A second union of other meshes in the same size bucket reuses the compiled rollout."""
    spec, params, stats = simulator("default", designs[0])
    third = design(drop_last_column(make_synthetic_trajectory(1.0)))

    def run(ds):
        b = batching.batch_graphs([d["topology"] for d in ds], [d["index"] for d in ds], [d["points"] for d in ds])
        init = [batching.to_union(b, [d[k] for d in ds]) for k in ("u0", "v0", "vm0")]
        return b, rl.rollout_union(spec, N_STEPS, params, stats, b, *init)

    b1, _ = run(designs)
    b2 = batching.batch_graphs([third["topology"]] * 2, [third["index"]] * 2, [third["points"]] * 2)
    assert b2.bucket() == b1.bucket() and b2.n_node.sum() != b1.n_node.sum()
    before = rl.rollout_union._cache_size()
    with CompileCounter("rollout_union") as c:
        jax.block_until_ready(run([third, third])[1])
        jax.block_until_ready(run([designs[1], third])[1])
    assert c.count == 0 and rl.rollout_union._cache_size() == before
