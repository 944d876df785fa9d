"""Validate the solver against Hertz impact theory.

python -m experiments.hertz_check --radius_mm 5 --velocity 0.62631 --target glass --json hertz.json
"""
from __future__ import annotations

import json
import sys
from dataclasses import dataclass
from typing import ClassVar, Literal

from pcmgn_jax import cli
from pcmgn_jax.atomic import atomic_write_json
from pcmgn_jax.sim.fem import DEFAULT_ELEMENT, Q4_ELEMENTS
from pcmgn_jax.sim.hertz import ELEMS_PER_RADIUS, TARGET_MATERIALS, hertz_check


@dataclass(frozen=True)
class HertzArgs:
    # cli.check_bounds: {flag: (lowest value, inclusive[, highest])}
    BOUNDS: ClassVar[dict] = {"radius_mm": (0, False), "velocity": (0, False), "elems_per_radius": (1, True),
                              "penalty_factor": (0, False)}
    radius_mm: float = 5.0                          # ball radius [mm]
    velocity: float = 0.62631                       # impact speed [m/s]
    target: Literal[tuple(TARGET_MATERIALS)] = "glass"       # block material
    elems_per_radius: float = ELEMS_PER_RADIUS      # elements across the Hertz contact radius
    penalty_factor: float = 2.0                     # contact penalty k_p = factor x E'/h (solver.SolverSettings)
    element: Literal[Q4_ELEMENTS] = DEFAULT_ELEMENT  # the Q4 formulation (pcmgn_jax.sim.fem)
    json: str | None = None                         # write the result here (JSON)


def main(argv=None) -> int:
    args = cli.parse(HertzArgs, argv, description=__doc__, prog="python -m experiments.hertz_check")
    result = hertz_check(radius=args.radius_mm * 1e-3, velocity=args.velocity, target=args.target,
                         elems_per_radius=args.elems_per_radius, penalty_factor=args.penalty_factor,
                         element=args.element)
    if args.json:
        atomic_write_json(args.json, result)
    print(json.dumps(result, indent=2))
    rel = result["relative_error"]
    ok = (abs(rel["contact_time_s"]) < 0.05 and abs(rel["peak_force_N"]) < 0.05 and
          abs(rel["max_indentation_m"]) < 0.05 and abs(rel["impulse_Ns"]) < 0.02 and
          result["energy_error"] < 0.01)
    print("Hertz targets met" if ok else "Hertz targets NOT met")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(cli.run(main))
