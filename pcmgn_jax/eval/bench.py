"""Benchmark helpers of the library (``python -m benchmarks.NAME`` are their entry points): the machine's facts,
interleaved timing, a benchmark graph on a real cropped mesh, the MeshGraphNet's analytic FLOP count and an XLA
op profile. Nothing here parses flags or writes files; ``benchmarks/common.py`` holds the benchmarks' shared
flags and output."""
from __future__ import annotations

import os
import platform
import statistics
import time
from collections.abc import Callable, Mapping
from pathlib import Path

import numpy as np

__all__ = ["OP_KIND_GROUPS", "PRESET_ORDER", "bench_graph", "group_ops", "jraph_graph", "machine_info",
           "matmul_gflops_jax", "matmul_gflops_torch", "mgn_flops", "op_group", "profile_ops", "roi_mesh", "time_calls"]


# ---- machine ---------------------------------------------------------------------------------

def machine_info(torch_threads: int | None = None) -> dict:
    import jax
    import jaxlib
    cpu = "unknown"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        affinity = len(os.sched_getaffinity(0))
    except AttributeError:
        affinity = os.cpu_count()
    info = {"cpu": cpu, "cores_visible": os.cpu_count(), "cores_usable": affinity,
            "platform": platform.platform(), "python": platform.python_version(),
            "jax": jax.__version__, "jaxlib": jaxlib.__version__, "jax_backend": jax.default_backend(),
            "xla_flags": os.environ.get("XLA_FLAGS", ""),
            "load_avg_1min": os.getloadavg()[0] if hasattr(os, "getloadavg") else None}
    try:
        import torch
        info["torch"] = torch.__version__
        info["torch_threads"] = torch.get_num_threads() if torch_threads is None else torch_threads
    except ImportError:
        info["torch"] = None
    return info


def matmul_gflops_jax(n: int = 1024, repeats: int = 20) -> float:
    """Dense float32 (n x n) @ (n x n) rate of jnp.dot on this machine, GFLOP/s (median)."""
    import jax
    import jax.numpy as jnp
    a = jax.random.normal(jax.random.PRNGKey(0), (n, n), jnp.float32)
    b = jax.random.normal(jax.random.PRNGKey(1), (n, n), jnp.float32)
    f = jax.jit(jnp.dot)
    ms = time_calls({"mm": lambda: f(a, b)}, repeats=repeats, warmup=3, block=jax.block_until_ready)["mm"]
    return 2.0 * n ** 3 / (ms["median_ms"] * 1e-3) / 1e9


def matmul_gflops_torch(n: int = 1024, repeats: int = 20) -> float:
    import torch
    a, b = torch.randn(n, n), torch.randn(n, n)
    with torch.no_grad():
        ms = time_calls({"mm": lambda: torch.mm(a, b)}, repeats=repeats, warmup=3)["mm"]
    return 2.0 * n ** 3 / (ms["median_ms"] * 1e-3) / 1e9


# ---- timing ------------------------------------------------------------------------------------

def time_calls(fns: Mapping[str, Callable[[], object]], *, repeats: int = 10, warmup: int = 2,
               block: Callable | None = None, min_time_s: float = 0.0) -> dict[str, dict]:
    """Interleaved timing of several zero-argument callables (round-robin, so machine noise hits all
    of them alike). ``block`` waits for a result (e.g. ``jax.block_until_ready``). Returns per name
    median/min/max ms over ``repeats`` calls (more, up to 10x, while under ``min_time_s``)."""
    block = block or (lambda x: x)
    for _ in range(warmup):
        for f in fns.values():
            block(f())
    times = {k: [] for k in fns}
    t_start = time.perf_counter()
    r = 0
    while r < repeats or (time.perf_counter() - t_start < min_time_s and r < 10 * repeats):
        for k, f in fns.items():
            t0 = time.perf_counter()
            block(f())
            times[k].append((time.perf_counter() - t0) * 1e3)
        r += 1
    return {k: {"median_ms": statistics.median(v), "min_ms": min(v), "max_ms": max(v), "n": len(v)}
            for k, v in times.items()}


# ---- benchmark graph -----------------------------------------------------------------------------

PRESET_ORDER = ("tiny", "cpu", "paper")


