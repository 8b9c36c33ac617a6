"""Candidate search with k-d trees: every point that could be the nearest, and few more."""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree


def tree_candidates(tree: cKDTree, q: np.ndarray, radius_of, measure=None, k: int = 16):
    """(query, tree point) pairs within a search radius of each query.

    The radius is `radius_of(bound)`, where `bound` is the smallest exact
    measure (`measure(query_index, point_index)`) over the k tree points
    nearest to the query, or the distance to the nearest point when no
    measure is given. The k nearest points usually contain every point within
    the radius; queries where they might not fall back to a ball search.
    """
    k = min(k, tree.n)
    dist, which = tree.query(q, k=k)
    dist, which = dist.reshape(len(q), k), which.reshape(len(q), k)
    if measure is None:
        bound = dist[:, 0]
    else:
        rows = np.repeat(np.arange(len(q)), k)
        bound = np.asarray(measure(rows, which.reshape(-1)), np.float64).reshape(len(q), k).min(axis=1)
    radius = radius_of(bound)
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
