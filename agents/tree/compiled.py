"""The causal tree GNN's per-node embedding, compiled (numba): what :class:`~agents.tree.engine.IncrementalTreeGNN`
runs for every new tree node.

A new node's embedding needs its causal k-NN among the earlier nodes of its tree, then per
message-passing layer its parent's and neighbours' cached sender terms, two small MLPs and a
LayerNorm: a few thousand multiply-adds and a few hundred ``erf``s. In numpy that is ~90 small
array operations per batch of new nodes (~0.15 ms of dispatch, about as much as the arithmetic
of a dozen nodes), which made the GNN samplers slower than uniform sampling in wall time on
cheap planning steps. Here it is one compiled function per batch of new nodes, in
float64, the math of :class:`agents.tree.models.TreeGNN` (``tests/test_tree_engine.py`` compares
the engine's outputs with the torch model's to 1e-5): the k-NN and the messages row by row, the
products with the weight matrices one BLAS call per layer for the whole batch, the GELUs' ``erf``
four values per call of glibc's vector math library where it exists (:data:`VECTOR_ERF`; about
half of a batched node's cost was libm's scalar ``erf``). Compiled once
per checkout and cached next to this file (``cache=True``); the first call in a fresh checkout
compiles for about 40 s (maze2d's GNN and GNN-CVAE together; the pendulum scorer ~10 s), which
:func:`announce_compilation` says in one line. :func:`scorer_embed_rows` does the same for the
pendulum's sample scorer (:class:`~agents.tree.engine.IncrementalTreeScorer`).
"""

from __future__ import annotations

import ctypes.util
import math

import numpy as np
from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

from gnn_mp_envs.core.nearest import PRUNE_FLOOR as KD_PRUNE_FLOOR
from gnn_mp_envs.core.nearest import PRUNE_MARGIN as KD_PRUNE_MARGIN
from gnn_mp_envs.core.nearest import SPLIT as KD_SPLIT
from gnn_mp_envs.core.nearest import index_insert, kd_pop_cell, kd_stack_far_side
from gnn_mp_envs.utils.compiled import announce_compilation as announce_loop_compilation
from gnn_mp_envs.utils.compiled import jit

_SQRT_HALF = 1.0 / math.sqrt(2.0)
#: The one-line refusal of a tree id the model has no slot for (unchecked, it would write past the caches).
_UNTRAINED_TREE = ("the observation holds a tree this GNN has no slot for (tree id >= its num_trees): a model "
                   "trained on RRT (one tree) cannot read a BiRRT observation; use a checkpoint trained for this env")
_TWO_PI = 2.0 * math.pi


def _load_vector_erf() -> bool:
    """Whether glibc's vector math library (libmvec, glibc 2.35+) and AVX2 are here, and numba builds
    for this CPU: then the GELUs take its ``erf`` of four doubles at a time (~5 ns a value against
    libm's 15-25 ns on this project's 2-core Xeon; the same values to a few ulp, see
    ``tests/test_tree_engine.py``), and the node mixtures its ``exp``. Else libm's scalar ``erf`` and
    ``exp``, four calls per group."""
    try:
        import llvmlite.binding as llvm
        from numba.core import config
        if config.CPU_NAME or config.CPU_FEATURES:      # kernels built for another CPU (NUMBA_CPU_NAME):
            return False                                # AVX2's register convention is not guaranteed
        if not llvm.get_host_cpu_features().get("avx2", False):
            return False
        path = ctypes.util.find_library("mvec")
        if path is None or not all(hasattr(ctypes.CDLL(path), f"_ZGVdN4v_{f}") for f in ("erf", "exp")):
            return False
        llvm.load_library_permanently(path)
        return True
    except (OSError, RuntimeError, AttributeError):
        return False


#: glibc's AVX2 ``erf`` of four doubles is linked into the compiled GELUs (else libm's, one by one).
VECTOR_ERF = _load_vector_erf()


def _four_in_place(name: str):
    """An intrinsic ``f(a, i)``: ``a[i:i+4] = name(a[i:i+4])`` (``a``: a 1-D contiguous float64 array with
    four values from ``i``): one call of libmvec's ``_ZGVdN4v_<name>`` (:data:`VECTOR_ERF`), or four of
    libm's ``name`` without it."""
    @intrinsic
    def four_in_place(typingctx, a, i):
        if not (isinstance(a, types.Array) and a.dtype == types.float64 and a.ndim == 1
                and isinstance(i, types.Integer)):
            return None

        def codegen(context, builder, signature, args):
            arr, idx = args
            data = context.make_array(signature.args[0])(context, builder, arr).data
            ptr = builder.gep(data, [idx])
            double = ir.DoubleType()
            if VECTOR_ERF:
                vec = ir.VectorType(double, 4)
                vptr = builder.bitcast(ptr, vec.as_pointer())
                fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(vec, [vec]), f"_ZGVdN4v_{name}")
                builder.store(builder.call(fn, [builder.load(vptr, align=8)]), vptr, align=8)
            else:
                fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(double, [double]), name)
                for lane in range(4):
                    p = builder.gep(ptr, [ir.Constant(ir.IntType(64), lane)])
                    builder.store(builder.call(fn, [builder.load(p)]), p)
            return context.get_dummy_value()
        return types.void(a, i), codegen
    return four_in_place


#: ``a[i:i+4] = erf(a[i:i+4])`` and ``exp``, four values a call (:func:`_four_in_place`).
_erf4_inplace = _four_in_place("erf")
_exp4_inplace = _four_in_place("exp")


@jit(inline=True)
def _gelu_with(v, u):
    """``v = GELU(v)`` for a 1-D contiguous array, with ``u`` as scratch (at least ``len(v)`` rounded
    up to 4 values; its contents are overwritten): the ``erf``s four at a time
    (:func:`_erf4_inplace`), then ``0.5 * v * (1 + erf(v * _SQRT_HALF))`` in that order (the scalar
    GELU's, with libm's ``erf``). Each value's result depends on that value only, so one call over
    many rows gives the floats of one call per row."""
    n = v.shape[0]
    for i in range(n):
        u[i] = v[i] * _SQRT_HALF
    for i in range(n, n + (-n) % 4):
        u[i] = 0.0
    for i in range(0, n + (-n) % 4, 4):
        _erf4_inplace(u, i)
    for i in range(n):
        v[i] = 0.5 * v[i] * (1.0 + u[i])


