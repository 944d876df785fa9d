"""Issue 42, the GPU path on any device: the persistent compilation cache (on by default, redirectable, off
by switch), compile notes, and no compilation after warm-up (the solver's padded calls in generation, the
validation rollout through two validations, evaluate's rollout)."""
from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from fixtures.helpers import ROOT, CompileCounter, make_synthetic_trajectory, tiny_config
from pcmgn_jax import compile_cache, compile_notes
from pcmgn_jax.scene import default_scene
from pcmgn_jax.sim import solver


# ---- the persistent compilation cache -------------------------------------------------------------------
def test_cache_dir_default_override_and_switch(tmp_path):
    home = str(tmp_path / "home")
    assert compile_cache.cache_dir({"HOME": home, "XDG_CACHE_HOME": "/x/c"}) == Path("/x/c/pcmgn_jax/jax")
    assert compile_cache.cache_dir({"PCMGN_JAX_CACHE_DIR": "/y"}) == Path("/y")
    for off in ("0", "false", "OFF", "no"):
        assert compile_cache.cache_dir({"PCMGN_JAX_CACHE": off, "PCMGN_JAX_CACHE_DIR": "/y"}) is None
    assert compile_cache.cache_dir({"PCMGN_JAX_CACHE": "1"}) == Path.home() / ".cache" / "pcmgn_jax" / "jax"


