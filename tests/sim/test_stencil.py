"""The solver's K u as shifted slices over structured blocks (pcmgn_jax.sim.stencil) against the
assembled sparse stiffness (the straightforward reference), on the tiny panel mesh."""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from pcmgn_jax.scene import default_scene
from pcmgn_jax.sim import fem, stencil
from pcmgn_jax.sim.solver import prepare

DESIGNS = [(50e-6, 140e-6), (120e-6, 60e-6)]


def _prepared(analysis):
    scenes = [default_scene(t_oca1=a, t_oca2=b, analysis=analysis) for a, b in DESIGNS]
    prep = prepare(scenes, "tiny")
    mesh = prep.mesh
    design_parts = [mesh.part_names.index(n) for n in scenes[0].design_layers]
    shared = np.ones(mesh.n_nodes, bool)
    shared[mesh.cells[np.isin(mesh.cell_part, design_parts)].ravel()] = False
    neighbours, blocks = fem.node_stencil(mesh.cells, prep.ke, mesh.n_nodes)
    layout, coefs = stencil.build(neighbours, blocks, shared)
    return prep, layout, coefs, shared


@pytest.fixture(scope="module")
def tiny():
    return _prepared("axisymmetric")


def _reference(prep, u):
    """K u per design from the assembled CSR matrix (float64). u (B,N,2) -> (B,N,2)."""
    n = prep.mesh.n_nodes
    return np.stack([(fem.assemble_csr(prep.mesh.cells, ke, n) @ ub.ravel()).reshape(n, 2)
                     for ke, ub in zip(prep.ke, u)])


def _apply(layout, coefs, u, dtype, **kw):
    cj = jax.tree.map(lambda v: jnp.asarray(v, dtype if np.asarray(v).dtype.kind == "f" else jnp.int32),
                      coefs)
    f = stencil.apply(jnp.asarray(np.moveaxis(u, -1, 0), dtype), cj, layout, **kw)  # (2,B,N)
    return np.moveaxis(np.asarray(f, np.float64), 0, -1)


def test_layout_is_mostly_slices(tiny):
    """Blocks cover the rows in order; only patch-interface couplings fall to the remainder; the
    per-design coefficient sets are only where the design layers are."""
    prep, layout, coefs, shared = tiny
    n = prep.mesh.n_nodes
    assert layout.blocks[0][0] == 0 and layout.blocks[-1][1] == n
    assert all(a[1] == b[0] for a, b in zip(layout.blocks[:-1], layout.blocks[1:]))
    n_entries = sum(int((np.abs(c) > 0).any(axis=(1, 2, 3)).sum()) for c in coefs["blocks"])
    assert len(coefs["rem_rows"]) < 0.15 * (n_entries + len(coefs["rem_rows"]))
    for (r0, r1, _, per_design), c in zip(layout.blocks, coefs["blocks"]):
        assert per_design == (not shared[r0]) and c.shape[3] == (2 if per_design else 1)
    assert any(pd for *_, pd in layout.blocks) and not layout.remainder_per_design


@pytest.mark.parametrize("analysis", ["axisymmetric", "plane_strain"])
def test_matches_assembled_stiffness_float64(tiny, analysis):
    """rigid_x (relative horizontal displacements) holds in plane strain only, where a
    horizontal translation is rigid; axisymmetry takes vertical ones only."""
    prep, layout, coefs, _ = tiny if analysis == "axisymmetric" else _prepared(analysis)
    rigid_x = analysis == "plane_strain"
    u = np.random.default_rng(1).normal(size=(2, prep.mesh.n_nodes, 2)) * 1e-6
    ref = _reference(prep, u)
    with jax.enable_x64(True):
        f = _apply(layout, coefs, u, jnp.float64, rigid_x=rigid_x)
    np.testing.assert_allclose(f, ref, rtol=0, atol=1e-12 * np.abs(ref).max())


def test_extra_forces_are_added_at_their_rows(tiny):
    prep, layout, coefs, _ = tiny
    n = prep.mesh.n_nodes
    u = np.random.default_rng(2).normal(size=(2, n, 2)) * 1e-6
    rows = np.array([3, n - 1, 3])  # repeated rows accumulate
    extra = np.random.default_rng(3).normal(size=(2, 2, 3))
    with jax.enable_x64(True):
        f = _apply(layout, coefs, u, jnp.float64, extra_rows=jnp.asarray(rows), extra=jnp.asarray(extra))
    ref = _reference(prep, u)
    np.add.at(ref, (slice(None), rows), np.moveaxis(extra, 0, -1))
    np.testing.assert_allclose(f, ref, rtol=0, atol=1e-12 * np.abs(ref).max())