@jit(inline=True)
def _gelu_into(v):
    """``v = GELU(v)`` for a 1-D contiguous array (:func:`_gelu_with` with its own scratch)."""
    n = v.shape[0]
    _gelu_with(v, np.empty(n + (-n) % 4))


@jit(inline=True)
def _wrapped(v: float, periodic: bool) -> float:
    """``wrap_periodic`` of one difference: ``(v + pi) % (2 pi) - pi`` (Python's floored modulo, as
    numpy's ``%``), by one exact step where ``v + pi`` lies in ``[-2 pi, 4 pi)`` (the case of two
    wrapped angles; see ``agents.samplers.base.wrap_pi``)."""
    if not periodic:
        return v
    a = v + math.pi
    if a >= _TWO_PI:
        if a >= 2.0 * _TWO_PI:
            return a % _TWO_PI - math.pi
        a -= _TWO_PI
    elif a < 0.0:
        if a < -_TWO_PI:
            return a % _TWO_PI - math.pi
        a += _TWO_PI
    elif a == 0.0:
        a = 0.0                     # -0.0 -> +0.0, as the modulo gives
    return a - math.pi


@jit(inline=True)
def _matvec_add(out, v, w, n_in, offset):
    """``out += v[:n_in] @ w[offset:offset + n_in]`` row by row (contiguous, vectorisable inner loop)."""
    H = out.shape[0]
    for q in range(n_in):
        vq = v[q]
        for c in range(H):
            out[c] += vq * w[offset + q, c]


@jit(inline=True)
def _first_layer(pre, rel, sender_j, bias, state_j, x_i, periodic, w_rel):
    """A message MLP's first layer for the edge ``j -> i`` (before its GELU): the sender's cached
    ``W_h h_j``, the bias, and ``wrap(x_j - x_i)`` times ``W_x / step`` (``rel``: scratch)."""
    for c in range(rel.shape[0]):
        rel[c] = _wrapped(state_j[c] - x_i[c], periodic[c])
    for c in range(pre.shape[0]):
        pre[c] = sender_j[c] + bias[c]
    _matvec_add(pre, rel, w_rel, rel.shape[0], 0)


@jit(inline=True)
def _knn_distance(states, j, x, r, unit, periodic):
    """The causal k-NN's squared distance from node ``j`` to row ``r`` of ``x``: :func:`_causal_knn`'s floats
    (each coordinate's ``wrap(x_j - x_i) / unit`` squared, summed in order)."""
    acc = 0.0
    for c in range(x.shape[1]):
        v = _wrapped(states[j, c] - x[r, c], periodic[c]) / unit[c]
        acc += v * v
    return acc


@jit(inline=True)
def _causal_knn(i0, x, tid, states, tree_id, knn, periodic, unit, planner_metric):
    """Each row's ``knn`` nearest earlier nodes of its own tree (row ``r`` is node ``i0 + r``; the
    batch's own earlier rows included), nearest first, the earlier node first on ties (a stable
    sort's order, as the torch models' k-NN): ``(nodes (B, max(knn, 1)), how many were found (B,))``.
    Squared distances: ``sum((wrap(x_j - x_i) / unit) ** 2)`` (the GNN's step units), or with
    ``planner_metric`` ``sum((min(|d|, 2 pi - |d|) * unit) ** 2)`` (the planner's weighted metric,
    the scorer's).

    Two passes per row: every earlier node's distance into a buffer, one coordinate at a time over
    a column copy of the states (contiguous and branch-free, so the loop over nodes pipelines; about
    twice as fast as one pass), then the selection scan. The same floats as
    one pass: each distance is the same operations in the same order (``_wrapped``'s single-step
    case written as selects; a difference outside it, never made by wrapped angles, is recomputed
    by :func:`_wrapped` itself). The pendulum's scorer reads it; the tree GNN's engine takes the same
    answer from its k-d trees (:func:`_kd_causal_knn`, held to this scan by the tests)."""
    B, d = x.shape
    kk = max(knn, 1)
    best_d = np.empty(kk)
    near = np.zeros((B, kk), dtype=np.int64)
    found = np.zeros(B, dtype=np.int64)
    two_pi = 2.0 * math.pi
    if knn <= 0:
        return near, found
    M = i0 + B
    cols = np.empty((d, M))                          # the states column by column: contiguous passes
    for j in range(M):
        for c in range(d):
            cols[c, j] = states[j, c]
    dist = np.empty(M)
    for r in range(B):
        t = tid[r]
        m = i0 + r
        dist[:m] = 0.0
        outside = False
        for c in range(d):
            xc = x[r, c]
            uc = unit[c]
            col = cols[c]
            if planner_metric:
                if periodic[c]:
                    for j in range(m):
                        v = abs(xc - col[j])
                        v = min(v, two_pi - v) * uc
                        dist[j] += v * v
                else:
                    for j in range(m):
                        v = abs(xc - col[j]) * uc
                        dist[j] += v * v
            elif periodic[c]:
                for j in range(m):
                    a = (col[j] - xc) + math.pi
                    outside |= (a >= 2.0 * _TWO_PI) | (a < -_TWO_PI)
                    a = a - _TWO_PI if a >= _TWO_PI else (a + _TWO_PI if a < 0.0 else a)
                    v = (a - math.pi) / uc
                    dist[j] += v * v
            else:
                for j in range(m):
                    v = (col[j] - xc) / uc
                    dist[j] += v * v
        if outside:                                  # not two wrapped angles: the exact wrap, node by node
            for j in range(m):
                dist[j] = _knn_distance(states, j, x, r, unit, periodic)
        n_found = 0
        for j in range(m):
            if tree_id[j] != t:
                continue
            dj = dist[j]
            if n_found < knn:
                pos = n_found
                n_found += 1
            elif dj < best_d[knn - 1]:
                pos = knn - 1
            else:
                continue
            while pos > 0 and best_d[pos - 1] > dj:
                best_d[pos] = best_d[pos - 1]
                near[r, pos] = near[r, pos - 1]
                pos -= 1
            best_d[pos] = dj
            near[r, pos] = j
        found[r] = n_found
    return near, found


