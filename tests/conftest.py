"""Shared tiny synthetic trajectories (no solver needed; others may reuse ``make_synthetic_trajectory``).

Geometry (SI): a 3 x 2-cell "ball" block (part 0) hovering 10 µm above a 6-cell-wide panel of two
layers -- "CG" (part 1, top row) and "PLATE" (part 2, two rows) -- whose bottom row is fixed
(node_type 3). Motion is analytic: the ball dips 15 µm and comes back (so it reaches the CG top), the
CG top is pushed down under the ball, the panel stress follows the dip. ``design`` scales the dip
amplitude and the CG thickness so trajectories differ.

Also the session fixture ``family_tiny`` (the one fixture here that runs the solver, for slow tests).
"""
from __future__ import annotations

import os

import numpy as np
import pytest

# the suite never writes the user's persistent compilation cache (pcmgn_jax/compile_cache.py); the
# cache's own tests point it at tmp_path in a subprocess
os.environ["PCMGN_JAX_CACHE"] = "0"

from pcmgn_jax.heap import keep_freed_memory  # noqa: E402

keep_freed_memory()  # before any JAX computation, as the entry points do (pcmgn_jax/heap.py)

from pcmgn_jax.scene import Layer, Scene
from pcmgn_jax.trajectory import Trajectory

DT = 4e-6


def _grid(x0, y0, nx, ny, dx, dys):
    xs = x0 + dx * np.arange(nx + 1)
    ys = y0 + np.concatenate([[0.0], np.cumsum(dys)])
    pts = np.array([(x, y) for y in ys for x in xs])
    cells = [[j * (nx + 1) + i, j * (nx + 1) + i + 1, (j + 1) * (nx + 1) + i + 1, (j + 1) * (nx + 1) + i]
             for j in range(ny) for i in range(nx)]
    return pts, np.array(cells)


def make_synthetic_trajectory(design: float = 1.0, n_frames: int = 12) -> Trajectory:
    dx = 50e-6
    t_cg = 100e-6 * design
    # panel: rows bottom->top: PLATE, PLATE, CG
    p_pts, p_cells = _grid(0.0, 0.0, 6, 3, dx, [200e-6, 200e-6, t_cg])
    p_cell_part = np.array([2] * 12 + [1] * 6)
    top = p_pts[:, 1].max()
    b_pts, b_cells = _grid(0.0, top + 10e-6, 3, 2, dx, [50e-6, 50e-6])
    points = np.concatenate([p_pts, b_pts])
    cells = np.concatenate([p_cells, b_cells + len(p_pts)])
    cell_part = np.concatenate([p_cell_part, np.zeros(len(b_cells), int)]).astype(np.int32)
    n_p = len(p_pts)
    node_part = np.full(len(points), 2, np.int32)
    node_part[n_p:] = 0
    node_part[:n_p][p_pts[:, 1] >= 400e-6 - 1e-12] = 1
    node_type = node_part.copy()
    node_type[:n_p][p_pts[:, 1] <= 1e-12] = 3

    times = DT * np.arange(n_frames)
    T = DT * (n_frames - 1)
    amp = 15e-6 * design
    ph = np.pi * times / T
    u = np.zeros((n_frames, len(points), 2))
    v = np.zeros_like(u)
    ball = node_part == 0
    u[:, ball, 1] = -amp * np.sin(ph)[:, None]
    v[:, ball, 1] = -amp * np.pi / T * np.cos(ph)[:, None]
    x = points[:, 0]
    shape = np.exp(-(x / 150e-6) ** 2) * (points[:, 1] / 400e-6).clip(0, 1.2)
    panel = ~ball
    dip = np.clip(np.sin(ph), 0, None) ** 2
    u[:, panel, 1] = -0.5 * amp * dip[:, None] * shape[panel]
    v[:, panel, 1] = -0.5 * amp * (2 * np.sin(ph) * np.cos(ph) * np.pi / T)[:, None] * shape[panel]
    u[:, panel, 0] = 0.1 * amp * dip[:, None] * (x[panel] / 300e-6) * shape[panel]
    v[:, panel, 0] = 0.1 * amp * (2 * np.sin(ph) * np.cos(ph) * np.pi / T)[:, None] * (x[panel] / 300e-6) * shape[panel]
    fixed = node_type == 3
    u[:, fixed] = 0.0
    v[:, fixed] = 0.0
    vm = 1e8 * design * dip[:, None] * np.exp(-x / 100e-6)[None] * np.where(ball, 0.3, 1.0)[None]

    scene = Scene(layers=(Layer("CG", 77e9, 0.21, t_cg, 2500.0), Layer("PLATE", 68.9e9, 0.33, 400e-6, 2700.0)),
                  half_width=300e-6, output_dt=DT, n_frames=n_frames - 1, design_layers=("CG",))
    traj = Trajectory(points=points, cells=cells, cell_part=cell_part, node_part=node_part,
                      node_type=node_type, times=times, displacement=u, velocity=v, von_mises=vm,
                      meta={"scene": scene.to_dict(), "output_dt": DT, "part_names": list(scene.part_names),
                            "design": {"CG": t_cg}, "source": "synthetic"})
    traj.validate()
    return traj


