"""The explorer (``python -m experiments.explore --workdir RUN``): a local web page over a trained run.

    ex = Explorer(run_dir)                  # loads the run, fits the baselines on its training split
    x = ex.start                            # (P,) scene parameters [SI] in ``ex.names`` order
    ex.predict(x)                           # {predictor: Prediction}, cached per design
    v = ex.view(x, frame=10, show="kriging")  # View: headline text, table rows, flags, Plotly figure dicts
    ex.check(x)                             # the built-in solver at x: Truth (fields, contact force)

:mod:`session` holds the run and the predictions (pure: numbers in, numbers out, no browser; each
predictor fitted and asked by :mod:`predictors`, the page's text and views by :mod:`page`, the vocabulary
in :mod:`types`),
:mod:`figures` turns them into Plotly figure dicts (plain dicts, no plotly import), :mod:`app` wires both
into a Dash page (needs the ``explore`` extra: ``pip install -e ".[explore]"``).
"""
from pcmgn_jax.explore.session import Explorer
from pcmgn_jax.explore.types import Parameter, Prediction, RunError, Truth, View

__all__ = ["Explorer", "Parameter", "Prediction", "RunError", "Truth", "View"]
