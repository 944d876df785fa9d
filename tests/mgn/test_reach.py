"""Reach (issue 39): the bi-stride hierarchy, the multi-scale and attention processors, the reach report.

The hierarchy covers every node and keeps every level connected; the report's coarsest diameter is an
independent BFS's; attention is permutation-equivariant; padding nodes and graphs never change a real
node's output; designs of one shape do not recompile; gradients are finite; a tiny training run with
each processor ends finite; the default (local) model is the model it was.
"""
import collections
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from fixtures.helpers import CompileCounter, drop_last_column, make_synthetic_trajectory, tiny_config
from pcmgn_jax.config import TrainConfig
from pcmgn_jax.mgn import batching, contact as contact_lib, rollout as rl
from pcmgn_jax.mgn.attention import PhysicsAttention
from pcmgn_jax.mgn.formulation import FORMULATIONS, Formulation
from pcmgn_jax.mgn.hierarchy import adjacency, build_levels
from pcmgn_jax.mgn.inputs import topology_from_trajectory
from pcmgn_jax.mgn.model import EncodeProcessDecode, global_block_steps
from pcmgn_jax.mgn.normalization import normalize_graph
from pcmgn_jax.mgn.reach import contact_graph, contact_node, hop_distances, processor_reach, reach_report

REACHES = ("multiscale", "attention")


@pytest.fixture(scope="module")
def cpu_mesh():
    from pcmgn_jax.scene import default_scene
    from pcmgn_jax.sim.mesh import build_mesh, roi
    scene = default_scene()
    mesh, _ = roi(build_mesh(scene, "cpu"), "cpu")
    return mesh


def components(s, r, n) -> int:
    from scipy.sparse import csgraph
    return csgraph.connected_components(adjacency(s, r, n), directed=False)[0]


def test_every_node_has_a_cluster_and_every_level_is_connected(cpu_mesh):
    topo = topology_from_trajectory_like(cpu_mesh)
    levels = build_levels(topo.mesh_senders, topo.mesh_receivers, topo.n_node, 4)
    n_comp = components(topo.mesh_senders, topo.mesh_receivers, topo.n_node)
    prev_n, prev_s, prev_r, prev_nodes = topo.n_node, topo.mesh_senders, topo.mesh_receivers, np.arange(topo.n_node)
    for lv in levels:
        assert lv.parent.shape == (prev_n,) and lv.parent.min() >= 0 and lv.parent.max() < lv.n_node
        assert np.all(np.bincount(lv.parent, minlength=lv.n_node) >= 1)  # no empty cluster
        # a kept node is its own cluster; any other node is one hop from its cluster's node
        kept = np.searchsorted(prev_nodes, lv.nodes)
        assert np.array_equal(lv.parent[kept], np.arange(lv.n_node))
        prev_adj = adjacency(prev_s, prev_r, prev_n).tolil()
        for i in np.flatnonzero(~np.isin(np.arange(prev_n), kept)):
            assert kept[lv.parent[i]] in prev_adj.rows[i]
        assert components(lv.senders, lv.receivers, lv.n_node) == n_comp  # ball + panel, each connected
        assert np.all(np.diff(lv.receivers) >= 0) and not np.any(lv.senders == lv.receivers)
        prev_n, prev_s, prev_r, prev_nodes = lv.n_node, lv.senders, lv.receivers, lv.nodes
    assert levels[-1].n_node < topo.n_node / 8


def topology_from_trajectory_like(mesh):
    from pcmgn_jax.mgn.inputs import design_topology
    return design_topology(mesh, n_parts=len(mesh.part_names))


def bfs_diameter(s, r, n) -> int:
    """The longest shortest path within a component, by plain Python BFS from every node."""
    nbrs = collections.defaultdict(list)
    for a, b in zip(s.tolist(), r.tolist()):
        nbrs[b].append(a)
    best = 0
    for src in range(n):
        dist, queue = {src: 0}, collections.deque([src])
        while queue:
            x = queue.popleft()
            for y in nbrs[x]:
                if y not in dist:
                    dist[y] = dist[x] + 1
                    queue.append(y)
        best = max(best, max(dist.values()))
    return best


