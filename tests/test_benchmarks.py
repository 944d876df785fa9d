"""The benchmarks run end to end at tiny sizes and write valid JSON / Markdown (no timing assertions)."""
from __future__ import annotations

import dataclasses
import importlib.util
import json

import numpy as np
import pytest

from fixtures.helpers import ROOT

HAVE_TORCH = importlib.util.find_spec("torch") is not None


def _load(path):
    data = json.loads(path.read_text())  # strict JSON (no NaN) is enforced by the writer
    return data


def test_bench_graph_and_flops():
    from pcmgn_jax.eval.bench import bench_graph, mgn_flops
    g = bench_graph(80)
    info = g["info"]
    assert abs(info["n_nodes"] - 80) < 40
    assert info["n_contact_edges_active"] > 0
    assert g["mesh_senders"].max() < info["n_nodes"] and g["nodes"].shape[0] == info["n_nodes"]
    assert np.isfinite(g["nodes"]).all() and np.isfinite(g["mesh_features"]).all()
    f = mgn_flops(100, {"mesh": 400, "contact": 10}, {"node": 12, "mesh": 6, "contact": 3},
                  latent=8, mlp_layers=2, steps=1)
    assert 0 < f["forward"] < f["forward_concat_variant"]


@pytest.mark.slow  # 18 s: a smoke run of the benchmark's command line (the default suite's 10-minute budget)
@pytest.mark.parametrize("with_torch", [False, pytest.param(True, marks=pytest.mark.skipif(
    not HAVE_TORCH, reason="torch not installed (pip install torch==2.13.0)"))])
def test_mgn_vs_torch_tiny(tmp_path, with_torch):
    from benchmarks import mgn_vs_torch
    out = tmp_path / "m.json"
    argv = ["--nodes", "60", "--layers", "1", "--latent", "8", "--repeats", "2", "--warmup", "1",
            "--scan", "2", "--compile", "off", "--no_torch_1thread", "--json", str(out)]
    if not with_torch:
        argv.append("--no_torch")
    mgn_vs_torch.main(argv)
    r = _load(out)
    assert r["jax"]["forward_ms"] > 0 and r["jax"]["train_step_ms"] > 0
    assert r["config"]["layers"] == 1 and r["machine"]["matmul_1024_gflops_jax"] > 0
    assert out.with_suffix(".md").exists()
    if with_torch:
        assert r["torch"]["forward_ms"] > 0 and r["torch"]["train_step_ms"] > 0
        assert r["ratios"]["forward_torch_over_jax"] > 0
    else:
        assert r["torch"] is None


@pytest.mark.skipif(not HAVE_TORCH, reason="torch not installed")
def test_torch_reference_matches_architecture():
    """Same parameter count as the Flax model (both first-layer variants describe the same MLPs)."""
    import jax

    from benchmarks.torch_mgn import TorchMGN, torch_graph
    from pcmgn_jax.eval.bench import bench_graph, jraph_graph
    from pcmgn_jax.mgn.model import EncodeProcessDecode
    g = bench_graph(60)
    model = EncodeProcessDecode(output_size=3, latent_size=8, mlp_layers=2, message_passing_steps=2)
    n_jax = sum(x.size for x in jax.tree.leaves(model.init(jax.random.PRNGKey(0), jraph_graph(g))))
    for trick in (False, True):
        m = TorchMGN(g["nodes"].shape[1], {"mesh": 6, "contact": 3}, latent=8, mlp_layers=2, steps=2,
                     concat_trick=trick)
        n_torch = sum(p.numel() for p in m.parameters())
        # the concat variant has one bias per edge MLP first layer, the trick variant too (edge_proj)
        assert n_torch == n_jax
        assert tuple(m(torch_graph(g)).shape) == (g["nodes"].shape[0], 3)


@pytest.mark.slow  # 38 s: a smoke run of the benchmark's command line (the default suite's 10-minute budget)
def test_rollout_throughput_tiny(tmp_path):
    from benchmarks import rollout_throughput
    out = tmp_path / "r.json"
    rollout_throughput.main(["--preset", "tiny", "--latent", "8", "--layers", "1", "--frames", "3",
                             "--batches", "1,2", "--union", "2", "--repeats", "1", "--profile", "--json", str(out)])
    r = _load(out)
    assert r["single"]["rollout_ms"] > 0 and r["python_loop"]["rollout_ms"] > 0
    assert set(r["batched"]) == {"1", "2"} and r["batched"]["2"]["designs_per_s"] > 0
    u = r["union"]["2"]
    assert u["ms_per_design"] > 0 and u["speedup_vs_vmap"] > 0 and u["real_nodes"] < u["nodes"]
    assert set(r["profile_step_ms_per_design"]) == {"1 design", "union 2", "vmap 2"}
    assert r["config"]["params"].startswith("random")


