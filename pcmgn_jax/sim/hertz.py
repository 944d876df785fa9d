"""Hertz impact of an elastic sphere on an elastic half-space (Hunter 1957), and the solver check.

Theory (SI): 1/E* = (1 - nu1^2)/E1 + (1 - nu2^2)/E2; delta_max = (15 m v^2 / (16 E* sqrt(R)))^(2/5);
F_max = 4/3 E* sqrt(R) delta_max^(3/2); t_c = 2.9432 delta_max / v; a = sqrt(R delta_max).
"""
from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from pcmgn_jax.scene import Ball, Layer, Scene
from pcmgn_jax.sim import solver
from pcmgn_jax.sim.mesh import MeshSpec

TARGET_MATERIALS = {
    # name: (E [Pa], nu, density [kg/m^3])
    "glass": (77.0e9, 0.21, 2500.0),
    "aluminium": (68.9e9, 0.33, 2700.0),
}


def hertz_impact(*, radius: float, velocity: float, ball: Ball, youngs: float, poisson: float) -> dict[str, float]:
    """Hertz figures for a sphere (``ball`` material, ``radius`` [m]) hitting a half-space at
    ``velocity`` [m/s]: contact_time_s, peak_force_N, max_indentation_m, contact_radius_m,
    impulse_Ns (2 m v, perfectly elastic), mass_kg, e_star_Pa."""
    e_star = 1.0 / ((1 - ball.poisson**2) / ball.youngs + (1 - poisson**2) / youngs)
    mass = 4.0 / 3.0 * math.pi * radius**3 * ball.density
    delta = (15.0 * mass * velocity**2 / (16.0 * e_star * math.sqrt(radius))) ** 0.4
    return {"contact_time_s": 2.9432 * delta / velocity,
            "peak_force_N": 4.0 / 3.0 * e_star * math.sqrt(radius) * delta**1.5,
            "max_indentation_m": delta, "contact_radius_m": math.sqrt(radius * delta),
            "impulse_Ns": 2.0 * mass * velocity, "mass_kg": mass, "e_star_Pa": e_star}


def hertz_scene(*, radius: float, velocity: float, target: str, gap: float = 1e-6) -> Scene:
    """Axisymmetric steel ball on a block 5 R deep and 5 R wide, fixed at the bottom."""
    if target not in TARGET_MATERIALS:
        raise ValueError(f"hertz: target must be one of {sorted(TARGET_MATERIALS)}, got {target!r}")
    e, nu, rho = TARGET_MATERIALS[target]
    ball = dataclasses.replace(Ball(), radius=radius, velocity=velocity, gap=gap)
    return Scene(layers=(Layer("BLOCK", e, nu, 5.0 * radius, rho),), ball=ball,
                 analysis="axisymmetric", half_width=5.0 * radius, design_layers=(),
                 contact_pairs=(("ball", "BLOCK"),))


# Elements across the Hertz contact radius a: 12 gives the README's check (all targets met, ~30 s);
# the targets already hold at 10, which the tests use for speed.
ELEMS_PER_RADIUS = 12.0


def hertz_mesh_spec(theory: dict[str, float], *, elems_per_radius: float = ELEMS_PER_RADIUS) -> MeshSpec:
    """Mesh graded around the contact: ``elems_per_radius`` elements across the Hertz contact
    radius a, a fine zone of 2 a (radius) and a (depth)."""
    a = theory["contact_radius_m"]
    h = a / elems_per_radius
    return MeshSpec(h_contact=h, fine_radius=2.0 * a, fine_depth=a, growth=1.15, layer_elems={},
                    h_layer=h, roi_x=2.0 * a, roi_ball_height=a)


def hertz_check(*, radius: float = 5e-3, velocity: float = 0.62631, target: str = "glass",
                elems_per_radius: float = ELEMS_PER_RADIUS, penalty_factor: float = 2.0,
                frames: int = 60, element: str = solver.DEFAULT_SETTINGS.element) -> dict[str, Any]:
    """Simulate the Hertz impact with the built-in solver and compare with theory.

    Force histories are taken every solver substep. The solver's indentation is the approach
    of the ball's centre of mass minus the initial gap (the block bottom is fixed 5 R below).
    The impulse is checked against momentum balance m (v_in + v_out) with the ball's measured
    rebound speed (v_out from the mass-weighted ball velocity after separation)."""
    scene = hertz_scene(radius=radius, velocity=velocity, target=target)
    e, nu, _ = TARGET_MATERIALS[target]
    theory = hertz_impact(radius=radius, velocity=velocity, ball=scene.ball, youngs=e, poisson=nu)
    spec = hertz_mesh_spec(theory, elems_per_radius=elems_per_radius)
    window = scene.ball.gap / velocity + 1.4 * theory["contact_time_s"]
    scene = dataclasses.replace(scene, output_dt=window / frames, n_frames=frames)
    settings = solver.SolverSettings(penalty_factor=penalty_factor, element=element)
    res = solver.simulate([scene], spec, settings=settings)
    force = res.force[0].ravel()
    phases = solver.contact_phases(force, res.dt)
    prep = res.prepared
    is_ball = prep.mesh.node_part == 0
    m_ball = prep.mass[0][is_ball]
    v_out = float(np.sum(m_ball * res.v[0, -1, is_ball, 1]) / m_ball.sum())
    approach = -res.approach[0].ravel() - scene.ball.gap
    measured = {"contact_time_s": phases["separation_s"] - phases["contact_start_s"],
                "peak_force_N": float(force.max()),
                "max_indentation_m": float(approach.max()),
                "impulse_Ns": float(force.sum() * res.dt)}
    mass = theory["mass_kg"]
    reference = {"contact_time_s": theory["contact_time_s"], "peak_force_N": theory["peak_force_N"],
                 "max_indentation_m": theory["max_indentation_m"],
                 "impulse_Ns": mass * (velocity + v_out)}
    rel = {k: (measured[k] - reference[k]) / reference[k] for k in reference}
    return {"solver": measured, "hertz": reference, "relative_error": rel,
            "energy_error": float(res.energy_error[0]),
            "details": {"radius_m": radius, "velocity_m_s": velocity, "target": target,
                        "rebound_velocity_m_s": v_out, "restitution": v_out / velocity,
                        "hertz_elastic_impulse_Ns": theory["impulse_Ns"],
                        "fe_ball_mass_kg": float(m_ball.sum()), "theory_mass_kg": mass,
                        "contact_radius_m": theory["contact_radius_m"],
                        "h_contact_m": spec.h_contact, "penalty_factor": penalty_factor, "element": element,
                        "nodes": prep.mesh.n_nodes, "dt_s": res.dt,
                        "substeps": int(res.n_sub * frames), "wall_time_s": res.wall_time_s}}