@jit(inline=True)
def _kd_causal_knn(i0, x, tid, states, knn, periodic, unit, kd):
    """:func:`_causal_knn`'s answer (the same nodes in the same order, ties to the earlier node) from the
    engine's bucketed k-d trees, one per GNN tree (``kd``: :class:`~gnn_mp_envs.core.nearest.IndexArrays`
    with weights ``1 / unit``, which only choose the splits, holding the nodes before ``i0``): per row a
    k-nearest query of its tree, then the row joins it. A cell is skipped only when its squared distance
    (its gaps in step units) exceeds the ``knn``-th so far by
    :data:`~gnn_mp_envs.core.nearest.PRUNE_MARGIN` (far above rounding), so every node that could tie or
    win is compared with the brute force's own floats (:func:`_knn_distance`'s, computed for a leaf's
    nodes one coordinate at a time over its block). The cost grows with the depth of the trees rather
    than their size (a brute force pass per row over every earlier node was a third of a Fetch forward
    at 4,000 nodes)."""
    B, d = x.shape
    kk = max(knn, 1)
    near = np.zeros((B, kk), dtype=np.int64)
    found = np.zeros(B, dtype=np.int64)
    if knn <= 0:
        return near, found
    best_d = np.empty(kk)
    links, cut, leaf, fill, chain, points, ids = kd.links, kd.cut, kd.leaf, kd.fill, kd.chain, kd.points, kd.ids
    stack, bounds, cell, squares = kd.stack, kd.bounds, kd.cell, kd.squares
    for r in range(B):
        t = tid[r]
        count = 0
        node = kd.root[t]
        if node >= 0:
            for c in range(d):
                cell[c] = 0.0
            limit = math.inf
            stack[0, 0], stack[0, 1], bounds[0, 0], bounds[0, 1] = node, 0, 0.0, 0.0
            top = 1
            while top > 0:
                node, bound, top = kd_pop_cell(stack, bounds, cell, top, limit)
                if node < 0:
                    continue
                while links[node, KD_SPLIT] >= 0:           # down toward the row, stacking the far sides
                    c = links[node, KD_SPLIT]
                    node, top = kd_stack_far_side(node, c, (x[r, c] - cut[node]) / unit[c], bound, limit, links,
                                                  stack, bounds, cell, top)
                block = leaf[node]
                while block >= 0:
                    k = fill[block]
                    for j in range(k):                        # _knn_distance's floats, a block at a time
                        squares[j] = 0.0
                    for c in range(d):
                        xc, uc, column = x[r, c], unit[c], points[block, c]
                        if periodic[c]:
                            for j in range(k):
                                v = _wrapped(column[j] - xc, True) / uc
                                squares[j] += v * v
                        else:
                            for j in range(k):
                                v = (column[j] - xc) / uc
                                squares[j] += v * v
                    for j in range(k):
                        dj, g = squares[j], ids[block, j]
                        if count < knn or dj < best_d[knn - 1] or (dj == best_d[knn - 1] and g < near[r, knn - 1]):
                            pos = count if count < knn else knn - 1
                            count = min(count + 1, knn)
                            while pos > 0 and (best_d[pos - 1] > dj or (best_d[pos - 1] == dj and near[r, pos - 1] > g)):
                                best_d[pos] = best_d[pos - 1]
                                near[r, pos] = near[r, pos - 1]
                                pos -= 1
                            best_d[pos] = dj
                            near[r, pos] = g
                            if count == knn:
                                limit = best_d[knn - 1] * KD_PRUNE_MARGIN + KD_PRUNE_FLOOR
                    block = chain[block]
        found[r] = count
        index_insert(i0 + r, t, states, kd)
    return near, found


@jit(inline=True)
def _residual_layer_norm(upd, h, g, b, eps):
    """``h = LayerNorm(h + upd)`` row by row, in place (``upd`` is overwritten)."""
    B, H = h.shape
    for r in range(B):
        mean = 0.0
        for c in range(H):
            upd[r, c] += h[r, c]
            mean += upd[r, c]
        mean /= H
        var = 0.0
        for c in range(H):
            upd[r, c] -= mean
            var += upd[r, c] * upd[r, c]
        inv_std = 1.0 / math.sqrt(var / H + eps)
        for c in range(H):
            h[r, c] = upd[r, c] * inv_std * g[c] + b[c]


@jit(inline=True)
def _gelu_rows(a):
    """GELU of a C-contiguous 2-D array, in place."""
    _gelu_into(a.reshape(a.size))


