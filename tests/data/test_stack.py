"""The stack family (issue 40, task (e)): sampling, index-free graph inputs, padded-vector baselines,
the named range warning, the ROM's refusal, and (slow) generate -> train -> evaluate on a held-out layer
count, the Hertz check at the range's smallest and largest impactor and a 7-layer scene's energy balance."""
from __future__ import annotations

import json
import warnings
from types import SimpleNamespace

import numpy as np
import pytest

from fixtures.helpers import make_synthetic_trajectory, synthetic_scene_trajectory, synthetic_stack
from pcmgn_jax.config import TrainConfig
from pcmgn_jax.data.stack import (
    BALL_RANGES,
    E3_RADIUS,
    STACK_FAMILIES,
    range_warnings,
    stack_layer_count,
    stack_warnings,
)
from pcmgn_jax.presets import STACK_FEATURES
from pcmgn_jax.scene import default_scene
from pcmgn_jax.surrogates.transfer import part_coordinates, transfer_fields

FAM = STACK_FAMILIES["stack_tiny"]


def _scene(row):
    return FAM.scene(FAM.base(default_scene()), dict(zip(FAM.names, row)))


def test_stack_sampling_plans_and_one_oled():
    assert len(FAM.names) >= 10
    a, b = FAM.sample_splits(12, 6, seed=3, plan="e1"), FAM.sample_splits(12, 6, seed=3, plan="e1")
    assert all(np.array_equal(x, y) for x, y in zip(a, b))                  # seeded
    counts = set()
    for row in np.concatenate(a):
        scene = _scene(row)
        names = [layer.name for layer in scene.layers]
        counts.add(len(names))
        assert names.count("OLED") == 1 and names[0] == "CG" and names[-1] == "PLATE"
        assert len(names) == stack_layer_count(dict(zip(FAM.names, row)))
        assert range_warnings("s", dict(zip(FAM.names, row))) == []
    assert counts <= {5, 6, 7} and len(counts) >= 2
    train, test = FAM.sample_splits(16, 6, seed=0, plan="e2")
    assert {stack_layer_count(dict(zip(FAM.names, r))) for r in train} == {5, 7}
    assert {stack_layer_count(dict(zip(FAM.names, r))) for r in test} == {6}
    train, test = FAM.sample_splits(8, 4, seed=0, plan="e3")
    r = FAM.names.index("ball.radius")
    assert train[:, r].max() <= BALL_RANGES[0][2] < E3_RADIUS[0] <= test[:, r].min()


def test_graph_inputs_have_one_width_for_every_layer_count():
    from pcmgn_jax.mgn.graphs import ROLES, node_features
    from pcmgn_jax.mgn.inputs import graph_inputs
    from pcmgn_jax.sim.mesh import build_mesh, roi
    form = TrainConfig.from_preset("stack_tiny").formulation
    widths = {}
    for count in (5, 6, 7):
        scene = _scene(FAM.sample(1, count, layer_counts=(count,))[0])
        mesh, _ = roi(build_mesh(scene, "stack_tiny"), "stack_tiny")
        topo = graph_inputs(mesh, scene, scene_features=form.scene_features, identity="role").topology
        zero = np.zeros_like(mesh.points)
        nodes = node_features(topo, mesh.points, zero, zero, form.features, identity="role", origin=form.origin)
        widths[count] = (topo.n_node_types, nodes.shape[1])
        oled = scene.part_names.index("OLED")
        assert set(np.asarray(topo.node_type)[np.asarray(mesh.node_type) == oled]) == {ROLES.index("objective")}
        # own thickness and depth below the contact top, per node, from its own part
        assert STACK_FEATURES[1:4] == ("material", "own_thickness", "layer_depth")
        rows, sel = np.asarray(topo.scene_features), np.asarray(mesh.node_type) == oled
        assert np.allclose(rows[sel, 4], scene.layers[oled - 1].thickness, rtol=1e-6)     # after radius, material (3)
        assert np.allclose(rows[sel, 5], sum(layer.thickness for layer in scene.layers[:oled - 1]), rtol=1e-6)
    assert len(set(widths.values())) == 1, widths


