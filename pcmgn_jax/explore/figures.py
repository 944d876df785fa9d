"""The explorer's figures as Plotly figure dicts (``{"data": [...], "layout": {...}}``; no plotly import).

Coordinates on the page are mm (x = radius, y = height, plate bottom at y = 0), stresses MPa, times µs.
The von Mises field is drawn cell by cell (a cell's colour: the mean of its nodes' values) in
:data:`N_COLOURS` steps of one colour scale; ``log`` spreads the steps over decades, so the OLED's ~1 MPa
and the cover glass's ~700 MPa are both readable in one picture; the OLED strip has its own linear scale.
"""
from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np

N_COLOURS = 24       # colour steps of a field figure
LOG_DECADES = 5      # a log scale spans this many decades below the field's maximum
CMAP = "viridis"
WIDEN_PLOT = 0.3     # the parameter-row chart shows this much beyond each end of the training box


def _colours(n: int) -> list[str]:
    import matplotlib
    cmap = matplotlib.colormaps[CMAP]
    return [matplotlib.colors.to_hex(cmap(i / max(n - 1, 1))) for i in range(n)]


def _stepped(colours: Sequence[str]) -> list:
    """A Plotly colour scale of constant steps (two stops per colour), matching binned cells."""
    n = len(colours)
    return [s for i, c in enumerate(colours) for s in ([i / n, c], [(i + 1) / n, c])]


def _polygons(xy_mm: np.ndarray, cells: np.ndarray) -> tuple[list, list]:
    """x, y lists of closed cell outlines separated by None (one Plotly trace, ``fill='toself'``)."""
    ring = np.concatenate([xy_mm[cells], xy_mm[cells[:, :1]]], axis=1)           # (E, 5, 2)
    gap = np.full((len(cells), 1, 2), np.nan)
    flat = np.round(np.concatenate([ring, gap], axis=1).reshape(-1, 2), 5)
    return ([None if np.isnan(v) else float(v) for v in flat[:, 0]],
            [None if np.isnan(v) else float(v) for v in flat[:, 1]])


def _scale(values_mpa: np.ndarray, vmax_mpa: float, scale: str) -> tuple[np.ndarray, float, float, dict]:
    """(colour coordinate per value, cmin, cmax, colour-bar dict) for ``scale`` 'log' | 'linear'."""
    top = float(vmax_mpa) if np.isfinite(vmax_mpa) and vmax_mpa > 0 else 1.0   # a zero field: a 1 MPa scale
    if scale == "log":
        hi = np.ceil(np.log10(top) * 4) / 4
        lo = hi - LOG_DECADES
        c = np.log10(np.clip(np.nan_to_num(values_mpa, nan=0.0), 10.0 ** lo, None))
        ticks = np.arange(np.ceil(lo), np.floor(hi) + 1)
        bar = {"tickvals": ticks.tolist(), "ticktext": [f"{10.0 ** t:g}" for t in ticks],
               "title": {"text": "MPa (log)"}}
        return c, lo, hi, bar
    if scale != "linear":
        raise ValueError(f"colour scale must be 'log' or 'linear', got {scale!r}")
    return np.nan_to_num(values_mpa, nan=0.0), 0.0, top, {"title": {"text": "MPa"}}


def _cell_traces(xy_mm, cells, cell_values, cmin, cmax) -> list[dict]:
    colours = _colours(N_COLOURS)
    step = np.clip(((cell_values - cmin) / max(cmax - cmin, 1e-30) * N_COLOURS).astype(int), 0, N_COLOURS - 1)
    out = []
    for k in np.unique(step):
        sel = np.asarray(cells)[step == k]
        x, y = _polygons(xy_mm, sel)
        out.append({"type": "scatter", "mode": "lines", "x": x, "y": y, "fill": "toself", "fillcolor": colours[k],
                    "line": {"color": colours[k], "width": 0.5}, "hoverinfo": "skip", "showlegend": False})
    return out