@jit
def embed_rows(i0, x, feats, tid, parent, states, tree_id, sender, keys, offsets, log_sigma, sums, counts, kd,
               periodic, step, center, scale, feature_scale, relative_inputs, knn, use_parent, heads, iw1, ib1, iw2,
               ib2, w_sender, wpx, bp1, wpu, bpu, wkx, bk1, wku, bku, uw1, ub1, uw2, ub2, norm_g, norm_b, norm_eps,
               kw, kb, hw, hb):
    """Embed rows ``i0..i0+B-1`` (their states ``x``, node features ``feats``, trees ``tid``, parents
    ``parent``; a row's neighbours and parent are earlier rows, this batch's included): the input
    MLP, the causal k-NN (``knn`` neighbours; 0: no k-NN messages), the message-passing layers (each
    row's per-layer sender terms ``W_h h`` cached in ``sender[layer, edge type, row]``), then the
    row's key, Gaussian offsets and log-sigmas (clipped to [-4, 1]) and its tree's embedding sum and
    count, all written in place (the caches: ``states`` to ``counts``; ``states``/``tree_id``
    already hold the rows; ``heads`` false: keys, offsets and log-sigmas are not computed, for a
    sampler that reads only the tree sums). The arguments after ``counts`` are the model's fixed
    settings and weights (``IncrementalTreeGNN.weights``); each message's second layer comes fused
    with its block of the update MLP's first layer (``wpu = W_2 U``, ``bpu = b_2 U``: the message
    itself is only ever used through that product).

    Layer by layer over the batch: a layer's sender terms depend only on the rows' inputs to that
    layer, so all of them exist before any row reads its parent's or neighbours'; the products with
    the weight matrices are then one BLAS product per matrix for the whole batch (~0.15 us per row
    and matrix, against ~0.5 us for a row's own loop)."""
    B, d = x.shape
    L, H = bp1.shape
    T = offsets.shape[1]
    for r in range(B):
        if tid[r] < 0 or tid[r] >= counts.shape[0]:
            raise ValueError(_UNTRAINED_TREE)
    F = feats.shape[1]
    n_in = iw1.shape[0]
    rel = np.empty(d)
    kpre = np.empty((max(knn, 1), H))
    scratch = np.empty(max(B, max(knn, 1)) * H + 4)
    # input MLP on [features / feature scale, (x - centre) / scale] (relative inputs: the features only)
    inp = np.zeros((B, n_in))
    for r in range(B):
        for c in range(F):
            inp[r, c] = feats[r, c] / feature_scale[c]
        if not relative_inputs:
            for c in range(d):
                inp[r, F + c] = (x[r, c] - center[c]) / scale[c]
    hid = np.dot(inp, iw1) + ib1
    _gelu_rows(hid)
    h = np.dot(hid, iw2) + ib2
    # causal k-NN: earlier nodes of the same tree, squared distance in step units, ties to the earlier node
    best_j, found = _kd_causal_knn(i0, x, tid, states, knn, periodic, step, kd)
    msg = np.zeros((B, H))
    for layer in range(L):
        # the rows' sender terms W_h h at this layer, for themselves and the rows after them
        for e in range(2):
            sender[layer, e, i0:i0 + B, :] = np.dot(h, w_sender[layer, e])
        # update MLP's first layer on [h, parent message, k-NN message]: its h block, then each
        # message's second layer fused with its block (an absent message adds nothing)
        hid = np.dot(h, uw1[layer]) + ub1[layer]
        # parent message: MLP([h_p, wrap(x_p - x) / step]), the first layer's h_p part cached
        # (a row without a parent keeps zeros, whose GELU is zero: one GELU call for the batch)
        msg[:, :] = 0.0
        for r in range(B):
            p = parent[r]
            if use_parent and p >= 0:
                _first_layer(msg[r], rel, sender[layer, 0, p], bp1[layer], states[p], x[r], periodic, wpx[layer])
                for c in range(H):
                    hid[r, c] += bpu[layer, c]
        _gelu_with(msg.reshape(B * H), scratch)
        hid += np.dot(msg, wpu[layer])
        # k-NN messages: the mean of the first layer's GELU over the neighbours (one GELU call per
        # row, summed over the neighbours in order), then the second layer
        msg[:, :] = 0.0
        for r in range(B):
            if found[r] > 0:
                for m in range(found[r]):
                    j = best_j[r, m]
                    _first_layer(kpre[m], rel, sender[layer, 1, j], bk1[layer], states[j], x[r], periodic, wkx[layer])
                _gelu_with(kpre[:found[r]].reshape(found[r] * H), scratch)
                for m in range(found[r]):
                    for c in range(H):
                        msg[r, c] += kpre[m, c]
                for c in range(H):
                    msg[r, c] /= found[r]
                    hid[r, c] += bku[layer, c]
        hid += np.dot(msg, wku[layer])
        _gelu_rows(hid)
        upd = np.dot(hid, uw2[layer]) + ub2[layer]
        _residual_layer_norm(upd, h, norm_g[layer], norm_b[layer], norm_eps[layer])
    # the node heads (the GNN sampler's mixture reads them) and the trees' embedding sums
    if heads:
        keys[i0:i0 + B, :] = np.dot(h, kw) + kb
        head = np.dot(h, hw) + hb
        for r in range(B):
            for a in range(T):
                for c in range(d):
                    offsets[i0 + r, a, c] = head[r, a * 2 * d + c] * step[c]
                    log_sigma[i0 + r, a, c] = min(max(head[r, a * 2 * d + d + c], -4.0), 1.0)
    for r in range(B):
        t = tid[r]
        for c in range(H):
            sums[t, c] += h[r, c]
        counts[t] += 1.0


@jit
def tree_context(ends, active, sums, counts, use_context, qw1, qb1, qw2, qb2):
    """The tree context ``q`` ``(H,)``: the query MLP on ``[ends, one-hot of the active tree, each
    tree's mean embedding (zeros without ``use_context``), log1p(node counts) / 5]`` (``ends``: the
    start and goal part, computed by the caller)."""
    T, H = sums.shape
    if active < 0 or active >= T:
        raise ValueError(_UNTRAINED_TREE)
    E = ends.shape[0]
    inp = np.zeros(E + T + T * H + T)
    inp[:E] = ends
    inp[E + active] = 1.0
    for t in range(T):
        inv = 1.0 / max(counts[t], 1.0)
        for c in range(H):
            inp[E + T + t * H + c] = sums[t, c] * inv if use_context else 0.0
        inp[E + T + T * H + t] = math.log1p(counts[t]) / 5.0
    hid = np.dot(inp, qw1) + qb1
    _gelu_into(hid)
    return np.dot(hid, qw2) + qb2


@jit
def node_mixture(keys, q, active, inv_temperature, shift_w, shift_b, step):
    """The GNN's node mixture at the ingested tree (``keys``: its rows): node probabilities
    ``softmax(keys . q / sqrt(H) / temperature)``, their running sums, and the active tree's
    component shift ``(d,)`` in state units."""
    n, H = keys.shape
    logits = np.dot(keys, q)
    scale = inv_temperature / math.sqrt(H)
    top = -np.inf
    for i in range(n):
        logits[i] *= scale
        top = max(top, logits[i])
    m4 = n + (-n) % 4
    e = np.empty(m4)                    # the exps four at a time (:func:`_exp4_inplace`)
    for i in range(n):
        e[i] = logits[i] - top
    for i in range(n, m4):
        e[i] = 0.0
    for i in range(0, m4, 4):
        _exp4_inplace(e, i)
    total = 0.0
    for i in range(n):
        logits[i] = e[i]
        total += logits[i]
    cumulative = np.empty(n)
    run = 0.0
    for i in range(n):
        logits[i] /= total
        run += logits[i]
        cumulative[i] = run
    d = step.shape[0]
    shift = np.dot(q, shift_w) + shift_b
    out = np.empty(d)
    for c in range(d):
        out[c] = shift[active * d + c] * step[c]
    return logits, cumulative, out


