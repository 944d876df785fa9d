"""Every error metric of the project, one definition each (evaluation, validation, export, benchmarks).

Arrays are SI (m, Pa); reports are µm and MPa. A prediction is compared with the truth over frames
1..T-1 (frame 0 is the given initial state and is excluded everywhere).

- ``position_mae_um``   mean over trajectories, frames 1.., nodes and the two components of
                        |u_pred - u_true| [µm] (per component, not the Euclidean norm)
- ``position_rmse_um``  the root mean square of the same per-component errors [µm]
- ``stress_mae_mpa``, ``stress_rmse_mpa``   the same for the nodal von Mises stress [MPa]
- ``per_frame_*``       the per-frame MAE (mean over nodes and components), mean and std across
                        trajectories (frame 0 included as 0, for plotting against time)
- penetration           fit-free: depth of ball boundary nodes below the cover-glass top polyline
                        (:func:`penetration_stats`), pooled over all (trajectory, frame, node) triples
- ``oled_objective``    the design objective of docs/design.md §8, in four readings (:data:`OBJECTIVES`):
                        the paper's node average, the section's area-weighted mean (the optimiser's
                        default), the 3D disc mean, the peak
"""
from __future__ import annotations

import jax.numpy as jnp
import numpy as np


def _check(pred, true, name):
    pred, true = np.asarray(pred, np.float64), np.asarray(true, np.float64)
    if pred.shape != true.shape:
        raise ValueError(f"{name}: prediction shape {pred.shape} != truth shape {true.shape}")
    if pred.ndim < 2 or pred.shape[-2 if name == "displacement" else -1] == 0:
        raise ValueError(f"{name}: empty arrays {pred.shape}")
    return pred, true


def position_errors_um(pred_u, true_u) -> np.ndarray:
    """|u_pred - u_true| per component [µm] of frames 1.. : (B, T-1, N, 2) from (B, T, N, 2) [m]."""
    pred, true = _check(pred_u, true_u, "displacement")
    return np.abs(pred - true)[:, 1:] * 1e6


def stress_errors_mpa(pred_vm, true_vm) -> np.ndarray:
    """|s_pred - s_true| [MPa] of frames 1.. : (B, T-1, N) from (B, T, N) [Pa]."""
    pred, true = _check(pred_vm, true_vm, "von_mises")
    return np.abs(pred - true)[:, 1:] * 1e-6


def _per_trajectory(fn, pred, true) -> list[np.ndarray]:
    """``fn`` on each trajectory of (B, T, N, ...) arrays or of lists of (T, N_b, ...) arrays (meshes that
    differ between trajectories): one error array per trajectory."""
    if len(pred) != len(true):
        raise ValueError(f"{len(pred)} predicted trajectories for {len(true)} true ones")
    return [fn(np.asarray(p)[None], np.asarray(t)[None])[0] for p, t in zip(pred, true)]


def _pooled(errors: list[np.ndarray]) -> np.ndarray:
    return np.concatenate([e.ravel() for e in errors])


def position_mae_um(pred_u, true_u) -> float:
    """Pooled over every (trajectory, frame >= 1, node, component); stacked arrays or per-trajectory lists."""
    return float(_pooled(_per_trajectory(position_errors_um, pred_u, true_u)).mean())


def field_metrics(pred_u, pred_vm, true_u, true_vm) -> dict:
    """Position and stress MAE / RMSE and their per-frame curves (see the module docstring). Stacked
    (B, T, N, ...) arrays, or lists of per-trajectory arrays when the meshes differ (then every node of
    every trajectory counts once in the pooled means; the per-frame curves are per-trajectory means)."""
    pe_b = _per_trajectory(position_errors_um, pred_u, true_u)
    se_b = _per_trajectory(stress_errors_mpa, pred_vm, true_vm)
    pe, se = _pooled(pe_b), _pooled(se_b)
    pf_pos = np.stack([np.concatenate([[0.0], e.mean(axis=(1, 2))]) for e in pe_b])
    pf_s = np.stack([np.concatenate([[0.0], e.mean(axis=1)]) for e in se_b])
    return dict(position_mae_um=float(pe.mean()), position_rmse_um=float(np.sqrt(np.mean(pe ** 2))),
                stress_mae_mpa=float(se.mean()), stress_rmse_mpa=float(np.sqrt(np.mean(se ** 2))),
                per_frame_position_mae_um_mean=pf_pos.mean(0).tolist(),
                per_frame_position_mae_um_std=pf_pos.std(0).tolist(),
                per_frame_stress_mae_mpa_mean=pf_s.mean(0).tolist(),
                per_frame_stress_mae_mpa_std=pf_s.std(0).tolist())


