"""Validate the solver against Hertz impact theory.

python -m experiments.hertz_check --radius-mm 5 --velocity 0.62631 --target glass --json hertz.json
"""
from __future__ import annotations

import argparse
import json

from pcmgn_jax.sim.hertz import TARGETS, hertz_check
from pcmgn_jax.data.trajectory_io import atomic_write_json


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--radius-mm", "--radius_mm", type=float, default=5.0, help="ball radius [mm]")
    p.add_argument("--velocity", type=float, default=0.62631, help="impact speed [m/s]")
    p.add_argument("--target", choices=sorted(TARGETS), default="glass")
    p.add_argument("--elems-per-radius", "--elems_per_radius", type=float, default=12.0,
                   help="elements across the Hertz contact radius")
    p.add_argument("--penalty-factor", "--penalty_factor", type=float, default=2.0)
    p.add_argument("--json", default=None, help="write the result here")
    args = p.parse_args(argv)
    result = hertz_check(radius=args.radius_mm * 1e-3, velocity=args.velocity, target=args.target,
                         elems_per_radius=args.elems_per_radius, penalty_factor=args.penalty_factor)
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
    raise SystemExit(main())
