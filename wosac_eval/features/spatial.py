"""Candidate search with k-d trees: every point that could be the nearest, and few more."""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree


def tree_candidates(tree: cKDTree, q: np.ndarray, radius_of):
    """(query, tree point) pairs within `radius_of(nearest distance)` of each query.

    The k nearest points usually contain them all; queries where they might
    not fall back to a ball search.
    """
    k = min(16, tree.n)
    dist, which = tree.query(q, k=k)
    dist, which = dist.reshape(len(q), k), which.reshape(len(q), k)
    radius = radius_of(dist[:, 0])
    within = dist <= radius[:, None]
    complete = ~within[:, -1] | (k == tree.n)
    take = within & complete[:, None]
    qi, pi = np.nonzero(take)[0], which[take]
    rest = np.flatnonzero(~complete)
    if rest.size:
        lists = tree.query_ball_point(q[rest], radius[rest])
        qi = np.concatenate([qi, np.repeat(rest, [len(l) for l in lists])])
        pi = np.concatenate([pi, np.concatenate([np.asarray(l, np.int64) for l in lists])])
    return qi, pi
