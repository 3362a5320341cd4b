"""The `k` nearest neighbours of each point in the order nanoflann's kd-tree returns them, ties included.

robust_laplacian (geometry-central `NearestNeighborFinder`) finds neighbours with nanoflann's (1.7)
`KDTreeSingleIndexAdaptor` (leaves of at most 10 points). Its order among neighbours at *equal*
distances, and which of them it keeps at the `k`-th place, is its search's: a found point is
inserted after those at the same distance already held, and one only as far as the current `k`-th is
not taken, so among ties the first visited comes first. The visiting order is a depth-first walk of
the tree, the child on the query's side of the cut first, each leaf in its slot order. Duplicated
points (every other point sees the copies at one distance) and regular grids tie this way, and the
order decides the local triangles there (`_triangulation.local_triangles`).

So the tree is rebuilt as nanoflann builds it (`middleSplit_`: the cut along the widest spread among
the dimensions whose box span is within `1e-5` of the widest, at the box's middle clamped to the
points; `planeSplit`'s two in-place partitions, `<`, `==`, `>` the cut; the balanced index), and the
neighbours found by SciPy's `cKDTree` are sorted by nanoflann's squared distance
`((dx^2 + dy^2) + dz^2)` then by that visiting order: at the deepest cut separating two points, the
one on the query's side first (`(q - divlow) + (q - divhigh) < 0` chooses the low child), then the
slot in the leaf. Rows without equal distances need none of it: the tree is built only where some row
ties, and only the tied candidates are ordered by it.

Reference: nanoflann (github.com/jlblancoc/nanoflann) `KDTreeBaseClass::divideTree`, `middleSplit_`,
`planeSplit`, `KDTreeSingleIndexAdaptor::searchLevel`, `KNNResultSet::addPoint`.
"""

from __future__ import annotations

import numpy as np
import scipy.spatial

_LEAF_SIZE = 10
_SPAN_EPS = 1e-5
# Candidates beyond the k + 1 asked for, so that ties at the last place are seen (more are fetched where not).
_EXTRA = 8


def nanoflann_neighbors(points: np.ndarray, k: int) -> np.ndarray:
    """`(n, k + 1)` each point's `k + 1` nearest points (itself among them), in nanoflann's order (module docstring)."""
    n = points.shape[0]
    m = min(k + 1 + _EXTRA, n)
    search = scipy.spatial.cKDTree(points)
    _, candidates = search.query(points, k=m, workers=-1)
    candidates = candidates.reshape(n, m)
    distance_sq = _distance_sq(points, points[candidates])
    order = np.argsort(distance_sq, axis=1, kind="stable")
    candidates, distance_sq = np.take_along_axis(candidates, order, axis=1), np.take_along_axis(distance_sq, order, axis=1)
    # Only rows with equal distances among their first k + 2 need the tree's visiting order.
    tied = np.flatnonzero(np.any(distance_sq[:, 1 : k + 2] == distance_sq[:, : min(k + 1, m - 1)], axis=1))
    result = candidates[:, : k + 1].copy()
    if tied.size == 0:
        return result
    tree = _Tree(points)
    result[tied] = tree.visit_sorted(points[tied], candidates[tied], distance_sq[tied])[:, : k + 1]
    if m < n:
        # A tie at the (k+1)-th place that reaches the last candidate may hold more points than were fetched.
        for row in tied[distance_sq[tied, k] >= distance_sq[tied, -1]]:
            radius = np.sqrt(distance_sq[row, k]) * (1.0 + 1e-12)
            around = np.asarray(search.query_ball_point(points[row], radius), dtype=np.int64)[None, :]
            around_sq = _distance_sq(points[[row]], points[around])
            result[row] = tree.visit_sorted(points[[row]], around, around_sq)[0, : k + 1]
    return result


def _distance_sq(queries: np.ndarray, found: np.ndarray) -> np.ndarray:
    """`(n, m)` squared distances from `queries` `(n, 3)` to `found` `(n, m, 3)`, summed as nanoflann's L2 adaptor."""
    difference = queries[:, None, :] - found
    return (
        difference[..., 0] * difference[..., 0]
        + difference[..., 1] * difference[..., 1]
        + difference[..., 2] * difference[..., 2]
    )


