"""Impact phases of the default panel scene for a few OCA designs (issue 2's panel report).

python -m experiments.panel_report --preset cpu --frames 150 --out results/solver/panel_report
Writes OUT.json, OUT.md (table) and OUT.png (contact force and peak OLED stress vs time);
the report: pcmgn_jax/eval/panel_report.py.
"""
from __future__ import annotations

import sys
from dataclasses import dataclass
from typing import ClassVar

from pcmgn_jax import cli
from pcmgn_jax.presets import PresetName


@dataclass(frozen=True)
class PanelReportArgs:
    # cli.check_bounds: {flag: (lowest value, inclusive[, highest])}
    BOUNDS: ClassVar[dict] = {"frames": (2, True)}
    preset: PresetName = "cpu"                    # mesh preset (pcmgn_jax.presets.PRESETS)
    designs: str = "50,50;100,100;150,150"       # T_OCA1,T_OCA2 [µm]; designs separated by ';'
    frames: int = 150                            # frames of 4 µs to simulate
    out: str = "results/solver/panel_report"            # output path stem: OUT.json, OUT.md, OUT.png


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    args = cli.parse(PanelReportArgs, argv, description=__doc__, prog="python -m experiments.panel_report")
    import matplotlib
    matplotlib.use("Agg")  # files only; set here, in the entry point, not in the library
    from pcmgn_jax.eval.panel_report import panel_report
    lines = panel_report(args.preset, args.designs, args.frames, args.out,
                         command=cli.command_line("experiments.panel_report", argv))
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(cli.run(main))
