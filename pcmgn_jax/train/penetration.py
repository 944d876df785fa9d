"""Ball / cover-glass penetration loss: stable polynomial fits and the paper's loss term.

Paper section 2.3 (docs/design.md §6), made numerically safe:

1. (in :mod:`pcmgn_jax.geometry`) ``boundary_nodes`` (host, NumPy, once per reference mesh): ball bottom nodes and
   cover-glass (CG) top nodes, sorted by reference x, plus a fixed fit interval ``[x_lo, x_hi]``.
2. :func:`poly_fit_eval` (jittable, differentiable): least-squares polynomial of a static degree. x is mapped
   to t in [-1, 1] on the fixed interval, the basis is Legendre (orthogonal on [-1, 1]), y is centred and
   scaled, and the problem is solved by a Householder QR of the (ridge-augmented) design matrix. The
   paper's normal equations (V^T V)^-1 V^T y on raw metre coordinates are never formed: in float32,
   x^6 of a millimetre is 1e-18 and cond(V^T V) = cond(V)^2.
3. :func:`penetration_depth`, :func:`penetration_loss`: d = y_CG(x) - y_ball(x) at the ball boundary nodes
   inside the overlap of both x ranges; L_pen = mean of (d / length_scale)^2 over nodes with d > 0.
4. (in :mod:`pcmgn_jax.metrics`) ``signed_distance_to_polyline``, ``penetration_stats``: fit-free evaluation metric
   (true Euclidean distance of ball boundary nodes to the CG top polyline, negative = penetration).

Coordinates: x = radius >= 0 (axisymmetric half model, axis at x = 0) or width, y = height, both [m];
the ball sits above the panel. All public inputs and outputs are SI metres except where a name says
``_um`` (micrometres) and the loss (dimensionless, d measured in ``length_scale`` units).
"""
from __future__ import annotations

import jax
import jax.numpy as jnp
from jax.scipy.linalg import solve_triangular

__all__ = [
    "legendre_basis",
    "poly_fit",
    "poly_fit_eval",
    "penetration_depth",
    "penetration_loss",
]

DEFAULT_RIDGE = 1e-10
DEFAULT_REFINE = 3


# ---------------------------------------------------------------------------------------------------------
# 2. Least-squares polynomial fit (jittable, differentiable)
# ---------------------------------------------------------------------------------------------------------
def legendre_basis(t, degree: int):
    """Legendre polynomials P_0..P_degree at t: (...,) -> (..., degree + 1). |P_k(t)| <= 1 on [-1, 1]."""
    cols = [jnp.ones_like(t)]
    if degree >= 1:
        cols.append(t)
    for k in range(1, degree):
        cols.append(((2 * k + 1) * t * cols[k] - k * cols[k - 1]) / (k + 1))
    return jnp.stack(cols, axis=-1)


def _to_t(x, interval):
    lo, hi = interval
    c = 0.5 * (hi + lo)
    h = 0.5 * (hi - lo)
    return (x - c) / h