def test_float32_keeps_forces_under_large_vertical_translation(tiny):
    """A 10 um vertical translation on top of 1 nm deformations: the float32 forces match the
    float64 reference of the deformation alone (the translation is force-free)."""
    prep, layout, coefs, _ = tiny
    u = np.random.default_rng(4).normal(size=(2, prep.mesh.n_nodes, 2)) * 1e-9
    ref = _reference(prep, u)
    shifted = u.copy()
    shifted[..., 1] += 1e-5
    f = _apply(layout, coefs, shifted, jnp.float32)
    assert np.abs(f - ref).max() < 1e-3 * np.abs(ref).max()


def test_rows_scaled_and_zeroed_as_the_solver_does(tiny):
    """The solver scales each row by -1/m and zeroes fixed dofs (accelerations, not forces);
    the layout must follow the non-zero pattern of those rows, not of K."""
    prep, _, _, shared = tiny
    mesh = prep.mesh
    free = (~mesh.fixed).astype(float)                              # (N,2)
    neighbours, blocks = fem.node_stencil(mesh.cells, prep.ke, mesh.n_nodes)
    blocks = blocks * (-free.T[None, None, :, None, :] / prep.mass[:, None, None, None, :])
    layout, coefs = stencil.build(neighbours, blocks, shared)
    u = np.random.default_rng(5).normal(size=(2, mesh.n_nodes, 2)) * 1e-6
    ref = -_reference(prep, u) / prep.mass[..., None] * free
    with jax.enable_x64(True):
        a = _apply(layout, coefs, u, jnp.float64)
    np.testing.assert_allclose(a, ref, rtol=0, atol=1e-12 * np.abs(ref).max())


# 23-25 s each, slow (the default suite stays under 10 minutes); the default suite reaches the same reverse pass
# through tests/sim/test_differentiable.py's central-difference check of the whole solver
@pytest.mark.slow
@pytest.mark.parametrize("analysis", ["axisymmetric", "plane_strain"])
def test_apply_symmetric_reverse_pass_equals_autodiff(analysis):
    """apply_symmetric's hand-written reverse pass (K D g for the displacement, products for the coefficients
    and the extra forces) equals jax's own transpose of apply, for rows scaled by -free/m as in the solver."""
    prep, *_ = _prepared(analysis)
    mesh = prep.mesh
    rigid_x = analysis == "plane_strain"
    free = (~mesh.fixed).astype(float)
    neighbours, blocks = fem.node_stencil(mesh.cells, prep.ke, mesh.n_nodes)
    scale = -free.T[:, None, :] / prep.mass[None]                   # (2,B,N)
    shared = np.zeros(mesh.n_nodes, bool)
    layout, coefs = stencil.build(neighbours, blocks * np.moveaxis(scale, 1, 0)[:, None, :, None, :], shared)
    _, sym = stencil.build(neighbours, blocks, shared, live=(np.abs(blocks) > 0).any(axis=(0, 2, 3)).T)
    rng = np.random.default_rng(6)
    rows = np.array([3, mesh.n_nodes - 1])
    with jax.enable_x64(True):
        w, g, extra = (jnp.asarray(rng.normal(size=s)) for s in ((2, 2, mesh.n_nodes), (2, 2, mesh.n_nodes),
                                                                  (2, 2, 2)))
        floats = {"blocks": [jnp.asarray(c) for c in coefs["blocks"]], "rem_blocks": jnp.asarray(coefs["rem_blocks"])}
        ints = {"rem_rows": coefs["rem_rows"], "rem_cols": coefs["rem_cols"]}

        def plain(w, c, e):
            return stencil.apply(w, {**c, **ints}, layout, rigid_x=rigid_x, extra_rows=rows, extra=e)

        def hand(w, c, e):
            return stencil.apply_symmetric(w, {**c, **ints}, {**sym}, jnp.asarray(scale), layout=layout,
                                           rigid_x=rigid_x, extra_rows=rows, extra=e)
        out_a, vjp_a = jax.vjp(plain, w, floats, extra)
        out_b, vjp_b = jax.vjp(hand, w, floats, extra)
        np.testing.assert_array_equal(np.asarray(out_a), np.asarray(out_b))
        for a, b in zip(jax.tree.leaves(vjp_a(g)), jax.tree.leaves(vjp_b(g))):
            np.testing.assert_allclose(np.asarray(b), np.asarray(a), rtol=0, atol=1e-10 * np.abs(np.asarray(a)).max())
