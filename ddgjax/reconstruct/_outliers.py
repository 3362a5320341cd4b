"""Statistical outlier rejection of a point cloud before it is splatted: the points far from their neighbours.

Each point's mean distance `d_i` to its `k` nearest other points (SciPy's `cKDTree` on every core: the
mean distance does not depend on the order of ties, so the point-cloud package's slower nanoflann-ordered
tree is not needed) is compared with their mean `mu` and standard deviation `sigma` over the cloud
(`sigma` with `n - 1`); a point with `d_i > mu + std_ratio sigma` is an outlier (PCL's
`StatisticalOutlierRemoval`, Open3D's `remove_statistical_outlier(nb_neighbors, std_ratio)`). Points sampled from a surface have neighbours at
about the sampling distance; points scattered through the volume around it have their nearest ones much
farther, so they stand out of the distribution. The selection is a host-side mask, piecewise constant in the
points: what is computed from the kept points stays differentiable in them, with zero gradient to the dropped.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from .._errors import DDGInputError


def check_std_ratio(std_ratio) -> float | None:
    """`std_ratio` as a positive float, or `None` (no rejection)."""
    if std_ratio is None:
        return None
    value = float(std_ratio)
    if not value > 0 or not np.isfinite(value):
        raise DDGInputError(f"outlier_std_ratio: expected a positive finite number or None, got {std_ratio!r}")
    return value


def statistical_inliers(points: np.ndarray, n_neighbors: int, std_ratio: float) -> np.ndarray:
    """`(n,)` bool: the points whose mean distance to their `n_neighbors` nearest others is at most
    `mu + std_ratio sigma` of those means (module docstring). `points` host `(n, 3)`, `n > n_neighbors`."""
    # The point itself is its own nearest (at distance 0, as is any coincident twin it may swap with).
    distances, _ = cKDTree(points).query(points, k=n_neighbors + 1, workers=-1)
    mean_distance = distances[:, 1:].mean(axis=1)
    threshold = mean_distance.mean() + std_ratio * mean_distance.std(ddof=1)
    return mean_distance <= threshold