def test_report_coarsest_diameter_and_local_reach(cpu_mesh):
    rep = reach_report(cpu_mesh, cpu_mesh.part_names, 1, {
        "local 8": dict(steps=8, reach="local"), "local 30": dict(steps=30, reach="local"),
        "ms": dict(steps=8, reach="multiscale", levels=4), "att": dict(steps=3, reach="attention")})
    topo = topology_from_trajectory_like(cpu_mesh)
    coarsest = build_levels(topo.mesh_senders, topo.mesh_receivers, topo.n_node, 4)[-1]
    assert rep["variants"]["ms"]["levels_detail"][-1]["diameter"] == bfs_diameter(coarsest.senders, coarsest.receivers,
                                                                                  coarsest.n_node)
    # local: the reach after k steps is exactly the nodes within k hops (the OLED: part 5)
    hops = hop_distances(*contact_graph(cpu_mesh.cells, topo.n_node, contact_node(cpu_mesh.points, topo.node_type, 1)),
                         topo.n_node, rep["contact_node"])
    oled = np.asarray(cpu_mesh.node_part) == 5
    for k in (8, 30):
        assert rep["variants"][f"local {k}"]["oled_fraction"] == pytest.approx(float(np.mean(hops[oled] <= k)))
    assert rep["hops"]["OLED"]["min"] > 8 and rep["variants"]["local 8"]["oled_fraction"] == 0.0
    assert rep["variants"]["att"]["oled_fraction_by_step"] == [0.0, 0.0, 1.0]  # one block, after the last step
    assert rep["variants"]["ms"]["oled_fraction"] == 1.0


def test_global_block_placement_and_multiscale_reach_grows():
    assert global_block_steps(8) == (4, 8) and global_block_steps(15) == (4, 8, 12, 15)
    assert global_block_steps(3) == (3,)
    t = make_synthetic_trajectory()
    topo = topology_from_trajectory(t)
    levels = build_levels(topo.mesh_senders, topo.mesh_receivers, topo.n_node, 2)
    local = processor_reach(topo.mesh_senders, topo.mesh_receivers, topo.n_node, 0, steps=1)[-1]
    ms = processor_reach(topo.mesh_senders, topo.mesh_receivers, topo.n_node, 0, steps=1, reach="multiscale",
                         levels=levels)[-1]
    assert (ms >= local).all() and ms.sum() > local.sum()


def test_attention_is_permutation_equivariant():
    n, lat = 23, 16
    v = jax.random.normal(jax.random.PRNGKey(0), (n, lat))
    node_graph = jnp.asarray([0] * 10 + [1] * 13, jnp.int32)
    block = PhysicsAttention(lat, slices=5, heads=4)
    params = block.init(jax.random.PRNGKey(1), v, node_graph, 3)
    out = block.apply(params, v, node_graph, 3)
    perm = np.random.default_rng(0).permutation(n)
    out_p = block.apply(params, v[perm], node_graph[perm], 3)
    np.testing.assert_allclose(np.asarray(out_p), np.asarray(out)[perm], rtol=1e-5, atol=1e-5)
    # graph 1 never sees graph 0: changing graph 0's nodes leaves graph 1's outputs as they were
    out_c = block.apply(params, v.at[:10].set(7.0), node_graph, 3)
    np.testing.assert_array_equal(np.asarray(out_c)[10:], np.asarray(out)[10:])


def design(t, levels: int) -> dict:
    topo = topology_from_trajectory(t, levels=levels)
    index = contact_lib.allocate(points=t.points, cells=t.cells, cell_part=t.cell_part, radius=20e-6, capacity=16)
    return dict(topology=topo, index=index, points=t.points, u0=t.displacement[3], v0=t.velocity[3])


def model_of(reach: str, form="default"):
    f = FORMULATIONS[form].replace(reach=reach, reach_levels=2, reach_slices=4, reach_heads=2)
    return f, EncodeProcessDecode(output_size=f.output_size, latent_size=16, message_passing_steps=2,
                                  decoder_condition=f.decoder_condition, reach=reach, reach_levels=2,
                                  reach_slices=4, reach_heads=2)


