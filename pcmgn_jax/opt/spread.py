"""The predicted ± spread of a surrogate optimum: no optimum is reported without one.

    s = optimum_spread("mgn", obj, x, train, part=part, reading="area_mean", members=("runs/b",))
    s["std_mpa"], s["source"]

Sources, by surrogate:

- ``kriging``                   its own posterior std at the optimum
- ``mgn`` with ``members``      the std (ddof 1) of the run's model and the members' objectives at the
                                optimum: an ensemble (``experiments.ensemble`` measures whether it ranks errors)
- ``mgn`` alone                 the std of a GP fitted to the model's objective residuals on the training
                                designs (the model's own predictions there cost one rollout per design)
- ``mop``, ``poly2``, ``rbf``, ``nearest``   the kriging std of the same training data: these have no
                                spread of their own, so the figure is a proxy and says so
- ``solver``                    0: its values are the solver's runs (pcmgn_jax/opt/truth.py), no prediction
"""
from __future__ import annotations

import warnings
from pathlib import Path
from typing import Sequence

import numpy as np

from pcmgn_jax.data.family import Design
from pcmgn_jax.opt.objectives import MGNObjective
from pcmgn_jax.surrogates.inputs import design_of
from pcmgn_jax.surrogates.kinds import TRUTH, CannotAnswer, names
from pcmgn_jax.surrogates.registry import fit, fit_objective
from pcmgn_jax.surrogates.surface_fit import ExtrapolationWarning, fit_gp, objective_table

SPREAD_OF = names(std=True)[0]   # the kind whose posterior std stands in for those without a spread (kriging)


def design_spread(model, designs: Sequence[Design], train: Sequence, *, reading: str,
                  part: int | None = None) -> tuple[np.ndarray, bool]:
    """((B,) std [MPa], own) at ``designs``: ``model``'s posterior std of the objective where it has one (``own``
    True), else the std of :data:`SPREAD_OF` fitted on the same training trajectories (a proxy, ``own`` False)."""
    try:
        return model.predict_objective_at(designs, reading=reading, return_std=True)[1], True
    except CannotAnswer:   # no spread of its own (or no surface): kriging's of the same data stands in
        proxy = fit_objective(SPREAD_OF, train, readings=(reading,), part=part)
        return proxy.predict_objective_at(designs, reading=reading, return_std=True)[1], False


def optimum_spread(surrogate: str, obj, x, train: Sequence, *, part: int, reading: str,
                   members: Sequence[str | Path] = ()) -> dict:
    """{'std_mpa', 'source', ...} at the optimum x (D,) [m] of objective ``obj`` (the module docstring)."""
    x = np.asarray(x, float).reshape(1, -1)
    if surrogate == TRUTH:
        return {"std_mpa": 0.0, "source": "none: the solver's own run at the optimum (no surrogate)"}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ExtrapolationWarning)
        if surrogate != "mgn":
            sd, own = design_spread(obj.surrogate, obj.designs(x), train, reading=reading, part=part)
            return {"std_mpa": float(sd[0]), "source": f"{surrogate} posterior std" if own else
                    f"proxy: the kriging std of the same training data ({surrogate} has no spread of its own)"}
        if members:
            vals = [float(obj(x)[0])]
            for m in members:
                other = MGNObjective(fit("mgn", workdir=Path(m), ref=train[0]), obj.map, part=part, reading=reading)
                vals.append(float(other(x)[0]))
            return {"std_mpa": float(np.std(vals, ddof=1)), "source": f"ensemble of {len(vals)} MGNs",
                    "members_mpa": vals, "members": [str(m) for m in members]}
        d = np.stack([design_of(t) for t in train])
        truth = objective_table(train, (reading,), part=part)[reading]
        resid = truth - np.asarray(obj(d), float)
        gp = fit_gp(d, {"r": resid}, names=[f"design[{i}]" for i in range(d.shape[1])])
        m, sd = gp.predict(x, return_std=True)
    return {"std_mpa": float(sd["r"][0]), "source": "GP of the model's residuals on the training designs",
            "residual_mean_mpa": float(m["r"][0]), "train_residual_rms_mpa": float(np.sqrt(np.mean(resid ** 2)))}