@jit
def draw_around_nodes(cumulative, shifts, rows, trees, r, z, states, offsets, log_sigma, sigma_scale, out):
    """The GNN's samples from node mixtures, per sample ``j``: the node of mixture ``rows[j]`` whose running
    sum first exceeds ``r[j] (1 - 1e-12)`` (numpy's ``searchsorted(..., "right")``, at most the last node),
    then ``out[j] = states[node] + offsets[node, trees[j]] + shifts[rows[j]] + sigma z[j]`` with ``sigma =
    sigma_scale exp(log_sigma[node, trees[j]])`` (per coordinate), summed in that order (numpy's,
    elementwise). One call for a batch, without numpy's dispatch: the node exactly numpy's, the state to
    an ulp (this ``exp`` is libm's; numpy's own vector ``exp``, on CPUs with AVX-512, can differ from it
    in the last bit), so the float32 actions made of it are numpy's but for a rounding boundary."""
    m, d = z.shape
    n = cumulative.shape[1]
    for j in range(m):
        row, tree = rows[j], trees[j]
        v = r[j] * (1 - 1e-12)
        lo, hi = 0, n
        while lo < hi:                  # the number of running sums <= v
            mid = (lo + hi) >> 1
            if cumulative[row, mid] <= v:
                lo = mid + 1
            else:
                hi = mid
        node = lo if lo < n - 1 else n - 1
        for c in range(d):
            sigma = sigma_scale * math.exp(log_sigma[node, tree, c])
            out[j, c] = states[node, c] + offsets[node, tree, c] + shifts[row, c] + sigma * z[j, c]


#: What each sample of a batch is (:func:`split_batch`): a uniform state, its tree's target, the model's.
UNIFORM_SAMPLE, TARGET_SAMPLE, MODEL_SAMPLE = 0, 1, 2


@jit
def split_batch(u, p_uniform, goal_bias, active, two_trees, kinds, trees):
    """The one mixture's choices for a batch: sample ``j`` is uniform when ``u[j] < p_uniform``, its tree's
    target below ``p_uniform + goal_bias``, else the model's (``kinds[j]``), for tree ``trees[j]``: BiRRT
    (``two_trees``) alternates from ``active``, RRT extends tree 0 (``batch_active_trees``' rule). Returns
    ``(uniform count, model count, whether tree 0's mixture is needed, whether tree 1's is)``."""
    k = u.shape[0]
    nu, nm, need0, need1 = 0, 0, False, False
    for j in range(k):
        t = (active + j) % 2 if two_trees else 0
        trees[j] = t
        if u[j] < p_uniform:
            kinds[j] = UNIFORM_SAMPLE
            nu += 1
        elif u[j] < p_uniform + goal_bias:
            kinds[j] = TARGET_SAMPLE
        else:
            kinds[j] = MODEL_SAMPLE
            nm += 1
            if t == 0:
                need0 = True
            else:
                need1 = True
    return nu, nm, need0, need1


@jit
def assemble_batch(kinds, trees, uniform, r, z, cumulative, shifts, mixture_of_tree, states, offsets, log_sigma,
                   sigma_scale, low, span, high, periodic, start, goal, out):
    """A GNN sampler's batch ``out`` ``(k, d)`` float32 in one call, in sample order: a uniform sample takes the
    next row of ``uniform`` (``low + span u``), a target sample its tree's target (the goal for tree 0, the
    start for tree 1), a model sample the next of ``r``/``z`` through :func:`draw_around_nodes` with its tree's
    mixture (``mixture_of_tree[tree]``: the row of ``cumulative``/``shifts``), then the periodic coordinates
    wrapped and the state clipped to ``[low, high]`` (``ModelSampler.finish``). The floats of the numpy steps
    of ``ModelSampler.act_batch`` and ``TreeGNNSampler.model_batch`` (the model's samples through
    :func:`draw_around_nodes`, as the general path's)."""
    k, d = out.shape
    iu, im = 0, 0
    x = np.empty((1, d))
    one = np.zeros(1, dtype=np.int64)
    tree = np.zeros(1, dtype=np.int64)
    for j in range(k):
        kind, t = kinds[j], trees[j]
        if kind == UNIFORM_SAMPLE:
            for c in range(d):
                out[j, c] = np.float32(low[c] + span[c] * uniform[iu, c])
            iu += 1
        elif kind == TARGET_SAMPLE:
            for c in range(d):
                out[j, c] = np.float32(goal[c] if t == 0 else start[c])
        else:
            one[0] = mixture_of_tree[t]
            tree[0] = t
            draw_around_nodes(cumulative, shifts, one, tree, r[im:im + 1], z[im:im + 1], states, offsets, log_sigma,
                              sigma_scale, x)
            im += 1
            for c in range(d):
                v = _wrapped(x[0, c], True) if periodic[c] else x[0, c]
                v = v if v >= low[c] or v != v else low[c]    # np.maximum, then np.minimum (NaN kept)
                v = v if v <= high[c] or v != v else high[c]
                out[j, c] = np.float32(v)


# ---------------------------------------------------------------------------- one call per step
#: The order of the weights packed by :func:`pack_weights` for :func:`mixture_after_rows` (the arguments
#: of :func:`embed_rows` after ``periodic``, then those of :func:`tree_context` and :func:`node_mixture`).
PACKED_WEIGHTS = ("step", "center", "scale", "feature_scale", "iw1", "ib1", "iw2", "ib2", "w_sender", "wpx", "bp1",
                  "wpu", "bpu", "wkx", "bk1", "wku", "bku", "uw1", "ub1", "uw2", "ub2", "norm_g", "norm_b",
                  "norm_eps", "kw", "kb", "hw", "hb", "qw1", "qb1", "qw2", "qb2", "shift_w", "shift_b")