def test_training_setup_takes_stacks_of_different_layer_counts():
    from pcmgn_jax.train.setup import graph_for, prepare
    cfg = TrainConfig.from_preset("stack_tiny")
    five, seven, six = (synthetic_stack(c, c) for c in (5, 7, 6))
    setup = prepare(cfg, [five, seven])
    assert np.shape(setup.stats.node_mean)[0] == 6                      # six role types, any layer count
    widths = {g.topology.n_node_types for g in setup.graphs} | {graph_for(setup, six)["topology"].n_node_types}
    assert widths == {6}
    noisy = prepare(cfg.replace(noise_rel=1.0, noise_parts="panel"), [five, seven])   # sigma per role type
    assert all(np.isfinite(g.sigma).all() for g in noisy.graphs)
    with pytest.raises(ValueError, match="one set of node types"):     # part ids, without the roles: refused
        prepare(cfg.replace(formulation=cfg.formulation.replace(part_identity="material")), [five, seven])


def test_generate_records_every_stack_and_shards_alike(tmp_path):
    from pcmgn_jax.data.dataset import ensure_dataset, load_manifest

    def solve(scene, designs, *, preset):   # the solver's contract, without the solver: one stack per call
        assert np.shape(designs) == (1, 0) and preset == "stack_tiny"
        return [synthetic_scene_trajectory(scene, {"wall_time_s": 0.1}, n_frames=3)]
    kw = dict(preset="stack_tiny", n_train=3, n_test=2, seed=0, stack_split="e2", solve_fn=solve, progress=False,
              batch=1)
    whole = load_manifest(ensure_dataset(tmp_path / "whole", **kw))
    strip = lambda m: [(e["name"], e["layers"], e["scene_params"]) for s in m["splits"].values()  # noqa: E731
                       for e in s["trajectories"]]
    assert whole["splits"]["train"]["origin"]["plan"] == "e2"
    for split, counts in (("train", {5, 7}), ("test", {6})):
        entries = whole["splits"][split]["trajectories"]
        assert {len(e["layers"]) for e in entries} <= counts and all("OLED" in e["layers"] for e in entries)
        assert all(list(e["scene_params"]) == list(FAM.names) and e["sha256"] for e in entries)
        assert [len(e["layers"]) for e in entries] == [stack_layer_count(e["scene_params"]) for e in entries]
    resumed = {k: v for k, v in kw.items() if k != "stack_split"}     # as training calls it: the manifest's plan
    assert strip(load_manifest(ensure_dataset(tmp_path / "whole", **resumed))) == strip(whole)
    # a learning-curve point (fewer training stacks) reads the dataset as it is: no second hypercube (which
    # would be other stacks, refused as "holds other designs")
    from pcmgn_jax.data.splits import load_splits, prepare_dataset
    prepare_dataset(tmp_path / "whole", preset="stack_tiny", n_train=2, n_test=1, seed=0, solve_fn=None)
    train, val, _ = load_splits(tmp_path / "whole", n_train=1, n_val=1, n_test=0)
    assert [t.meta["name"] for t in train + val] == [e["name"] for e in whole["splits"]["train"]["trajectories"][:2]]
    for k in (0, 1):
        ensure_dataset(tmp_path / "sharded", shard=(k, 2), **kw)
    merged = load_manifest(ensure_dataset(tmp_path / "sharded", merge=True, **kw))
    assert strip(merged) == strip(whole)


def test_role_identity_refuses_per_layer_features():
    with pytest.raises(ValueError, match="per-layer"):
        TrainConfig.from_preset("stack_tiny", scene_features=("material", "layer_thickness"))


def test_kriging_and_mop_on_the_padded_vector_recover_a_known_function():
    from pcmgn_jax.surrogates.surface_fit import fit_surface
    fam = STACK_FAMILIES["stack"]
    names = list(fam.names)
    x, q = fam.sample(60, 0), fam.sample(20, 5)

    def target(v):   # an exact function of the padded vector: a layer's presence, thickness, modulus, the ball
        return (1.0 + 2e3 * v[:, names.index("POL.thickness")] + 0.5 * v[:, names.index("TSP.present")]
                - 0.3 * v[:, names.index("OCA1.log10_youngs")] + 100 * v[:, names.index("ball.radius")])
    spread = np.abs(target(q) - target(q).mean()).max()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for kind in ("kriging", "mop"):
            pred = fit_surface(kind, x, {"y": target(x)}, names=names).predict(q)["y"]
            assert np.abs(pred - target(q)).max() < 0.01 * spread, kind