@pytest.mark.slow  # 13 s: a smoke run of the benchmark's command line
def test_solver_speed_tiny(tmp_path):
    from benchmarks import solver_speed
    out = tmp_path / "s.json"
    solver_speed.main(["--presets", "tiny", "--batch", "2", "--frames", "2", "--probe_frames", "1",
                       "--json", str(out)])
    r = _load(out)
    t = r["solver"]["tiny"]
    assert t["1"]["substeps_per_s"] > 0 and t["2"]["wall_s_per_design"] > 0
    assert t["batch_throughput_ratio"] > 0
    # extrapolation path: a budget of 0 s skips the full run
    out2 = tmp_path / "s2.json"
    solver_speed.main(["--presets", "tiny", "--batch", "1", "--frames", "3", "--probe_frames", "1",
                       "--budget", "0", "--json", str(out2)])
    assert _load(out2)["solver"]["tiny"]["1"]["extrapolated"] is True


def test_transfer_reproduces_linear_field():
    from benchmarks.speed_vs_error import transfer
    xs, ys = np.meshgrid(np.linspace(0, 1e-3, 5), np.linspace(0, 1e-4, 3))
    pts = np.stack([xs.ravel(), ys.ravel()], axis=1)
    cells = np.array([[j * 5 + i, j * 5 + i + 1, (j + 1) * 5 + i + 1, (j + 1) * 5 + i]
                      for j in range(2) for i in range(4)])
    field = np.stack([pts * 2.0, pts * -1.0])                     # (T=2, N, 2), linear
    dst = np.array([[0.33e-3, 0.5e-4], [0.9e-3, 0.2e-4], [1.2e-3, 0.5e-4]])  # last one outside
    out = transfer(pts, cells, np.zeros(8, int), field, dst, np.zeros(3, int))
    np.testing.assert_allclose(out[:, :2], np.stack([dst[:2] * 2.0, dst[:2] * -1.0]), rtol=1e-9, atol=1e-15)
    assert np.isfinite(out).all()                                  # nearest-node fallback outside


def test_pareto_and_verdicts():
    from benchmarks.speed_vs_error import pareto, verdicts
    pts = [dict(kind="solver", label="ref", seconds_per_design=10.0, position_mae_um=0.0),
           dict(kind="solver", label="coarse", seconds_per_design=1.0, position_mae_um=2.0),
           dict(kind="surrogate", label="mgn", seconds_per_design=0.1, position_mae_um=1.0),
           dict(kind="surrogate", label="bad", seconds_per_design=5.0, position_mae_um=3.0)]
    assert [pts[i]["label"] for i in pareto(pts)] == ["mgn", "ref"]
    v = {x["surrogate"]: x for x in verdicts(pts)}
    assert v["mgn"]["fastest_solver_as_accurate"] == "ref" and v["mgn"]["speedup"] == pytest.approx(100)
    assert v["bad"]["dominated_by"] == ["coarse"]


def test_speed_vs_error_surrogate_and_report(tiny_run, tiny_trajs, tmp_path):
    """Surrogate point from a trained tiny run (synthetic data) + stub solver points -> JSON/MD/PNG."""
    from benchmarks.speed_vs_error import report, surrogate_point
    _, workdir, _ = tiny_run
    p = surrogate_point(workdir, tiny_trajs[3:])
    assert p["kind"] == "surrogate" and p["finite"] and p["seconds_per_design"] > 0
    stubs = [dict(kind="solver", label="solver ref", seconds_per_design=2.0, position_mae_um=0.0,
                  stress_mae_mpa=0.0, n_designs=1),
             dict(kind="solver", label="solver coarse", seconds_per_design=0.5,
                  position_mae_um=p["position_mae_um"] * 2, stress_mae_mpa=p["stress_mae_mpa"] * 2 + 1,
                  n_designs=1)]
    out = tmp_path / "sve.json"
    report([p] + stubs, command="test", json_path=out, md_path=tmp_path / "sve.md", png_path=tmp_path / "sve.png")
    r = _load(out)
    assert len(r["points"]) == 3 and r["verdicts_position"][0]["surrogate"] == p["label"]
    assert (tmp_path / "sve.png").stat().st_size > 1000