def announce_compilation(dispatcher, what: str) -> bool:
    """:func:`gnn_mp_envs.utils.compiled.announce_compilation` for this module's loops (about 40 s to
    compile, cached next to this file)."""
    return announce_loop_compilation(dispatcher, what, "about 40 s", "agents/tree/compiled.py")


def pack_weights(arrays: dict) -> tuple[np.ndarray, np.ndarray]:
    """``(flat, layout)``: the arrays named in :data:`PACKED_WEIGHTS`, float64, one after the other in
    ``flat``, row ``i`` of ``layout`` their offset and shape (up to 4 axes, padded with 1). A compiled
    call's dispatch costs about 0.1 us per argument: two arrays instead of 34 (see :func:`mixture_after_rows`)."""
    parts, layout, offset = [], [], 0
    for name in PACKED_WEIGHTS:
        a = np.ascontiguousarray(arrays[name], dtype=np.float64)
        if a.ndim > 4:
            raise ValueError(f"weight {name} has {a.ndim} axes (at most 4 are packed)")
        layout.append([offset, *a.shape, *([1] * (4 - a.ndim))])
        parts.append(a.reshape(-1))
        offset += a.size
    return np.concatenate(parts), np.asarray(layout, dtype=np.int64)


@jit(inline=True)
def _w1(flat, layout, i):
    o = layout[i, 0]
    return flat[o:o + layout[i, 1]]


@jit(inline=True)
def _w2(flat, layout, i):
    o, a, b = layout[i, 0], layout[i, 1], layout[i, 2]
    return flat[o:o + a * b].reshape((a, b))


@jit(inline=True)
def _w3(flat, layout, i):
    o, a, b, c = layout[i, 0], layout[i, 1], layout[i, 2], layout[i, 3]
    return flat[o:o + a * b * c].reshape((a, b, c))


@jit(inline=True)
def _w4(flat, layout, i):
    o, a, b, c, e = layout[i, 0], layout[i, 1], layout[i, 2], layout[i, 3], layout[i, 4]
    return flat[o:o + a * b * c * e].reshape((a, b, c, e))


@jit(inline=True)
def _embed_new_rows(i0, n, nodes, node_features, parents, states, tree_id, sender, keys, offsets, log_sigma, sums,
                    counts, kd, periodic, flags, flat, layout):
    """:func:`embed_rows` of the observation's rows ``i0..n-1``, read from its arrays as they are
    (float32 states and features, integer parents), with the packed weights."""
    d = states.shape[1]
    F = node_features.shape[1]
    B = n - i0
    if B <= 0:
        return
    x = np.empty((B, d))
    feats = np.empty((B, F))
    tid = np.empty(B, dtype=np.int64)
    parent = np.empty(B, dtype=np.int64)
    for r in range(B):
        for c in range(d):
            x[r, c] = nodes[i0 + r, c]
            states[i0 + r, c] = x[r, c]
        for c in range(F):
            feats[r, c] = node_features[i0 + r, c]
        tid[r] = np.int64(feats[r, 2 * d])
        tree_id[i0 + r] = tid[r]
        parent[r] = parents[i0 + r]
    embed_rows(i0, x, feats, tid, parent, states, tree_id, sender, keys, offsets, log_sigma, sums, counts, kd,
               periodic, _w1(flat, layout, 0), _w1(flat, layout, 1), _w1(flat, layout, 2), _w1(flat, layout, 3),
               flags[0] != 0, flags[1], flags[2] != 0, flags[3] != 0,
               _w2(flat, layout, 4), _w1(flat, layout, 5), _w2(flat, layout, 6), _w1(flat, layout, 7),
               _w4(flat, layout, 8), _w3(flat, layout, 9), _w2(flat, layout, 10), _w3(flat, layout, 11),
               _w2(flat, layout, 12), _w3(flat, layout, 13), _w2(flat, layout, 14), _w3(flat, layout, 15),
               _w2(flat, layout, 16), _w3(flat, layout, 17), _w2(flat, layout, 18), _w3(flat, layout, 19),
               _w2(flat, layout, 20), _w2(flat, layout, 21), _w2(flat, layout, 22), _w1(flat, layout, 23),
               _w2(flat, layout, 24), _w1(flat, layout, 25), _w2(flat, layout, 26), _w1(flat, layout, 27))


@jit
def context_after_rows(i0, n, nodes, node_features, parents, states, tree_id, sender, keys, offsets, log_sigma, sums,
                       counts, kd, periodic, flags, flat, layout, ends, active):
    """The GNN-CVAE's forward up to its decoder in one compiled call: embed the observation's rows
    ``i0..n-1`` (nothing when ``n == i0``), then the tree context (:func:`tree_context`). ``flags``
    are ``(relative_inputs, knn, use_parent, heads, use_context)``, ``flat``/``layout`` the weights of
    :func:`pack_weights`; the same compiled functions, so the same floats as calling them one by one."""
    _embed_new_rows(i0, n, nodes, node_features, parents, states, tree_id, sender, keys, offsets, log_sigma, sums,
                    counts, kd, periodic, flags, flat, layout)
    return tree_context(ends, active, sums, counts, flags[4] != 0, _w2(flat, layout, 28), _w1(flat, layout, 29),
                        _w2(flat, layout, 30), _w1(flat, layout, 31))


@jit
def mixture_after_rows(i0, n, nodes, node_features, parents, states, tree_id, sender, keys, offsets, log_sigma, sums,
                       counts, kd, periodic, flags, flat, layout, ends, active, inv_temperature):
    """One GNN sampler step in one compiled call: :func:`context_after_rows`, then the node mixture
    (:func:`node_mixture`) of the grown tree: probabilities, their running sums and the shift."""
    q = context_after_rows(i0, n, nodes, node_features, parents, states, tree_id, sender, keys, offsets, log_sigma,
                           sums, counts, kd, periodic, flags, flat, layout, ends, active)
    return node_mixture(keys[:n], q, active, inv_temperature, _w2(flat, layout, 32), _w1(flat, layout, 33),
                        _w1(flat, layout, 0))