def poly_fit(x, y, degree: int, *, interval, weights=None, ridge: float = DEFAULT_RIDGE,
             refine: int = DEFAULT_REFINE):
    """Weighted least-squares Legendre fit on a fixed interval; returns (coef, offset, scale).

    The fitted polynomial is  p(x) = offset + scale * sum_k coef[k] * P_k(t(x)),
    t(x) = (2 x - x_lo - x_hi) / (x_hi - x_lo).  See :func:`poly_fit_eval` for the method and arguments.
    coef: (degree + 1,); offset, scale: scalars in the units of y.
    """
    degree = int(degree)
    x = jnp.asarray(x)
    y = jnp.asarray(y)
    if x.ndim != 1 or y.shape != x.shape:
        raise ValueError(f"poly_fit: x and y must be 1-D of equal length, got {x.shape} and {y.shape}")
    if degree < 0:
        raise ValueError(f"poly_fit: degree must be >= 0, got {degree}")
    n = degree + 1
    m = x.shape[0]
    if m < n:
        raise ValueError(f"poly_fit: {m} points cannot determine a degree-{degree} polynomial "
                         f"({n} coefficients); lower the degree or add boundary nodes")
    dtype = jnp.result_type(x.dtype, y.dtype, jnp.float32)
    x = x.astype(dtype)
    y = y.astype(dtype)
    if weights is None:
        w = jnp.ones((m,), dtype)
    else:
        w = jnp.asarray(weights).astype(dtype)
        if w.shape != (m,):
            raise ValueError(f"poly_fit: weights must have shape {(m,)}, got {w.shape}")
    w = jax.lax.stop_gradient(jnp.where(w > 0, w, 0))
    use = w > 0
    lo, hi = interval
    mid = 0.5 * (lo + hi)
    # double-where: padded / excluded entries may hold anything (even NaN) without poisoning values or grads
    xs = jnp.where(use, x, jnp.asarray(mid, dtype))
    ys = jnp.where(use, y, 0)
    wsum = jnp.sum(w)
    wsafe = jnp.where(wsum > 0, wsum, 1)
    offset = jnp.sum(w * ys) / wsafe
    dev = jnp.where(use, ys - offset, 0)
    scale = jax.lax.stop_gradient(jnp.max(jnp.abs(dev)))
    scale = jnp.where(scale > 0, scale, 1).astype(dtype)
    z = dev / scale
    sw = jnp.where(use, jnp.sqrt(jnp.where(use, w, 1)), 0)
    basis = legendre_basis(_to_t(xs, (lo, hi)), degree)  # (m, n)
    a = sw[:, None] * basis
    b = sw * z
    # Tikhonov ridge as extra rows: [A; sqrt(mu) I] c = [b; 0]. Keeps R non-singular (finite values and
    # gradients for all-equal x or too few weighted points) and stays an orthogonal-factorisation solve.
    mu = jnp.asarray(ridge, dtype) * wsafe
    a_aug = jnp.concatenate([a, jnp.sqrt(mu) * jnp.eye(n, dtype=dtype)], axis=0)
    q, r = jnp.linalg.qr(a_aug, mode="reduced")
    q_top, q_bot = q[:m], q[m:]
    qtb = q_top.T @ b  # = Q^T [b; 0]: the ridge rows' right-hand side is zero
    coef = solve_triangular(r, qtb, lower=False)
    # Iterated Tikhonov with the same factorisation: c <- argmin |A c - b|^2 + mu |c - c_prev|^2, i.e.
    # rhs [b; sqrt(mu) c_prev]. Each pass shrinks the ridge bias in a direction with singular value s by
    # mu / (s^2 + mu); directions with s = 0 stay at 0 (minimum-norm solution), so degenerate inputs
    # remain finite while well- and moderately-conditioned fits converge to the unregularised LS fit.
    sqrt_mu = jnp.sqrt(mu)
    for _ in range(int(refine)):
        coef = solve_triangular(r, qtb + sqrt_mu * (q_bot.T @ coef), lower=False)
    return coef, offset, scale