def _hover(xy_mm, node_values, c, cmin, cmax, bar, labels) -> dict:
    """Invisible node markers carrying the hover text and the colour bar."""
    return {"type": "scatter", "mode": "markers", "x": np.round(xy_mm[:, 0], 5).tolist(),
            "y": np.round(xy_mm[:, 1], 5).tolist(), "showlegend": False,
            "text": [f"{lab}: {v:.4g} MPa" for lab, v in zip(labels, node_values)], "hoverinfo": "text+x+y",
            "marker": {"size": 4, "opacity": 0.0, "color": np.round(c, 4).tolist(), "cmin": cmin, "cmax": cmax,
                       "colorscale": _stepped(_colours(N_COLOURS)), "showscale": True, "colorbar": bar}}


def field_figure(points, cells, cell_part, vm_pa, part_names: Sequence[str], *, title: str, scale: str = "log",
                 vmax_pa: float | None = None) -> dict:
    """The von Mises field ``vm_pa`` (N,) [Pa] on the deformed mesh ``points`` (N, 2) [m] (cells (E, 4),
    cell_part (E,)); the colour range ends at ``vmax_pa`` (default the field's max) and spans
    :data:`LOG_DECADES` below it on the log scale. Axes in mm, one mm per mm."""
    xy = 1e3 * np.asarray(points, float)
    vm = 1e-6 * np.asarray(vm_pa, float)
    cells = np.asarray(cells)
    top = float(np.nanmax(vm)) if vmax_pa is None else 1e-6 * vmax_pa
    c_node, cmin, cmax, bar = _scale(vm, top, scale)
    c_cell, *_ = _scale(vm[cells].mean(axis=1), top, scale)
    node_part = np.zeros(len(xy), int)
    node_part[cells.ravel()] = np.repeat(np.asarray(cell_part), 4)
    labels = [part_names[k] if k < len(part_names) else str(k) for k in node_part]
    data = _cell_traces(xy, cells, c_cell, cmin, cmax) + [_hover(xy, vm, c_node, cmin, cmax, bar, labels)]
    return {"data": data, "layout": {
        "title": {"text": title, "font": {"size": 14}}, "uirevision": "field", "hovermode": "closest",
        "xaxis": {"title": {"text": "x [mm] (radius)"}, "zeroline": False, "constrain": "domain"},
        "yaxis": {"title": {"text": "y [mm] (height)"}, "scaleanchor": "x", "scaleratio": 1, "zeroline": False,
                  "constrain": "domain"},
        "margin": {"l": 60, "r": 20, "t": 50, "b": 50}, "plot_bgcolor": "white", "height": 520}}


def oled_figure(points, cells, cell_part, vm_pa, part: int, *, title: str, x_max: float,
                vmax_pa: float | None = None) -> dict:
    """The OLED layer's cells (``cell_part == part``) alone, on a linear scale from 0 to ``vmax_pa`` (default
    the field's max there), the height stretched; the objective's section ends at ``x_max`` [m] (dashed,
    where the mesh reaches beyond it)."""
    cells = np.asarray(cells)[np.asarray(cell_part) == part]
    xy = 1e3 * np.asarray(points, float)
    vm = 1e-6 * np.asarray(vm_pa, float)
    nodes = np.unique(cells)
    top = float(np.nanmax(vm[nodes])) if vmax_pa is None else 1e-6 * vmax_pa
    c_node, cmin, cmax, bar = _scale(vm, top, "linear")
    c_cell, *_ = _scale(vm[cells].mean(axis=1), top, "linear")
    data = _cell_traces(xy, cells, c_cell, cmin, cmax)
    data.append(_hover(xy[nodes], vm[nodes], c_node[nodes], cmin, cmax, bar, ["OLED"] * len(nodes)))
    return {"data": data, "layout": {
        "title": {"text": f"{title}: max {np.nanmax(vm[nodes]):.3g} MPa", "font": {"size": 14}},
        "uirevision": "oled", "hovermode": "closest",
        "xaxis": {"title": {"text": "x [mm] (radius)"}, "zeroline": False},
        "yaxis": {"title": {"text": "y [mm]"}, "zeroline": False},
        "shapes": [{"type": "line", "x0": 1e3 * x_max, "x1": 1e3 * x_max, "yref": "paper", "y0": 0, "y1": 1,
                    "line": {"dash": "dash", "color": "grey"}}] if 1e3 * x_max < xy[nodes, 0].max() else [],
        "margin": {"l": 60, "r": 20, "t": 50, "b": 50}, "plot_bgcolor": "white", "height": 260}}