def per_part_metrics(pred_u, pred_vm, true_u, true_vm, node_parts, part_names) -> dict:
    """Position and stress MAE of each part's nodes {name: {position_mae_um, stress_mae_mpa}} (the same
    per-component errors as :func:`field_metrics`, pooled over the part's nodes of every trajectory;
    ``node_parts``: each trajectory's (N,) part ids; a node on an interface counts for its own part)."""
    pe_b = _per_trajectory(position_errors_um, pred_u, true_u)
    se_b = _per_trajectory(stress_errors_mpa, pred_vm, true_vm)
    out = {}
    for k, name in enumerate(part_names):
        sel = [np.asarray(p) == k for p in node_parts]
        if not any(s.any() for s in sel):
            continue
        out[name] = dict(position_mae_um=float(_pooled([e[:, m] for e, m in zip(pe_b, sel)]).mean()),
                         stress_mae_mpa=float(_pooled([e[:, m] for e, m in zip(se_b, sel)]).mean()))
    return out


def penetration_summary(per_trajectory: list[dict], *, prefix: str = "penetration", suffix: str = "") -> dict:
    """Pool :func:`penetration_stats` results of several rollouts: the max depth, the mean depth over
    every penetrating (trajectory, frame, node) triple, and the number of frames with penetration."""
    total = sum(p["mean_um"] * p["n_penetrating"] for p in per_trajectory)
    count = sum(p["n_penetrating"] for p in per_trajectory)
    return {f"{prefix}_max_um{suffix}": float(max(p["max_um"] for p in per_trajectory)),
            f"{prefix}_mean_um{suffix}": float(total / count) if count else 0.0,
            f"{prefix}_frames{suffix}": int(sum(p["frames_with_penetration"] for p in per_trajectory))}


OBJECTIVES = ("area_mean", "node_mean", "disc_mean", "peak")
DEFAULT_OBJECTIVE = "area_mean"
OBJECTIVE_X_MAX = 3e-3   # [m] the paper's section: OLED at x < 3 mm


def objective_weights(points, cells, cell_part, node_part, *, part: int, reading: str = DEFAULT_OBJECTIVE,
                      x_max: float = OBJECTIVE_X_MAX) -> np.ndarray:
    """(N,) float64 nodal weights (summing to 1) of an objective reading over the section of ``part`` at
    reference x < ``x_max`` [m]; ``peak`` gets the selection mask (1 on the nodes it maximises over).

    - ``node_mean``  the paper's: every ``part`` node at x < x_max weighs the same (mesh-dependent on a
                     graded mesh: it weighs the contact zone by its node density)
    - ``area_mean``  the section's area-weighted mean: cells of ``part`` whose nodes all lie at
                     x <= x_max, integrated with the Q4 shape functions (2x2 Gauss, exact for
                     parallelograms): w_a = sum_cells int N_a dA / area
    - ``disc_mean``  the same over the 3D disc (axisymmetric ring, dA -> 2 pi r dA): weighs the far field
    - ``peak``       max over the section's nodes (and frames, see :func:`oled_objective`)
    Weights come from the reference coordinates (small strains). ValueError when the section is empty.
    """
    if reading not in OBJECTIVES:
        raise ValueError(f"objective reading must be one of {OBJECTIVES}, got {reading!r}")
    pts = np.asarray(points, np.float64)
    node_part = np.asarray(node_part)
    if reading in ("node_mean", "peak"):
        sel = (node_part == part) & (pts[:, 0] < x_max)
        if not sel.any():
            raise ValueError(f"objective {reading!r}: no node of part {part} at x < {x_max} m")
        return sel / sel.sum()
    cells = np.asarray(cells)
    keep = section_cells(pts, cells, cell_part, part=part, x_max=x_max)
    if not keep.any():
        raise ValueError(f"objective {reading!r}: no cell of part {part} lies wholly at x <= {x_max} m")
    out = section_weights(pts, cells[keep], disc=reading == "disc_mean")
    if not out.sum() > 0:
        raise ValueError(f"objective {reading!r}: the section has zero measure")
    return out


def section_cells(points, cells, cell_part, *, part: int, x_max: float = OBJECTIVE_X_MAX) -> np.ndarray:
    """(E,) bool: the cells of ``part`` whose nodes all lie at reference x <= ``x_max`` [m] (the area and
    disc readings' section); host NumPy."""
    pts = np.asarray(points, np.float64)
    return (np.asarray(cell_part) == part) & np.all(pts[np.asarray(cells), 0] <= x_max * (1 + 1e-9), axis=1)


