"""Encode-process-decode model: shapes, jit equality, masking of padded contact edges, config flags."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from pcmgn_jax import cli
from pcmgn_jax.config import TrainConfig
from pcmgn_jax.mgn import contact, graphs
from pcmgn_jax.mgn.inputs import topology_from_trajectory
from pcmgn_jax.mgn.model import EncodeProcessDecode


@pytest.fixture(scope="module")
def graph(tiny_trajs):
    t = tiny_trajs[0]
    topo = topology_from_trajectory(t)
    idx = contact.allocate(points=t.points, cells=t.cells, cell_part=t.cell_part, radius=20e-6,
                           positions=[t.positions])
    e = contact.update(idx, jnp.asarray(t.positions[5], jnp.float32))
    g = graphs.build_graph(topo, points=t.points, displacement=t.displacement[5], velocity=t.velocity[5],
                           contact=e)
    # features roughly O(1) for the test (real runs normalise with training stats)
    return g._replace(nodes=g.nodes.at[:, 4:].multiply(1e3),
                      edges={k: v._replace(features=v.features * 1e5) for k, v in g.edges.items()})


def test_shapes_jit_equality_and_param_layout(graph):
    model = EncodeProcessDecode(latent_size=16, message_passing_steps=3)
    params = model.init(jax.random.PRNGKey(0), graph)
    out = model.apply(params, graph)
    assert out.shape == (graph.nodes.shape[0], 3) and np.all(np.isfinite(out))
    np.testing.assert_allclose(jax.jit(model.apply)(params, graph), out, rtol=2e-5, atol=2e-6)
    p = params["params"]
    assert {"node_encoder", "mesh_edge_encoder", "contact_edge_encoder", "decoder"} <= set(p)
    assert {"step2_mesh_edge", "step2_contact_edge", "step2_node"} <= set(p)
    # concat trick: node projections of the first edge layer, no (3L -> L) dense on a concatenation
    assert set(p["step0_mesh_edge"]) >= {"sender_proj", "receiver_proj", "edge_proj"}
    assert p["step0_mesh_edge"]["edge_proj"]["kernel"].shape == (16, 16)
    assert "LayerNorm_0" not in p["decoder"]


def test_padded_contact_edges_do_not_matter(graph):
    model = EncodeProcessDecode(latent_size=16, message_passing_steps=2)
    params = model.init(jax.random.PRNGKey(1), graph)
    c = graph.edges["contact"]
    junk = c._replace(features=jnp.where(c.mask[:, None], c.features, 123.0),
                      senders=jnp.where(c.mask, c.senders, 3), receivers=jnp.where(c.mask, c.receivers, 7))
    g2 = graph._replace(edges={**graph.edges, "contact": junk})
    np.testing.assert_allclose(model.apply(params, g2), model.apply(params, graph), rtol=1e-6, atol=1e-6)


def test_sorted_mesh_aggregation_is_the_plain_sum(graph):
    """Mesh messages are summed with indices_are_sorted=True (receivers ascending); same result as the
    plain segment sum, and the contact set (slot order, unsorted) keeps the plain one."""
    assert np.all(np.diff(np.asarray(graph.edges["mesh"].receivers)) >= 0)
    fast = EncodeProcessDecode(latent_size=16, message_passing_steps=2)
    plain = EncodeProcessDecode(latent_size=16, message_passing_steps=2, sorted_receivers=())
    assert fast.sorted_receivers == ("mesh",)
    params = fast.init(jax.random.PRNGKey(2), graph)
    np.testing.assert_allclose(jax.jit(fast.apply)(params, graph), jax.jit(plain.apply)(params, graph),
                               rtol=1e-6, atol=1e-6)


def test_config_flags():
    cfg = cli.parse_config(["--preset", "tiny", "--lambda_pen=0", "--latent_size=48", "--no-progress"])
    assert cfg.preset == "tiny" and cfg.latent_size == 48 and cfg.progress is False and cfg.lambda_pen == 0
    assert cli.parse_config(["--lambda_pen=10"]).lambda_pen == 10.0
    assert TrainConfig.from_preset("paper").message_passing_steps == 15
    with pytest.raises(ValueError, match="unknown flag"):
        cli.parse_config(["--lamda_pen=10"])
    with pytest.raises(ValueError):
        cli.parse_config(["--ball_target=jerk"])
    assert TrainConfig.from_json(cfg.to_dict()) == cfg