@jit
def mixtures_after_rows(i0, n, nodes, node_features, parents, states, tree_id, sender, keys, offsets, log_sigma, sums,
                        counts, kd, periodic, flags, flat, layout, ends, actives, inv_temperature):
    """A batch's forward in one compiled call: embed the observation's rows ``i0..n-1`` once, then the node
    mixture of each tree in ``actives`` (int64): running sums ``(len(actives), n)`` and shifts
    ``(len(actives), d)``. Row ``a`` is what :func:`mixture_after_rows` gives for tree ``actives[a]`` (the
    same compiled functions in the same order, so the same floats)."""
    _embed_new_rows(i0, n, nodes, node_features, parents, states, tree_id, sender, keys, offsets, log_sigma, sums,
                    counts, kd, periodic, flags, flat, layout)
    A, d = actives.shape[0], states.shape[1]
    cumulative = np.empty((A, n))
    shifts = np.empty((A, d))
    for a in range(A):
        q = tree_context(ends, actives[a], sums, counts, flags[4] != 0, _w2(flat, layout, 28), _w1(flat, layout, 29),
                         _w2(flat, layout, 30), _w1(flat, layout, 31))
        _, c, s = node_mixture(keys[:n], q, actives[a], inv_temperature, _w2(flat, layout, 32), _w1(flat, layout, 33),
                               _w1(flat, layout, 0))
        cumulative[a] = c
        shifts[a] = s
    return cumulative, shifts


# ---------------------------------------------------------------------------- the pendulum's scorer
@jit(inline=True)
def _sin_cos_into(out, r, o, v, cols):
    """``out[r, o:o+A]`` = ``sin(v[cols])`` and ``out[r, o+A:o+2A]`` = ``cos(v[cols])``: the angle features."""
    A = cols.shape[0]
    for a in range(A):
        out[r, o + a] = math.sin(v[cols[a]])
        out[r, o + A + a] = math.cos(v[cols[a]])


@jit(inline=True)
def _mlp2(x, w1, b1, w2, b2):
    """``Linear -> GELU -> Linear`` on rows ``x`` (``agents.nn.twins.mlp`` of two layers)."""
    hid = np.dot(x, w1) + b1
    _gelu_rows(hid)
    return np.dot(hid, w2) + b2


@jit
def scorer_embed_rows(i0, x, feats, tid, parent, goal, states, tree_id, depth, h, front, periodic, metric, angle_cols,
                      center, scale, feature_scale, step, depth_scale, knn, in_w1, in_b1, in_w2, in_b2, pc_w1, pc_b1,
                      pc_w2, pc_b2, kc_w1, kc_b1, kc_w2, kc_b2, up_w1, up_b1, up_w2, up_b2, norm_g, norm_b, norm_eps,
                      fr_w1, fr_b1, fr_w2, fr_b2):
    """:class:`~agents.tree.engine.IncrementalTreeScorer`'s per-node work for rows ``i0..i0+B-1`` in
    one compiled call (the numpy version was ~90 small array operations per call, ~0.7 ms): depth,
    the input MLP, the causal k-NN under the planner's metric (earlier nodes of the same tree, ties to
    the earlier node), the message-passing layers (each layer's embeddings cached in ``h``), and the
    frontier sums of every new edge (parent: type 0, k-NN: type 1) added to ``front`` in the numpy
    version's order. The states and trees of the rows are in ``states`` / ``tree_id`` already."""
    B, d = x.shape
    L = pc_w1.shape[0]
    H = in_w2.shape[1]
    F = feats.shape[1]
    A = angle_cols.shape[0]
    for r in range(B):
        p = parent[r]
        depth[i0 + r] = depth[p] + 1.0 if p >= 0 else 0.0
    # input MLP on [features, x, goal (centred, scaled), sin/cos of x's, the features' and the goal's angles, depth]
    n_in = F + 2 * d + 6 * A + 1
    inp = np.empty((B, n_in))
    for r in range(B):
        c0 = 0
        for c in range(F):
            inp[r, c0 + c] = feats[r, c] / feature_scale[c]
        c0 += F
        for c in range(d):
            inp[r, c0 + c] = (x[r, c] - center[c]) / scale[c]
        c0 += d
        for c in range(d):
            inp[r, c0 + c] = (goal[c] - center[c]) / scale[c]
        c0 += d
        _sin_cos_into(inp, r, c0, x[r], angle_cols)
        c0 += 2 * A
        _sin_cos_into(inp, r, c0, feats[r, d:], angle_cols)
        c0 += 2 * A
        _sin_cos_into(inp, r, c0, goal, angle_cols)
        c0 += 2 * A
        inp[r, c0] = depth[i0 + r] / depth_scale
    hb = _mlp2(inp, in_w1, in_b1, in_w2, in_b2)
    h[0, i0:i0 + B, :] = hb
    # causal k-NN under the planner's metric
    near, found = _causal_knn(i0, x, tid, states, tree_id, knn, periodic, metric, True)
    # relative positions of parents and neighbours, in step units
    rel_p = np.zeros((B, d))
    for r in range(B):
        p = parent[r] if parent[r] >= 0 else 0
        for c in range(d):
            rel_p[r, c] = _wrapped(states[p, c] - x[r, c], periodic[c]) / step[c]
    E = 0
    for r in range(B):
        E += found[r]
    for layer in range(L):
        # parent messages
        pin = np.empty((B, H + d))
        for r in range(B):
            p = parent[r] if parent[r] >= 0 else 0
            for c in range(H):
                pin[r, c] = h[layer, p, c]
            for c in range(d):
                pin[r, H + c] = rel_p[r, c]
        mp = _mlp2(pin, pc_w1[layer], pc_b1[layer], pc_w2[layer], pc_b2[layer])
        for r in range(B):
            if parent[r] < 0:
                for c in range(H):
                    mp[r, c] = 0.0
        # k-NN messages, averaged over each row's neighbours
        mk = np.zeros((B, H))
        if E > 0:
            kin = np.empty((E, H + d))
            e = 0
            for r in range(B):
                for m in range(found[r]):
                    j = near[r, m]
                    for c in range(H):
                        kin[e, c] = h[layer, j, c]
                    for c in range(d):
                        kin[e, H + c] = _wrapped(states[j, c] - x[r, c], periodic[c]) / step[c]
                    e += 1
            msg = _mlp2(kin, kc_w1[layer], kc_b1[layer], kc_w2[layer], kc_b2[layer])
            e = 0
            for r in range(B):
                for m in range(found[r]):
                    for c in range(H):
                        mk[r, c] += msg[e, c]
                    e += 1
                if found[r] > 0:
                    for c in range(H):
                        mk[r, c] /= found[r]
        # update MLP on [h, parent message, k-NN message], residual, LayerNorm
        uin = np.empty((B, 3 * H))
        for r in range(B):
            for c in range(H):
                uin[r, c] = hb[r, c]
                uin[r, H + c] = mp[r, c]
                uin[r, 2 * H + c] = mk[r, c]
        upd = _mlp2(uin, up_w1[layer], up_b1[layer], up_w2[layer], up_b2[layer])
        _residual_layer_norm(upd, hb, norm_g[layer], norm_b[layer], norm_eps[layer])
        h[layer + 1, i0:i0 + B, :] = hb
    # frontier: each new row is a newer node pointing at its parent (type 0), then at its neighbours (type 1)
    n_par = 0
    for r in range(B):
        if parent[r] >= 0:
            n_par += 1
    Q = n_par + E
    if Q == 0:
        return
    senders = np.empty(Q, dtype=np.int64)
    receivers = np.empty(Q, dtype=np.int64)
    etype = np.empty(Q, dtype=np.int64)
    q = 0
    for r in range(B):
        if parent[r] >= 0:
            senders[q], receivers[q], etype[q] = r, parent[r], 0
            q += 1
    for r in range(B):
        for m in range(found[r]):
            senders[q], receivers[q], etype[q] = r, near[r, m], 1
            q += 1
    fin = np.zeros((Q, H + d + 2))
    for q in range(Q):
        r, j = senders[q], receivers[q]
        for c in range(H):
            fin[q, c] = hb[r, c]
        for c in range(d):
            fin[q, H + c] = _wrapped(x[r, c] - states[j, c], periodic[c]) / step[c]
        fin[q, H + d + etype[q]] = 1.0
    phi = _mlp2(fin, fr_w1, fr_b1, fr_w2, fr_b2)
    for q in range(Q):
        j = receivers[q]
        for c in range(H):
            front[j, c] += phi[q, c]
        front[j, H + etype[q]] += 1.0