def poly_fit_eval(x, y, degree: int, x_eval, *, interval, weights=None, ridge: float = DEFAULT_RIDGE,
                  refine: int = DEFAULT_REFINE, split: bool = False):
    """Least-squares polynomial of degree ``degree`` through (x, y), evaluated at ``x_eval``.

    x, y:     (M,) sample abscissae and values (e.g. metres, float32 is fine).
    degree:   static int; M >= degree + 1 is required (ValueError at trace time otherwise).
    x_eval:   (K,) where to evaluate the fit.
    interval: (x_lo, x_hi) fixed mapping of x to t = (2 x - x_lo - x_hi) / (x_hi - x_lo) in [-1, 1]
              (use BoundaryNodes.interval: the same for every frame, so fits are comparable).
    weights:  optional (M,) non-negative weights; 0 excludes a point (padding, out-of-window nodes) with
              static shapes. Excluded entries may contain garbage (inf/NaN): they touch neither values
              nor gradients. Weights are not differentiated.
    ridge:    relative Tikhonov weight (mu = ridge * sum(weights)) on the Legendre coefficients of the
              centred, scaled data, followed by ``refine`` passes of iterated Tikhonov with the same QR.
              Directions of the weighted design matrix with singular value s >> sqrt(mu) (relative
              s / sqrt(sum w) >> 1e-5 by default) are fitted as by plain least squares; weaker ones
              (extreme clustering: e.g. 55 of 60 points in 1 % of the interval at degree 8) are damped,
              which can differ from numpy's float64 fit by ~1e-3 of the y range there. Rank-deficient
              cases (all points at one x, fewer weighted points than coefficients) give the
              minimum-norm-like fit (the weighted mean at the data's x) instead of NaN; their gradients
              are finite but large (the problem itself is ill-posed). Larger ridge = smaller gradients
              at degenerate inputs, more bias.
    split:    return (offset, deviation) with fit = offset + deviation instead of their sum. offset is the
              weighted mean of y (scalar), deviation (K,) the rest; use it to keep sub-ulp detail when y
              sits on a large offset (difference of two fits: subtract the offsets first, as
              :func:`penetration_depth` does). With all weights 0 the fit is 0.

    Method: y is centred (weighted mean) and scaled (max |y - mean|, gradient-stopped: the fit is linear
    in y, so the scale cancels exactly), x is mapped to [-1, 1], the Legendre design matrix (rows scaled by
    sqrt(w)) is augmented by sqrt(mu) I and solved with a Householder QR (jnp.linalg.qr) and a triangular
    solve. Never the normal equations. Differentiable in x, y and x_eval (finite gradients, incl.
    duplicated and all-equal x). Jittable and vmappable (degree, interval and ridge static/closed over).
    """
    coef, offset, scale = poly_fit(x, y, degree, interval=interval, weights=weights, ridge=ridge,
                                   refine=refine)
    x_eval = jnp.asarray(x_eval).astype(coef.dtype)
    dev = scale * (legendre_basis(_to_t(x_eval, interval), int(degree)) @ coef)
    if split:
        return offset, dev
    return offset + dev


# ---------------------------------------------------------------------------------------------------------
# 3. Penetration depth and loss
# ---------------------------------------------------------------------------------------------------------
def _masked_min_max(x, mask):
    big = jnp.asarray(jnp.finfo(x.dtype).max, x.dtype)
    return jnp.min(jnp.where(mask, x, big)), jnp.max(jnp.where(mask, x, -big))


