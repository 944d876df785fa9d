"""Fields carried from one mesh to another of another scene, part by part (the ``nearest`` and ``rom`` rule).

    u, vm = transfer_fields(src_traj, dst_points, dst_node_part, dst_scene)   # (T, N_dst, 2) [m], (T, N_dst) [Pa]

A node's place is its part-relative coordinate (:func:`part_coordinates`): a layer node keeps x and gets its
height's fraction through its layer; a ball node its offset from the ball's lowest point over the radius.
"""
from __future__ import annotations

import numpy as np
from scipy.interpolate import LinearNDInterpolator, NearestNDInterpolator, interp1d
from scipy.spatial import QhullError


def _layer_bounds(scene: dict) -> tuple[np.ndarray, np.ndarray]:
    """(bottom, top) heights [m] of the part ids 1.. (layers from the top), plate bottom at y = 0."""
    t = np.array([layer["thickness"] for layer in scene["layers"]], np.float64)
    tops = t[::-1].cumsum()[::-1]
    return tops - t, tops


def part_coordinates(points, node_part, scene: dict) -> np.ndarray:
    """(N, 2) part-relative coordinates of reference ``points`` [m]: a layer node keeps x and gets its
    height's fraction through its layer's thickness (+ the part id, so layers never mix); a ball node
    gets its offset from the ball's lowest point divided by the radius. Two scenes' nodes with equal
    coordinates sit at the same place relative to their parts (the carry-over rule of :class:`NearestScene`)."""
    pts = np.asarray(points, np.float64)
    part = np.asarray(node_part)
    lo, hi = _layer_bounds(scene)
    out = np.empty_like(pts)
    ball = part == 0
    R = float(scene["ball"]["radius"])
    bottom = hi[0] + float(scene["ball"]["gap"])
    out[ball] = np.stack([pts[ball, 0] / R, (pts[ball, 1] - bottom) / R], axis=1)
    k = part[~ball] - 1
    out[~ball] = np.stack([pts[~ball, 0], part[~ball] + (pts[~ball, 1] - lo[k]) / (hi[k] - lo[k])], axis=1)
    return out


def transfer_fields(src, dst_points, dst_node_part, dst_scene: dict) -> tuple[np.ndarray, np.ndarray]:
    """Trajectory ``src``'s displacement (T, N, 2) [m] and von Mises (T, N) [Pa] carried over to another
    mesh of another scene: per part, linear interpolation over ``src``'s nodes in part-relative coordinates
    (:func:`part_coordinates`, scaled to the part's extent), nearest node outside their hull."""
    a = part_coordinates(src.points, src.node_part, src.meta["scene"])
    b = part_coordinates(dst_points, dst_node_part, dst_scene)
    values = np.concatenate([np.asarray(src.displacement, np.float64),
                             np.asarray(src.von_mises, np.float64)[..., None]], axis=-1)  # (T, N, 3)
    T = values.shape[0]
    out = np.zeros((T, len(b), 3))
    src_part, dst_part = np.asarray(src.node_part), np.asarray(dst_node_part)
    # x scaled by the source's span so that both part-relative coordinates are O(1) for the nearest-node rule
    scale = np.array([max(float(np.ptp(a[:, 0])), 1e-30), 1.0])
    for k in np.unique(dst_part):
        s_sel, d_sel = src_part == k, dst_part == k
        if not s_sel.any():
            # a part without nodes of its own in the source (a one-element layer whose nodes all sit on its
            # interfaces and so belong to the stiffer neighbour): the nearest source node over every part
            got = NearestNDInterpolator(a / scale, values.transpose(1, 0, 2).reshape(len(a), -1))(b[d_sel] / scale)
            out[:, d_sel] = got.reshape(d_sel.sum(), T, 3).transpose(1, 0, 2)
            continue
        lo, span = a[s_sel].min(0), np.maximum(np.ptp(a[s_sel], axis=0), 1e-30)
        xa, xb = (a[s_sel] - lo) / span, (b[d_sel] - lo) / span
        vals = values[:, s_sel].transpose(1, 0, 2).reshape(s_sel.sum(), -1)
        try:
            got = LinearNDInterpolator(xa, vals)(xb)
        except QhullError:  # the part's nodes lie on one line (e.g. one row): interpolate along it
            axis = int(np.argmax(np.ptp(xa, axis=0)))
            order = np.argsort(xa[:, axis], kind="stable")
            got = interp1d(xa[order, axis], vals[order], axis=0, bounds_error=False,
                           fill_value=np.nan, assume_sorted=True)(xb[:, axis]) if len(order) > 1 else \
                np.full((d_sel.sum(), vals.shape[1]), np.nan)
        miss = np.isnan(got).any(axis=1)
        if miss.any():
            got[miss] = NearestNDInterpolator(xa, vals)(xb[miss])
        out[:, d_sel] = got.reshape(d_sel.sum(), T, 3).transpose(1, 0, 2)
    return out[..., :2], out[..., 2]
