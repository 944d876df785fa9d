"""The stress output's target (``Formulation.stress_target``, :mod:`pcmgn_jax.mgn.formulation`) and its inverse.

- ``linear``: the von Mises stress vm [Pa] itself (the paper's).
- ``log``: s = log1p(vm / VM_REF) with VM_REF = 1 MPa: the 1 MPa OLED and the 100 MPa cover glass map to O(1) values
  (s ~ 0.7 and ~4.6) and a low-stress frame's error is relative rather than lost under the peak's scale; s ~ vm /
  VM_REF below VM_REF, so vm = 0 is an ordinary target with a finite gradient.

:func:`stress_to_target` builds the target (:func:`pcmgn_jax.mgn.formulation.training_sample`, so the normaliser's
statistics see it too); :func:`target_to_stress` turns a (denormalised) prediction back into Pa wherever one is read
as a stress (the rollout's :func:`pcmgn_jax.mgn.rollout.integrate_output`, the ``lambda_obj`` loss term). Both take
NumPy or JAX arrays. Kept apart from formulation.py only because that module is at the 400-line limit.
"""
from __future__ import annotations

from typing import Literal, get_args

import jax.numpy as jnp
import numpy as np

StressTarget = Literal["linear", "log"]    # Formulation.stress_target's values (--help lists them)
VM_REF = 1e6                               # [Pa] the log target's reference stress: s = log1p(vm / VM_REF)
# the largest s a prediction is decoded from (vm = VM_REF expm1(s) <= 1e12 Pa, 1000x any stress of the stack)
LOG_STRESS_MAX = float(np.log1p(1e6))


def _xp(a):
    return np if isinstance(a, (np.ndarray, np.generic)) else jnp


def _check(kind: str) -> None:
    if kind not in get_args(StressTarget):
        raise ValueError(f"stress_target must be one of {get_args(StressTarget)}, got {kind!r}")


def stress_to_target(kind: str, vm):
    """The stress output's physical target of the von Mises stress ``vm`` [Pa] (>= 0): vm (``linear``, returned
    as it is) or log1p(vm / VM_REF) (``log``)."""
    _check(kind)
    return vm if kind == "linear" else _xp(vm).log1p(vm / VM_REF)


def target_to_stress(kind: str, s):
    """Inverse of :func:`stress_to_target` for a prediction ``s``: the von Mises stress [Pa], >= 0.

    von Mises is a norm, but nothing in the network keeps its output >= 0 (a late-frame band of -6 MPa along the
    cover glass was seen): ``linear`` reads it as max(s, 0). ``log`` decodes VM_REF expm1(s) with s clipped to
    [0, LOG_STRESS_MAX] first: s < 0 would be a negative stress, and an untrained or diverging network's s of ~90
    would overflow expm1 and its gradient exp(s) to inf in float32 (and inf times a zero loss weight is a NaN
    gradient); the clip keeps the value and the gradient finite."""
    _check(kind)
    xp = _xp(s)
    if kind == "linear":
        return xp.maximum(s, 0.0)
    return VM_REF * xp.expm1(xp.clip(s, 0.0, LOG_STRESS_MAX))