def history_figure(times_us, objective_curves: Mapping[str, np.ndarray], ball_um: Mapping[str, np.ndarray],
                   force_n: np.ndarray | None, frame: int, *, objective: Mapping[str, float] = ()) -> dict:
    """Top: the OLED section reading per frame [MPa] of each field predictor (and the solver); its window
    mean is the objective (``objective``: {label: MPa}, in the legend). Bottom: the ball's mean vertical
    displacement [µm] and, after a solver check, the contact force [N] (right axis). A line at ``frame``."""
    t = np.asarray(times_us, float).tolist()
    colours = ["#1f77b4", "#ff7f0e", "#2ca02c", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22"]
    data = []
    for i, (name, y) in enumerate(objective_curves.items()):
        solver = name == "solver"
        style = {"color": "black", "dash": "dash", "width": 2} if solver else {"color": colours[i % len(colours)]}
        mean = dict(objective).get(name)
        label = name + (f" ({mean:.4g} MPa)" if mean is not None else "")
        data.append({"type": "scatter", "mode": "lines", "x": t, "y": np.round(y, 6).tolist(), "name": label,
                     "legendgroup": name, "line": style, "xaxis": "x", "yaxis": "y"})
        if name in ball_um:
            data.append({"type": "scatter", "mode": "lines", "x": t, "y": np.round(ball_um[name], 5).tolist(),
                         "name": name, "legendgroup": name, "showlegend": False, "line": style,
                         "xaxis": "x", "yaxis": "y2"})
    if force_n is not None:
        data.append({"type": "scatter", "mode": "lines", "x": t, "y": np.round(force_n, 4).tolist(),
                     "name": "contact force (solver)", "line": {"color": "crimson", "dash": "dot"},
                     "xaxis": "x", "yaxis": "y3"})
    at = t[frame] if 0 <= frame < len(t) else None
    return {"data": data, "layout": {
        "title": {"text": "over time: OLED section reading (window mean = objective) and the ball",
                  "font": {"size": 14}},
        "xaxis": {"title": {"text": "t [µs]"}, "anchor": "y2"},
        "yaxis": {"title": {"text": "OLED [MPa]"}, "domain": [0.55, 1.0]},
        "yaxis2": {"title": {"text": "ball u_y [µm]"}, "domain": [0.0, 0.45]},
        "yaxis3": {"title": {"text": "force [N]"}, "overlaying": "y2", "side": "right", "showgrid": False},
        "shapes": [] if at is None else [{"type": "line", "x0": at, "x1": at, "yref": "paper", "y0": 0, "y1": 1,
                                          "line": {"color": "grey", "width": 1}}],
        "legend": {"orientation": "h", "y": -0.2}, "uirevision": "history", "height": 480,
        "margin": {"l": 60, "r": 60, "t": 50, "b": 40}}}


def box_figure(params, x, samples, outside: Sequence[bool], *, band: tuple[float, float] | None = None) -> dict:
    """The training box, its samples (B, P) [SI] and the design x (P,) [SI] (red when ``outside`` it).
    Two parameters: the design plane (with the optimiser's sum ``band`` (low, high) [m] when given);
    more: one row per parameter, each scaled so that its training box is [0, 1]."""
    x, samples = np.asarray(x, float), np.asarray(samples, float)
    colour = "crimson" if any(outside) else "seagreen"
    if len(params) == 2:
        a, b = params
        ra, rb = [(p.slider_range()[0] * p.scale, p.slider_range()[1] * p.scale) for p in params]
        data = [{"type": "scatter", "mode": "markers", "x": (samples[:, 0] * a.scale).tolist(),
                 "y": (samples[:, 1] * b.scale).tolist(), "name": "training designs",
                 "marker": {"color": "grey", "size": 7}},
                {"type": "scatter", "mode": "markers", "x": [x[0] * a.scale], "y": [x[1] * b.scale],
                 "name": "this design", "marker": {"color": colour, "size": 14, "symbol": "star"}}]
        shapes = [{"type": "rect", "x0": a.low * a.scale, "x1": a.high * a.scale, "y0": b.low * b.scale,
                   "y1": b.high * b.scale, "line": {"color": "seagreen"}, "fillcolor": "rgba(46,139,87,0.08)"}]
        if band is not None and a.unit == b.unit:
            for s in band:
                s = s * a.scale
                data.append({"type": "scatter", "mode": "lines", "x": list(ra), "y": [s - ra[0], s - ra[1]],
                             "name": "optimiser's sum band", "showlegend": s == band[0] * a.scale,
                             "line": {"color": "grey", "dash": "dot"}, "hoverinfo": "skip"})
        layout = {"xaxis": {"title": {"text": a.heading}, "range": list(ra)},
                  "yaxis": {"title": {"text": b.heading}, "range": list(rb)}, "shapes": shapes}
    else:
        def z(v, p):
            return (((np.asarray(v) - p.low) / (p.high - p.low)).tolist() if p.varied
                    else (np.asarray(v) * 0 + 0.5).tolist())
        rows = [p.label for p in params]
        data = [{"type": "scatter", "mode": "markers", "name": "training scenes", "hoverinfo": "skip",
                 "x": [v for i, p in enumerate(params) for v in z(samples[:, i], p)],
                 "y": [p.label for p in params for _ in samples], "marker": {"color": "grey", "size": 6}},
                {"type": "scatter", "mode": "markers+text", "name": "this scene",
                 "x": [z(x[i], p) for i, p in enumerate(params)], "y": rows,
                 "text": [f"{x[i] * p.scale:.4g} {p.unit}" for i, p in enumerate(params)], "textposition": "top center",
                 "marker": {"color": ["crimson" if o else "seagreen" for o in outside], "size": 13, "symbol": "star"}}]
        layout = {"xaxis": {"title": {"text": "position in the training box (0 = its low end, 1 = its high end)"},
                            "range": [-WIDEN_PLOT, 1 + WIDEN_PLOT]},
                  "yaxis": {"type": "category", "automargin": True},
                  "shapes": [{"type": "rect", "x0": 0, "x1": 1, "yref": "paper", "y0": 0, "y1": 1,
                              "line": {"color": "seagreen"}, "fillcolor": "rgba(46,139,87,0.08)"}]}
    layout.update(title={"text": "training box" + (": this design is OUTSIDE it" if any(outside) else ""),
                         "font": {"size": 14, "color": colour}}, height=330, uirevision="box",
                  margin={"l": 60, "r": 20, "t": 50, "b": 50}, legend={"orientation": "h", "y": -0.3})
    return {"data": data, "layout": layout}


def message_figure(text: str) -> dict:
    """An empty figure saying ``text``."""
    return {"data": [], "layout": {"annotations": [{"text": text, "showarrow": False, "xref": "paper",
                                                    "yref": "paper", "x": 0.5, "y": 0.5}],
                                   "xaxis": {"visible": False}, "yaxis": {"visible": False}, "height": 200}}