def test_a_scene_outside_the_ranges_gets_a_named_warning():
    row = dict(zip(FAM.names, FAM.sample(1, 0, layer_counts=(6,))[0]))
    inside = SimpleNamespace(meta={"family": "stack", "name": "in", "scene_params": row})
    outside = SimpleNamespace(meta={"family": "stack", "name": "big_ball",
                                    "scene_params": {**row, "ball.radius": 7e-3, "OLED.thickness": 60e-6}})
    got = stack_warnings([inside, outside])
    assert len(got) == 2 and all(w.startswith("stack range: big_ball: ") for w in got)
    assert any("ball.radius" in w for w in got) and any("OLED.thickness" in w for w in got)


def _fake(name, scene, n=12):
    """A trajectory-like object: meta and a mesh of ``n`` nodes, enough for the ROM's checks."""
    d = scene.to_dict()
    return SimpleNamespace(meta={"name": name, "scene": d, "part_names": list(scene.part_names),
                                 "scene_params": {"ball.radius": scene.ball.radius}}, n_frames=3, n_nodes=n)


def test_rom_refuses_stacks_of_other_layers_by_name():
    from pcmgn_jax.surrogates.rom import Rom, StackRom, fit_rom
    rows = [FAM.sample(1, s, layer_counts=(c,))[0] for s, c in ((0, 5), (1, 7), (2, 5))]
    trajs = [_fake(f"t{i}", _scene(r)) for i, r in enumerate(rows)]
    with pytest.raises(ValueError, match="rom: the meshes do not map"):
        Rom(trajs)
    rom = fit_rom(trajs)                 # one rom per layer list: a 6-layer stack has none
    assert isinstance(rom, StackRom) and sorted(len(p) - 1 for p in rom.groups) == [5, 7]
    with pytest.raises(ValueError, match="rom: the meshes do not map: no training scene has the parts"):
        rom.predict_trajectories([_fake("six", _scene(FAM.sample(1, 3, layer_counts=(6,))[0]))])


def test_the_rom_answers_a_stack_from_the_training_stacks_of_its_layer_list():
    from pcmgn_jax.surrogates.rom import StackRom, fit_rom
    train = [synthetic_stack(5, s) for s in (11, 12, 13)] + [synthetic_stack(7, s) for s in (14, 15)]
    query = synthetic_stack(5, 16)
    rom = fit_rom(train)
    assert isinstance(rom, StackRom)
    (u,), (vm,) = rom.predict_trajectories([query])
    assert u.shape == query.displacement.shape and vm.shape == query.von_mises.shape
    assert np.all(np.isfinite(u)) and np.all(np.isfinite(vm)) and list(rom.pod_modes) == ["CG/OCA1/OCA2/OLED/PLATE"]


