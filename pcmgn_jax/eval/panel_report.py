"""Impact phases of the default panel scene for a few OCA designs (the panel report), from the
built-in solver (:func:`pcmgn_jax.sim.solver.simulate`, :func:`pcmgn_jax.sim.solver.contact_phases`).

:func:`panel_report` writes OUT.json (per design: contact start, peak force and its time, separation,
peak OLED von Mises and its time, energy error), OUT.md (the table) and OUT.png (contact force and peak
OLED stress vs time). Times in µs, forces in N, stresses in MPa. The caller picks the matplotlib backend.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from pcmgn_jax import markdown
from pcmgn_jax.atomic import atomic_write_json
from pcmgn_jax.data.designs import parse_designs
from pcmgn_jax.scene import default_scene
from pcmgn_jax.sim import solver


def panel_report(preset: str = "cpu", designs: str = "50,50;100,100;150,150", frames: int = 150,
                 out: str | Path = "results/solver/panel_report", command: str = "") -> list[str]:
    """Simulate the default scene with each design of ``designs`` (``T_OCA1,T_OCA2`` in µm, designs
    separated by ``;``) on mesh ``preset`` for ``frames`` frames of the scene's output interval; write
    OUT.json (``command`` recorded), OUT.md and OUT.png; return the markdown table's lines."""
    base = default_scene()
    parsed = parse_designs(designs)
    scenes = [base.with_design(*d) for d in parsed]
    res = solver.simulate(scenes, preset, n_frames=frames)
    oled = np.flatnonzero(np.array(res.prepared.mesh.part_names) == "OLED")[0]
    is_oled = res.prepared.mesh.node_part == oled
    window = base.n_frames * base.output_dt
    rows = []
    for i, d in enumerate(parsed):
        ph = solver.contact_phases(res.force[i], res.dt)
        vm = res.von_mises[i][:, is_oled].max(axis=1)
        sep = ph["separation_s"]
        rows.append({"t_oca1_um": d[0] * 1e6, "t_oca2_um": d[1] * 1e6,
                     "contact_start_us": ph["contact_start_s"] * 1e6,
                     "peak_force_time_us": ph["peak_force_time_s"] * 1e6,
                     "peak_force_N": ph["peak_force_N"],
                     "separation_us": sep * 1e6 if math.isfinite(sep) else None,
                     "peak_oled_von_mises_mpa": float(vm.max() / 1e6),
                     "peak_oled_time_us": float(np.argmax(vm) * base.output_dt * 1e6),
                     "all_phases_in_default_window": bool(math.isfinite(sep) and sep < window),
                     "energy_error": float(res.energy_error[i])})
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    summary = {"preset": preset, "default_window_us": window * 1e6, "frames_simulated": frames,
               "dt_s": res.dt, "wall_time_s": res.wall_time_s, "designs": rows, "command": command}
    atomic_write_json(out.with_suffix(".json"), summary)
    lines = markdown.table(
        ("T_OCA1 / T_OCA2 [µm]", "contact start [µs]", "peak force [N] at [µs]", "separation [µs]",
         "peak OLED von Mises [MPa] at [µs]", "all 4 phases in 400 µs?"),
        ((f"{r['t_oca1_um']:.0f} / {r['t_oca2_um']:.0f}", f"{r['contact_start_us']:.1f}",
          f"{r['peak_force_N']:.1f} at {r['peak_force_time_us']:.0f}",
          f"{r['separation_us']:.0f}" if r["separation_us"] is not None else f"> {frames * 4}",
          f"{r['peak_oled_von_mises_mpa']:.2f} at {r['peak_oled_time_us']:.0f}",
          "yes" if r["all_phases_in_default_window"] else "no") for r in rows))
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    _plot(out.with_suffix(".png"), res, rows, is_oled, base, window, preset)
    return lines


def _plot(path, res, rows, is_oled, base, window, preset) -> None:
    """Contact force on the ball and peak OLED von Mises vs time, one curve per design, to ``path``."""
    import matplotlib.pyplot as plt
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4))
    t_sub = (np.arange(res.force[0].size) + 1) * res.dt * 1e6
    t_frame = np.arange(res.von_mises.shape[1]) * base.output_dt * 1e6
    for i, r in enumerate(rows):
        label = f"OCA {r['t_oca1_um']:.0f}/{r['t_oca2_um']:.0f} µm"
        a1.plot(t_sub, res.force[i].ravel(), label=label)
        a2.plot(t_frame, res.von_mises[i][:, is_oled].max(axis=1) / 1e6, label=label)
    for ax in (a1, a2):
        ax.axvline(window * 1e6, color="k", ls="--", lw=0.8)
        ax.set_xlabel("time [µs]")
        ax.legend()
    a1.set_ylabel("contact force on ball [N]")
    a2.set_ylabel("max OLED von Mises [MPa]")
    fig.suptitle(f"Default panel scene, preset {preset} (dashed: default 100 x 4 µs window)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