def section_weights(points, section_cells, *, disc: bool = False):
    """(N,) nodal weights (summing to 1) of the area mean (``disc``: the 3D disc's, dA -> 2 pi r dA) over
    ``section_cells`` (E_s, 4) of a mesh with points (N, 2) [m]: w_a = sum_cells int N_a dA / area (2x2
    Gauss). NumPy in -> float64 NumPy out; jax points in -> jax out (differentiable in the points: the
    differentiable solver's section weights move with the design map)."""
    # the element integration weights (det J, x 2 pi r for the disc) are the solver's own (sim.fem)
    from pcmgn_jax.sim.fem import GAUSS_2x2, b_matrices

    xp = _xp(points)
    xy = points[section_cells]                             # (E_s, 4, 2)
    w = 0.0
    for xi, eta in GAUSS_2x2:                              # Gauss weights are 1 for the 2x2 rule
        _, dvol, shp = b_matrices(xy, xi, eta, axisymmetric=disc)
        w = w + dvol[:, None] * shp[None, :]
    if xp is np:
        out = np.zeros(len(points))
        np.add.at(out, section_cells.ravel(), w.ravel())
    else:
        out = xp.zeros(points.shape[0], w.dtype).at[section_cells.ravel()].add(w.ravel())
    return out / out.sum()


def oled_objective(von_mises, weights, *, reading: str = DEFAULT_OBJECTIVE):
    """docs/design.md §8's objective [MPa] from nodal von Mises (..., T, N) [Pa] and :func:`objective_weights`:
    the weighted section mean averaged over all T frames of the window, or for ``peak`` the max over
    frames and the section's nodes. (..., ) out. NumPy in -> float64 NumPy out; jax in -> jax out
    (differentiable: the design optimiser takes gradients through it)."""
    if reading not in OBJECTIVES:
        raise ValueError(f"objective reading must be one of {OBJECTIVES}, got {reading!r}")
    xp = _xp(von_mises)
    vm = xp.asarray(von_mises, np.float64) if xp is np else von_mises
    w = xp.asarray(weights, vm.dtype)
    if reading == "peak":
        return xp.max(xp.where(w > 0, vm, -xp.inf), axis=(-2, -1)) * 1e-6
    return xp.mean(xp.sum(vm * w, axis=-1), axis=-1) * 1e-6


def oled_objective_of(traj, von_mises=None, *, part: int | None = None, reading: str = DEFAULT_OBJECTIVE):
    """:func:`oled_objective` on a trajectory's mesh (its own von Mises unless ``von_mises`` (..., T, N) [Pa]
    is given); the OLED part is found by name in the trajectory's scene unless ``part`` is given."""
    if part is None:
        names = list(traj.meta.get("part_names") or [])
        if "OLED" not in names:
            raise ValueError(f"trajectory {traj.meta.get('name', '?')}: no part named 'OLED' in {names}")
        part = names.index("OLED")
    w = objective_weights(traj.points, traj.cells, traj.cell_part, traj.node_part, part=part, reading=reading)
    return oled_objective(traj.von_mises if von_mises is None else von_mises, w, reading=reading)


def relative_error_pct(pred, true) -> np.ndarray:
    """|pred - true| / |true| in % (guarded against a zero truth)."""
    pred, true = np.asarray(pred, np.float64), np.asarray(true, np.float64)
    return np.abs(pred - true) / np.maximum(np.abs(true), 1e-12) * 100.0


def _xp(*arrays):
    return np if all(isinstance(a, (np.ndarray, float, int, list, tuple)) for a in arrays) else jnp