@jit
def scorer_candidate_logits(cands, n, active, multi_tree, states, tree_id, h_last, front, goal, periodic, weights,
                            unit, scale, center, angle_cols, w1, b1, w2, b2, w3, b3):
    """The pendulum scorer's candidate head in one compiled call (:meth:`IncrementalTreeScorer.nearest`
    then :meth:`~agents.tree.engine.IncrementalTreeScorer.logits`, whose ~40 numpy operations cost
    ~0.25 ms per sampler step): each candidate's nearest node of tree ``active`` under the planner's
    metric (the first of equals), its features relative to that node and the goal, the node's
    embedding and frontier statistics, then the head ``Linear -> GELU -> Linear -> GELU -> Linear``.
    The same operations in the same order as the numpy head, but the GELU's ``erf`` is glibc's
    vector ``erf`` (or libm's; scipy's there) and the products go through numba's BLAS: equal to
    ~1e-13 (``tests/test_tree_scorer.py``). Returns the logits ``(M,)``."""
    M, d = cands.shape
    H = h_last.shape[1]
    A = angle_cols.shape[0]
    two_pi = 2.0 * math.pi
    near = np.empty(M, dtype=np.int64)
    for i in range(M):
        best, best_d = -1, 0.0
        for j in range(n):
            if multi_tree and tree_id[j] != active:
                continue
            s = 0.0
            for c in range(d):
                v = abs(cands[i, c] - states[j, c])
                if periodic[c]:
                    v = min(v, two_pi - v)
                v *= weights[c]
                s += v * v
            if best < 0 or s < best_d:
                best, best_d = j, s
        near[i] = best
    T = front.shape[1] - H
    width = 2 * H + T + 3 * d + 1 + 4 * A
    z = np.empty((M, width))
    rel = np.empty(d)
    to_goal = np.empty(d)
    for i in range(M):
        j = near[i]
        ss = 0.0
        for c in range(d):
            rel[c] = _wrapped(cands[i, c] - states[j, c], periodic[c])
            to_goal[c] = _wrapped(goal[c] - cands[i, c], periodic[c])
            v = weights[c] * rel[c]
            ss += v * v
        csum = 0.0
        for t in range(T):
            csum += front[j, H + t]
        for c in range(H):
            z[i, c] = h_last[j, c]
            z[i, H + c] = front[j, c] / (1.0 + csum)
        o = 2 * H
        for t in range(T):
            z[i, o + t] = math.log1p(front[j, H + t])
        o += T
        for c in range(d):
            z[i, o + c] = rel[c] / scale[c]
        o += d
        z[i, o] = math.sqrt(ss) / unit
        o += 1
        for c in range(d):
            z[i, o + c] = to_goal[c] / scale[c]
        o += d
        for c in range(d):
            z[i, o + c] = (cands[i, c] - center[c]) / scale[c]
        o += d
        _sin_cos_into(z, i, o, cands[i], angle_cols)
        o += 2 * A
        _sin_cos_into(z, i, o, to_goal, angle_cols)
    hid = np.dot(z, w1) + b1
    _gelu_rows(hid)
    hid = np.dot(hid, w2) + b2
    _gelu_rows(hid)
    out = np.dot(hid, w3) + b3
    return out[:, 0]

__all__ = ["PACKED_WEIGHTS", "context_after_rows", "embed_rows", "mixture_after_rows", "mixtures_after_rows", "node_mixture", "pack_weights", "scorer_candidate_logits", "scorer_embed_rows",
           "tree_context"]
