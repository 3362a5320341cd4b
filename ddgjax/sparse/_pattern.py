"""Fixed sparsity patterns: built once in NumPy, then reused under jit for any values.

A `SparsityPattern` is the set of structurally nonzero positions of a matrix plus the *storage
order* of its values. Operators whose values change with the geometry (the cotan Laplacian, mass
matrices, Hodge stars) keep their pattern and re-assemble only the values with one gather: no
sorting, searching or deduplication happens inside jit (DESIGN.md, Architecture).

Three storage layouts:

- `"csr"`: values in CSR order (sorted by row, then column). Any code may build one directly from
  JAX arrays, also inside jit (e.g. `ddgjax.dec.d0`). Products use a sorted `segment_sum`.
- `"coo"`: values in any order, no repeated position (the transpose of a `"csr"` pattern, or of
  an ELL pattern without transpose data: rows and columns swapped, values untouched). Products use
  an unsorted `segment_sum`.
- `"ell"`: built on the host by `from_coo` / `from_edges` / `diagonal`. Slots `k * n_rows + i`
  (`k < width`) hold the `k`-th entry of row `i` (column-major padded ELLPACK; for a square pattern
  with a full diagonal, `k = 0` is the diagonal); rows longer than `width` put their remaining
  entries in a COO tail after the ELL block, sorted by row. A padding slot sits at a position that
  row already holds (its diagonal or first entry; `(i, 0)` for an empty row) and always has value 0,
  so exports merge it away. `width` minimises `n_rows * width + 3 * tail` (the tail costs about three
  ELL slots). `A @ x` is then `width` contiguous multiply-adds with gathers of `x`, at the speed of
  SciPy's CSR product on CPU (a flat gather-and-`segment_sum` is several times slower; DESIGN.md).

Host-built patterns also carry their transpose: a symmetric pattern the permutation of its own slots
(`(i, j) -> (j, i)`), any other its transposed pattern and the slot each transposed entry reads.
`SparsityPattern.entries` lists the distinct positions and `SparsityPattern.slots` locates positions,
both on the host (for maps built once, e.g. `congruence_plan`, `dirichlet_plan`).
"""

from __future__ import annotations

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Int

from .._compile import at_top_level, device_array
from .._errors import DDGInputError, is_traced

# Cost of one COO-tail entry relative to one ELL slot (scatter vs contiguous multiply-add).
_TAIL_COST = 3


