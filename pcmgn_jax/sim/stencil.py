"""K u for the explicit solver as shifted slices over the mesh's structured blocks.

The quad meshes of :mod:`pcmgn_jax.sim.mesh` are structured blocks numbered row by row (the
panel's layers; the ball's four O-grid patches), so in most rows the neighbours of node i sit at
i + d for the nine offsets d in {0, +-1, +-(w-1), +-w, +-(w+1)}, w the block's row length. The
global stiffness, arranged as 2x2 node blocks over each node's neighbours
(:func:`fem.node_stencil`), is applied here as nine shifted slices of the displacement per block:
contiguous loads that XLA's CPU backend vectorises, with no gather and no scatter. The few
couplings that fit no block's offsets (patch interfaces) form a small "remainder" applied with
a gather and a scatter-add. The layout is found from the neighbour lists alone, so any mesh works;
an unstructured one just ends up mostly in the remainder.

Node arrays here are (2, B, N): component (x, y), design, node in mesh order; the node axis is
contiguous. Stiffness entries are [N/m], displacements [m], forces [N].

Why shifted slices rather than an einsum over element matrices or a gathered node stencil: slices
vectorise over a batch of designs and gathers do not (docs/design.md §9; timings in benchmarks/README.md §3).
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np


@dataclass(frozen=True)
class SliceLayout:
    """Static description of the blocks (hashable: a jit static argument).

    blocks: per block (first row, end row, offsets, per_design): rows [first, end) use
            neighbours at row + offset; per_design False means one coefficient set serves
            every design of the batch.
    pad:    largest |offset| (the displacement is zero-padded by it on both ends).
    remainder_per_design: whether the remainder's coefficients differ between designs.
    """

    blocks: tuple[tuple[int, int, tuple[int, ...], bool], ...]
    pad: int
    remainder_per_design: bool


_MIN_BLOCK_ROWS = 4  # shorter runs of rows are folded into the previous block


def _offsets_for_width(w: int | None) -> tuple[int, ...]:
    if w is None:
        return (-1, 0, 1)
    return tuple(sorted({0, 1, -1, w - 1, -(w - 1), w, -w, w + 1, -(w + 1)}))


def _best_width(offsets: set[int], current: int | None) -> int | None:
    """The row length w whose nine offsets cover most of ``offsets`` (ties: closest to current)."""
    long = {abs(d) for d in offsets if abs(d) > 1}
    if not long:
        return current
    cands = sorted({c for d in long for c in (d - 1, d, d + 1) if c >= 2})
    def score(w):
        return (len(offsets & set(_offsets_for_width(w))), -abs(w - (current or w)))
    return max(cands, key=score)


def build(neighbours: np.ndarray, blocks, shared_rows: np.ndarray, live: np.ndarray | None = None):
    """The slice layout and its coefficient arrays: :func:`plan` (host, the structure) then :func:`gather`
    (the coefficients: NumPy on the host, jax arrays in the differentiable solver).

    neighbours (N,W) and blocks (B,W,2,2,N) [N/m] from :func:`fem.node_stencil` (B designs of
    one topology); shared_rows (N,) bool: rows whose blocks are the same for every design;
    live (N,W) bool: the non-zero blocks (default: read from ``blocks``, which must then be NumPy).
    Returns (layout, coefs) with coefs = {"blocks": [per block (n_off,2,2,Bc,rows)],
    "rem_rows": (R,), "rem_cols": (R,), "rem_blocks": (2,2,Bc,R)} (R remainder entries:
    row, neighbour, block), Bc = 1 or B.
    """
    if live is None:
        live = (np.abs(blocks) > 0).any(axis=(0, 2, 3)).T                    # (N,W) non-zero entries
    layout, sources = plan(neighbours, live, shared_rows)
    return layout, gather(blocks, layout, sources)


def plan(neighbours: np.ndarray, live: np.ndarray, shared_rows: np.ndarray):
    """Host side of :func:`build`: the layout, and the sources of every coefficient: {"blocks": per block
    (n_off, rows) int64, "rem": (R,) int64, "rem_rows", "rem_cols"}, a source being ``k * N + i`` (block k
    of row i in the flattened (W, N) node-block axes) or ``W * N`` (an empty slot, read as zero)."""
    n, width = neighbours.shape
    rows = np.arange(n)
    empty = width * n
    offsets = [set((neighbours[i, live[i]] - i).tolist()) | {0} for i in rows]
    # 1. runs of rows sharing one row length w (misfit rows stay and feed the remainder)
    runs, start, w_cur = [], 0, None
    for i in rows:
        fits = offsets[i] <= set(_offsets_for_width(w_cur))
        if fits:
            continue
        w_new = _best_width(offsets[i], w_cur)
        if w_cur is None:
            w_cur = w_new
            continue
        better = len(offsets[i] & set(_offsets_for_width(w_new))) > \
            len(offsets[i] & set(_offsets_for_width(w_cur)))
        if better:
            runs.append((start, int(i), w_cur))
            start, w_cur = int(i), w_new
    runs.append((start, n, w_cur))
    # a run of a few rows is an interface row, not a block: fold it into its neighbour (its
    # misfit couplings go to the remainder), which keeps the padding at one block row length
    merged = []
    for r0, r1, w in runs:
        if merged and (r1 - r0 < _MIN_BLOCK_ROWS or merged[-1][1] - merged[-1][0] < _MIN_BLOCK_ROWS):
            a, _, w_prev = merged[-1]
            merged[-1] = (a, r1, w_prev if r1 - r0 < _MIN_BLOCK_ROWS else w)
        else:
            merged.append((r0, r1, w))
    runs = merged
    # 2. split runs where the shared / per-design flag changes
    cut = np.flatnonzero(np.diff(shared_rows.astype(int))) + 1
    layout_blocks, sources, rem = [], [], []
    for r0, r1, w in runs:
        edges = [r0] + [int(c) for c in cut if r0 < c < r1] + [r1]
        offs = _offsets_for_width(w)
        slot_of = {d: k for k, d in enumerate(offs)}
        for a, b in zip(edges[:-1], edges[1:]):
            src = np.full((len(offs), b - a), empty, np.int64)
            for i in range(a, b):
                for k in np.flatnonzero(live[i]):
                    d = int(neighbours[i, k] - i)
                    if d in slot_of:
                        src[slot_of[d], i - a] = k * n + i
                    else:
                        rem.append((i, int(neighbours[i, k]), k))
            layout_blocks.append((a, b, offs, not bool(shared_rows[a])))
            sources.append(src)
    # 3. the remainder as a flat list of (row, neighbour, block) entries
    rem_rows = np.asarray([r for r, _, _ in rem], np.int64)
    rem_cols = np.asarray([c for _, c, _ in rem], np.int64)
    rem_per_design = bool(len(rem)) and not bool(np.all(shared_rows[rem_rows]))
    pad = max(max(abs(d) for d in offs) for _, _, offs, _ in layout_blocks)
    layout = SliceLayout(blocks=tuple(layout_blocks), pad=int(pad), remainder_per_design=rem_per_design)
    rem_src = np.asarray([k * n + r for r, _, k in rem], np.int64)
    return layout, {"blocks": sources, "rem": rem_src, "rem_rows": rem_rows, "rem_cols": rem_cols}


def gather(blocks, layout: SliceLayout, sources: dict):
    """The coefficient arrays of :func:`build` from blocks (B,W,2,2,N) [N/m] and :func:`plan`'s sources;
    NumPy in -> NumPy out, jax in -> jax out (a gather: differentiable in the blocks)."""
    xp = np if isinstance(blocks, np.ndarray) else jnp
    n_design, width, _, _, n = blocks.shape
    flat = xp.transpose(blocks, (2, 3, 0, 1, 4)).reshape(2, 2, n_design, width * n)     # (2,2,B,W*N)
    flat = xp.concatenate([flat, xp.zeros((2, 2, n_design, 1), flat.dtype)], axis=-1)

    def take(src, per_design):
        vals = flat[:, :, :, src] if per_design else flat[:, :, :1, src]     # (2,2,Bc,*src.shape)
        return vals if src.ndim == 1 else xp.moveaxis(vals, 3, 0)           # (n_off,2,2,Bc,rows)

    coef_blocks = [take(src, per_design) for (_, _, _, per_design), src in zip(layout.blocks, sources["blocks"])]
    return {"blocks": coef_blocks, "rem_rows": sources["rem_rows"], "rem_cols": sources["rem_cols"],
            "rem_blocks": take(sources["rem"], layout.remainder_per_design)}


def apply(w, coefs, layout: SliceLayout, *, rigid_x: bool = False, extra_rows=None, extra=None):
    """K w: w (2,B,N) [m] -> (2,B,N) [N], plus optional ``extra`` nodal forces (2,B,K) [N] added
    at ``extra_rows`` (K,) in the same scatter as the remainder (the solver's contact forces).

    Neighbour displacements are taken relative to the node's own vertical one (and horizontal
    one if ``rigid_x``, i.e. plane strain): a row's blocks sum to zero on a rigid translation,
    so this changes nothing in exact arithmetic (also when a row is split between a block and
    the remainder), but in float32 a ~1e-5 m rigid motion times stiffness entries ~1e11 would
    otherwise leave round-off forces of the order of the contact forces themselves."""
    p = layout.pad
    wx, wy = w[0], w[1]
    px = jnp.pad(wx, ((0, 0), (p, p)))
    py = jnp.pad(wy, ((0, 0), (p, p)))
    out = []
    for (r0, r1, offs, _), c in zip(layout.blocks, coefs["blocks"]):
        own_x = wx[:, r0:r1] if rigid_x else 0.0
        own_y = wy[:, r0:r1]
        fx = fy = 0.0
        for k, d in enumerate(offs):
            gx = px[:, p + r0 + d:p + r1 + d] - own_x
            gy = py[:, p + r0 + d:p + r1 + d] - own_y
            fx = fx + c[k, 0, 0] * gx + c[k, 0, 1] * gy
            fy = fy + c[k, 1, 0] * gx + c[k, 1, 1] * gy
        out.append(jnp.stack([fx, fy]))
    f = out[0] if len(out) == 1 else jnp.concatenate(out, axis=-1)
    rows, cols, c = coefs["rem_rows"], coefs["rem_cols"], coefs["rem_blocks"]
    idx, vals = [], []
    if rows.shape[0]:
        gx = wx[:, cols] - (wx[:, rows] if rigid_x else 0.0)
        gy = wy[:, cols] - wy[:, rows]
        idx.append(rows)
        vals.append(jnp.stack([c[0, 0] * gx + c[0, 1] * gy, c[1, 0] * gx + c[1, 1] * gy]))
    if extra is not None:
        idx.append(extra_rows)
        vals.append(extra)
    if not idx:
        return f
    return f.at[:, :, jnp.concatenate(idx)].add(jnp.concatenate(vals, axis=-1))


def _float_coefs(coefs):
    return {"blocks": coefs["blocks"], "rem_blocks": coefs["rem_blocks"]}


@partial(jax.custom_vjp, nondiff_argnums=(0, 1))
def _apply_sym(layout, rigid_x, w, coefs, sym, row_scale, rem_rows, rem_cols, extra_rows, extra):
    full = {**coefs, "rem_rows": rem_rows, "rem_cols": rem_cols}
    return apply(w, full, layout, rigid_x=rigid_x, extra_rows=extra_rows, extra=extra)


def _apply_sym_fwd(layout, rigid_x, w, coefs, sym, row_scale, rem_rows, rem_cols, extra_rows, extra):
    out = _apply_sym(layout, rigid_x, w, coefs, sym, row_scale, rem_rows, rem_cols, extra_rows, extra)
    return out, (w, coefs, sym, row_scale, rem_rows, rem_cols, extra_rows, extra)


def _apply_sym_bwd(layout, rigid_x, res, g):
    w, coefs, sym, row_scale, rem_rows, rem_cols, extra_rows, extra = res
    # the operator is D K (D = row_scale, K symmetric): its transpose K D is the same stencil of K on D g
    w_bar = apply(row_scale * g, {**sym, "rem_rows": rem_rows, "rem_cols": rem_cols}, layout, rigid_x=rigid_x)
    # the coefficients' cotangents: each output row's cotangent times the neighbour differences it multiplied
    p = layout.pad
    wx, wy = w[0], w[1]
    px, py = jnp.pad(wx, ((0, 0), (p, p))), jnp.pad(wy, ((0, 0), (p, p)))
    blocks_bar = []
    for (r0, r1, offs, _), c in zip(layout.blocks, coefs["blocks"]):
        own = jnp.stack([wx[:, r0:r1] if rigid_x else jnp.zeros_like(wx[:, r0:r1]), wy[:, r0:r1]])  # (2,B,rows)
        diffs = jnp.stack([jnp.stack([px, py])[:, :, p + r0 + d:p + r1 + d] for d in offs]) - own  # (n_off,2,B,rows)
        cb = g[None, :, None, :, r0:r1] * diffs[:, None]              # (n_off,2,2,B,rows): [k, a, b] = g_a d_b
        blocks_bar.append(cb if c.shape[3] == cb.shape[3] else cb.sum(axis=3, keepdims=True))
    rem = coefs["rem_blocks"]
    if rem_rows.shape[0]:
        gx = wx[:, rem_cols] - (wx[:, rem_rows] if rigid_x else 0.0)
        gy = wy[:, rem_cols] - wy[:, rem_rows]
        fx, fy = g[0][:, rem_rows], g[1][:, rem_rows]
        rb = jnp.stack([jnp.stack([fx * gx, fx * gy]), jnp.stack([fy * gx, fy * gy])])
        rem_bar = rb if rem.shape[2] == rb.shape[2] else rb.sum(axis=2, keepdims=True)
    else:
        rem_bar = jnp.zeros_like(rem)
    extra_bar = None if extra is None else g[:, :, extra_rows]
    return (w_bar, {"blocks": blocks_bar, "rem_blocks": rem_bar}, None, None, None, None, None, extra_bar)


_apply_sym.defvjp(_apply_sym_fwd, _apply_sym_bwd)


def apply_symmetric(w, coefs, sym_coefs, row_scale, *, layout: SliceLayout, rigid_x: bool = False, extra_rows=None,
                    extra=None):
    """:func:`apply` of coefficients that are a row scaling of a symmetric operator's, ``coefs = D K`` with
    D = ``row_scale`` (2,B,N) and K's own coefficients ``sym_coefs`` (the same layout), with a hand-written
    reverse pass: the displacement's cotangent is K (D g), one more stencil product, and the coefficients'
    are the products of g with the neighbour differences (autodiff's transpose of the shifted slices would
    pad every slice to the full length). Only ``coefs`` and ``extra`` enter the value: the cotangents of
    ``sym_coefs`` and ``row_scale`` are zero (they describe the transpose)."""
    return _apply_sym(layout, rigid_x, w, _float_coefs(coefs), _float_coefs(sym_coefs), row_scale,
                      coefs["rem_rows"], coefs["rem_cols"], extra_rows, extra)