def identity_stats(graph, n_types: int):
    from pcmgn_jax.mgn.normalization import Stats
    k = graph.nodes.shape[1] - n_types
    cm, cc = graph.edges["mesh"].features.shape[1], graph.edges["contact"].features.shape[1]
    z, o = (lambda *s: np.zeros(s, np.float32)), (lambda *s: np.ones(s, np.float32))
    return Stats(z(n_types, k), o(n_types, k), z(n_types, cm), o(n_types, cm), z(cc), o(cc), z(n_types, 3),
                 o(n_types, 3), z(2), o(2))


def union_graph(form, ds, **kw):
    b = batching.batch_graphs([d["topology"] for d in ds], [d["index"] for d in ds], [d["points"] for d in ds], **kw)
    u = batching.to_union(b, [d["u0"] for d in ds])
    v = batching.to_union(b, [d["v0"] for d in ds])
    g, _ = _input_graph(form, b.topology, b.index, b.points, u, v, b.layout)
    return b, normalize_graph(identity_stats(g, b.topology.n_node_types), g, b.topology.node_type)


_input_graph = jax.jit(rl.input_graph, static_argnums=0)
# multiscale's two checks below take ~16 s each: slow, so the default suite stays under 10 minutes
# the default suite keeps the local (default) processor; the reach processors (~12 s each per test) run with -m slow
REACHES_DEFAULT_SUITE = [pytest.param(r, marks=pytest.mark.slow) if r in ("multiscale", "attention") else r
                         for r in REACHES]


