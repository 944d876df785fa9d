"""The explorer's Dash page over an :class:`~pcmgn_jax.explore.session.Explorer` (``pip install -e ".[explore]"``).

    app = build_app(explorer)          # a dash.Dash; serve(explorer, host="127.0.0.1", port=8050) runs it

Callbacks (each a thin call into the explorer; an error becomes a message on the page, never a trace):

- a slider move (on release) -> ``Explorer.ask``: the design store, its out-of-box flags; the fast
  predictors are computed there;
- the design store -> ``Explorer.predict_rest``: the predictors too slow to run at once (e.g. the MGN's
  rollout on the cpu preset), for the latest design only, then a tick of the "rest" store;
- "check with the solver" -> ``Explorer.check`` (ticks the truth store);
- the design or truth store, the frame slider, the field choice or the colour scale -> ``Explorer.view``:
  headline, table and figures (from the explorer's cache); the "rest" tick redraws them the same way (a
  second callback, so the first never waits for the slow predictors).
"""
from __future__ import annotations

import time
import traceback

import numpy as np

from pcmgn_jax.explore.session import Explorer
from pcmgn_jax.explore.types import LABELS

PAGE = {"fontFamily": "sans-serif", "margin": "12px 24px", "maxWidth": "1500px"}
NOTE = {"color": "#555", "fontSize": "13px", "margin": "2px 0"}
FLAG = {"color": "crimson", "fontWeight": "bold", "margin": "2px 0"}


def _step(lo: float, hi: float) -> float:
    return float(10.0 ** np.floor(np.log10((hi - lo) / 100)))


def _snap(v: float, step: float) -> float:
    """``v`` rounded to the decimals of ``step`` (no 24.900000000000002 on the page)."""
    return float(round(v, max(0, -int(np.floor(np.log10(step))))))


def _slider(i: int, p, value: float):
    from dash import dcc, html
    lo, hi = (v * p.scale for v in p.slider_range())
    step = _step(lo, hi)
    marks = {float(np.round(lo, 6)): f"{lo:.4g}", float(np.round(hi, 6)): f"{hi:.4g}",
             float(np.round(p.low * p.scale, 6)): {"label": f"box {p.low * p.scale:.4g}",
                                                   "style": {"color": "seagreen"}},
             float(np.round(p.high * p.scale, 6)): {"label": f"box {p.high * p.scale:.4g}",
                                                    "style": {"color": "seagreen"}}}
    return html.Div([
        html.Label(p.heading, htmlFor=f"p-{i}", style={"fontWeight": "bold"}),
        dcc.Slider(id=f"p-{i}", min=_snap(np.floor(lo / step) * step, step), max=_snap(np.ceil(hi / step) * step, step),
                   step=step, value=_snap(np.round(value * p.scale / step) * step, step), marks=marks,
                   updatemode="mouseup", tooltip={"placement": "bottom", "always_visible": False},
                   allow_direct_input=True)], style={"marginBottom": "14px"})


def _table(rows):
    from dash import html
    head = ["predictor", "OLED objective", "vs solver", "test-split error, mean (worst)", "time"]
    body = [html.Tr([html.Td(r["label"]), html.Td(r["text"], id=f"value-{r['name']}"),
                     html.Td("" if r["error_pct"] is None else f"{r['error_pct']:.3g} %"),
                     html.Td(r["test"]), html.Td("" if r["ms"] is None else f"{r['ms']:.0f} ms")])
            for r in rows]
    cell = {"borderBottom": "1px solid #ddd", "padding": "2px 8px", "textAlign": "left"}
    return html.Table([html.Thead(html.Tr([html.Th(h, style=cell) for h in head]))] + [html.Tbody(body)],
                      style={"borderCollapse": "collapse", "fontSize": "14px"})