def _crop(full, spec, roi_x: float):
    from pcmgn_jax.sim.mesh import crop_roi
    h = spec.roi_ball_height * min(max(roi_x / spec.roi_x, 0.25), 4.0)
    return crop_roi(full, roi_x=roi_x, roi_ball_height=h)


def roi_mesh(n_nodes: int, preset: str = "auto"):
    """A real cropped mesh (default scene) of about ``n_nodes`` nodes.

    ``preset='auto'``: the coarsest mesh preset whose own region of interest holds >= n_nodes nodes
    (else 'paper'); the ROI radius (and ball height) is then bisected to get closest to n_nodes.
    Returns (submesh, info dict).
    """
    from pcmgn_jax.scene import default_scene
    from pcmgn_jax.sim.mesh import build_mesh, mesh_spec, roi
    scene = default_scene()
    if preset == "auto":
        preset = "paper"
        for p in PRESET_ORDER:
            if roi(build_mesh(scene, p), p)[0].n_nodes >= n_nodes:
                preset = p
                break
    spec = mesh_spec(preset)
    full = build_mesh(scene, preset)
    lo, hi = 2 * spec.h_contact, float(full.points[:, 0].max())
    best = None
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        try:
            sub, _ = _crop(full, spec, mid)
        except ValueError:
            lo = mid
            continue
        if best is None or abs(sub.n_nodes - n_nodes) < abs(best[0].n_nodes - n_nodes):
            best = (sub, mid)
        if sub.n_nodes < n_nodes:
            lo = mid
        else:
            hi = mid
    sub, roi_x = best
    return sub, {"mesh_preset": preset, "roi_x_m": roi_x, "full_mesh_nodes": full.n_nodes, "scene": scene}


def bench_graph(n_nodes: int, preset: str = "auto", seed: int = 0) -> dict:
    """A normalised MeshGraphNet input graph on a real cropped quad mesh of ~n_nodes nodes, with the
    ball pressed 3 µm into the cover glass (so contact edges are active).

    Returns numpy arrays: nodes (N,F), mesh_{features,senders,receivers}, contact_{features,senders,
    receivers,mask}, target (N,3) (random), and ``info``.
    """
    import jax.numpy as jnp

    from pcmgn_jax.mgn import contact as contact_lib
    from pcmgn_jax.mgn.graphs import build_graph
    from pcmgn_jax.mgn.inputs import graph_inputs

    mesh, info = roi_mesh(n_nodes, preset)
    scene = info.pop("scene")
    ball = mesh.node_part == 0
    u = np.zeros_like(mesh.points)
    u[ball, 1] = -(scene.ball.gap + 3e-6)
    v = np.zeros_like(mesh.points)
    v[ball, 1] = -scene.ball.velocity
    # contact radius: contact_lib.auto_radius of the cover glass (the default of graph_inputs)
    topo, index, _ = graph_inputs(mesh, scene, positions=[mesh.points + u], capacity_factor=2.0)
    radius = index.radius
    edges = contact_lib.update(index, jnp.asarray(mesh.points + u, jnp.float32))
    g = build_graph(topo, points=mesh.points, displacement=u, velocity=v, contact=edges)

    def z(x, mask=None):
        x = np.asarray(x, np.float32)
        sel = x if mask is None else x[mask]
        if sel.shape[0] == 0:
            return x
        return ((x - sel.mean(0)) / np.maximum(sel.std(0), 1e-8)).astype(np.float32)

    k = topo.n_node_types
    nodes = np.asarray(g.nodes, np.float32).copy()
    nodes[:, k:] = z(nodes[:, k:])
    cmask = np.asarray(edges.mask)
    cfeat = np.where(cmask[:, None], z(g.edges["contact"].features, cmask), 0.0).astype(np.float32)
    rng = np.random.default_rng(seed)
    out = {"nodes": nodes,
           "mesh_features": z(g.edges["mesh"].features),
           "mesh_senders": np.asarray(topo.mesh_senders, np.int32),
           "mesh_receivers": np.asarray(topo.mesh_receivers, np.int32),
           "contact_features": cfeat,
           "contact_senders": np.asarray(edges.senders, np.int32),
           "contact_receivers": np.asarray(edges.receivers, np.int32),
           "contact_mask": cmask,
           "target": rng.standard_normal((mesh.n_nodes, 3)).astype(np.float32)}
    info.update(n_nodes=int(mesh.n_nodes), n_mesh_edges=int(topo.mesh_senders.shape[0]),
                n_contact_edges_active=int(cmask.sum()), contact_capacity=int(index.capacity),
                node_feature_dim=int(nodes.shape[1]), contact_radius_m=radius)
    out["info"] = info
    return out


