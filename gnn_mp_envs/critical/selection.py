"""Choosing k planning samples from a model's output, with diversity: no two within ``min_sep``.

Three sources, one rule (a chosen state is never within ``min_sep`` of an earlier one):

* :func:`top_k_diverse`: node scores over the fixed graph -> the best-scoring nodes, greedily
  (non-maximum suppression): the highest score first, then the highest one farther than
  ``min_sep`` from every chosen node, and so on;
* :func:`sample_k_diverse`: the same, but each node is drawn from the (renormalised) node
  distribution instead of taken greedily;
* :func:`first_k_diverse`: decoded samples of a generative model, kept in draw order.

Fewer than ``k`` states come back when the candidates run out (e.g. a CVAE whose samples all
lie within ``min_sep`` of each other). Numpy only, like the rest of this package.
"""

from __future__ import annotations

import numpy as np


def _far_enough(chosen: list[int] | np.ndarray, points: np.ndarray, candidate: np.ndarray, min_sep: float) -> bool:
    if len(chosen) == 0:
        return True
    d2 = ((points[np.asarray(chosen)] - candidate) ** 2).sum(-1)
    return bool((d2 > min_sep ** 2).all())


def top_k_diverse(scores: np.ndarray, points: np.ndarray, k: int, min_sep: float) -> np.ndarray:
    """Indices of up to ``k`` highest-scoring points, no two within ``min_sep`` (greedy NMS).

    Ties go to the lower index (a stable sort), so the result is deterministic.
    """
    if k <= 0:
        return np.zeros(0, np.int64)
    order = np.argsort(-np.asarray(scores, dtype=np.float64), kind="stable")
    chosen: list[int] = []
    for i in order:
        if _far_enough(chosen, points, points[i], min_sep):
            chosen.append(int(i))
            if len(chosen) == k:
                break
    return np.array(chosen, dtype=np.int64)


def sample_k_diverse(log_probs: np.ndarray, points: np.ndarray, k: int, min_sep: float,
                     rng: np.random.Generator) -> np.ndarray:
    """Indices of up to ``k`` points drawn one at a time from ``softmax(log_probs)``; after each
    draw every point within ``min_sep`` of it is removed and the rest renormalised."""
    logp = np.asarray(log_probs, dtype=np.float64)
    alive = np.isfinite(logp)
    chosen: list[int] = []
    while len(chosen) < k and alive.any():
        lp = np.where(alive, logp, -np.inf)
        p = np.exp(lp - lp.max())
        p /= p.sum()
        i = int(rng.choice(len(p), p=p))
        chosen.append(i)
        alive &= ((points - points[i]) ** 2).sum(-1) > min_sep ** 2
    return np.array(chosen, dtype=np.int64)


def first_k_diverse(samples: np.ndarray, k: int, min_sep: float) -> np.ndarray:
    """Up to ``k`` of ``samples`` (M, d) in draw order, skipping any within ``min_sep`` of a kept one."""
    kept: list[int] = []
    for i in range(len(samples)):
        if len(kept) == k:
            break
        if _far_enough(kept, samples, samples[i], min_sep):
            kept.append(i)
    return samples[np.array(kept, dtype=np.int64)] if kept else samples[:0]
