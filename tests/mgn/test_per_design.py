"""The per-design processor (formulation ``processor='per_design'``): the rollout runs the message passing
once per design and is the same network as the per-frame path (``step``, ``predict``)."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from pcmgn_jax.mgn import rollout as rl
from pcmgn_jax.mgn.formulation import FORMULATIONS, Formulation
from pcmgn_jax.mgn.model import EncodeProcessDecode
from pcmgn_jax.mgn.normalization import normalize_graph


def _per_design_sim(tiny_run, tiny_trajs):
    """A per-design simulator on the tiny run's setup (statistics reused: the node channels are the
    same), with freshly initialised parameters."""
    _, _, summary = tiny_run
    s = summary["setup"]
    form = s.spec.sim.formulation.replace(processor="per_design")
    model = EncodeProcessDecode(output_size=form.output_size, latent_size=16, message_passing_steps=2,
                                decoder_condition=form.decoder_condition)
    spec = rl.Spec(model=model, formulation=form, dt=s.spec.sim.dt)
    topo, idx, t = s.graphs[0].topology, s.graphs[0].index, tiny_trajs[3]
    g, _ = rl.input_graph(form, topo, idx, t.points, t.displacement[0], t.velocity[0])
    params = model.init(jax.random.PRNGKey(1), normalize_graph(s.stats, g, topo.node_type))
    return spec, params, s.stats, topo, idx, t


def test_per_design_rollout_is_the_per_frame_network(tiny_run, tiny_trajs):
    spec, params, stats, topo, idx, t = _per_design_sim(tiny_run, tiny_trajs)
    args = (t.points, t.displacement[0], t.velocity[0], t.von_mises[0])
    res = rl.rollout(spec, 5, params, stats, topo, idx, *args)
    u, v = np.float32(t.displacement[0]), np.float32(t.velocity[0])
    from pcmgn_jax.mgn.formulation import rigidify
    u, v = (np.asarray(rigidify(a, np.asarray(topo.node_type) == 0)) for a in (u, v))
    for k in range(5):  # the whole network every frame (predict), as in training
        u, v, vm, _ = rl.jitted_step(spec, params, stats, topo, idx, t.points, u, v)
        scale = float(np.abs(np.asarray(res.displacement[k + 1])).max()) + 1e-12
        np.testing.assert_allclose(np.asarray(res.displacement[k + 1]), np.asarray(u), rtol=1e-4, atol=1e-5 * scale)
        np.testing.assert_allclose(np.asarray(res.von_mises[k + 1]), np.asarray(vm), rtol=1e-4,
                                   atol=1e-5 * float(np.abs(vm).max()))
    assert np.all(np.isfinite(np.asarray(res.displacement)))


def test_per_design_scan_body_has_no_message_passing(tiny_run, tiny_trajs):
    """The scan's body holds only the decoder's matmuls: the processor ran before the loop. The
    per-frame default's body holds them all (the check can fail)."""
    spec, params, stats, topo, idx, t = _per_design_sim(tiny_run, tiny_trajs)
    args = (t.points, t.displacement[0], t.velocity[0], t.von_mises[0])

    def sub_jaxprs(eqn):
        for v in eqn.params.values():
            for j in (v if isinstance(v, (tuple, list)) else [v]):
                if hasattr(j, "eqns"):
                    yield j
                elif hasattr(j, "jaxpr") and hasattr(j.jaxpr, "eqns"):
                    yield j.jaxpr

    def eqns(j):
        for e in j.eqns:
            yield e
            for sub in sub_jaxprs(e):
                yield from eqns(sub)

    def body_prims(sp, p):
        jaxpr = jax.make_jaxpr(lambda *a: rl._rollout(sp, 3, p, stats, topo, idx, *a))(*args).jaxpr
        scans = [e for e in eqns(jaxpr) if e.primitive.name == "scan" and e.params["length"] == 3]  # the frames
        return [e.primitive.name for body in sub_jaxprs(scans[0]) for e in eqns(body)]

    # per frame: the decoder's condition projection, hidden layer and output (3 matmuls); the per-frame
    # network's body holds the encoders and every message-passing block too
    assert body_prims(spec, params).count("dot_general") <= 3
    _, _, summary = tiny_run
    default = summary["setup"].spec.sim
    assert body_prims(default, summary["state"].params).count("dot_general") > 20


def test_per_design_needs_a_quasi_static_panel():
    with pytest.raises(ValueError, match="per_design"):
        Formulation(processor="per_design")  # the dynamic panel
    with pytest.raises(ValueError, match="processor"):
        FORMULATIONS["default"].replace(processor="sometimes")
    assert FORMULATIONS["default"].replace(processor="per_design").decoder_condition == 2