def jraph_graph(g: dict):
    """The benchmark graph as the project's GraphsTuple (two typed edge sets)."""
    import jax.numpy as jnp
    import jraph

    from pcmgn_jax.mgn.graphs import EdgeSet
    mesh = EdgeSet(jnp.asarray(g["mesh_features"]), jnp.asarray(g["mesh_senders"]),
                   jnp.asarray(g["mesh_receivers"]), jnp.ones(g["mesh_senders"].shape, bool))
    cont = EdgeSet(jnp.asarray(g["contact_features"]), jnp.asarray(g["contact_senders"]),
                   jnp.asarray(g["contact_receivers"]), jnp.asarray(g["contact_mask"]))
    n = g["nodes"].shape[0]
    return jraph.GraphsTuple(nodes=jnp.asarray(g["nodes"]), edges={"mesh": mesh, "contact": cont},
                             senders=mesh.senders, receivers=mesh.receivers,
                             n_node=jnp.array([n], jnp.int32),
                             n_edge=jnp.array([mesh.senders.shape[0]], jnp.int32), globals=None)


def mgn_flops(n_nodes: int, n_edges: Mapping[str, int], in_dims: Mapping[str, int], *, latent: int,
              mlp_layers: int, steps: int, out: int = 3) -> dict:
    """Analytic multiply-add FLOPs (2 per MAC) of the MLP matmuls of one forward pass of
    EncodeProcessDecode with the concat trick (what pcmgn_jax.mgn.model computes). ``in_dims``: 'node',
    and one entry per edge set. Aggregation, LayerNorm and gathers are not counted."""
    L, H = latent, mlp_layers

    def mlp(rows, d_in, d_out):
        return 2 * rows * (d_in * L + (H - 1) * L * L + L * d_out)

    enc = mlp(n_nodes, in_dims["node"], L) + sum(mlp(e, in_dims[k], L) for k, e in n_edges.items())
    per_step = 0
    for e in n_edges.values():
        per_step += 2 * 2 * n_nodes * L * L        # sender / receiver projections (concat trick)
        per_step += mlp(e, L, L)                   # edge_proj + hidden + output layer on E rows
    per_step += mlp(n_nodes, L * (1 + len(n_edges)), L)
    dec = mlp(n_nodes, L, out)
    fwd = enc + steps * per_step + dec
    # concat-first-layer variant (E x 3L input) for reference
    per_step_cat = sum(mlp(e, 3 * L, L) for e in n_edges.values()) + mlp(n_nodes, L * (1 + len(n_edges)), L)
    return {"forward": fwd, "train_step_approx": 3 * fwd,
            "forward_concat_variant": enc + steps * per_step_cat + dec}


def profile_ops(fn, repeats: int = 3) -> dict:
    """Device time [ms per call] of ``fn()`` by XLA op kind (fusion names without their number), from a
    jax.profiler trace read back with ``jax.profiler.ProfileData``. Self time: an op that holds others (a
    ``while`` loop, e.g. a ``lax.scan``, holds its body's ops; a ``call``) counts only the time none of them ran."""
    import collections
    import glob
    import re
    import tempfile

    import jax
    from jax.profiler import ProfileData
    fn()
    d = tempfile.mkdtemp(prefix="rollout_profile_")
    jax.profiler.start_trace(d)
    for _ in range(repeats):
        fn()
    jax.profiler.stop_trace()
    tot = collections.Counter()
    for plane in ProfileData.from_file(glob.glob(d + "/**/*.xplane.pb", recursive=True)[0]).planes:
        for line in plane.lines:
            if "XLA" not in line.name:
                continue
            events = sorted(((ev.start_ns, ev.duration_ns, ev.name) for ev in line.events
                             if not ev.name.startswith(("Thunk", "Slinky", "end:", "ThreadpoolListener"))),
                            key=lambda e: (e[0], -e[1]))
            stack: list[tuple[str, float]] = []   # (kind, end) of the ops that hold the current one
            for start, dur, name in events:
                while stack and start >= stack[-1][1]:
                    stack.pop()
                kind = re.sub(r"[._]?\d+$", "", name)
                if stack:
                    tot[stack[-1][0]] -= dur      # the holder's self time
                tot[kind] += dur
                stack.append((kind, start + dur))
    return {k: v / repeats / 1e6 for k, v in tot.most_common()}