@pytest.mark.parametrize("reach", REACHES_DEFAULT_SUITE)
def test_padding_never_changes_a_real_node(reach):
    form, model = model_of(reach)
    ds = [design(make_synthetic_trajectory(0.9), form.hierarchy_levels),
          design(drop_last_column(make_synthetic_trajectory(1.2)), form.hierarchy_levels)]
    b, g = union_graph(form, ds, min_nodes=200, min_edges=600, min_slots=4, min_levels=((120, 400), (64, 300)))
    params = jax.jit(model.init)(jax.random.PRNGKey(0), g)
    apply = jax.jit(model.apply)
    out = np.asarray(apply(params, g))
    real = np.asarray(b.layout.node_mask)
    assert (~real).sum() > 50 and b.layout.n_node.shape[0] == 5  # padding nodes and empty padding graphs
    rng = np.random.default_rng(0)
    nodes = np.asarray(g.nodes).copy()
    nodes[~real] = rng.normal(size=nodes[~real].shape) * 10
    edges = dict(g.edges)
    for key, es in g.edges.items():  # padded edge slots: garbage features
        f = np.asarray(es.features).copy()
        f[~np.asarray(es.mask)] = rng.normal(size=f[~np.asarray(es.mask)].shape) * 10
        edges[key] = es._replace(features=jnp.asarray(f))
    out2 = np.asarray(apply(params, g._replace(nodes=jnp.asarray(nodes), edges=edges)))
    np.testing.assert_array_equal(out2[real], out[real])
    # each design alone (its own, unpadded-size bucket): the same outputs as in the union
    n0 = ds[0]["topology"].n_node
    _, g0 = union_graph(form, ds[:1])
    np.testing.assert_allclose(np.asarray(apply(params, g0))[:n0], out[:n0], rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("reach", REACHES_DEFAULT_SUITE)
def test_gradients_finite_and_no_recompilation_across_designs(reach):
    form, model = model_of(reach, "realtime")
    mk = lambda d: design(make_synthetic_trajectory(d), form.hierarchy_levels)  # noqa: E731
    b1, g1 = union_graph(form, [mk(0.9), mk(1.1)])
    b2, g2 = union_graph(form, [mk(1.2), mk(0.8)])
    assert b1.bucket() == b2.bucket()
    params = jax.jit(model.init)(jax.random.PRNGKey(0), g1)

    @jax.jit
    def reach_grad(p, g):
        return jax.value_and_grad(lambda q: jnp.mean(model.apply(q, g) ** 2))(p)

    with CompileCounter("reach_grad") as c:
        for g in (g1, g2, g1):
            loss, grads = jax.block_until_ready(reach_grad(params, g))
    assert c.count == 1
    leaves = jax.tree.leaves(grads)
    assert np.isfinite(float(loss)) and all(bool(jnp.all(jnp.isfinite(x))) for x in leaves)
    assert sum(float(jnp.sum(jnp.abs(x))) for x in leaves) > 0


def test_multiscale_without_levels_is_refused():
    form, model = model_of("multiscale")
    _, g = union_graph(form, [design(make_synthetic_trajectory(), 0)])
    with pytest.raises(ValueError, match="coarse levels"):
        model.init(jax.random.PRNGKey(0), g)


def test_local_model_unchanged_and_formulation_fields():
    t = make_synthetic_trajectory()
    form = FORMULATIONS["default"]
    assert form.reach == "local" and form.hierarchy_levels == 0
    _, g = union_graph(form, [design(t, 0)])
    old = EncodeProcessDecode(output_size=4, latent_size=16, message_passing_steps=3)
    new = EncodeProcessDecode(output_size=4, latent_size=16, message_passing_steps=3, reach="local", reach_levels=2)
    p_old, p_new = old.init(jax.random.PRNGKey(0), g), new.init(jax.random.PRNGKey(0), g)
    assert jax.tree.structure(p_old) == jax.tree.structure(p_new)
    np.testing.assert_array_equal(np.asarray(old.apply(p_old, g)), np.asarray(new.apply(p_new, g)))
    with pytest.raises(ValueError, match="reach"):
        Formulation(reach="global")
    with pytest.raises(ValueError, match="reach_levels"):
        Formulation(reach_levels=0)
    # a config.json written before the field loads as local
    data = json.loads(json.dumps(TrainConfig.from_preset("tiny").to_dict()))
    for k in ("reach", "reach_levels", "reach_slices", "reach_heads"):
        data["formulation"].pop(k)
    assert TrainConfig.from_json(data).formulation.reach == "local"


def test_reach_flags():
    from pcmgn_jax.cli import parse_train
    args = parse_train(["--preset=tiny", "--formulation=realtime", "--reach=multiscale", "--reach_levels=3"])
    cfg = args.config
    assert cfg.formulation.reach == "multiscale" and cfg.formulation.reach_levels == 3
    assert cfg.formulation.processor == "per_design"


@pytest.mark.slow  # 15-45 s each (compilation of the training chunk), 2026-12-04
@pytest.mark.parametrize("reach,form", [("multiscale", "realtime"), ("attention", "default")])
def test_tiny_training_run_is_finite(reach, form, tiny_trajs, tmp_path):
    from pcmgn_jax.train import loop
    cfg = tiny_config(num_steps=20, ckpt_every=20, val_every=20, formulation=form, reach=reach, reach_levels=2,
                      reach_slices=4, reach_heads=2)
    res = loop.train(cfg, tmp_path, train_trajs=tiny_trajs[:3], val_trajs=tiny_trajs[3:])
    losses = [json.loads(line)["loss"] for line in (tmp_path / "metrics.jsonl").read_text().splitlines()
              if "loss" in json.loads(line)]
    assert res["step"] == 20 and losses and np.isfinite(losses).all()


@pytest.mark.slow  # ~80 s: compiles 8 rollouts (the benchmark's smoke run, no timing assertion)
def test_reach_cost_benchmark_runs(tmp_path):
    from benchmarks import reach_cost
    out = reach_cost.main(["--preset", "tiny", "--frames", "2", "--repeats", "1", "--formulations", "realtime",
                           "--json", str(tmp_path / "r.json")])
    assert set(out["variants"]) == {f"realtime / {k}" for k in reach_cost.VARIANTS}
    assert json.loads((tmp_path / "r.json").read_text())["variants"]


def test_reach_entry_point_writes_the_report(tmp_path, capsys):
    from experiments import reach
    assert reach.main(["--preset", "tiny", "--out", str(tmp_path / "r.json")]) == 0
    rep = json.loads((tmp_path / "r.json").read_text())
    assert {"hops", "variants", "command"} <= set(rep) and "OLED" in capsys.readouterr().out