def penetration_depth(ball_xy, panel_xy, *, degree_ball: int = 6, degree_panel: int = 5, interval,
                      ball_mask=None, panel_mask=None, ridge: float = DEFAULT_RIDGE,
                      refine: int = DEFAULT_REFINE):
    """Penetration depth d = y_CG(x) - y_ball(x) [m] at the ball boundary nodes (paper eq. step 3).

    ball_xy:   (Mb, 2) predicted world positions [m] of the ball bottom nodes (BoundaryNodes.ball).
    panel_xy:  (Mp, 2) predicted world positions [m] of the CG top nodes (BoundaryNodes.panel).
    degree_ball, degree_panel: static polynomial degrees (paper best: B.6 / P.5).
    interval:  fixed fit interval (BoundaryNodes.interval).
    ball_mask, panel_mask: optional (Mb,), (Mp,) bool; False excludes a node from fit and result.

    y_ball(x), y_CG(x) are least-squares fits (:func:`poly_fit_eval`) of each boundary, both evaluated at
    the ball nodes' predicted x. The offsets (mean heights) are subtracted before the deviations are added,
    so float32 keeps sub-nm resolution on mm heights. d > 0 means the ball surface is below the glass
    surface (penetration); d < 0 is a gap.

    Returns (d, valid): d (Mb,) [m], 0 where not valid; valid (Mb,) bool = node masked in and its x inside
    the overlap [max(min x_b, min x_p), min(max x_b, max x_p)] of the two boundaries' predicted x ranges.
    Use jax.vmap over a leading frame axis for several frames.

    Fit floor: on an exact contact state (gap 0) the two fits still differ by a few tenths of a µm
    inside the contact patch, so ground truth can show d > 0 and a real penetration below ~0.1 µm can be
    hidden by a negative fit error (docs/design.md §6). The fit-free metric
    (``pcmgn_jax.metrics.penetration_stats``) does not have this floor.
    """
    ball_xy = jnp.asarray(ball_xy)
    panel_xy = jnp.asarray(panel_xy)
    mb, mp = ball_xy.shape[0], panel_xy.shape[0]
    bm = jnp.ones((mb,), bool) if ball_mask is None else jnp.asarray(ball_mask, bool)
    pm = jnp.ones((mp,), bool) if panel_mask is None else jnp.asarray(panel_mask, bool)
    xb, yb = ball_xy[:, 0], ball_xy[:, 1]
    xp, yp = panel_xy[:, 0], panel_xy[:, 1]
    xb_eval = jnp.where(bm, xb, 0.5 * (interval[0] + interval[1]))
    off_b, dev_b = poly_fit_eval(xb, yb, degree_ball, xb_eval, interval=interval, weights=bm, ridge=ridge,
                                 refine=refine, split=True)
    off_p, dev_p = poly_fit_eval(xp, yp, degree_panel, xb_eval, interval=interval, weights=pm, ridge=ridge,
                                 refine=refine, split=True)
    d = (off_p - off_b) + (dev_p - dev_b)
    xs_b = jax.lax.stop_gradient(xb)
    xs_p = jax.lax.stop_gradient(xp)
    lo_b, hi_b = _masked_min_max(xs_b, bm)
    lo_p, hi_p = _masked_min_max(xs_p, pm)
    enough = (jnp.sum(bm) >= degree_ball + 1) & (jnp.sum(pm) >= degree_panel + 1)
    valid = bm & (xs_b >= jnp.maximum(lo_b, lo_p)) & (xs_b <= jnp.minimum(hi_b, hi_p)) & enough
    return jnp.where(valid, d, 0), valid


def penetration_loss(d, valid, *, length_scale: float = 1e-6, reduction: str = "positive"):
    """Paper's penetration loss L_pen = (1/|N_p|) sum_{i in N_p} (d_i / length_scale)^2, N_p = {valid, d_i > 0}.

    d:            (..., M) penetration depth [m] (from :func:`penetration_depth`); valid: (..., M) bool.
    length_scale: unit of d inside the loss, default 1e-6 m: d is measured in micrometres. Why: the data
                  loss is an MSE of normalised targets, O(1) (and O(1e-2..1e-1) once trained). In metres a
                  penetration would give L_pen ~ 1e-12 and lambda = 10 would do nothing; in µm a 1 µm
                  penetration gives L_pen = 1, so lambda * L_pen = 10 outweighs the data loss until the
                  penetration is well below a micrometre - the regime the paper's lambda = 10 describes
                  (the paper's ANSYS data are in µm units, x 1e-6 m). Log lambda * L_pen / L_data to check.
    reduction:    'positive' (paper): mean over the penetrating nodes of each frame (the last axis);
                  'valid': sum over penetrating nodes / number of valid nodes (continuous in d; an option).
    Returns the loss of shape d.shape[:-1] (a scalar for one frame); average over frames yourself.
    Exactly 0 with an exactly zero, finite gradient when no node penetrates (safe division, double where).
    """
    d = jnp.asarray(d)
    valid = jnp.asarray(valid, bool)
    ds = jnp.where(valid, d, 0) / length_scale  # double-where: invalid entries never reach the gradient
    pos = valid & (ds > 0)
    sq = jnp.where(pos, ds * ds, 0)
    if reduction == "positive":
        count = jnp.sum(pos, axis=-1)
    elif reduction == "valid":
        count = jnp.sum(valid, axis=-1)
    else:
        raise ValueError(f"penetration_loss: reduction must be 'positive' or 'valid', got {reduction!r}")
    total = jnp.sum(sq, axis=-1)
    has = count > 0
    return jnp.where(has, total / jnp.where(has, count, 1).astype(total.dtype), 0)


# ---------------------------------------------------------------------------------------------------------
# 4. Fit-free metric
# ---------------------------------------------------------------------------------------------------------