# the groups of XLA op kinds (profile_ops' names: a fusion is named by its first ops, e.g. bitcast_gather_fusion):
# the GEMMs XLA hands to YNNPACK (with their bias / activation epilogues) and those it emits itself (dot: e.g. the
# backward's transposed products), gathers and scatters (segment sums and their gradients), elementwise ops and
# reductions (activations, LayerNorm, loss, optimiser; forward and backward), layout ops, and the self time of ops
# that hold others (a lax.scan's while loop)
OP_KIND_GROUPS = ("GEMM (YNNPACK fusions)", "GEMM (XLA dot)", "gathers / scatters", "elementwise / reductions",
                  "copies / transposes / layout", "loop control (self time)")
_GEMM_OPS = {"dot", "convolution"}
_GATHER_OPS = {"gather", "scatter"}
_ELEMENTWISE_OPS = {
    "add", "subtract", "multiply", "divide", "maximum", "minimum", "select", "compare", "exponential",
    "exponential-minus-one", "log", "log-plus-one", "rsqrt", "sqrt", "cbrt", "tanh", "logistic", "negate", "abs",
    "sign", "power", "convert", "xor", "and", "or", "not", "shift-left", "shift-right-logical",
    "shift-right-arithmetic", "floor", "ceil", "round-nearest-even", "round-nearest-afz", "clamp", "remainder",
    "atan2", "sine", "cosine", "is-finite", "erf", "reduce", "reduce-window", "rng-bit-generator", "loop", "input"}
_LAYOUT_OPS = {"copy", "transpose", "bitcast", "broadcast", "concatenate", "slice", "dynamic-slice",
               "dynamic-update-slice", "pad", "reshape", "reverse", "iota", "constant", "tuple", "get-tuple-element"}
_CONTROL_OPS = {"while", "call", "conditional"}
_MULTIWORD_OPS = sorted((op for ops in (_ELEMENTWISE_OPS, _LAYOUT_OPS) for op in ops if "-" in op),
                        key=len, reverse=True)


def op_group(kind: str) -> str | None:
    """The :data:`OP_KIND_GROUPS` entry of an XLA op kind (:func:`profile_ops`' names), by the ops its name lists:
    YNNPACK, then dot, gather/scatter, any elementwise or reduction op, only layout ops, control; None for a name
    no rule knows."""
    for op in _MULTIWORD_OPS:     # an op name of several words written with underscores (dynamic_update_slice)
        kind = kind.replace(op.replace("-", "_"), op)
    ops = set(kind.removeprefix("wrapped_").removesuffix("fusion").strip("_").split("_"))
    rules = (("ynn" in ops, 0), (bool(ops & _GEMM_OPS), 1), (bool(ops & _GATHER_OPS), 2),
             (bool(ops & _ELEMENTWISE_OPS), 3), (ops <= _LAYOUT_OPS, 4), (bool(ops & _CONTROL_OPS), 5))
    return next((OP_KIND_GROUPS[i] for hit, i in rules if hit), None)


def group_ops(profile: Mapping[str, float]) -> dict[str, dict]:
    """:func:`profile_ops`' ms per op kind summed into :data:`OP_KIND_GROUPS` (every group, in order, then one
    ``kind NAME`` entry per kind :func:`op_group` does not know): {name: {"ms", "share" (of the total),
    "kinds" (the op kinds in it, largest first)}}."""
    out = {g: {"ms": 0.0, "kinds": []} for g in OP_KIND_GROUPS}
    for kind, ms in sorted(profile.items(), key=lambda kv: -kv[1]):
        row = out.setdefault(op_group(kind) or f"kind {kind}", {"ms": 0.0, "kinds": []})
        row["ms"] += ms
        row["kinds"].append(kind)
    total = sum(r["ms"] for r in out.values())
    for r in out.values():
        r["share"] = r["ms"] / total if total > 0 else 0.0
    return out