def drop_last_column(t: Trajectory) -> Trajectory:
    """The trajectory on a mesh without its outermost column of cells (fewer nodes, another topology)."""
    keep = t.points[:, 0] < t.points[:, 0].max() - 1e-12
    new = -np.ones(len(keep), int)
    new[keep] = np.arange(keep.sum())
    cells_kept = np.all(keep[t.cells], axis=1)
    return Trajectory(points=t.points[keep], cells=new[t.cells[cells_kept]], cell_part=t.cell_part[cells_kept],
                      node_part=t.node_part[keep], node_type=t.node_type[keep], times=t.times,
                      displacement=t.displacement[:, keep], velocity=t.velocity[:, keep],
                      von_mises=t.von_mises[:, keep], meta=dict(t.meta))


@pytest.fixture(scope="session")
def tiny_trajs():
    """Four synthetic trajectories of one topology (designs 0.8..1.2)."""
    return [make_synthetic_trajectory(d) for d in (0.8, 0.93, 1.07, 1.2)]


class CompileCounter:
    """Counts XLA compilations (jax.log_compiles records) of functions whose name contains ``name``."""

    def __init__(self, name: str):
        import logging
        self.name, self.count = name, 0
        outer = self

        class _H(logging.Handler):
            def emit(self, record):
                msg = record.getMessage()
                if msg.startswith("Finished XLA compilation of") and outer.name in msg:
                    outer.count += 1
        self._handler = _H()

    def __enter__(self):
        import logging

        import jax
        self._ctx = jax.log_compiles(True)
        self._ctx.__enter__()
        logging.getLogger("jax").addHandler(self._handler)
        return self

    def __exit__(self, *exc):
        import logging
        logging.getLogger("jax").removeHandler(self._handler)
        self._ctx.__exit__(*exc)


def one_union(setup, trajs, pairs, graph_ids=None):
    """The training union (train.sampling.union_batch) of the (trajectory, frame) ``pairs`` of ``trajs``
    (the setup's training trajectories), sized for exactly these graphs."""
    from pcmgn_jax.train.sampling import union_batch
    from pcmgn_jax.train.setup import union_sizes
    sizes = union_sizes(setup.graphs, per_union=len(pairs), capacity=setup.sizes.capacity)
    ids = np.arange(len(pairs)) if graph_ids is None else graph_ids
    return union_batch(setup.spec.sim.formulation, trajs, setup.graphs, [tuple(p) for p in pairs],
                       dt=setup.spec.sim.dt, sizes=sizes, graph_ids=ids)


def tiny_config(**kw):
    from pcmgn_jax.config import TrainConfig
    base = dict(num_steps=160, steps_per_dispatch=20, log_every=20, ckpt_every=40, val_every=80,
                contact_radius=20e-6, progress=False, latent_size=32, message_passing_steps=2)
    return TrainConfig.from_preset("tiny", **{**base, **kw})


@pytest.fixture(scope="session")
def tiny_run(tiny_trajs, tmp_path_factory):
    """A short tiny training run: (cfg, workdir, summary). Shared by the training and rollout tests."""
    from pcmgn_jax.train import loop as training
    cfg = tiny_config()
    workdir = tmp_path_factory.mktemp("tiny_run")
    summary = training.train(cfg, workdir, train_trajs=tiny_trajs[:3], val_trajs=tiny_trajs[3:])
    return cfg, workdir, summary


@pytest.fixture(scope="session")
def family_tiny(tmp_path_factory):
    """The family_tiny dataset through the built-in solver (one call per scene; 5 train + 2 test scenes,
    each on its own mesh), made once per session for the slow tests that share it (test_family.py,
    test_imported_dataset.py). Treat it as read-only: its users may only add its ``.cache``."""
    from experiments import generate
    out = tmp_path_factory.mktemp("family_tiny")
    assert generate.main(["--preset", "family_tiny", "--out", str(out), "--no_progress"]) == 0
    return out
