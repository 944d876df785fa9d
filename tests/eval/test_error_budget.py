"""pcmgn_jax.eval.error_budget: the splits of the objective error add up, the node groups partition the section, the
teacher-forced mode separates the drift, and the tiny run's budget is written whole."""
from __future__ import annotations

import numpy as np
import pytest

from fixtures.helpers import make_synthetic_trajectory
from pcmgn_jax import metrics
from pcmgn_jax.eval.error_budget import (
    MODES,
    PHASES,
    budget,
    node_groups,
    part_errors,
    section_mean,
    shares,
    trajectory_budget,
)

CG = 1   # the synthetic panel: ball (0), CG (1, one row of cells), PLATE (2)


def _phases(T):
    return {"drop": (0, 2), "contact": (3, 6), "rebound_in_contact": (7, 9), "separated": (10, T - 1)}


def _noisy(traj, seed=0, bias=0.05):
    rng = np.random.default_rng(seed)
    vm = np.asarray(traj.von_mises) * (1 + bias + 0.1 * rng.standard_normal(traj.von_mises.shape))
    vm[0] = traj.von_mises[0]
    return np.asarray(traj.displacement), vm


def test_node_groups_partition_the_parts_cell_nodes():
    t = make_synthetic_trajectory()
    for part in (CG, 2):
        groups = node_groups(t, part)
        own = np.zeros(t.n_nodes, bool)
        own[t.cells[t.cell_part == part].ravel()] = True
        stacked = np.array(list(groups.values()))
        assert (stacked.sum(0) == own).all()   # disjoint, and together every node of the part's cells
    g = node_groups(t, CG)
    assert set(g) == {"interior", "interface PLATE"}            # the CG row's bottom nodes are the plate's top
    assert np.allclose(t.points[g["interface PLATE"], 1], 400e-6) and g["interior"].sum() == 7


def test_the_splits_add_up_to_the_signed_objective_error():
    t = make_synthetic_trajectory(n_frames=14)
    u, vm = _noisy(t)
    b = trajectory_budget(t, u, vm, part=CG, phases=_phases(14))
    w = metrics.objective_weights(t.points, t.cells, t.cell_part, t.node_part, part=CG)
    j_t, j_p = metrics.oled_objective(t.von_mises, w), metrics.oled_objective(vm, w)
    assert b["error_pct"] == pytest.approx((j_p - j_t) / j_t * 100, rel=1e-12)
    assert abs(b["error_pct"]) == pytest.approx(float(metrics.relative_error_pct(j_p, j_t)), rel=1e-12)
    assert np.mean(section_mean(vm, w)) == pytest.approx(j_p, rel=1e-12)     # the objective: the frames' mean
    assert sum(b["phases"].values()) == pytest.approx(b["error_pct"], rel=1e-9)
    assert sum(v["contribution_pct"] for v in b["nodes"].values()) == pytest.approx(b["error_pct"], rel=1e-9)
    assert b["pulse"]["peak_pct"] + b["pulse"]["width_pct"] == pytest.approx(b["error_pct"], rel=1e-9)
    assert sum(v["weight"] for v in b["nodes"].values()) == pytest.approx(1.0)


def test_shares_sum_to_the_mean_abs_error_and_parts_are_their_own_sections():
    e = np.array([3.0, -1.0, 2.0])
    parts = {"a": np.array([1.0, -2.0, 2.5]), "b": np.array([2.0, 1.0, -0.5])}
    assert sum(shares(e, parts).values()) == pytest.approx(np.abs(e).mean())
    t = make_synthetic_trajectory()
    pe = part_errors(t, np.asarray(t.von_mises) * 1.1)
    assert set(pe) == {"ball", "CG", "PLATE"}
    assert all(v["objective_error_pct"] == pytest.approx(10.0) for v in pe.values())   # 10 % on every section


def test_teacher_forcing_separates_the_drift():
    """A model whose one-step error is a fixed offset: teacher-forced it errs by that offset every frame, rolled out
    the offsets pile up; the drift is the difference, and the steps add up to the rollout's mean |error|."""
    trajs = [make_synthetic_trajectory(d, n_frames=14) for d in (0.9, 1.1)]
    T, ball = 14, trajs[0].node_part == 0
    preds = {m: ([], []) for m in ("rollout", "teacher_forced")}
    for t in trajs:
        for m, grow in (("rollout", np.arange(T)), ("teacher_forced", np.minimum(np.arange(T), 1))):
            u = np.array(t.displacement)
            u[:, ball, 1] += 0.1e-6 * grow[:, None]
            preds[m][0].append(u)
            preds[m][1].append(np.asarray(t.von_mises) * (1 + 0.01 * grow)[:, None])
    b = budget(trajs, preds, part_name="CG")
    tf, ro = b["modes"]["teacher_forced"], b["modes"]["rollout"]
    assert np.all(np.array(tf["per_frame_ball_error_um"]) <= np.array(ro["per_frame_ball_error_um"]) + 1e-9)
    assert tf["mean_abs_error_pct"] < ro["mean_abs_error_pct"]
    assert sum(b["steps"].values()) == pytest.approx(ro["mean_abs_error_pct"], rel=1e-9)
    for m in b["modes"].values():
        assert sum(m["phases"].values()) == pytest.approx(m["mean_abs_error_pct"], rel=1e-9)
        assert set(m["phases"]) == set(PHASES)


@pytest.mark.slow  # ~15 s: a tiny run's whole budget; the splits' arithmetic is tested above by default
def test_the_tiny_runs_budget(tiny_run, tiny_trajs, tmp_path):
    """On a trained tiny run: the teacher-forced frame 1 is the rollout's (both one step from the true frame 0), every
    mode of a quasi-static panel is there, and the page, figure and JSON are written."""
    import matplotlib
    matplotlib.use("Agg")
    from pcmgn_jax.eval.error_budget import predictions
    from pcmgn_jax.eval.error_budget_page import FILES, write
    _, workdir, _ = tiny_run
    test = tiny_trajs[2:]
    preds = predictions(workdir, test)
    assert set(preds) == set(MODES)
    for m in MODES:
        for t, vm in zip(test, preds[m][1]):
            assert vm.shape == t.von_mises.shape and np.array_equal(vm[0], t.von_mises[0])
    for a, b in zip(preds["teacher_forced"][1], preds["rollout"][1]):
        np.testing.assert_allclose(a[1], b[1], rtol=1e-5, atol=1e-3)   # [Pa]
    b = budget(test, preds, part_name="CG")
    assert sum(b["steps"].values()) == pytest.approx(b["modes"]["rollout"]["mean_abs_error_pct"], rel=1e-9)
    write(tmp_path, b, np.asarray(test[0].times) * 1e6, header="`test`")
    assert all((tmp_path / f).stat().st_size > 0 for f in FILES)
    assert "By node group" in (tmp_path / FILES[0]).read_text()
