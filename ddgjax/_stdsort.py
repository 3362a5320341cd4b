"""libstdc++'s `std::sort`, replayed: where keys tie (or are NaN) the order it leaves is its own, not a stable one.

geometry-central sorts with `std::sort`, which is not stable: robust_laplacian's point-cloud Laplacian
depends on that order where neighbours sit at equal angles (duplicated points) and where a tufted
cover's triangles tie about an edge. Reproducing its Laplacian there needs the same permutation, so
this module replays GCC's algorithm step by step (plain Python: it serves the few tied rows only).
"""

from __future__ import annotations

import numpy as np

# libstdc++'s threshold below which `std::sort` leaves a range to its final insertion sort.
_INSERTION_THRESHOLD = 16


def std_sort_order(keys: list[float]) -> np.ndarray:
    """The permutation libstdc++'s `std::sort` of `0..n-1` by `keys[a] < keys[b]` makes (GCC's `stl_algo.h`).

    Quicksort with the median of (second, middle, last) moved to the front and Hoare's unguarded
    partition, down to ranges of 16; past `2 floor(log2 n)` levels a heap sort; then one insertion sort.
    A NaN key compares false both ways, as in C++ (its neighbours stop at it).
    """
    # Comparisons are written out (no helper function): a run-time type checker would wrap every call.
    key = list(keys)
    items = list(range(len(key)))
    n = len(items)
    # The recursion on the upper part, as an explicit stack of (first, last, depth).
    pending = [(0, n, 2 * (n.bit_length() - 1))] if n > 1 else []
    while pending:
        first, last, depth = pending.pop()
        while last - first > _INSERTION_THRESHOLD:
            if depth == 0:
                items[first:last] = _heap_sorted(items[first:last], key)
                break
            depth -= 1
            middle = first + (last - first) // 2
            a, b, c = first + 1, middle, last - 1
            ka, kb, kc = key[items[a]], key[items[b]], key[items[c]]
            # `__move_median_to_first`: the median of the three, by its sequence of comparisons.
            pick = (b if kb < kc else (c if ka < kc else a)) if ka < kb else (a if ka < kc else (c if kb < kc else b))
            items[first], items[pick] = items[pick], items[first]
            pivot = key[items[first]]
            low, high = first + 1, last
            while True:
                while key[items[low]] < pivot:
                    low += 1
                high -= 1
                while pivot < key[items[high]]:
                    high -= 1
                if not low < high:
                    break
                items[low], items[high] = items[high], items[low]
                low += 1
            # libstdc++ recurses into the upper part first, then loops on the lower; the order of the two
            # does not matter (they are disjoint), only the depth each starts with.
            pending.append((low, last, depth))
            last = low
    # The final insertion sort: equal keys keep the order the partitions left.
    for i in range(1, n):
        value = items[i]
        k = key[value]
        if k < key[items[0]]:
            items[1 : i + 1] = items[0:i]
            items[0] = value
            continue
        j = i
        while k < key[items[j - 1]]:
            items[j] = items[j - 1]
            j -= 1
        items[j] = value
    return np.asarray(items, dtype=np.int64)


def _heap_sorted(items: list[int], key: list[float]) -> list[int]:
    """libstdc++'s `__partial_sort(first, last, last)`: `make_heap` then `sort_heap` (GCC's `stl_heap.h`)."""
    heap = list(items)
    n = len(heap)

    def adjust(hole, length, value):
        top = hole
        child = hole
        while child < (length - 1) // 2:
            child = 2 * (child + 1)
            if key[heap[child]] < key[heap[child - 1]]:
                child -= 1
            heap[hole] = heap[child]
            hole = child
        if length % 2 == 0 and child == (length - 2) // 2:
            child = 2 * (child + 1)
            heap[hole] = heap[child - 1]
            hole = child - 1
        parent = (hole - 1) // 2
        while hole > top and key[heap[parent]] < key[value]:
            heap[hole] = heap[parent]
            hole = parent
            parent = (hole - 1) // 2
        heap[hole] = value

    for parent in range((n - 2) // 2, -1, -1):
        adjust(parent, n, heap[parent])
    for last in range(n - 1, 0, -1):
        value = heap[last]
        heap[last] = heap[0]
        adjust(0, last, value)
    return heap
