"""The explorer's page: the headline, the objective table, what the figures can show, and the view.

:class:`Page` is the part of :class:`pcmgn_jax.explore.session.Explorer` that turns its predictions into
what the page shows (text, table rows, Plotly figure dicts through :mod:`pcmgn_jax.explore.figures`);
it reads the explorer's state and computes nothing of its own but the figures.
"""
from __future__ import annotations

import numpy as np

from pcmgn_jax import metrics
from pcmgn_jax.explore import figures
from pcmgn_jax.explore.types import LABELS, PREDICTORS, Prediction, View, design_key
from pcmgn_jax.opt.problem import DesignBox


class Page:
    """The page's methods of an Explorer (module docstring)."""

    def _text(self, kind: str, p: Prediction | None) -> str:
        if kind in self.skipped:
            return f"n/a: {self.skipped[kind]}"
        if p is None:
            return "computing ..."
        if p.objective_mpa is None:
            return f"n/a: {p.note}"
        std = f" ± {p.std_mpa:.2g}" if p.std_mpa is not None else ""
        return f"{p.objective_mpa:.4g}{std} MPa"

    def rows(self, x) -> list[dict]:
        """The objective table: per predictor its label, value text, [MPa] and std, time [ms], test-split
        error [%] (RUN/eval/metrics.json) and, after a solver check, its error against the truth [%]."""
        preds = self._pred.get(design_key(self.values(x)), {})
        truth = self.truth(x)
        out = []
        for kind in [k for k in PREDICTORS if k in self.models or k in self.skipped]:
            p = preds.get(kind)
            test = self.test_errors.get(kind)
            err = None
            if truth is not None and p is not None and p.objective_mpa is not None:
                err = float(metrics.relative_error_pct(p.objective_mpa, truth.objective_mpa))
            out.append({"name": kind, "label": LABELS[kind] + (" (default)" if kind == self.default else ""),
                        "text": self._text(kind, p), "mpa": None if p is None else p.objective_mpa,
                        "std": None if p is None else p.std_mpa, "ms": None if p is None else 1e3 * p.seconds,
                        "note": "" if p is None else p.note, "error_pct": err,
                        "test": "" if test is None else f"{test[0]:.3g} % ({test[1]:.3g})"})
        if truth is not None:
            out.append({"name": "truth", "label": "the solver (truth)", "text": f"{truth.objective_mpa:.4g} MPa",
                        "mpa": truth.objective_mpa, "std": None, "ms": 1e3 * truth.seconds,
                        "note": f"{self.preset} preset", "error_pct": 0.0, "test": ""})
        return out

    def headline(self, x) -> str:
        """'OLED objective (<reading>) by <predictor>: value ± std MPa', for the default predictor."""
        p = self._pred.get(design_key(self.values(x)), {}).get(self.default)
        what = f"OLED objective ({self.reading.replace('_', ' ')}) by {LABELS[self.default]}"
        if p is None:
            fast = self._pred.get(design_key(self.values(x)), {}).get("kriging")
            meanwhile = f"; kriging meanwhile: {self._text('kriging', fast)}" if fast is not None else ""
            return f"{what}: computing ...{meanwhile}"
        std = f" ± {p.std_mpa:.2g} ({p.note.removeprefix('± ')})" if p.std_mpa is not None else ""
        if p.objective_mpa is None:
            return f"{what}: n/a ({p.note})"
        return f"{what}: {p.objective_mpa:.4g}{std} MPa"

    def choices(self, x) -> list[str]:
        """What the field figures can show at x: predictors with fields, then 'truth' and 'error:<p>' after a check."""
        preds = self._pred.get(design_key(self.values(x)), {})
        have = [k for k in self._field_kinds() if k in preds and preds[k].vm is not None]
        truth = self.truth(x)
        if truth is not None:
            have += ["truth"] + [f"error:{k}" for k in have if preds[k].vm.shape == truth.traj.von_mises.shape]
        return have

    def view(self, x, *, frame: int | None = None, show: str | None = None, scale: str = "log") -> View:
        """The page at x (P,) [SI]: the :attr:`live` predictors are computed if missing (the others by
        :meth:`predict_rest`), then the headline, the table, the flags and the figures of ``show``
        ('truth', 'error:<predictor>' or a predictor with fields; default: the default predictor, or
        the first with fields when it has none yet) at ``frame`` with colour ``scale`` ('log' | 'linear')."""
        x = self.values(x)
        preds = self.predict(x)
        choices = self.choices(x)
        frame = self.start_frame if frame is None else int(np.clip(frame, 0, self.ref.n_frames - 1))
        notes = list(self.notes)
        if show not in choices:
            if show is not None and show != self.default:
                notes.append(f"{show!r} has no fields at this design yet: showing {choices[0] if choices else 'none'}")
            show = choices[0] if choices else None
        q, truth = self.query(x), self.truth(x)
        figs = {"box": figures.box_figure(self.params, x, self.samples, self.out_of_box(x),
                                          band=None if self.family else _band(len(x)))}
        names = list(q.meta["part_names"])     # the design's layers (a stack's follow its sliders)
        if show is None:
            empty = figures.message_figure("no predictor with fields at this design")
            figs.update(field=empty, oled=empty, history=empty)
        else:
            if show == "truth" or show.startswith("error:"):
                mesh, u = truth.traj, truth.traj.displacement
                vm = truth.traj.von_mises
                label = f"the solver ({self.preset} preset)"
                if show.startswith("error:"):
                    kind = show.split(":", 1)[1]
                    vm = np.abs(preds[kind].vm - truth.traj.von_mises)
                    label = f"|{LABELS[kind]} − solver|"
            else:
                mesh, u, vm, label = q, preds[show].u, preds[show].vm, LABELS[show]
            t_us = 1e6 * float(self.ref.times[frame])
            pts = np.asarray(mesh.points) + u[frame]
            figs["field"] = figures.field_figure(pts, mesh.cells, mesh.cell_part, vm[frame], names,
                                                 title=f"von Mises: {label}, frame {frame} (t = {t_us:.0f} µs), "
                                                       f"deformed section at true scale", scale=scale,
                                                 vmax_pa=float(np.nanmax(vm)))
            part = self.oled(q)
            figs["oled"] = figures.oled_figure(pts, mesh.cells, mesh.cell_part, vm[frame], part,
                                               x_max=metrics.OBJECTIVE_X_MAX, vmax_pa=float(
                                                   np.nanmax(vm[:, np.asarray(mesh.node_part) == part])),
                                               title=f"OLED layer: {label}, frame {frame} (linear scale)")
            curves, ball = {}, {}
            for k in self._field_kinds():
                if k in preds and preds[k].vm is not None:
                    curves[LABELS[k]] = self.objective_history(q, preds[k].vm)
                    ball[LABELS[k]] = _ball_um(q, preds[k].u)
            if truth is not None:
                curves["solver"] = self.objective_history(truth.traj, truth.traj.von_mises)
                ball["solver"] = _ball_um(truth.traj, truth.traj.displacement)
            figs["history"] = figures.history_figure(
                1e6 * np.asarray(self.ref.times), curves, ball, None if truth is None else truth.force, frame,
                objective={LABELS[k]: p.objective_mpa for k, p in preds.items() if p.objective_mpa is not None})
        return View(self.headline(x), self.rows(x), self.flags(x), notes, show or "", figs)


def _band(dim: int):
    """The optimiser's sum band (low, high) [m] of a design of ``dim`` design layers (opt/problem.py)."""
    b = DesignBox(dim=dim)
    return b.sum_low, b.sum_high


def _ball_um(traj, u) -> np.ndarray:
    """(T,) the ball's mean vertical displacement [µm] (the ROI's ball nodes) of u (T, N, 2) [m]."""
    ball = np.asarray(traj.node_part) == 0
    return 1e6 * np.asarray(u)[:, ball, 1].mean(axis=1)