def signed_distance_to_polyline(points_xy, polyline_xy):
    """Signed Euclidean distance [m] of points to a polyline (the CG top surface).

    points_xy:   (..., P, 2) points [m] (ball bottom nodes).
    polyline_xy: (..., S + 1, 2) polyline vertices [m] ordered by increasing x (the CG top nodes in
                 BoundaryNodes.panel order); leading axes broadcast with points_xy.
    Returns (..., P): distance to the nearest point of the polyline, positive above it (gap, the outward
    side of the panel = left of the direction of increasing x), negative below it (penetration), 0 on it.
    The sign is the side of the nearest segment (at a vertex both adjacent segments agree). Points beyond
    the polyline's ends are measured to the end vertex; exclude them (penetration_stats does).
    NumPy in -> NumPy out (float64 stays float64); jax arrays in -> jax array out (jittable).
    """
    xp = _xp(points_xy, polyline_xy)
    p = xp.asarray(points_xy)[..., :, None, :]  # (..., P, 1, 2)
    poly = xp.asarray(polyline_xy)
    a = poly[..., None, :-1, :]  # (..., 1, S, 2)
    ab = poly[..., None, 1:, :] - a
    l2 = xp.sum(ab * ab, axis=-1)
    l2s = xp.where(l2 > 0, l2, 1)
    ap = p - a
    u = xp.clip(xp.sum(ap * ab, axis=-1) / l2s, 0, 1)
    diff = ap - u[..., None] * ab  # p - closest point
    d2 = xp.sum(diff * diff, axis=-1)  # (..., P, S)
    k = xp.argmin(d2, axis=-1)[..., None]
    d2min = xp.take_along_axis(d2, k, axis=-1)[..., 0]
    abk = xp.take_along_axis(xp.broadcast_to(ab, diff.shape), k[..., None], axis=-2)[..., 0, :]
    dk = xp.take_along_axis(diff, k[..., None], axis=-2)[..., 0, :]
    cross = abk[..., 0] * dk[..., 1] - abk[..., 1] * dk[..., 0]
    dist = xp.sqrt(xp.where(d2min > 0, d2min, 0))
    return xp.where(cross < 0, -dist, dist)


def penetration_stats(ball_xy_frames, panel_xy_frames, *, ball_mask=None, threshold_um: float = 0.0):
    """Fit-free penetration statistics of a rollout (or ground truth), in micrometres.

    ball_xy_frames:  (T, Mb, 2) or (Mb, 2) world positions [m] of the ball bottom nodes.
    panel_xy_frames: (T, Mp, 2) or (Mp, 2) world positions [m] of the CG top nodes, ordered by x.
    ball_mask:       optional (Mb,) bool of nodes to include.
    threshold_um:    a node penetrates when its depth exceeds this [µm] (0: any depth > 0).

    Penetration of a node = max(0, -signed distance to the CG polyline), counted only for nodes whose x
    lies inside the polyline's x range of that frame. Computed in float64 NumPy.
    Returns dict:
      n_penetrating:           number of (frame, node) pairs that penetrate
      max_um:                  largest penetration over all frames and nodes [µm]
      mean_um:                 mean depth over all (frame, node) pairs that penetrate [µm] (0 if none)
      frames_with_penetration: number of frames whose max exceeds threshold_um (int)
      per_frame_max_um:        (T,) float64 per-frame max [µm]
      per_frame_mean_um:       (T,) float64 per-frame mean over penetrating nodes [µm] (0 if none)
    Note: penalty-contact ground truth penetrates slightly too; compare models against its numbers.
    """
    b = np.asarray(ball_xy_frames, dtype=np.float64)
    p = np.asarray(panel_xy_frames, dtype=np.float64)
    if b.ndim == 2:
        b = b[None]
    if p.ndim == 2:
        p = p[None]
    t = max(b.shape[0], p.shape[0])
    b = np.broadcast_to(b, (t,) + b.shape[1:])
    p = np.broadcast_to(p, (t,) + p.shape[1:])
    sd = signed_distance_to_polyline(b, p)  # (T, Mb)
    inside = (b[..., 0] >= p[..., 0].min(axis=-1, keepdims=True)) & \
             (b[..., 0] <= p[..., 0].max(axis=-1, keepdims=True))
    if ball_mask is not None:
        inside &= np.asarray(ball_mask, bool)[None]
    depth_um = np.where(inside, np.maximum(-sd, 0.0), 0.0) * 1e6
    pen = depth_um > threshold_um
    per_max = depth_um.max(axis=-1) if depth_um.shape[-1] else np.zeros(t)
    cnt = pen.sum(axis=-1)
    per_mean = np.where(cnt > 0, np.where(pen, depth_um, 0).sum(axis=-1) / np.maximum(cnt, 1), 0.0)
    n_pen = int(pen.sum())
    return {
        "n_penetrating": n_pen,
        "max_um": float(per_max.max()) if t else 0.0,
        "mean_um": float(depth_um[pen].sum() / n_pen) if n_pen else 0.0,
        "frames_with_penetration": int(np.sum(per_max > threshold_um)),
        "per_frame_max_um": per_max,
        "per_frame_mean_um": per_mean,
    }
