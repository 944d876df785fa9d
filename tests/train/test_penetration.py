"""Tests for pcmgn_jax.train.penetration: float32 fit accuracy vs numpy float64, gradients, hard cases, metric."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from pcmgn_jax.geometry import boundary_nodes
from pcmgn_jax.metrics import penetration_stats, signed_distance_to_polyline
from pcmgn_jax.train.penetration import penetration_depth, penetration_loss, poly_fit_eval

INTERVAL = (-2e-5, 1.02e-3)  # [m] fixed fit interval around x in [0, 1 mm]
R = 5e-3


def _case(name, rng, m=60):
    if name == "uniform":
        x = np.linspace(0, 1e-3, m)
        y = 2e-3 + 1e-5 * np.sin(5e3 * x)
    elif name == "clustered":  # 50 of 60 points in the first 5 % of the interval
        x = np.concatenate([rng.uniform(0, 5e-5, m - 10), np.linspace(2e-4, 1e-3, 10)])
        y = 1e-3 + 1e-6 * np.cos(3e3 * x) + 1e-7 * rng.standard_normal(m)
    elif name == "graded":  # geometric mesh grading towards the axis, ball-like profile
        x = 1e-3 * (np.geomspace(1, 101, m) - 1) / 100
        y = 1e-3 + R - np.sqrt(R**2 - x**2)
    elif name == "duplicated":
        x = np.repeat(np.linspace(0, 1e-3, m // 3), 3)
        y = 2e-3 + 1e-5 * (x / 1e-3) ** 2 + 1e-7 * rng.standard_normal(m)
    elif name == "um_on_mm":  # µm-scale step on a 2 mm offset
        x = np.linspace(0, 1e-3, m)
        y = 2e-3 + 1e-6 * np.tanh((x - 3e-4) / 1e-4)
    elif name == "random":
        x = np.sort(rng.uniform(0, 1e-3, m))
        y = 1.5e-3 + 2e-5 * rng.standard_normal(m)
    elif name == "flat_zero":  # nearly flat: 1 nm range around 0
        x = np.linspace(0, 1e-3, m)
        y = 1e-9 * np.sin(4e3 * x)
    elif name == "edges":  # data exactly on the interval ends (t = -1, +1)
        x = np.linspace(INTERVAL[0], INTERVAL[1], m)
        y = 1e-3 + 3e-6 * np.cos(6e3 * x)
    return x.astype(np.float32), y.astype(np.float32)


def _ref(x, y, deg, xe):
    return np.polynomial.Polynomial.fit(x.astype(np.float64), y.astype(np.float64), deg)(xe.astype(np.float64))


_fit32 = jax.jit(poly_fit_eval, static_argnames=("degree", "interval", "split"))

CASES = ["uniform", "clustered", "graded", "duplicated", "um_on_mm", "random", "flat_zero", "edges"]


@pytest.mark.parametrize("degree", range(2, 9))
def test_fit_float32_matches_numpy_float64(degree):
    rng = np.random.default_rng(degree)
    worst = {}
    for name in CASES:
        x, y = _case(name, rng)
        xe = np.linspace(x.min(), x.max(), 37).astype(np.float32)
        ref = _ref(x, y, degree, xe)
        out = np.asarray(_fit32(x, y, degree=degree, x_eval=xe, interval=INTERVAL), np.float64)
        worst[name] = np.abs(out - ref).max() / np.ptp(y.astype(np.float64))
    assert max(worst.values()) < 1e-3, worst


@pytest.mark.parametrize("degree", [2, 5, 8])
def test_fit_nearly_flat_on_mm_offset_split(degree):
    """1 nm range on a 2 mm offset: below the float32 ulp of the offset (2.3e-10 m), so compare the split
    (offset, deviation) form, which keeps the detail, against numpy on the same float32 inputs."""
    x = np.linspace(0, 1e-3, 50).astype(np.float32)
    y = (np.float32(2e-3) + (1e-9 * np.sin(4e3 * x.astype(np.float64))).astype(np.float32)).astype(np.float32)
    ref = _ref(x, y, degree, x)
    off, dev = _fit32(x, y, degree=degree, x_eval=x, interval=INTERVAL, split=True)
    out = np.float64(off) + np.asarray(dev, np.float64)
    assert np.abs(out - ref).max() <= 1e-3 * np.ptp(y.astype(np.float64)) + 1e-18
    # the summed float32 output is within one float32 ulp of the offset
    summed = np.asarray(_fit32(x, y, degree=degree, x_eval=x, interval=INTERVAL), np.float64)
    assert np.abs(summed - ref).max() <= np.spacing(np.float32(2e-3))


def test_fit_matches_numpy_inside_jit_vmap():
    rng = np.random.default_rng(0)
    xs, ys = zip(*[_case("random", rng) for _ in range(4)])
    xs, ys = np.stack(xs), np.stack(ys)
    out = jax.vmap(lambda x, y: poly_fit_eval(x, y, 6, x, interval=INTERVAL))(xs, ys)
    for i in range(4):
        np.testing.assert_allclose(out[i], _ref(xs[i], ys[i], 6, xs[i]), atol=1e-3 * np.ptp(ys[i]))


@pytest.mark.parametrize("name", ["uniform", "graded", "duplicated", "clustered"])
def test_gradients_match_finite_differences_float64(name):
    rng = np.random.default_rng(7)
    x, y = _case(name, rng, m=30)
    with jax.enable_x64(True):
        x, y = jnp.asarray(x, jnp.float64), jnp.asarray(y, jnp.float64)
        xe = jnp.linspace(0.0, 1e-3, 11)
        w = jnp.asarray(rng.standard_normal(11))

        @jax.jit
        def f(x, y):
            return jnp.sum(w * poly_fit_eval(x, y, 5, xe, interval=INTERVAL))

        gx, gy = jax.jit(jax.grad(f, (0, 1)))(x, y)
        assert np.all(np.isfinite(gx)) and np.all(np.isfinite(gy))
        for i in rng.choice(30, 6, replace=False):
            h = 1e-8  # [m]; f ~ 3e-3, so float64 rounding in the FD is ~1e-10 relative to the gradient
            e = jnp.zeros(30).at[i].set(h)
            fdx = (f(x + e, y) - f(x - e, y)) / (2 * h)
            fdy = (f(x, y + e) - f(x, y - e)) / (2 * h)
            np.testing.assert_allclose(gx[i], fdx, rtol=1e-5, atol=1e-6 * np.abs(gx).max())
            np.testing.assert_allclose(gy[i], fdy, rtol=1e-5, atol=1e-6 * np.abs(gy).max())


DEGENERATE = {
    "all_equal_x": (np.full(20, 5e-4), np.linspace(1e-3, 1.001e-3, 20)),
    "all_equal_x_at_edge": (np.full(20, INTERVAL[0]), np.linspace(1e-3, 1.001e-3, 20)),
    "few_distinct_x": (np.repeat(np.linspace(0, 1e-3, 3), 7)[:20], np.linspace(0, 1e-6, 20)),
    "constant_y": (np.linspace(0, 1e-3, 20), np.full(20, 2e-3)),
    "all_zero": (np.zeros(20), np.zeros(20)),
}


@pytest.mark.parametrize("degree", [0, 6, 15])
@pytest.mark.parametrize("name", list(DEGENERATE))
def test_degenerate_inputs_finite_values_and_gradients(name, degree):
    x, y = (a.astype(np.float32) for a in DEGENERATE[name])
    xe = jnp.linspace(0, 1e-3, 9)

    def f(x, y):
        return jnp.sum(poly_fit_eval(x, y, degree, xe, interval=INTERVAL) ** 2)

    val, (gx, gy) = jax.jit(jax.value_and_grad(f, (0, 1)))(x, y)
    assert np.isfinite(val) and np.all(np.isfinite(gx)) and np.all(np.isfinite(gy))
    if name in ("constant_y", "all_zero"):
        assert float(val) == pytest.approx(9 * float(y[0]) ** 2, rel=1e-6, abs=1e-30)
    if name == "all_equal_x":  # regularised fit at the data's x: the mean, not an extrapolated polynomial
        fit = _fit32(x, y, degree=degree, x_eval=x[:1], interval=INTERVAL)
        np.testing.assert_allclose(fit, y.mean(), rtol=1e-5)


def test_too_few_points_raises_at_trace_time():
    x = jnp.linspace(0, 1e-3, 5)
    with pytest.raises(ValueError, match="cannot determine"):
        poly_fit_eval(x, x, 5, x, interval=INTERVAL)
    with pytest.raises(ValueError, match="cannot determine"):
        jax.jit(lambda a: poly_fit_eval(a, a, 6, a, interval=INTERVAL))(x)
    poly_fit_eval(x, x, 4, x, interval=INTERVAL)  # exactly enough


def test_weights_exclude_padding_even_nan():
    rng = np.random.default_rng(1)
    x, y = _case("random", rng, m=40)
    xp = np.concatenate([x, [np.nan, np.inf, 1.0]]).astype(np.float32)
    yp = np.concatenate([y, [np.nan, -np.inf, 5.0]]).astype(np.float32)
    w = np.concatenate([np.ones(40), np.zeros(3)]).astype(np.float32)
    xe = np.linspace(0, 1e-3, 7).astype(np.float32)
    full = poly_fit_eval(x, y, 6, xe, interval=INTERVAL)
    pad = poly_fit_eval(xp, yp, 6, xe, interval=INTERVAL, weights=w)
    np.testing.assert_allclose(pad, full, atol=1e-6 * np.ptp(y))
    gx, gy = jax.jit(jax.grad(lambda a, b: jnp.sum(poly_fit_eval(a, b, 6, xe, interval=INTERVAL, weights=w)),
                              (0, 1)))(xp, yp)
    assert np.all(np.isfinite(gx)) and np.all(np.isfinite(gy))
    assert np.all(gx[40:] == 0) and np.all(gy[40:] == 0)
    # all weights zero: a finite zero fit, not NaN
    z = poly_fit_eval(xp, yp, 6, xe, interval=INTERVAL, weights=np.zeros_like(w))
    assert np.all(np.asarray(z) == 0)


# ------------------------------------------------------------------------------------------------------
# boundary nodes
# ------------------------------------------------------------------------------------------------------
def _columnar_scene(nx=21, gap=10e-6, jitter=0.0, seed=0):
    """Columnar half model: panel (CG + one layer) on x in [0, 2 mm], ball as columns above its surface."""
    rng = np.random.default_rng(seed)
    xs = np.linspace(0, 2e-3, nx)
    pts, part = [], []
    for yv, pid in [(0.0, 1), (-50e-6, 1), (-100e-6, 1), (-200e-6, 2)]:  # CG top at y = 0
        pts += [(x, yv) for x in xs]
        part += [pid] * nx
    xb = np.linspace(0, 1e-3, 11)
    for x in xb:
        ys = gap + R - np.sqrt(R**2 - x**2)
        for k in range(4):
            pts.append((x + jitter * rng.uniform(-1, 1), ys + k * 100e-6))
            part.append(0)
    return np.array(pts), np.array(part)


def test_boundary_nodes_columnar_matches_paper_definition():
    pts, part = _columnar_scene(jitter=1e-9)  # sub-tolerance noise in x (export rounding)
    bn = boundary_nodes(pts, part)
    assert bn.ball_rule == bn.panel_rule == "columns"
    assert len(bn.ball) == 11 and len(bn.panel) == 21
    assert np.all(np.diff(pts[bn.ball, 0]) > 0) and np.all(np.diff(pts[bn.panel, 0]) > 0)
    np.testing.assert_allclose(pts[bn.ball, 1], 10e-6 + R - np.sqrt(R**2 - pts[bn.ball, 0] ** 2), atol=3e-10)
    assert np.all(pts[bn.panel, 1] == 0.0)
    lo, hi = bn.interval
    assert lo < 0 and hi > 2e-3 and hi - 2e-3 < 0.1e-3
    bn2 = boundary_nodes(pts, part, x_max=0.5e-3)
    assert pts[bn2.ball, 0].max() <= 0.5e-3 and pts[bn2.panel, 0].max() <= 0.5e-3 and bn2.interval[1] < 0.52e-3


def _polar_ball(nr=4, nt=13, r0=3e-3, gap=10e-6):
    """Quad mesh of the lower-right quarter annulus of the ball (not columnar), centre at (0, gap + R)."""
    r = np.linspace(r0, R, nr)
    th = np.linspace(-np.pi / 2, 0, nt)
    rr, tt = np.meshgrid(r, th, indexing="ij")
    pts = np.stack([rr * np.cos(tt), gap + R + rr * np.sin(tt)], -1).reshape(-1, 2)
    pts[:, 0] = np.maximum(pts[:, 0], 0)
    idx = np.arange(nr * nt).reshape(nr, nt)
    cells = np.stack([idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]], -1).reshape(-1, 4)
    return pts, cells, idx[-1]  # outer arc = lower surface


def test_boundary_nodes_unstructured_ball_uses_downward_boundary_edges():
    bpts, bcells, outer = _polar_ball()
    ppts, ppart = _columnar_scene()
    keep = ppart != 0
    pts = np.concatenate([bpts, ppts[keep]])
    part = np.concatenate([np.zeros(len(bpts), int), ppart[keep]])
    bn = boundary_nodes(pts, part, cells=bcells, cell_part=np.zeros(len(bcells), int))
    assert bn.ball_rule == "edges" and bn.panel_rule == "columns"
    # the outer arc except its top end node (the equator edge's normal is horizontal there: n_y -> 0)
    assert set(bn.ball.tolist()) >= set(outer[:-1].tolist())
    assert set(bn.ball.tolist()) <= set(outer.tolist())
    # without cells: the bin fallback still finds the lower surface near the contact zone
    bn2 = boundary_nodes(pts, part, x_max=2e-3)
    assert bn2.ball_rule == "bins"
    assert set(bn2.ball.tolist()) <= set(outer.tolist())


def test_boundary_nodes_on_project_mesh():
    """On the project's own O-grid ball + columnar panel ROI mesh, 'auto' finds exactly the mesh's
    ball surface (by downward boundary edges) and panel top (by columns)."""
    mesh_mod = pytest.importorskip("pcmgn_jax.sim.mesh")
    from pcmgn_jax.scene import default_scene

    # x_max inside the crop, as training does: at the crop's far edge the cut leaves down-facing
    # edges that no surface edge hides from below.
    sub, _ = mesh_mod.roi(mesh_mod.build_mesh(default_scene(), "tiny"), "tiny")
    x_max = 0.8 * sub.points[:, 0].max()
    bn = boundary_nodes(sub.points, sub.node_part, cells=sub.cells, cell_part=sub.cell_part, x_max=x_max)
    assert (bn.ball_rule, bn.panel_rule) == ("edges", "columns")
    want_ball = sub.ball_surface[sub.points[sub.ball_surface, 0] <= x_max]
    want_panel = sub.panel_top[sub.points[sub.panel_top, 0] <= x_max]
    assert np.array_equal(np.sort(bn.ball), np.sort(want_ball))
    assert np.array_equal(np.sort(bn.panel), np.sort(want_panel))


# ------------------------------------------------------------------------------------------------------
# penetration depth and loss
# ------------------------------------------------------------------------------------------------------
def _frame(gap, y0=1.5e-3, xb=np.linspace(0, 0.8e-3, 17), xp=np.linspace(0, 1e-3, 21)):
    """Ball bottom = parabola y0 + gap + x^2/(2R) (exact in degree 2); CG top flat at y0. d = -gap - x^2/2R."""
    ball = np.stack([xb, y0 + gap + xb**2 / (2 * R)], 1)
    panel = np.stack([xp, np.full_like(xp, y0)], 1)
    return ball.astype(np.float32), panel.astype(np.float32)


_depth = jax.jit(penetration_depth, static_argnames=("degree_ball", "degree_panel", "interval"))


def test_penetration_depth_exact_geometry_float32_on_mm_offset():
    for gap in [10e-6, 0.0, -1e-6, -30e-9]:
        ball, panel = _frame(gap)
        d, valid = _depth(ball, panel, interval=INTERVAL)
        assert np.all(valid)
        yb = ball[:, 1].astype(np.float64)
        exact = np.full(len(yb), 1.5e-3, np.float32).astype(np.float64) - yb  # on the float32 inputs
        # sub-nm accuracy on a 1.5 mm offset (input float32 ulp there is 2.3e-10 m)
        assert np.abs(np.asarray(d, np.float64) - exact).max() < 5e-10


def test_no_contact_loss_exactly_zero_and_gradient_zero():
    ball, panel = _frame(10e-6)

    def total(ball, panel):
        d, valid = penetration_depth(ball, panel, interval=INTERVAL)
        return penetration_loss(d, valid)

    val = jax.jit(total)(ball, panel)
    gb, gp = jax.jit(jax.grad(total, (0, 1)))(ball, panel)
    assert float(val) == 0.0
    assert np.all(np.asarray(gb) == 0) and np.all(np.asarray(gp) == 0)


def test_single_penetrating_node():
    # loss alone: mean over the positive set, in µm^2
    d = jnp.array([-1e-6, 2e-6, -3e-6, 0.0, 5e-6])
    valid = jnp.array([True, True, True, True, False])  # the 5 µm node is outside the overlap
    assert float(penetration_loss(d, valid)) == pytest.approx(4.0, rel=1e-6)
    g = jax.grad(lambda d: penetration_loss(d, valid))(d)
    np.testing.assert_allclose(g, [0, 2 * 2e-6 / 1e-12, 0, 0, 0], rtol=1e-6)
    assert float(penetration_loss(d, valid, length_scale=1.0)) == pytest.approx(4e-12, rel=1e-6)
    # through the fits: only the axis node penetrates (gap -50 nm; the next node is 1.25e-7 m higher)
    ball, panel = _frame(-50e-9)
    d, valid = _depth(ball, panel, interval=INTERVAL)
    assert np.sum(np.asarray(d) > 0) == 1 and np.asarray(d)[0] > 0
    loss = penetration_loss(d, valid)
    assert float(loss) == pytest.approx((float(d[0]) / 1e-6) ** 2, rel=1e-6)
    assert float(loss) == pytest.approx(0.05**2, rel=2e-2)

    def total(ball, panel):
        return penetration_loss(*penetration_depth(ball, panel, interval=INTERVAL))

    gb, gp = jax.jit(jax.grad(total, (0, 1)))(ball, panel)
    assert np.all(np.isfinite(gb)) and np.all(np.isfinite(gp))
    assert np.asarray(gb)[:, 1].sum() < 0 < np.asarray(gp)[:, 1].sum()  # lift the ball, lower the glass


def test_overlap_window_and_masks():
    xb = np.linspace(0, 1.2e-3, 25)  # ball boundary reaches beyond the CG nodes (x <= 1 mm)
    ball, panel = _frame(-1e-6, xb=xb)
    d, valid = _depth(ball, panel, interval=(-2e-5, 1.25e-3))
    assert np.array_equal(np.asarray(valid), xb <= 1e-3 + 1e-12)
    assert np.all(np.asarray(d)[~np.asarray(valid)] == 0)
    # masked (padded) ball and panel nodes holding garbage
    bm = np.ones(len(ball), bool)
    bm[-3:] = False
    ball_bad = ball.copy()
    ball_bad[-3:] = np.nan
    d2, v2 = _depth(ball_bad, panel, interval=(-2e-5, 1.25e-3), ball_mask=bm)
    assert np.all(np.isfinite(d2)) and not np.any(np.asarray(v2)[-3:])
    g = jax.jit(jax.grad(lambda b: penetration_loss(*penetration_depth(b, panel, interval=(-2e-5, 1.25e-3),
                                                                       ball_mask=bm))))(ball_bad)
    assert np.all(np.isfinite(g))


def test_boundaries_at_fit_interval_edges_and_beyond():
    lo, hi = 0.0, 1e-3
    ball, panel = _frame(-2e-6, xb=np.linspace(lo, hi, 17), xp=np.linspace(lo, hi, 21))
    ball[:, 0] += np.float32(-1e-6)  # predicted motion pushes nodes slightly outside the interval (t < -1)
    panel[-1, 0] += np.float32(3e-6)  # and beyond t = +1
    for deg_b, deg_p in [(6, 5), (8, 7)]:
        def total(b, p):
            d, v = penetration_depth(b, p, degree_ball=deg_b, degree_panel=deg_p, interval=(lo, hi))
            return penetration_loss(d, v), (d, v)

        (val, (d, v)), (gb, gp) = jax.jit(jax.value_and_grad(total, (0, 1), has_aux=True))(ball, panel)
        assert np.isfinite(val) and np.all(np.isfinite(gb)) and np.all(np.isfinite(gp))
        v = np.asarray(v)
        assert not v[0] and v[1:].all()  # node 0 moved to x < 0 = left of the CG range: outside the overlap
        if deg_b <= 8:  # the exact parabola is recovered to float32 precision, up to t = +-1 and beyond
            exact = 2e-6 - np.linspace(lo, hi, 17) ** 2 / (2 * R)  # the ball's y was built on the unshifted x
            assert np.abs(np.asarray(d) - exact)[v].max() < 2e-9


@pytest.mark.parametrize("deg_b,deg_p", [(0, 1), (16, 20)])
def test_extreme_degrees_finite(deg_b, deg_p):
    ball, panel = _frame(-1e-6)

    def total(b, p):
        return penetration_loss(*penetration_depth(b, p, degree_ball=deg_b, degree_panel=deg_p,
                                                   interval=INTERVAL))

    val, (gb, gp) = jax.jit(jax.value_and_grad(total, (0, 1)))(ball, panel)
    assert np.isfinite(val) and np.all(np.isfinite(gb)) and np.all(np.isfinite(gp))
    with pytest.raises(ValueError):
        penetration_depth(ball, panel, degree_ball=17, interval=INTERVAL)  # 17 ball nodes, 18 coefficients


def test_degenerate_clustered_boundary_finite():
    """All ball nodes collapsed to one x (a broken prediction): finite loss and gradient."""
    ball, panel = _frame(-1e-6)
    ball[:, 0] = 4e-4
    val, g = jax.jit(jax.value_and_grad(
        lambda b: penetration_loss(*penetration_depth(b, panel, interval=INTERVAL))))(ball)
    assert np.isfinite(val) and np.all(np.isfinite(g))


def test_vmap_over_frames_matches_loop():
    frames = [_frame(g) for g in [5e-6, 0.0, -0.5e-6, -2e-6]]
    balls = np.stack([f[0] for f in frames])
    panels = np.stack([f[1] for f in frames])

    @jax.jit
    def per_frame(b, p):
        return jax.vmap(lambda bb, pp: penetration_loss(*penetration_depth(bb, pp, interval=INTERVAL)))(b, p)

    batched = np.asarray(per_frame(balls, panels))
    loop = [float(penetration_loss(*_depth(b, p, interval=INTERVAL))) for b, p in frames]
    np.testing.assert_allclose(batched, loop, rtol=1e-3, atol=1e-12)  # d to ~1e-10 m of 0.5..2 µm
    assert batched[0] == 0.0 and batched[-1] > batched[-2] > 0
    g = jax.grad(lambda b: per_frame(b, panels).mean())(balls)
    assert np.all(np.isfinite(g)) and np.all(np.asarray(g)[0] == 0)


# ------------------------------------------------------------------------------------------------------
# fit-free metric
# ------------------------------------------------------------------------------------------------------
def test_signed_distance_hand_geometry_numpy_and_jax():
    poly = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 1.0], [3.0, 1.0]])
    pts = np.array([
        [0.5, 0.25],   # above first segment: +0.25
        [0.5, -0.5],   # below: -0.5
        [1.5, 0.0],    # below the slanted segment: -(distance to y = x - 1) = -0.5/sqrt2
        [1.0, 1.0],    # above the slanted segment, nearest point (1.5, 0.5): +sqrt(0.5)
        [2.0, 1.0],    # on a vertex: 0
        [2.5, 0.0],    # below the last segment
    ])
    expect = np.array([0.25, -0.5, -0.5 / np.sqrt(2), np.sqrt(0.5), 0.0, -np.sqrt(0.5**2 + 1.0) * 0])
    # last point: nearest to segment 2 interior? distance to y = x - 1 line: |2.5 - 0 - 1|/sqrt2 = 1.06,
    # to segment 3 (y = 1, x in [2, 3]): 1.0 -> -1.0
    expect[5] = -1.0
    sd = signed_distance_to_polyline(pts, poly)
    assert isinstance(sd, np.ndarray) and sd.dtype == np.float64
    np.testing.assert_allclose(sd, expect, atol=1e-15)
    sdj = jax.jit(signed_distance_to_polyline)(jnp.asarray(pts), jnp.asarray(poly))
    np.testing.assert_allclose(np.asarray(sdj), expect, atol=1e-6)
    # batched frames
    sd2 = signed_distance_to_polyline(np.stack([pts, pts + [0, 1]]), np.stack([poly, poly + [0, 1]]))
    np.testing.assert_allclose(sd2, np.stack([expect, expect]), atol=1e-15)


def test_penetration_stats_hand_geometry():
    panel = np.stack([np.linspace(0, 1e-3, 11), np.full(11, 1e-3)], 1)  # CG top at y = 1 mm
    ball_x = np.linspace(0, 1.2e-3, 7)  # last node (1.2 mm) outside the CG range: ignored
    frames_b = np.stack([
        np.stack([ball_x, np.full(7, 1e-3 + 5e-6)], 1),                      # gap 5 µm
        np.stack([ball_x, 1e-3 + np.array([-2, -1, 0, 1, 2, 3, -9]) * 1e-6], 1),  # 2 penetrating nodes
        np.stack([ball_x, np.full(7, 1e-3 - 0.5e-6)], 1),                    # all 6 inside penetrate 0.5
    ])
    s = penetration_stats(frames_b, panel)
    np.testing.assert_allclose(s["per_frame_max_um"], [0.0, 2.0, 0.5], atol=1e-9)
    assert s["max_um"] == pytest.approx(2.0, abs=1e-9)
    assert s["frames_with_penetration"] == 2
    assert s["mean_um"] == pytest.approx((2 + 1 + 6 * 0.5) / 8, abs=1e-9)
    np.testing.assert_allclose(s["per_frame_mean_um"], [0.0, 1.5, 0.5], atol=1e-9)
    assert penetration_stats(frames_b, panel, threshold_um=1.0)["frames_with_penetration"] == 1
    s1 = penetration_stats(frames_b[0], panel)
    assert s1["max_um"] == 0.0 and s1["mean_um"] == 0.0 and s1["frames_with_penetration"] == 0


def test_penalty_weight_schedule():
    """lambda_start: no penetration term before the start, a linear ramp over 10 % of training, then
    lambda_pen; lambda_start = 0 is the paper's constant weight."""
    from pcmgn_jax.config import TrainConfig
    from pcmgn_jax.train.setup import TrainSpec
    from pcmgn_jax.train.step import penalty_weight

    spec = TrainSpec(sim=None, cfg=TrainConfig.from_preset("tiny", lambda_pen=10.0, lambda_start=0.5),
                     decay_steps=1000)
    got = [float(penalty_weight(spec, s)) for s in (0, 499, 500, 550, 600, 601, 1000)]
    assert got == pytest.approx([0.0, 0.0, 0.0, 5.0, 10.0, 10.0, 10.0])
    const = TrainSpec(sim=None, cfg=TrainConfig.from_preset("tiny", lambda_pen=10.0), decay_steps=1000)
    assert float(penalty_weight(const, 0)) == 10.0
    with pytest.raises(ValueError, match="lambda_start"):
        TrainConfig.from_preset("tiny", lambda_start=1.0)
