"""Intrinsic edge flips on the host: Lawson's algorithm in rounds, mollification, the flat-quad diagonal, the replay layout.

The host half of `ddgjax.laplacian._intrinsic` (its module docstring has the method and references),
shared with the tufted cover (`ddgjax.laplacian._tufted`), which flips its own corner tables the same
way. `mollified` and `diagonal_after_flip` take the array library as arguments, so the replay in JAX
(`ddgjax.laplacian._intrinsic.replayed_lengths_sq`) computes exactly what the host decided on.
"""

from __future__ import annotations

import numpy as np

from ..mesh import MeshTopology

# An edge is flipped when cot a + cot b < -DELAUNAY_TOLERANCE * (the sum of the six cotangents of its
# two faces, the scale of the test's rounding error; `_delaunay_defects`): a co-circular quad (a + b = pi
# on both diagonals) could otherwise be flipped back and forth by rounding. So a weight left negative
# is at most this tolerance times that sum, in size.
DELAUNAY_TOLERANCE = 1e-12


def mollified(lengths_sq, face_edges, mollify_factor: float, xp, sqrt, take):
    """Squared edge lengths after intrinsic mollification (module docstring), in NumPy (`xp=np`) or JAX.

    `lengths_sq` per mesh edge, `face_edges` `(nf, 3)` the edges of each face; `sqrt` and `take` are
    the array library's (NaN-safe ones in JAX). `l_C - l_A - l_B` is largest at a face's longest
    edge, where it is `2 l_max - (l_A + l_B + l_C)`. Unchanged (exactly) where `delta = 0`.
    """
    if mollify_factor == 0:
        return lengths_sq
    lengths = sqrt(lengths_sq)
    face_lengths = take(lengths, face_edges)
    slack = xp.max(2.0 * xp.max(face_lengths, axis=1) - xp.sum(face_lengths, axis=1))
    delta = xp.maximum(slack + mollify_factor * xp.mean(lengths), 0.0)
    return xp.where(delta > 0, (lengths + delta) ** 2, lengths_sq)


def diagonal_after_flip(quad_lengths_sq, face_areas, divide, stack):
    """Squared length of the other diagonal `ij` of the quad `(i, a, j, b)` laid flat (formula in `intrinsic_delaunay`).

    `quad_lengths_sq` is `(ab, ia, ib, ja, jb)`, squared lengths; `face_areas` maps `(n, 3)` squared
    lengths to areas, `divide` and `stack` are the array library's (NumPy on the host; the NaN-safe
    JAX ones in the replay). With `a` at the origin and `b` on the x axis, `i` and `j` lie at
    `(n_i, -4 A_i) / (2 l_ab)` and `(n_j, 4 A_j) / (2 l_ab)`: a sum of squares, so no cancellation.
    """
    ab, ia, ib, ja, jb = quad_lengths_sq
    areas = face_areas(stack([ab, ia, ib], 1)) + face_areas(stack([ab, ja, jb], 1))
    return divide((ia - ib - ja + jb) ** 2 + 16.0 * areas**2, 4.0 * ab)