def stable_order(keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`(order, keys[order])` for a stable ascending sort of non-negative integer `keys` (host, NumPy).

    When each key and its position fit together in 63 bits, one value sort of `key << b | position`
    does it (NumPy's value sort is vectorised, its stable argsort is not);
    otherwise a stable argsort.
    """
    keys = np.asarray(keys, dtype=np.int64)
    position_bits = max(1, int(keys.size - 1).bit_length())
    if keys.size and int(keys.max()).bit_length() + position_bits <= 63:
        packed = np.sort((keys << position_bits) | np.arange(keys.size, dtype=np.int64))
        return (packed & ((1 << position_bits) - 1)).astype(np.int32), packed >> position_bits
    order = np.argsort(keys, kind="stable").astype(np.int32)
    return order, keys[order]


class SparsityPattern(eqx.Module):
    """Positions of the stored entries of an `(n_rows, n_cols)` matrix, and their storage order.

    Attributes:
        rows: `(nnz,)` row of each storage slot (`nnz` counts ELL padding slots too).
        cols: `(nnz,)` column of each storage slot.
        indptr: `(n_rows + 1,)` CSR row pointer of the distinct entries (the storage for `"csr"`);
            `None` for `"coo"`.
        shape: `(n_rows, n_cols)`, static.
        layout: `"csr"`, `"coo"` or `"ell"` (module docstring), static.
        width: ELL width (0 for `"csr"`), static.
        diagonal_first: ELL slot block 0 is the diagonal, static.
        symmetric: the pattern equals its transpose, static.
        transpose_slot: for each storage slot of the transpose, the slot of this pattern it reads
            (`nnz` for a padding slot: read as 0); `None` where unknown (patterns built under jit) or
            the identity (a diagonal pattern).
        transpose_pattern: the transposed pattern of a non-symmetric host-built pattern, else `None`.
        row_cols: `(n_rows, width - diagonal_first)` columns of the ELL block row by row, without the
            diagonal block of a diagonal-first pattern: `cols[:n_rows * width]` reshaped
            `(width, n_rows)` and transposed, built on the host by `from_coo` / `from_edges`
            (`None` for other layouts, the diagonal pattern, and ELL patterns made by hand). `A @ x`
            gathers every row's columns with it in one row-major gather; transposing the index
            inside jit instead costs as much as the product itself on each call.
        n_entries: number of distinct stored positions (SciPy's `nnz`: ELL padding excluded), static;
            counted once by the host builders (`from_coo`, `from_edges`, `diagonal`), `None` for
            patterns made by hand (`SparseMatrix.nnz` then counts on the host).
    """

    rows: Int[Array, " nnz"]
    cols: Int[Array, " nnz"]
    indptr: Int[Array, " n_rows_plus_1"] | None
    shape: tuple[int, int] = eqx.field(static=True)
    layout: str = eqx.field(static=True, default="csr")
    width: int = eqx.field(static=True, default=0)
    diagonal_first: bool = eqx.field(static=True, default=False)
    symmetric: bool = eqx.field(static=True, default=False)
    transpose_slot: Int[Array, " nnz_t"] | None = None
    transpose_pattern: "SparsityPattern | None" = None
    row_cols: Int[Array, "n_rows k"] | None = None
    n_entries: int | None = eqx.field(static=True, default=None)

    @property
    def nnz(self) -> int:
        """Number of storage slots (the length of a matrix's `values`), ELL padding included.

        SciPy's `nnz` (distinct positions) is `n_entries`, or `SparseMatrix.nnz`.
        """
        return int(self.rows.shape[0])

    @property
    def is_diagonal(self) -> bool:
        """The `(n, n)` diagonal pattern (`SparsityPattern.diagonal`): exactly one slot per row, on the diagonal."""
        return self.layout == "ell" and self.diagonal_first and self.width == 1 and self.nnz == self.shape[0]

    def entries(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Host list of the distinct stored positions in CSR order: `(rows, cols, slot)`, NumPy.

        `slot[k]` is the storage slot of position `(rows[k], cols[k])`: where ELL padding repeats a
        position, the real (lowest) slot; the padding of an empty row (at `(i, 0)`, a position the
        row does not hold) is left out. So `rows.size` is SciPy's `nnz` and
        `csr_matrix((values[slot], (rows, cols)))` is the matrix. Once, outside jit (a sort of the
        pattern's keys); needs concrete pattern arrays.
        """
        if is_traced(self.rows) or is_traced(self.cols) or is_traced(self.indptr):
            raise DDGInputError("pattern: a host lookup in a SparsityPattern needs concrete (non-traced) arrays")
        rows = np.asarray(self.rows, dtype=np.int64)
        cols = np.asarray(self.cols, dtype=np.int64)
        order, sorted_keys = stable_order(rows * self.shape[1] + cols)  # by key, then slot: real slots first
        first = np.ones(sorted_keys.size, dtype=bool)
        first[1:] = sorted_keys[1:] != sorted_keys[:-1]
        slot = order[first].astype(np.int64)
        if self.layout == "ell" and self.indptr is not None:
            row_counts = np.diff(np.asarray(self.indptr))
            slot = slot[row_counts[rows[slot]] > 0]
        return rows[slot], cols[slot], slot

    def slots(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """Host lookup: the storage slot of each position `(rows[k], cols[k])`, or `nnz` where it has none.

        NumPy, once, outside jit (`entries`); needs concrete pattern arrays. Where an ELL padding
        slot repeats a position, the real (lowest) slot is returned.
        """
        n_cols = self.shape[1]
        entry_rows, entry_cols, entry_slots = self.entries()
        unique_keys = entry_rows * n_cols + entry_cols
        rows = np.asarray(rows, dtype=np.int64)
        cols = np.asarray(cols, dtype=np.int64)
        result = np.full(rows.shape, self.nnz, dtype=np.int64)
        if unique_keys.size == 0:
            return result
        query = rows * n_cols + cols
        inside = (rows >= 0) & (rows < self.shape[0]) & (cols >= 0) & (cols < n_cols)
        position = np.minimum(np.searchsorted(unique_keys, query), unique_keys.size - 1)
        found = inside & (unique_keys[position] == query)
        result[found] = entry_slots[position[found]]
        return result

    @classmethod
    def from_coo(cls, rows: np.ndarray, cols: np.ndarray, shape: tuple[int, int]) -> tuple["SparsityPattern", np.ndarray]:
        """Pattern of a COO list that may repeat positions, and where each entry lands.

        Args:
            rows, cols: `(m,)` integer positions (NumPy; this is topology, built outside jit).
            shape: `(n_rows, n_cols)`.

        Returns:
            `(pattern, slot)`: `slot[k]` is the storage slot that entry `k` is summed into; values for
            the pattern are `jax.ops.segment_sum(entries, slot, pattern.nnz)` (padding slots get 0).
        """
        rows = np.asarray(rows, dtype=np.int64).reshape(-1)
        cols = np.asarray(cols, dtype=np.int64).reshape(-1)
        n_rows, n_cols = int(shape[0]), int(shape[1])
        if rows.shape != cols.shape:
            raise DDGInputError(f"rows, cols: expected equal lengths, got {rows.shape[0]} and {cols.shape[0]}")
        outside = (rows < 0) | (rows >= n_rows) | (cols < 0) | (cols >= n_cols)
        if outside.any():
            raise DDGInputError(
                f"rows, cols: positions must lie inside shape {shape}; entry {int(np.flatnonzero(outside)[0])} does not"
            )
        unique_keys, inverse = np.unique(rows * n_cols + cols, return_inverse=True)
        csr_rows, csr_cols = unique_keys // n_cols, unique_keys % n_cols
        transposed_keys = csr_cols * n_rows + csr_rows
        symmetric = n_rows == n_cols and _is_permutation_of(transposed_keys, unique_keys)
        csr_transpose = np.searchsorted(unique_keys, transposed_keys) if symmetric else None
        pattern, storage_of_csr = _ell_pattern(csr_rows, csr_cols, (n_rows, n_cols), csr_transpose)
        return pattern, storage_of_csr[inverse.reshape(-1)].astype(np.int32)

    @classmethod
    def from_edges(cls, edges: np.ndarray, n: int) -> tuple["SparsityPattern", np.ndarray]:
        """Vertex-vertex pattern (diagonal plus both directions of every edge), without any sort of `nnz` keys.

        Args:
            edges: `(ne, 2)` distinct edges with `edges[:, 0] < edges[:, 1]`, sorted lexicographically
                (as `Mesh.edges`).
            n: number of vertices.

        Returns:
            `(pattern, source)`: `source[s]` is the index of storage slot `s` in the list
            `[diagonal (n) | edges low->high (ne) | edges high->low (ne)]`, or `n + 2 ne` for padding,
            so values assemble with `jnp.take(entries, source, mode="fill", fill_value=0)`.
        """
        # Built straight in diagonal-first ELL storage (the layout `_ell_pattern` gives this pattern):
        # row i holds [i | lows of edges (., i), ascending | highs of edges (i, .), ascending], so each
        # entry's ELL position follows from ranks within the edge list, with no sort of `nnz` keys.
        low = np.asarray(edges[:, 0], dtype=np.int32)
        high = np.asarray(edges[:, 1], dtype=np.int32)
        ne = low.shape[0]
        n_below = np.bincount(high, minlength=n)  # entries left of the diagonal in each row
        n_above = np.bincount(low, minlength=n)
        counts = n_below + n_above + 1
        indptr = np.zeros(n + 1, dtype=np.int32)
        np.cumsum(counts, out=indptr[1:])
        width = _ell_width(counts)
        # Edges are sorted by (low, high), so a stable sort by `high` keeps the lows ascending.
        by_high = stable_order(high)[0]
        first_below = (np.cumsum(n_below) - n_below).astype(np.int32)
        position_high_low = np.empty(ne, dtype=np.int32)
        position_high_low[by_high] = np.arange(1, ne + 1, dtype=np.int32) - np.repeat(first_below, n_below)
        first_above = (np.cumsum(n_above) - n_above).astype(np.int32)
        position_low_high = np.arange(1, ne + 1, dtype=np.int32) - first_above[low] + n_below[low].astype(np.int32)
        # Entries past `width` go to the COO tail in CSR order (row, then column).
        tail_low_high = np.flatnonzero(position_low_high >= width)
        tail_high_low = np.flatnonzero(position_high_low >= width)
        tail_rows = np.concatenate([low[tail_low_high], high[tail_high_low]])
        tail_cols = np.concatenate([high[tail_low_high], low[tail_high_low]])
        tail_order = np.lexsort((tail_cols, tail_rows))
        n_tail = tail_order.size
        n_storage = n * width + n_tail
        tail_slot = np.empty(n_tail, dtype=np.int32)
        tail_slot[tail_order] = n * width + np.arange(n_tail, dtype=np.int32)
        slot_low_high = position_low_high * np.int32(n) + low
        slot_high_low = position_high_low * np.int32(n) + high
        slot_low_high[tail_low_high] = tail_slot[: tail_low_high.size]
        slot_high_low[tail_high_low] = tail_slot[tail_low_high.size :]
        # Padding sits at the row's first CSR entry: its lowest neighbour below the diagonal, else i.
        lowest_below = low[by_high][np.minimum(first_below, max(ne - 1, 0))] if ne else np.zeros(n, np.int32)
        pad_cols = np.where(n_below > 0, lowest_below, np.arange(n, dtype=np.int32))
        storage_rows = np.empty(n_storage, dtype=np.int32)
        storage_cols = np.empty(n_storage, dtype=np.int32)
        storage_rows[: n * width].reshape(width, n)[:] = np.arange(n, dtype=np.int32)
        storage_cols[: n * width].reshape(width, n)[:] = pad_cols
        storage_cols[:n] = np.arange(n, dtype=np.int32)
        storage_rows[n * width :] = tail_rows[tail_order]
        storage_cols[slot_low_high] = high
        storage_cols[slot_high_low] = low
        nnz = n + 2 * ne
        source = np.full(n_storage, nnz, dtype=np.int32)
        source[:n] = np.arange(n, dtype=np.int32)
        source[slot_low_high] = np.arange(n, n + ne, dtype=np.int32)
        source[slot_high_low] = np.arange(n + ne, nnz, dtype=np.int32)
        # Transpose of an entry: the diagonal and padding map to themselves, an edge to its other direction.
        transpose_slot = np.arange(n_storage, dtype=np.int32)
        transpose_slot[slot_low_high] = slot_high_low
        transpose_slot[slot_high_low] = slot_low_high
        pattern = SparsityPattern(
            **jax.device_put(
                {
                    "rows": storage_rows,
                    "cols": storage_cols,
                    "indptr": indptr,
                    "transpose_slot": transpose_slot,
                    "row_cols": _row_major(storage_cols, n, width, first=1),
                }
            ),
            shape=(n, n),
            layout="ell",
            width=width,
            diagonal_first=True,
            symmetric=True,
            transpose_pattern=None,
            n_entries=n + 2 * ne,
        )
        return pattern, source

    @classmethod
    def diagonal(cls, n: int) -> "SparsityPattern":
        """The `(n, n)` diagonal pattern (values are the diagonal; `A @ x` is `values * x`)."""
        if at_top_level():  # transferred from the host: an eager `jnp.arange` compiles a program per size
            index, indptr = _diagonal_indices(n)
        else:  # inside a trace an iota, rather than a constant embedded in the program
            index, indptr = (jnp.arange(size, dtype=jnp.int32) for size in (n, n + 1))
        return cls(
            rows=index,
            cols=index,
            indptr=indptr,
            shape=(n, n),
            layout="ell",
            width=1,
            diagonal_first=True,
            symmetric=True,
            n_entries=n,
        )


@functools.lru_cache(maxsize=8)
def _diagonal_indices(n: int) -> tuple[Int[Array, " n"], Int[Array, " n_plus_1"]]:
    """`(arange(n), arange(n + 1))` on the device, for the last few sizes: an eager mass matrix transfers nothing."""
    return device_array(np.arange(n, dtype=np.int32)), device_array(np.arange(n + 1, dtype=np.int32))


def _row_major(storage_cols: np.ndarray, n_rows: int, width: int, first: int) -> np.ndarray:
    """ELL block columns row by row, from block `first` on: `(n_rows, width - first)` (`SparsityPattern.row_cols`)."""
    return np.ascontiguousarray(storage_cols[: n_rows * width].reshape(width, n_rows)[first:].T)


def _is_permutation_of(keys: np.ndarray, sorted_keys: np.ndarray) -> bool:
    position = np.searchsorted(sorted_keys, keys)
    position = np.minimum(position, sorted_keys.shape[0] - 1)
    return bool(np.all(sorted_keys[position] == keys))


def _ell_width(counts: np.ndarray) -> int:
    """Width minimising `n_rows * width + _TAIL_COST * (entries beyond width)`."""
    if counts.size == 0 or counts.max() == 0:
        return 1
    histogram = np.bincount(counts)
    longer = counts.size - np.cumsum(histogram)  # rows with more than w entries, for w = 0..max
    tail = np.cumsum(longer[::-1])[::-1] - longer  # entries beyond width w
    widths = np.arange(histogram.size)
    cost = counts.size * widths + _TAIL_COST * (tail + longer)
    return max(1, int(np.argmin(cost[1:]) + 1))


def _ell_pattern(
    csr_rows: np.ndarray,
    csr_cols: np.ndarray,
    shape: tuple[int, int],
    csr_transpose: np.ndarray | None,
    with_transpose: bool = True,
) -> tuple[SparsityPattern, np.ndarray]:
    """ELL(+COO tail) pattern of distinct CSR-ordered entries, and the storage slot of each entry.

    `csr_transpose[k]` is the CSR index of the mirror entry of a symmetric pattern; for a
    non-symmetric pattern (`None`) the transposed pattern is built too, unless `with_transpose` is
    False (the transposed pattern itself: one level, not an endless chain).
    """
    n_rows, n_cols = shape
    nnz = csr_rows.shape[0]
    counts = np.bincount(csr_rows, minlength=n_rows)
    indptr = np.zeros(n_rows + 1, dtype=np.int64)
    np.cumsum(counts, out=indptr[1:])
    position = np.arange(nnz) - indptr[csr_rows]
    is_diagonal = csr_rows == csr_cols
    diagonal_first = n_rows == n_cols and int(is_diagonal.sum()) == n_rows
    if diagonal_first:
        diagonal_position = position[is_diagonal][csr_rows]
        position = np.where(is_diagonal, 0, np.where(position < diagonal_position, position + 1, position))
    width = _ell_width(counts)
    in_ell = position < width
    n_tail = nnz - int(in_ell.sum())
    storage_of_csr = np.where(in_ell, position * n_rows + csr_rows, 0)
    storage_of_csr[~in_ell] = n_rows * width + np.arange(n_tail)
    n_storage = n_rows * width + n_tail
    storage_rows = np.empty(n_storage, dtype=np.int32)
    storage_cols = np.empty(n_storage, dtype=np.int32)
    # Padding: the row's diagonal / first entry (an existing position), or column 0 for an empty row.
    ell_rows = np.tile(np.arange(n_rows, dtype=np.int32), width)
    first_cols = csr_cols[np.minimum(indptr[:-1], nnz - 1)] if nnz else np.zeros(n_rows, dtype=np.int64)
    pad_cols = np.where(counts > 0, first_cols, 0)
    storage_rows[: n_rows * width] = ell_rows
    storage_cols[: n_rows * width] = np.tile(pad_cols.astype(np.int32), width)
    storage_rows[storage_of_csr] = csr_rows
    storage_cols[storage_of_csr] = csr_cols
    csr_of_storage = np.full(n_storage, nnz, dtype=np.int64)
    csr_of_storage[storage_of_csr] = np.arange(nnz)
    transposed = transpose_slot = None
    if csr_transpose is not None:
        # Padding reads itself (value 0).
        transpose_slot = np.arange(n_storage)
        real = csr_of_storage < nnz
        transpose_slot[real] = storage_of_csr[csr_transpose[csr_of_storage[real]]]
    elif with_transpose:
        by_col = np.lexsort((csr_rows, csr_cols))
        transposed, t_storage_of_t_csr = _ell_pattern(
            csr_cols[by_col], csr_rows[by_col], (n_cols, n_rows), None, with_transpose=False
        )
        transpose_slot = np.full(transposed.nnz, n_storage, dtype=np.int64)
        transpose_slot[t_storage_of_t_csr] = storage_of_csr[by_col]
    pattern = SparsityPattern(
        rows=device_array(storage_rows),
        cols=device_array(storage_cols),
        indptr=device_array(indptr.astype(np.int32)),
        shape=(n_rows, n_cols),
        layout="ell",
        width=width,
        diagonal_first=diagonal_first,
        symmetric=csr_transpose is not None,
        transpose_slot=None if transpose_slot is None else device_array(transpose_slot.astype(np.int32)),
        transpose_pattern=transposed,
        row_cols=device_array(_row_major(storage_cols, n_rows, width, first=int(diagonal_first))),
        n_entries=nnz,
    )
    return pattern, storage_of_csr.astype(np.int64)