def test_speed_vs_error_baseline_points_score_like_the_evaluation(tiny_trajs, tmp_path):
    """A design-space baseline as a speed-vs-error point: its errors are the evaluation's (nearest training
    design -> that design's fields), and it appears in the report beside the other kinds."""
    from benchmarks.speed_vs_error import baseline_point, errors, report
    train, test = tiny_trajs[:2], tiny_trajs[2:]
    p = baseline_point("nearest", train, test)
    near = np.stack([train[1].displacement] * 2), np.stack([train[1].von_mises] * 2)  # 0.93 is nearest to both
    assert p["kind"] == "baseline" and p["seconds_per_design"] > 0
    assert p["position_mae_um"] == pytest.approx(errors(*near, test)["position_mae_um"])
    report([p, dict(kind="solver", label="solver ref", seconds_per_design=2.0, position_mae_um=0.0,
                    stress_mae_mpa=0.0, n_designs=2)], command="test", json_path=tmp_path / "b.json",
           md_path=tmp_path / "b.md", png_path=tmp_path / "b.png")
    assert "baseline nearest" in (tmp_path / "b.md").read_text()


@pytest.mark.slow  # 15 s: real solver runs of the benchmark (the default suite's 10-minute budget)
def test_speed_vs_error_solver_points():
    """Solver at the reference mesh reproduces it (error ~0); a coarser mesh is interpolated."""
    from benchmarks.speed_vs_error import solver_point
    from pcmgn_jax.scene import default_scene
    from pcmgn_jax.sim import solver
    scene = dataclasses.replace(default_scene(), n_frames=2)
    trajs = solver.solve_designs(scene, np.array([[80e-6, 120e-6]]), preset="tiny")
    same = solver_point("tiny", trajs)
    assert same["same_mesh_as_reference"] and same["position_mae_um"] < 1e-3
    coarse = solver_point("tiny@2", trajs)
    assert not coarse["same_mesh_as_reference"] and coarse["finite"]


def test_surrogate_speed_trained_point_scores_the_rollout_it_times(tiny_run, tiny_trajs):
    """The benchmark's MGN point: warm per-design time and the errors of the same rollouts (the
    evaluation's metrics), from a trained tiny run."""
    from benchmarks.speed_vs_error import errors
    from benchmarks.surrogate_speed import trained_point
    from pcmgn_jax.surrogates.mgn import MGNSurrogate
    _, workdir, _ = tiny_run
    test = tiny_trajs[3:]
    p = trained_point(workdir, test, batch=2, repeats=1, which="best")
    assert p["mgn_s_per_design"] > 0 and p["mgn_compile_s"] >= 0
    ref = errors(*MGNSurrogate(workdir, test[0], batch=2).rollout_trajectories(test), test)
    assert p["position_mae_um"] == pytest.approx(ref["position_mae_um"], rel=1e-6)
    assert p["stress_mae_mpa"] == pytest.approx(ref["stress_mae_mpa"], rel=1e-6)
    assert p["objective_error_pct"] is None  # the synthetic scene has no OLED layer


@pytest.mark.slow  # ~60 s: the benchmark's command line, untrained (random parameters) on the tiny preset
def test_surrogate_speed_untrained_tiny(tmp_path):
    from benchmarks import surrogate_speed
    out = tmp_path / "ss.json"
    r = surrogate_speed.main(["--preset", "tiny", "--workdir", str(tmp_path / "none"), "--n_test", "1",
                              "--repeats", "1", "--json", str(out), "--md", str(tmp_path / "ss.md")])
    j = _load(out)
    for k in ("mgn_s_per_design", "solver_s_per_design", "ratio", "mgn_per_frame_s_per_design"):
        assert j[k] > 0, k
    assert j["position_mae_um"] is None and not r["trained"]