def replay_layout(rounds: list[np.ndarray], face_edges: np.ndarray, n_edges: int) -> tuple[np.ndarray, np.ndarray]:
    """`(flip_slots, face_length_slots)` of `IntrinsicTriangulation` from the rounds of `[ab, ia, ib, ja, jb]` edge indices.

    A round is cut into steps of `width` flips, `width` the power of two at or above 1/32 of all
    flips (at least 16): rounds shrink fast (most flips happen in the first), so the padding of each
    round's last step stays a few percent, and a step costs about as much as its padded width. The
    step count is padded to a multiple of 8, so that flip sequences of similar sizes (the same mesh
    moved a little) share a compiled replay.
    """
    n_flips = sum(quads.shape[0] for quads in rounds)
    width = 1 << max(4, int(np.ceil(np.log2(max(n_flips, 1) / 32))))
    steps_per_round = [-(-quads.shape[0] // width) for quads in rounds]
    n_steps = sum(steps_per_round)
    padded_steps = np.zeros((-(-n_steps // 8) * 8, width, 5), dtype=np.int32)
    slot_of_edge = np.arange(n_edges, dtype=np.int32)  # where each edge's current length is
    step = 0
    for quads, n_round_steps in zip(rounds, steps_per_round):
        block = padded_steps[step : step + n_round_steps].reshape(-1, 5)
        block[: quads.shape[0]] = slot_of_edge[quads]
        slot_of_edge[quads[:, 0]] = n_edges + step * width + np.arange(quads.shape[0], dtype=np.int32)
        step += n_round_steps
    return np.ascontiguousarray(padded_steps.transpose(0, 2, 1)), slot_of_edge[face_edges]


def _host_face_areas(lengths_sq: np.ndarray) -> np.ndarray:
    """Kahan's Heron formula in NumPy (as `face_areas_from_lengths_sq`), for the flip decisions on the host."""
    x, y, z = np.sqrt(np.maximum(lengths_sq, 0.0)).T
    a, c = np.maximum(np.maximum(x, y), z), np.minimum(np.minimum(x, y), z)  # sorted without a sort: a >= b >= c
    b = (x + y + z) - a - c
    product = (a + (b + c)) * (c - (a - b)) * (c + (a - b)) * (a + (b - c))
    return 0.25 * np.sqrt(np.maximum(product, 0.0))


def _host_divide(numerator: np.ndarray, denominator: np.ndarray) -> np.ndarray:
    return np.divide(numerator, denominator, out=np.zeros_like(numerator), where=denominator != 0)


def _delaunay_defects(
    corners: np.ndarray, twins: np.ndarray, face_edges: np.ndarray, lengths_sq: np.ndarray, weight_tolerance: float | None = None
) -> np.ndarray:
    """How far each edge (a corner and its twin) is from Delaunay: `> 0` means flip it, larger is worse.

    With `n = l_{k+1}^2 + l_{k+2}^2 - l_k^2 = 4 A cot(alpha)` at each of the two opposite corners,
    `cot a + cot b = (n_f A_g + A_f n_g) / (4 A_f A_g)`: the numerator has its sign and needs no
    division (so a zero-area face with a straight angle opposite the edge counts as non-Delaunay). That sum is compared with its rounding error, `DELAUNAY_TOLERANCE (s_f A_g + A_f s_g)`
    with `s` the sum of a face's squared lengths (`s / (4 A)` is the sum of its cotangents). With
    `weight_tolerance`, the edge's weight `(cot a + cot b) / 2` is compared with `-weight_tolerance`
    instead (geometry-central `flipToDelaunay`'s `delaunayEPS`): `> 0` where
    `-(n_f A_g + A_f n_g) > 8 weight_tolerance A_f A_g`.
    """
    values = []
    for corner in (corners, twins):
        face, k = np.divmod(corner, 3)
        face_lengths_sq = lengths_sq[face_edges[face]]
        opposite = np.take_along_axis(face_lengths_sq, k[:, None], axis=1)[:, 0]
        total = face_lengths_sq.sum(axis=1)
        values.append((total - 2.0 * opposite, total, _host_face_areas(face_lengths_sq)))
    (n_f, s_f, area_f), (n_g, s_g, area_g) = values
    if weight_tolerance is not None:
        return -(n_f * area_g + area_f * n_g) - 8.0 * weight_tolerance * area_f * area_g
    return -(n_f * area_g + area_f * n_g) - DELAUNAY_TOLERANCE * (s_f * area_g + area_f * s_g)


def flip_to_delaunay(
    topology: MeshTopology, lengths_sq: np.ndarray, *, weight_tolerance: float | None = None
) -> tuple[np.ndarray, np.ndarray, list[np.ndarray]]:
    """Lawson flips in rounds of independent flips (module docstring); `lengths_sq` per edge is updated in place.

    `weight_tolerance`: flip only edges whose cotan weight is below `-weight_tolerance` (absolute, as
    geometry-central's `delaunayEPS`), rather than below the rounding-sized `DELAUNAY_TOLERANCE`.

    The connectivity is a corner table: `faces` and `face_edges` `(nf, 3)`, and `twins[3 f + k]` the
    corner across the edge opposite corner `k` of face `f` (`-1` on the boundary). On a consistently
    oriented mesh the twin `3 g + m` of `3 f + k` runs the edge the other way:
    `faces[g, m+1] = faces[f, k+2]`, `faces[g, m+2] = faces[f, k+1]`; flips keep that, so everything
    below goes by corner positions, never by vertex indices (which a Delta-complex may repeat).

    Returns `(faces, face_edges, flips)`, `flips` one `(n_r, 5)` array `[ab, ia, ib, ja, jb]` per round.
    """
    faces = topology.faces.astype(np.int64)
    face_edges = topology.face_edges.astype(np.int64)
    n_corners = faces.size
    twins = np.full(n_corners, -1, dtype=np.int64)
    interior = np.flatnonzero(topology.edge_face_counts == 2)
    first, second = (
        3 * topology.edge_faces[interior, s].astype(np.int64) + topology.edge_face_corners[interior, s] for s in (0, 1)
    )
    twins[first], twins[second] = second, first
    # Scratch arrays reset after each round: the best candidate claiming each corner, and where a flip moves each corner.
    claims = np.full(n_corners, -1, dtype=np.int64)
    moved_to = np.arange(n_corners, dtype=np.int64)
    candidates = np.minimum(first, second)
    flips = []
    max_rounds = 100 * n_corners + 1000  # Lawson's algorithm terminates; this only stops a rounding cycle
    while candidates.size:
        if len(flips) > max_rounds:
            raise RuntimeError(f"intrinsic_delaunay: no convergence after {max_rounds} rounds of flips (please report this mesh)")
        defects = _delaunay_defects(candidates, twins[candidates], face_edges, lengths_sq, weight_tolerance)
        bad = defects > 0
        # A corner whose twin lies in the same face (an edge with one face on both sides) is always Delaunay.
        bad &= candidates // 3 != twins[candidates] // 3
        if not bad.any():
            break
        corners, defects = candidates[bad], defects[bad]
        twin_corners = twins[corners]
        # Each face goes to its most violating candidate edge (ties by position): those edges share no face.
        rank = np.empty(corners.size, dtype=np.int64)
        rank[np.argsort(defects, kind="stable")] = np.arange(corners.size)
        claims[corners], claims[twin_corners] = rank, rank
        face_claims = claims.reshape(-1, 3)
        wins = (face_claims[corners // 3].max(axis=1) == rank) & (face_claims[twin_corners // 3].max(axis=1) == rank)
        claims[corners], claims[twin_corners] = -1, -1
        flips.append(_flip(corners[wins], twin_corners[wins], faces, face_edges, twins, lengths_sq, moved_to))
        # Next: the four outer edges of each flipped quad, and the losers (moved where their face was flipped).
        new_corners = np.concatenate([moved_to[corners[~wins]], _outer_corners(corners[wins], twin_corners[wins])])
        moved_to[...] = np.arange(n_corners)
        new_corners = new_corners[twins[new_corners] >= 0]
        is_candidate = np.zeros(n_corners, dtype=bool)  # sorted and deduplicated, faster than np.unique
        is_candidate[np.minimum(new_corners, twins[new_corners])] = True
        candidates = np.flatnonzero(is_candidate)
    return faces, face_edges, flips


def _outer_corners(corners: np.ndarray, twin_corners: np.ndarray) -> np.ndarray:
    """Corners (after `_flip`) opposite the four outer edges of each flipped quad: 0 and 2 of both new faces."""
    f, g = corners // 3, twin_corners // 3
    return np.concatenate([3 * f, 3 * f + 2, 3 * g, 3 * g + 2])


def _flip(corners, twin_corners, faces, face_edges, twins, lengths_sq, moved_to) -> np.ndarray:
    """Flip the edges opposite `corners` (faces `(i, a, b)`) and `twin_corners` (faces `(j, b, a)`) in place.

    No two flips share a face. The new faces are `(i, a, j)` in slot `f` and `(j, b, i)` in slot `g`,
    with the new edge `ij` opposite corner 1 of both (it keeps the index of `ab`). `moved_to` records
    where each old corner of a flipped face went, so that twins pointing into another flipped face
    of the same round land right. Returns the round's `[ab, ia, ib, ja, jb]`.
    """
    f, k = np.divmod(corners, 3)
    g, m = np.divmod(twin_corners, 3)
    k1, k2, m1, m2 = (k + 1) % 3, (k + 2) % 3, (m + 1) % 3, (m + 2) % 3
    i, a, b, j = faces[f, k], faces[f, k1], faces[f, k2], faces[g, m]
    ab, ia, ib, ja, jb = face_edges[f, k], face_edges[f, k2], face_edges[f, k1], face_edges[g, m1], face_edges[g, m2]
    quads = np.stack([ab, ia, ib, ja, jb], axis=1)
    lengths_sq[ab] = diagonal_after_flip(lengths_sq[quads.T], _host_face_areas, _host_divide, np.stack)
    # Old corner -> new corner, by the edge it is opposite: ia -> (f, 2), ja -> (f, 0), ib -> (g, 0), jb -> (g, 2).
    old = np.stack([3 * f + k2, 3 * g + m1, 3 * f + k1, 3 * g + m2])
    new = np.stack([3 * f + 2, 3 * f, 3 * g, 3 * g + 2])
    outer = twins[old]
    moved_to[old] = new
    outer = np.where(outer >= 0, moved_to[np.maximum(outer, 0)], -1)
    faces[f], faces[g] = np.stack([i, a, j], axis=1), np.stack([j, b, i], axis=1)
    face_edges[f], face_edges[g] = np.stack([ja, ab, ia], axis=1), np.stack([ib, ab, jb], axis=1)
    twins[3 * f + 1], twins[3 * g + 1] = 3 * g + 1, 3 * f + 1
    twins[new] = outer
    outside = outer >= 0
    twins[outer[outside]] = new[outside]
    return quads
