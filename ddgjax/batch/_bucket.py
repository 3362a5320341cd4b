"""Bucket sizes: padded array sizes from a short fixed ladder, so batches of similar sizes share one compiled program.

XLA compiles one program per array shape. A stream of batches padded to their exact largest mesh
would compile a program per batch; padded to the next size of a ladder `m 2^e` with `m` in
`{4, 5, 6, 7}` (four sizes per doubling: 64, 80, 96, 112, 128, 160, ...), batches whose largest
meshes fall in one rung share a program, at most 25 % of each padded array is padding, and sizes
from 64 to a million use 57 programs at most. The same ladder pads vertices, faces and vertex
degrees. (PyTorch3D pads to the exact maximum; jraph's `pad_with_graphs` and bucketing input
pipelines round up as here.)
"""

from __future__ import annotations

from .._errors import check_count

#: The mantissas of the ladder: four rungs per doubling.
_MANTISSAS = (4, 5, 6, 7)


def bucket(size: int, *, minimum: int = 64) -> int:
    """The padded size for `size` elements: the smallest `m 2^e >= max(size, minimum)` with `m` in `{4, 5, 6, 7}`.

    Args:
        size: the number of elements (vertices, faces, ...) to hold; a nonnegative integer.
        minimum: the smallest padded size returned (a positive integer), so tiny meshes share one program.

    Returns:
        An integer `>= size` with `bucket(size) < 1.25 size + 1` once `size >= minimum`
        (`bucket(100) == 112`, `bucket(1000) == 1024`, `bucket(1025) == 1280`).
    """
    size = check_count("size", size, minimum=0)
    target = max(size, check_count("minimum", minimum))
    exponent = max(target.bit_length() - 3, 0)
    while True:
        for mantissa in _MANTISSAS:
            if mantissa << exponent >= target:
                return mantissa << exponent
        exponent += 1