def _options(explorer: Explorer, choices):
    def label(c):
        if c == "truth":
            return "the solver (truth)"
        if c.startswith("error:"):
            return f"error: {LABELS[c.split(':', 1)[1]]} − solver"
        return LABELS[c]
    return [{"label": label(c), "value": c} for c in choices]


def build_app(explorer: Explorer):
    """The Dash app of ``explorer`` (module docstring)."""
    import dash
    from dash import Input, Output, State, dcc, html
    from dash.exceptions import PreventUpdate

    ex = explorer
    T = ex.ref.n_frames
    times_us = 1e6 * np.asarray(ex.ref.times)
    every = max(1, T // 10)
    first = ex.view(ex.start)
    how = ("Sliders answer on release with every predictor at once" if not ex.deferred else
           f"Sliders answer on release with the fast predictors at once; {', '.join(LABELS[k] for k in ex.deferred)} "
           f"follow for the latest design (their rows say 'computing ...' until then)")
    app = dash.Dash(__name__, title="pcmgn explorer")
    app.layout = html.Div(style=PAGE, children=[
        html.H2(f"pcmgn explorer: {ex.run}"),
        html.P(f"{len(ex.train)} training trajectories, preset {ex.preset or 'imported data'}; objective: "
               f"docs/design.md §8, reading '{ex.reading}'. {how}. The training box is drawn green; a design "
               f"outside it is flagged red.", style=NOTE),
        html.Div(id="notes", children=[html.P(n, style=NOTE) for n in first.notes]),
        html.Div(style={"display": "flex", "gap": "32px", "flexWrap": "wrap"}, children=[
            html.Div(style={"flex": "1 1 420px", "minWidth": "380px"}, children=[
                *[_slider(i, p, v) for i, (p, v) in enumerate(zip(ex.params, ex.start))],
                html.Div(id="flags"),
                html.Button("check with the solver", id="check", n_clicks=0,
                            disabled=ex.preset is None, style={"margin": "6px 0", "fontSize": "15px"}),
                dcc.Loading(html.Div(id="solver-status", style=NOTE)),
                dcc.Graph(id="box", figure=first.figures["box"], config={"displaylogo": False}),
            ]),
            html.Div(style={"flex": "1 1 560px"}, children=[
                html.H3(first.headline, id="objective", style={"margin": "6px 0 10px"}),
                html.Div(_table(first.rows), id="table"),
                html.P("± : kriging's GP posterior std; the MGN's (explore --mgn_spread) the std of a GP of its "
                       "objective residuals on the training scenes. 'vs solver': after a solver check, each "
                       "predictor's relative error on the objective. Test-split errors: RUN/eval/metrics.json.",
                       style=NOTE),
            ]),
        ]),
        html.Div(style={"display": "flex", "gap": "24px", "alignItems": "center", "margin": "10px 0"}, children=[
            html.Div(style={"flex": "1 1 500px"}, children=[
                html.Label("frame", htmlFor="frame", style={"fontWeight": "bold"}),
                dcc.Slider(id="frame", min=0, max=T - 1, step=1, value=ex.start_frame,
                           marks={int(k): f"{times_us[k]:.0f} µs" for k in range(0, T, every)},
                           updatemode="mouseup")]),
            html.Div([html.Label("fields of", style={"fontWeight": "bold"}),
                      dcc.Dropdown(id="show", options=_options(ex, ex.choices(ex.start)), value=first.show,
                                   clearable=False, style={"width": "320px"})]),
            html.Div([html.Label("colour scale", style={"fontWeight": "bold"}),
                      dcc.RadioItems(id="scale", options=[{"label": " log (every layer readable)", "value": "log"},
                                                          {"label": " linear", "value": "linear"}],
                                     value="log", inline=True)]),
        ]),
        dcc.Graph(id="field", figure=first.figures["field"], config={"displaylogo": False}),
        dcc.Graph(id="oled", figure=first.figures["oled"], config={"displaylogo": False}),
        dcc.Graph(id="history", figure=first.figures["history"], config={"displaylogo": False}),
        dcc.Store(id="design", data=[float(v) for v in ex.start]),
        dcc.Store(id="rest-tick"), dcc.Store(id="truth-tick"),
    ])

    def design_of(values):
        if any(v is None for v in values):
            raise ValueError("every slider needs a number")
        return np.array([float(v) / p.scale for v, p in zip(values, ex.params)])

    def failed(err: Exception) -> str:
        traceback.print_exc()
        return f"error: {type(err).__name__}: {err}"

    @app.callback(Output("design", "data"), Output("flags", "children"),
                  *[Input(f"p-{i}", "value") for i in range(len(ex.params))])
    def on_design(*values):
        try:
            x = design_of(values)
            flags = ex.ask(x)
        except Exception as err:   # the page says what went wrong; the previous design stays
            return dash.no_update, [html.P(failed(err), style=FLAG)]
        return [float(v) for v in x], [html.P(f, style=FLAG if f.startswith("OUT") else NOTE) for f in flags]

    @app.callback(Output("rest-tick", "data"), Input("design", "data"))
    def on_rest(x):
        if not ex.deferred or x is None:
            raise PreventUpdate
        try:
            if not ex.predict_rest(np.asarray(x)):
                raise PreventUpdate
        except PreventUpdate:
            raise
        except Exception as err:
            failed(err)
            raise PreventUpdate from None
        return time.time()

    @app.callback(Output("truth-tick", "data"), Output("solver-status", "children"),
                  Input("check", "n_clicks"), State("design", "data"), prevent_initial_call=True)
    def on_check(n, x):
        try:
            truth = ex.check(np.asarray(x))
        except Exception as err:
            return dash.no_update, html.Span(failed(err), style=FLAG)
        x_text = ", ".join(f"{p.label} {v * p.scale:.4g} {p.unit}" for p, v in zip(ex.params, x))
        return time.time(), (f"solver at {x_text}: {truth.objective_mpa:.4g} MPa in {truth.seconds:.1f} s "
                             f"(choose 'the solver' or 'error: ...' under 'fields of' for the overlay)")

    outputs = ("objective.children", "table.children", "notes.children", "field.figure", "oled.figure",
               "history.figure", "box.figure", "show.options", "show.value")

    def page(x, frame, show, scale):
        try:
            x = np.asarray(x, float)
            v = ex.view(x, frame=frame, show=show, scale=scale)
        except Exception as err:
            return (failed(err),) + (dash.no_update,) * 8
        return (v.headline, _table(v.rows), [html.P(n, style=NOTE) for n in v.notes], v.figures["field"],
                v.figures["oled"], v.figures["history"], v.figures["box"], _options(ex, ex.choices(x)), v.show)

    # the page at once: not an input of the slow predictors' tick, so Dash does not hold it back for them
    @app.callback(*[Output(*o.split(".")) for o in outputs],
                  Input("design", "data"), Input("truth-tick", "data"), Input("frame", "value"),
                  Input("show", "value"), Input("scale", "value"))
    def render(x, _truth, frame, show, scale):
        return page(x, frame, show, scale)

    # and again when the slow predictors are done
    @app.callback(*[Output(*o.split("."), allow_duplicate=True) for o in outputs], Input("rest-tick", "data"),
                  State("design", "data"), State("frame", "value"), State("show", "value"), State("scale", "value"),
                  prevent_initial_call=True)
    def render_rest(_rest, x, frame, show, scale):
        return page(x, frame, show, scale)

    return app


def serve(explorer: Explorer, *, host: str = "127.0.0.1", port: int = 8050) -> None:
    """Serve the page at http://host:port/ until interrupted (Flask's threaded server, local use)."""
    app = build_app(explorer)
    print(f"explorer at http://{host}:{port}/ (Ctrl-C stops it)")
    app.run(host=host, port=port, debug=False)