@pytest.mark.slow   # 40 s on this CPU: the GPU script's CPU smoke (the default suite stays under 10 minutes)
def test_gpu_check_smoke(tmp_path):
    """`python -m benchmarks.gpu_check --smoke`: the GPU check's code at tiny sizes on the CPU, in a process of
    its own (so its quick XLA compile flags apply); every figure it reports is there, finite and positive
    (no timing assertions)."""
    import math
    import subprocess
    import sys

    out = tmp_path / "g.json"
    run = subprocess.run([sys.executable, "-m", "benchmarks.gpu_check", "--smoke", "--json", str(out)], check=False,
                         cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stdout + run.stderr
    r = _load(out)
    assert "--xla_backend_optimization_level=0" in r["machine"]["xla_flags"]
    assert r["config"]["smoke"] and r["config"]["preset"] == "tiny" and r["device"]["backend"]
    figures = {"matmul": ("gflops",),
               "mgn": ("forward_ms", "train_step_ms", "train_step_scan_ms", "train_steps_per_s",
                       "train_steps_per_s_scan", "forward_fraction_of_matmul", "train_step_fraction_of_matmul",
                       "train_step_scan_fraction_of_matmul", "compile_s"),
               "rollout": ("s", "ms_per_frame", "compile_s"),
               "solver": ("wall_s", "compile_s", "substeps_per_s", "wall_s_per_design")}
    for group, keys in figures.items():
        for k in keys:
            v = r[group][k]
            assert isinstance(v, (int, float)) and math.isfinite(v) and v > 0, (group, k, v)
    assert r["rollout"]["frames"] == 3 and r["mgn"]["n_nodes"] > 0 and r["total_s"] > 0
    assert "| MGN rollout |" in out.with_suffix(".md").read_text()


def test_gpu_check_budget_skips_and_says_so(tmp_path):
    """A budget too small for any part: nothing is started, every part is recorded as skipped with the reason,
    and the JSON and table are still written (the check always returns something)."""
    from benchmarks import gpu_check
    out = tmp_path / "g.json"
    r = gpu_check.main(["--smoke", "--budget_s", "0", "--json", str(out)])
    j = _load(out)
    for part in gpu_check.PARTS:
        assert "not started" in j[part]["skipped"] and "--budget_s=0" in j[part]["skipped"], part
    assert r["config"]["budget_s"] == 0 and "skipped: not started" in out.with_suffix(".md").read_text()


@pytest.mark.slow  # ~11 s: solver calls of the benchmark
def test_solver_throughput_rows(tmp_path):
    """`benchmarks.solver_throughput` at tiny sizes: one row per batch size, written as measured, finite."""
    import math

    from benchmarks import solver_throughput
    out = tmp_path / "s.json"
    solver_throughput.main(["--presets", "tiny", "--sizes", "1,2", "--frames", "1", "--repeats", "1",
                            "--json", str(out)])
    rows = _load(out)["rows"]
    assert [r["batch"] for r in rows] == [1, 2] and rows[0]["speedup_vs_batch_1"] == 1.0
    for r in rows:
        for k in ("compile_s", "call_s", "designs_per_s", "designs_per_s_full_trajectory", "prepare_s_per_design"):
            assert isinstance(r[k], float) and math.isfinite(r[k]) and r[k] > 0, (k, r[k])
        assert r["finite"] and r["extrapolated_to_frames"] == 100 and r["substeps_per_call"] > 0


def test_profile_ops_self_time_and_op_groups():
    """bench.profile_ops counts a lax.scan's body ops once each (its while loop only the time no op of the body
    ran), and bench.group_ops sums op kinds into the named groups, a kind no rule knows as its own row."""
    import jax
    import jax.numpy as jnp

    from pcmgn_jax.eval.bench import OP_KIND_GROUPS, group_ops, profile_ops
    w = jnp.full((256, 256), 1e-3)
    f = jax.jit(lambda x: jax.lax.scan(lambda c, _: (jnp.tanh(c @ w), None), x, None, length=4)[0])
    x = jnp.ones((256, 256))
    prof = profile_ops(lambda: f(x).block_until_ready(), repeats=2)
    groups = group_ops(prof)
    gemm = groups["GEMM (YNNPACK fusions)"]["ms"] + groups["GEMM (XLA dot)"]["ms"]
    assert gemm > 0 and prof.get("while", 0.0) < 0.5 * sum(prof.values())
    g = group_ops({"ynn_fusion": 2.0, "dot": 1.0, "bitcast_gather_fusion": 0.5, "multiply_add_fusion": 0.25,
                   "copy_bitcast_fusion": 0.125, "while": 0.0625, "sort": 0.0625})
    assert list(g) == [*OP_KIND_GROUPS, "kind sort"] and g["kind sort"]["share"] == pytest.approx(0.0625 / 4)
    assert [g[k]["ms"] for k in OP_KIND_GROUPS] == [2.0, 1.0, 0.5, 0.25, 0.125, 0.0625]
    assert sum(r["share"] for r in g.values()) == pytest.approx(1.0)


TINY_STEP_FLAGS = "--contact_radius=2e-5 --latent_size=8 --message_passing_steps=1 --steps_per_dispatch=2"


def _train_step_run(tmp_path, trajs, *flags):
    """`benchmarks.train_step` on a directory of the tiny synthetic trajectories (an imported dataset: 3 train
    + 1 val, the tiny preset's split); its JSON, checked to be finite and consistent (no timing assertions)."""
    import math

    from benchmarks import train_step
    from pcmgn_jax.data.trajectory_io import write_trajectory
    for i, t in enumerate(trajs):
        write_trajectory(t, tmp_path / "data" / "train" / f"run{i:02d}")
    out = tmp_path / "ts.json"
    train_step.main(["--preset", "tiny", "--dataset_dir", str(tmp_path / "data"), f"--train_flags={TINY_STEP_FLAGS}",
                     "--repeats", "1", "--json", str(out), *flags])
    r = _load(out)
    K = r["config"]["steps_per_dispatch"]
    assert K == 2 and r["config"]["n_train"] == 3 and r["config"]["latent_size"] == 8
    parts = ("host_gather", "transfer", "device")
    for k in (*parts, "total"):
        assert math.isfinite(r["per_step_ms"][k]) and r["per_step_ms"][k] > 0, k
        assert r["per_dispatch_ms"][k] == pytest.approx(K * r["per_step_ms"][k])
    assert r["per_step_ms"]["total"] == pytest.approx(sum(r["per_step_ms"][k] for k in parts))
    assert 0 < r["host_share"] < 1 and r["xla_counts_loop_body_once"]
    assert r["flops_per_step"] > 0 and r["xla"]["train_chunk"]["bytes_accessed"] > 0
    for k in ("device", "wall"):
        assert r["gflops"][k] > 0 and r["fraction_of_matmul"][k] == pytest.approx(r["gflops"][k] / r["matmul_gflops"])
    assert r["machine"]["matmul_1024_gflops_jax"] > 0 and not r["contact_overflow"]
    prof = r["profile"]["train_step"]
    assert prof["thread_ms"] > 0 and prof["groups"]["GEMM (YNNPACK fusions)"]["ms"] > 0
    assert sum(g["share"] for g in prof["groups"].values()) == pytest.approx(1.0)
    assert sum(g["ms"] for g in prof["groups"].values()) == pytest.approx(prof["thread_ms"])
    kinds = [k for g in prof["groups"].values() for k in g["kinds"]]
    assert sorted(kinds) == sorted(prof["kinds_ms"])   # every op kind in exactly one group
    assert "XLA op profile" in out.with_suffix(".md").read_text()
    return r


@pytest.mark.slow  # 20-32 s here: two compilations of the training step; the op-grouping test stays fast
def test_train_step_tiny(tmp_path, tiny_trajs):
    """`python -m benchmarks.train_step`: the training loop's own dispatch (one compilation: --no_split) on a
    tiny dataset; the per-step times, XLA's FLOPs, the matmul fraction and the grouped op profile."""
    r = _train_step_run(tmp_path, tiny_trajs, "--no_split")
    assert r["config"]["processor"] == "per_frame" and r["config"]["frames_per_sample"] == 1
    assert set(r["split_ms"]) == {"train_step_in_chunk"} and set(r["profile"]) == {"train_step"}


@pytest.mark.slow  # ~50 s on this CPU beside other jobs: four compilations
def test_train_step_split_realtime(tmp_path, tiny_trajs):
    """The realtime formulation (per-design processor, 8 frames per sample) with the split: forward, backward and
    update add up to the one-step dispatch, and XLA's FLOPs grow from the loss to value_and_grad to the step."""
    r = _train_step_run(tmp_path, tiny_trajs, "--formulation", "realtime")
    assert r["config"]["processor"] == "per_design" and r["config"]["frames_per_sample"] == 8
    sp, x = r["split_ms"], r["xla"]
    assert sp["forward"] > 0 and sp["value_and_grad"] > 0 and sp["train_step_1_per_dispatch"] > 0
    assert sp["forward"] + sp["backward"] + sp["update_and_dispatch"] == pytest.approx(sp["train_step_1_per_dispatch"])
    assert 0 < x["loss"]["flops"] < x["value_and_grad"]["flops"] <= x["train_chunk_1"]["flops"]
    assert x["train_chunk_1"]["flops"] == pytest.approx(r["flops_per_step"], rel=1e-3)
    for name in ("loss", "value_and_grad"):
        assert sum(g["share"] for g in r["profile"][name]["groups"].values()) == pytest.approx(1.0)