class _Tree:
    """nanoflann's kd-tree of `points` (module docstring): each point's slot and its root-to-leaf path of cuts."""

    def __init__(self, points: np.ndarray):
        self.points = points
        n = points.shape[0]
        self.slots = np.arange(n)  # nanoflann's vAcc_: the point in each slot
        self.cut_dimension: list[int] = []
        self.cut_low: list[float] = []
        self.cut_high: list[float] = []
        self.ranges: list[tuple[int, int, int, int]] = []  # (first slot, middle, end, depth) of each cut
        box = np.stack([points.min(axis=0), points.max(axis=0)], axis=1)
        self._divide(0, n, box, 0)
        depth = 1 + max((r[3] for r in self.ranges), default=0)
        self.path_cut = np.full((n, depth), -1, dtype=np.int64)
        self.path_low = np.zeros((n, depth), dtype=bool)
        for cut, (first, middle, end, level) in enumerate(self.ranges):
            held = self.slots[first:end]
            self.path_cut[held, level] = cut
            self.path_low[held, level] = np.arange(first, end) < middle
        self.slot_of = np.empty(n, dtype=np.int64)
        self.slot_of[self.slots] = np.arange(n)

    def _divide(self, first: int, end: int, box: np.ndarray, level: int) -> np.ndarray:
        """Split slots `[first, end)` inside `box` `(3, 2)` as nanoflann's `divideTree`; returns the points' tight box."""
        held = self.points[self.slots[first:end]]
        if end - first <= _LEAF_SIZE:
            return np.stack([held.min(axis=0), held.max(axis=0)], axis=1)
        spans = box[:, 1] - box[:, 0]
        dimension, spread, low, high = 0, -1.0, 0.0, 0.0
        for i in range(3):
            if spans[i] >= (1 - _SPAN_EPS) * spans.max():
                values = held[:, i]
                if values.max() - values.min() > spread:
                    dimension, spread, low, high = i, values.max() - values.min(), values.min(), values.max()
        cut = min(max((box[dimension, 0] + box[dimension, 1]) / 2, low), high)
        values = held[:, dimension]
        below = self._partition(first, end, values < cut)
        equal = self._partition(first + below, end, self.points[self.slots[first + below : end], dimension] <= cut)
        count = end - first
        middle = below if below > count // 2 else (below + equal if below + equal < count // 2 else count // 2)
        index = len(self.ranges)
        self.ranges.append((first, first + middle, end, level))
        self.cut_dimension.append(dimension)
        self.cut_low.append(0.0)
        self.cut_high.append(0.0)
        low_box, high_box = box.copy(), box.copy()
        low_box[dimension, 1] = cut
        high_box[dimension, 0] = cut
        low_tight = self._divide(first, first + middle, low_box, level + 1)
        high_tight = self._divide(first + middle, end, high_box, level + 1)
        self.cut_low[index], self.cut_high[index] = low_tight[dimension, 1], high_tight[dimension, 0]
        return np.stack([np.minimum(low_tight[:, 0], high_tight[:, 0]), np.maximum(low_tight[:, 1], high_tight[:, 1])], axis=1)

    def _partition(self, first: int, end: int, goes_low: np.ndarray) -> int:
        """`planeSplit`'s in-place Hoare partition of slots `[first, end)` by `goes_low`; returns the low count.

        Its scans swap the i-th misplaced slot from the left with the i-th from the right while the first
        lies before the second.
        """
        misplaced_left = np.flatnonzero(~goes_low)
        misplaced_right = np.flatnonzero(goes_low)[::-1]
        pairs = min(misplaced_left.size, misplaced_right.size)
        swapped = misplaced_left[:pairs] < misplaced_right[:pairs]
        a, b = first + misplaced_left[:pairs][swapped], first + misplaced_right[:pairs][swapped]
        self.slots[a], self.slots[b] = self.slots[b], self.slots[a].copy()
        return int(np.count_nonzero(goes_low))

    def visit_sorted(self, queries: np.ndarray, candidates: np.ndarray, distance_sq: np.ndarray) -> np.ndarray:
        """`candidates` `(n, m)` of each query sorted by squared distance, ties in the order the search visits them."""
        tied = np.zeros(candidates.shape, dtype=bool)
        ordered = np.sort(distance_sq, axis=1)
        repeated = ordered[:, 1:] == ordered[:, :-1]
        # Only candidates sharing their distance with another need the visiting order.
        repeated_values = np.where(repeated, ordered[:, 1:], np.nan)
        tied = np.any(distance_sq[:, :, None] == repeated_values[:, None, :], axis=2)
        row, column = np.nonzero(tied)
        cuts = self.path_cut[candidates[row, column]]  # (t, depth)
        known = cuts >= 0
        cuts = np.where(known, cuts, 0)
        value = queries[row[:, None], np.asarray(self.cut_dimension, dtype=np.int64)[cuts]]
        query_low = (value - np.asarray(self.cut_low)[cuts]) + (value - np.asarray(self.cut_high)[cuts]) < 0
        # 1 where the candidate lies on the side the search takes second: its leaves come later.
        later = known & (self.path_low[candidates[row, column]] != query_low)
        # The visiting order as one integer per candidate: its bits from the root down (depths stay far below 63).
        weights = np.left_shift(1, np.arange(cuts.shape[1] - 1, -1, -1, dtype=np.int64))
        visit = np.zeros(candidates.shape, dtype=np.int64)
        slot = np.zeros(candidates.shape, dtype=np.int64)
        visit[row, column] = np.sum(later * weights, axis=1)
        slot[row, column] = self.slot_of[candidates[row, column]]
        return np.take_along_axis(candidates, np.lexsort((slot, visit, distance_sq), axis=1), axis=1)