def _entry_point_jit(tmp_path, **env):
    """A fresh process that imports the entry points' package (which turns the cache on) and compiles a
    small function; HOME and XDG_CACHE_HOME point into tmp_path so nothing reaches the user's folders."""
    base = {k: v for k, v in os.environ.items() if not k.startswith(("PCMGN_JAX_CACHE", "XDG_CACHE"))}
    base.update(HOME=str(tmp_path / "home"), PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]),
                **env)
    code = ("import experiments, jax, jax.numpy as jnp\n"
            "from pcmgn_jax import compile_cache\n"
            "print(compile_cache.active())\n"
            "print(float(jax.jit(lambda x: jnp.sin(x) @ x.T)(jnp.ones((32, 32))).sum()))\n")
    run = subprocess.run([sys.executable, "-c", code], env=base, cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    return run.stdout.splitlines()[0]


def _files(folder: Path) -> list[Path]:
    return [p for p in folder.rglob("*") if p.is_file()] if folder.exists() else []


def test_cache_written_where_told_and_not_when_off(tmp_path):
    where = tmp_path / "cache"
    assert _entry_point_jit(tmp_path, PCMGN_JAX_CACHE_DIR=str(where)) == str(where)
    assert _files(where), "the small jit left nothing in PCMGN_JAX_CACHE_DIR"
    off = tmp_path / "off"
    assert _entry_point_jit(off, PCMGN_JAX_CACHE="0", PCMGN_JAX_CACHE_DIR=str(off / "cache")) == "None"
    assert not _files(off), "PCMGN_JAX_CACHE=0 still wrote files"


@pytest.mark.slow  # ~4 s: one more process
def test_cache_default_is_under_the_users_cache_folder(tmp_path):
    assert _entry_point_jit(tmp_path) == str(tmp_path / "home" / ".cache" / "pcmgn_jax" / "jax")
    assert _files(tmp_path / "home" / ".cache" / "pcmgn_jax" / "jax")


# ---- compile notes --------------------------------------------------------------------------------------
def test_compile_note_once_per_key_with_seconds_logged(tmp_path, capsys):
    log = tmp_path / "compile.jsonl"
    compile_notes.log_to(log)
    try:
        for key in ("a", "a", "b"):
            with compile_notes.first_call("the test step", ("test_compile_note", key)):
                pass
    finally:
        compile_notes.log_to(None)
    err = capsys.readouterr().err
    assert err.count("compiling the test step…") == 2 and err.count("compiled the test step in") == 2
    recs = [json.loads(line) for line in log.read_text().splitlines()]
    assert [r["compile"] for r in recs] == ["the test step"] * 2
    assert all(r["seconds"] >= 0 and r["xla_seconds"] >= 0 and r["time"] > 0 for r in recs)


# ---- the solver: padded calls, batched == one at a time -------------------------------------------------
SCENES = [default_scene(t_oca1=a * 1e-6, t_oca2=b * 1e-6) for a, b in ((50, 150), (120, 60), (90, 90))]
FRAMES = 6


def test_padded_calls_equal_unpadded_and_compile_once():
    """3 designs at 2 per call (the last call padded with a copy) give what one call of 3 gives (float32
    round-off; one call against one design at a time: test_solver.test_batch_equals_single_runs), and every
    call of the padded run shares one compilation."""
    with CompileCounter("_run") as c:
        padded = solver.simulate(SCENES, "tiny", n_frames=FRAMES, settings=solver.SolverSettings(designs_per_call=2))
    assert c.count <= 1        # 0 when another test compiled this shape already
    with CompileCounter("_run") as c:
        solver.simulate(SCENES[::-1], "tiny", n_frames=FRAMES, settings=solver.SolverSettings(designs_per_call=2))
    assert c.count == 0
    ref = solver.simulate(SCENES, "tiny", n_frames=FRAMES, settings=solver.SolverSettings(designs_per_call=3))
    assert ref.n_sub == padded.n_sub and ref.dt == padded.dt
    for name in ("u", "v", "von_mises", "force"):
        a, b = getattr(padded, name), getattr(ref, name)
        assert a.shape == b.shape and np.abs(a - b).max() <= 1e-5 * np.abs(b).max(), name
    assert np.abs(padded.u[0] - padded.u[1]).max() > 1e-3 * np.abs(padded.u).max()  # the designs differ


def test_designs_per_call_device_default():
    import jax
    want = 1 if jax.default_backend() == "cpu" else solver.ACCELERATOR_DESIGNS_PER_CALL
    assert solver.designs_per_call() == want
    assert solver.designs_per_call(solver.SolverSettings(designs_per_call=5)) == 5
    with pytest.raises(ValueError, match="designs_per_call"):
        solver.designs_per_call(solver.SolverSettings(designs_per_call=-1))


@pytest.mark.slow  # ~15 s; compile-once of padded calls stays in the default suite
def test_generate_ragged_last_batch_compiles_the_solver_once(tmp_path, monkeypatch):
    """5 designs in batches of 2 (2, 2, 1) with 2 designs per compiled call (as an accelerator's 64, here on
    the CPU): the last batch is padded with a copy, so the solver compiles once (a shape no other test uses:
    7 frames), and its design's trajectory is the one an unpadded call gives."""
    from pcmgn_jax.data.dataset import ensure_dataset, load_manifest
    from pcmgn_jax.data.trajectory_io import read_trajectory
    monkeypatch.setattr(solver, "designs_per_call", lambda settings=solver.DEFAULT_SETTINGS: 2)
    scene = dataclasses.replace(default_scene(), n_frames=7)
    calls = []
    solve = lambda sc, des, preset: calls.append(len(des)) or solver.solve_designs(sc, des, preset=preset)  # noqa
    with CompileCounter("_run") as c:
        ensure_dataset(tmp_path / "d", preset="tiny", n_train=4, n_test=1, seed=3, scene=scene, batch=2,
                       progress=False, solve_fn=solve)
    assert c.count == 1 and calls == [2, 2, 2]
    man = load_manifest(tmp_path / "d")
    entries = [e for s in man["splits"].values() for e in s["trajectories"]]
    assert len(entries) == 5 and all(e["sha256"] for e in entries)
    last = entries[-1]
    got = read_trajectory(tmp_path / "d" / last["path"])
    monkeypatch.setattr(solver, "designs_per_call", lambda settings=solver.DEFAULT_SETTINGS: 1)
    (ref,) = solver.solve_designs(scene, np.asarray([last["design_m"]]), preset="tiny")
    assert np.abs(got.displacement - ref.displacement).max() <= 1e-5 * np.abs(ref.displacement).max()
    assert np.abs(got.von_mises - ref.von_mises).max() <= 1e-5 * np.abs(ref.von_mises).max()


# ---- the learned simulator: validation and evaluation rollouts ------------------------------------------
@pytest.mark.slow  # ~16 s on the shared 2-core machine (a training run of its own, so the counter sees it)
def test_training_through_two_validations_compiles_the_validation_rollout_once(tiny_trajs, tmp_path):
    from pcmgn_jax.train import loop as training
    cfg = tiny_config(num_steps=20, steps_per_dispatch=10, log_every=10, ckpt_every=20, val_every=10,
                      latent_size=16, message_passing_steps=1)   # a model no other test compiles
    with CompileCounter("rollout_union") as c:
        training.train(cfg, tmp_path, train_trajs=tiny_trajs[:3], val_trajs=tiny_trajs[3:])
    recs = [json.loads(line) for line in (tmp_path / "metrics.jsonl").read_text().splitlines()]
    assert sum("val_position_mae_um" in r for r in recs) == 2
    assert c.count == 1
    notes = [json.loads(line)["compile"] for line in (tmp_path / "compile.jsonl").read_text().splitlines()]
    assert notes.count("the training step") == 1 and notes.count("the validation rollout") == 1


def test_evaluate_compiles_its_rollout_once_per_shape(tiny_run, tmp_path):
    from pcmgn_jax.eval import evaluate as evaluation
    _, workdir, _ = tiny_run
    test = [make_synthetic_trajectory(d, n_frames=9) for d in (0.85, 1.15)]   # 8 steps: a shape of its own
    with CompileCounter("rollout_union") as c:
        evaluation.evaluate(workdir, test_trajs=test, plot=False, name="once_a")
    assert c.count == 1
    with CompileCounter("rollout_union") as c:
        evaluation.evaluate(workdir, test_trajs=test, plot=False, name="once_b")
    assert c.count == 0


def _mgn_objective(workdir, ref, batch: int):
    """The optimiser's MGN objective of the run ``workdir`` over the CG thickness of ``ref``'s mesh."""
    from types import SimpleNamespace

    from pcmgn_jax.opt.objectives import MGNObjective
    from pcmgn_jax.sim.design_map import DesignMap
    from pcmgn_jax.surrogates.mgn import MGNSurrogate
    jac = np.zeros((1,) + ref.points.shape)
    jac[0, :, 1] = ref.points[:, 1] >= 400e-6 + 1e-9
    mesh = SimpleNamespace(cells=ref.cells, cell_part=ref.cell_part, node_part=ref.node_part)
    dmap = DesignMap(mesh=mesh, d0=np.array([ref.meta["design"]["CG"]]), p0=ref.points, jac=jac)
    return MGNObjective(MGNSurrogate(workdir, ref, batch=batch), dmap, part=1, reading="area_mean")


def test_optimize_objective_compiles_once_over_population_sizes(tiny_run, tiny_trajs):
    """The optimiser's MGN objective (the GA's populations and a line search's single designs) rolls out
    padded batches whose shape depends only on their slot count (a power of two), each compiled once:
    after every population size has been seen once, new designs compile nothing. (The cause of the
    recompilations before: a population's designs already in the objective's cache are dropped, so the
    surrogate saw 2 or 6 new designs where the warm-up saw 3 or 2, and the union's node count followed.)"""
    _, workdir, _ = tiny_run
    ref = tiny_trajs[1]
    t0 = ref.meta["design"]["CG"]
    obj = _mgn_objective(workdir, ref, batch=4)
    sizes = (3, 4, 1, 7)                                           # GA populations, a line search's one design
    for n in sizes:                                                # warm-up: each population size once
        obj(t0 * np.linspace(0.9, 0.95, n)[:, None])
    with CompileCounter("rollout") as c:
        for n, scale in zip(sizes, (1.02, 1.04, 0.97, 1.01)):       # the same sizes, new designs
            f = obj(t0 * np.linspace(scale, scale + 0.01, n)[:, None])
            assert f.shape == (n,) and np.isfinite(f).all()
    assert c.count == 0


def test_padded_objective_equals_one_design_at_a_time(tiny_run, tiny_trajs):
    """The slot padding changes no value: 3 designs in one union of 4 slots (176 nodes) give the objective
    each design gets alone (a union of one, 64 nodes: the shape the code before the padding used for a
    single design), to float32 round-off."""
    _, workdir, _ = tiny_run
    ref = tiny_trajs[1]
    designs = ref.meta["design"]["CG"] * np.array([[0.92], [1.0], [1.06]])
    padded = _mgn_objective(workdir, ref, batch=4)(designs)
    alone = _mgn_objective(workdir, ref, batch=1)(designs)
    assert np.ptp(alone) > 0  # the designs differ
    np.testing.assert_allclose(padded, alone, rtol=1e-5, atol=1e-6 * np.abs(alone).max())


# ---- the start-up cache: statistics and initial parameters beside the compiled programs -----------------
def _hashed(trajs):
    """Copies of ``trajs`` carrying a content hash, as the dataset's read cache gives them."""
    return [dataclasses.replace(t, meta=dict(t.meta, source_sha256=f"sha-{i}")) for i, t in enumerate(trajs)]


def test_startup_cache_key_covers_data_config_and_code(tiny_trajs):
    from pcmgn_jax.train import startup_cache
    cfg, trajs = tiny_config(), _hashed(tiny_trajs[:2])
    k = startup_cache.key("stats", cfg, trajs, {"capacity": 16})
    assert len(k) == 64 and k == startup_cache.key("stats", cfg, trajs, {"capacity": 16})
    others = [startup_cache.key("params", cfg, trajs, {"capacity": 16}),
              startup_cache.key("stats", cfg, trajs, {"capacity": 32}),
              startup_cache.key("stats", cfg, trajs[::-1], {"capacity": 16}),
              startup_cache.key("stats", tiny_config(seed=1), trajs, {"capacity": 16})]
    assert len({k, *others}) == 5
    assert startup_cache.key("stats", cfg, list(tiny_trajs[:2]), {}) is None   # no content hash: no cache
    assert len(startup_cache.code_hash()) == 64


def test_startup_cache_round_trip_and_off(tiny_trajs, tmp_path, monkeypatch):
    """Statistics and parameters read back bit for bit; computed once per key; a damaged file is computed
    again; nothing is kept when the compilation cache is off."""
    import jax

    from pcmgn_jax.train import setup as setup_lib, startup_cache
    from pcmgn_jax.train.loop import init_params
    cfg = tiny_config(latent_size=8, message_passing_steps=1)
    trajs = _hashed(tiny_trajs[:2])
    monkeypatch.setattr(startup_cache.compile_cache, "active", lambda: tmp_path)
    calls = []
    real = setup_lib.compute_stats
    monkeypatch.setattr(setup_lib, "compute_stats", lambda *a, **k: calls.append(1) or real(*a, **k))
    first = setup_lib.prepare(cfg, trajs)
    again = setup_lib.prepare(cfg, trajs)
    assert len(calls) == 1
    for a, b in zip(first.stats, again.stats):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    p1, p2 = init_params(first, trajs[0], 0), init_params(first, trajs[0], 0)
    assert jax.tree.structure(p1) == jax.tree.structure(p2)
    assert all(np.array_equal(np.asarray(a), np.asarray(b)) for a, b in zip(jax.tree.leaves(p1), jax.tree.leaves(p2)))
    files = sorted((tmp_path / "start").iterdir())
    assert sorted(f.suffix for f in files) == [".json", ".npz"]
    for f in files:
        f.write_text("damaged")
    setup_lib.prepare(cfg, trajs)
    assert len(calls) == 2 and init_params(first, trajs[0], 0) is not None
    assert all(f.stat().st_size > len("damaged") for f in files)         # replaced by good files
    monkeypatch.setattr(startup_cache.compile_cache, "active", lambda: None)
    setup_lib.prepare(cfg, _hashed(tiny_trajs[1:3]))
    assert len(calls) == 3 and len(list((tmp_path / "start").iterdir())) == 2