@pytest.mark.slow  # ~31 s (the default suite's 10-minute budget)
def test_per_design_gradient_through_the_rollout_is_finite(tiny_run, tiny_trajs):
    spec, params, stats, topo, idx, t = _per_design_sim(tiny_run, tiny_trajs)

    def f(points):
        res = rl._rollout(spec, 3, params, stats, topo, idx, points, t.displacement[0], t.velocity[0],
                          t.von_mises[0])
        return jnp.mean(res.von_mises[-1])

    g = jax.grad(f)(jnp.asarray(t.points, jnp.float32))
    assert np.all(np.isfinite(np.asarray(g))) and float(jnp.abs(g).max()) > 0


@pytest.mark.slow  # ~51 s: eager losses (the default suite's 10-minute budget)
def test_multi_frame_loss_is_the_mean_of_its_frames_losses(tiny_trajs):
    """frames_per_sample = F: one processor pass, F readouts; the loss is the mean of the F single-frame
    losses (each the per-frame network's loss of that frame: same network, one pass each)."""
    from fixtures.helpers import tiny_config
    from pcmgn_jax.train.loop import init_params
    from pcmgn_jax.train.sampling import sample_frames, union_batch
    from pcmgn_jax.train.setup import prepare, union_sizes
    from pcmgn_jax.train.step import loss_fn

    trajs = tiny_trajs[:2]
    cfg = tiny_config(processor="per_design", frames_per_sample=3)
    setup = prepare(cfg, trajs)
    params = init_params(setup, trajs[0], 0)
    sizes = union_sizes(setup.graphs, per_union=2, capacity=setup.sizes.capacity)
    form, dt = setup.spec.sim.formulation, setup.spec.sim.dt
    pairs = [(0, 2), (1, 5)]
    multi = union_batch(form, trajs, setup.graphs, pairs, dt=dt, sizes=sizes, graph_ids=[0, 1], frames=3)
    assert multi.u.shape[0] == 3 and multi.ball.shape[0] == 3
    key = jax.random.PRNGKey(0)
    total, aux = loss_fn(params, setup.spec, setup.stats, multi, key)
    n_steps = trajs[0].n_frames - 1
    singles = []
    for k in range(3):  # the k-th frame of each pair, as a one-frame batch
        frame_pairs = [(i, sample_frames(t, n_steps, 3)[k]) for i, t in pairs]
        singles.append(loss_fn(params, setup.spec, setup.stats,
                               union_batch(form, trajs, setup.graphs, frame_pairs, dt=dt, sizes=sizes,
                                           graph_ids=[0, 1]), key)[0])
    assert float(total) == pytest.approx(float(np.mean(singles)), rel=1e-5)
    # one frame through the per-design loss == the whole network per frame (predict)
    from pcmgn_jax.train import step as step_lib
    one = union_batch(form, trajs, setup.graphs, pairs, dt=dt, sizes=sizes, graph_ids=[0, 1])
    graph = one.graph
    out, _ = rl.predict(setup.spec.sim, params, setup.stats, graph.topology, graph.index, graph.points, one.u,
                        one.v, graph.layout)
    data, _, _ = step_lib._frame_losses(setup.spec, setup.stats, one, dict(points=graph.points, u=one.u, v=one.v,
                                                                         target=one.target, ball=one.ball), out)
    assert float(loss_fn(params, setup.spec, setup.stats, one, key)[1]["loss_data"]) == \
        pytest.approx(float(jnp.mean(data[:2])), rel=1e-5)


def test_frames_per_sample_needs_a_per_design_processor():
    from fixtures.helpers import tiny_config
    with pytest.raises(ValueError, match="frames_per_sample"):
        tiny_config(frames_per_sample=4)
    assert tiny_config(processor="per_design", frames_per_sample=4).frames_per_sample == 4


def test_frames_auto_and_the_realtime_formulation():
    from pcmgn_jax.config import TrainConfig
    assert TrainConfig.from_preset("cpu").frames == 1  # the main job: per-frame processor
    rt = TrainConfig.from_preset("cpu", formulation="realtime")
    assert rt.formulation.processor == "per_design" and rt.frames == 8
    assert TrainConfig.from_preset("cpu", formulation="realtime", frames_per_sample=1).frames == 1
    with pytest.raises(ValueError, match="per_design"):  # the per-design processor needs the quasi-static panel
        TrainConfig.from_preset("cpu", formulation="realtime", panel_model="dynamic")