# ---- solver and end to end (slow) --------------------------------------------------------------------
@pytest.mark.slow   # ~60 s: the solver for 6 tiny stacks, 20 training steps, two evaluations
def test_train_on_5_and_7_layers_evaluate_on_6(tmp_path):
    from experiments import evaluate, generate, train
    from pcmgn_jax.data.layout import load_manifest
    data, run = tmp_path / "stacks", tmp_path / "run"
    assert generate.main(["--preset", "stack_tiny", "--out", str(data), "--stack_split", "e2", "--n_train", "3",
                          "--n_val", "1", "--n_test", "1", "--no_progress"]) == 0
    man = load_manifest(data)
    count = lambda e: stack_layer_count(e["scene_params"])  # noqa: E731
    assert {count(e) for e in man["splits"]["train"]["trajectories"]} == {5, 7}
    assert [count(e) for e in man["splits"]["test"]["trajectories"]] == [6]
    assert {count(e) for e in man["splits"]["train"]["trajectories"][:3]} == {5, 7}   # the 3 trained on (then 1 val)
    # one more 6-layer scene with a ball outside the family's radius range
    row = dict(zip(FAM.names, FAM.sample(1, 9, layer_counts=(6,))[0]), **{"ball.radius": 7.0e-3})
    assert generate.main(["--preset", "stack_tiny", "--out", str(data), "--split", "extrap", "--no_progress",
                          "--scene_params", ",".join(f"{k}={float(v)!r}" for k, v in row.items())]) == 0
    assert train.main(["--preset", "stack_tiny", f"--dataset_dir={data}", f"--workdir={run}",
                       "--num_steps=20", "--val_every=20", "--progress=False"]) == 0
    assert evaluate.main(["--workdir", str(run)]) == 0
    m = json.loads((run / "eval" / "metrics.json").read_text())
    assert m["n_test"] == 1 and np.isfinite(m["position_mae_um"])
    assert np.isfinite(m["oled_objective_area_rel_error_pct_mean"])
    assert m["warnings"] == []
    b = m["baselines"]
    assert "do not map" in b["rom"]["not_applicable"]
    assert "no training scene has the parts" in b["nearest"]["not_applicable"]
    assert np.isfinite(b["none"]["position_mae_um"])
    assert evaluate.main(["--workdir", str(run), "--data", str(data / "extrap")]) == 0
    m = json.loads((run / "eval" / "extrap" / "metrics.json").read_text())
    assert any(w.startswith("stack range: ") and "ball.radius" in w for w in m["warnings"]), m["warnings"]


@pytest.mark.slow   # ~20 s each
@pytest.mark.parametrize("radius,velocity", [(BALL_RANGES[0][1], BALL_RANGES[1][2]), (E3_RADIUS[1], BALL_RANGES[1][1])])
def test_hertz_at_the_smallest_and_largest_impactor(radius, velocity):
    from pcmgn_jax.sim.hertz import hertz_check
    r = hertz_check(radius=radius, velocity=velocity, target="glass", elems_per_radius=10)
    rel = r["relative_error"]
    assert abs(rel["contact_time_s"]) < 0.05 and abs(rel["peak_force_N"]) < 0.05
    assert abs(rel["max_indentation_m"]) < 0.05 and abs(rel["impulse_Ns"]) < 0.02 and r["energy_error"] < 0.01


@pytest.mark.slow
def test_a_7_layer_scene_keeps_its_energy():
    from pcmgn_jax.sim.solver import simulate
    scene = _scene(STACK_FAMILIES["stack"].sample(1, 4, layer_counts=(7,))[0])
    assert len(scene.layers) == 7
    res = simulate([scene], "stack")
    total = np.asarray(res.energy[0]).sum(-1)     # kinetic + internal + contact [J], every frame
    assert res.energy_error[0] < 0.01, res.energy_error[0]
    assert abs(total[-1] - total[0]) < 0.01 * total[0]


def test_transfer_to_a_part_the_source_has_no_nodes_of():
    """A one-element layer whose nodes all sit on its interfaces has no nodes of its own (node_part goes to the
    neighbour): the fields of the destination's nodes of that part come from the nearest source node over all
    parts, instead of a refusal that left the rom and the nearest scene without an answer (a stack dataset's BF)."""
    dst = make_synthetic_trajectory(1.0)
    src = make_synthetic_trajectory(0.9)
    src.node_part = np.where(src.node_part == 1, 2, src.node_part)          # the source's CG nodes relabelled
    u, vm = transfer_fields(src, dst.points, dst.node_part, dst.meta["scene"])
    assert u.shape == dst.displacement.shape and vm.shape == dst.von_mises.shape
    assert np.isfinite(u).all() and np.isfinite(vm).all()
    cg = dst.node_part == 1
    a = part_coordinates(src.points, src.node_part, src.meta["scene"])
    b = part_coordinates(dst.points, dst.node_part, dst.meta["scene"])
    span = np.ptp(a[:, 0])                                                   # x scaled by the source's span
    a[:, 0] /= span
    b[:, 0] /= span
    nearest = np.argmin(((b[cg, None] - a[None]) ** 2).sum(-1), axis=1)
    np.testing.assert_allclose(vm[:, cg], src.von_mises[:, nearest])
    np.testing.assert_allclose(u[:, cg], src.displacement[:, nearest])
