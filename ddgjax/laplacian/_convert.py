"""Converters between ddgjax's cotan Laplacian and the conventions of libigl, gpytoolbox and PyTorch3D.

ddgjax (DESIGN.md): `L` is PSD and halved, `L_ij = -(cot a_ij + cot b_ij) / 2` off the diagonal,
`L_ii = -sum_{j != i} L_ij`. All converters take / return host `scipy.sparse.csr_matrix`.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ..sparse import SparseMatrix


def to_igl_cotmatrix(laplacian: SparseMatrix) -> sp.csr_matrix:
    """libigl's `cotmatrix(V, F)`: the negative semidefinite Laplacian, `-L` (`C_ij = +(cot a + cot b) / 2`).

    Args:
        laplacian: ddgjax's PSD cotan Laplacian `L`, `(nv, nv)` (`cotan_laplacian`).

    Returns:
        `(nv, nv)` host `scipy.sparse.csr_matrix`, `-L`.
    """
    return -laplacian.to_scipy()


def to_gpytoolbox_cotangent_laplacian(laplacian: SparseMatrix) -> sp.csr_matrix:
    """gpytoolbox's `cotangent_laplacian(V, F)`: the same PSD convention, so just `L` as SciPy CSR.

    Args:
        laplacian: ddgjax's PSD cotan Laplacian `L`, `(nv, nv)` (`cotan_laplacian`).

    Returns:
        `(nv, nv)` host `scipy.sparse.csr_matrix`, `L`.
    """
    return laplacian.to_scipy()


def to_pytorch3d_cot_laplacian(laplacian: SparseMatrix) -> sp.csr_matrix:
    """PyTorch3D's `pytorch3d.ops.cot_laplacian(verts, faces)[0]`: un-halved, positive, no diagonal.

    PyTorch3D returns `W` with `W_ij = cot a_ij + cot b_ij` for every edge `ij` and `W_ii = 0`
    (its second output, `inv_areas`, is `1 / sum of incident face areas`, unrelated to `L`). Hence
    `W = -2 (L - diag(L))` and `L = (diag(W 1) - W) / 2` (`from_pytorch3d_cot_laplacian`). Its
    `mesh_laplacian_smoothing(method="cot")` then uses `W` row-normalised, not `L`.

    Args:
        laplacian: ddgjax's PSD cotan Laplacian `L`, `(nv, nv)` (`cotan_laplacian`).

    Returns:
        `(nv, nv)` host `scipy.sparse.csr_matrix` `W`, zero diagonal (explicit zeros removed).
    """
    matrix = laplacian.to_scipy()
    off_diagonal = matrix - sp.diags(matrix.diagonal())
    result = (-2.0 * off_diagonal).tocsr()
    result.eliminate_zeros()
    return result


def from_pytorch3d_cot_laplacian(cot_weights: sp.spmatrix) -> sp.csr_matrix:
    """ddgjax's `L` from PyTorch3D's cot matrix `W` (see `to_pytorch3d_cot_laplacian`): `L = (diag(W 1) - W) / 2`.

    Args:
        cot_weights: PyTorch3D's un-halved cot matrix `W`, `(nv, nv)`, any SciPy sparse matrix (e.g. from
            `cot_laplacian(verts, faces)[0]` moved to the host).

    Returns:
        `(nv, nv)` host `scipy.sparse.csr_matrix`, ddgjax's PSD `L`.
    """
    weights = sp.csr_matrix(cot_weights)
    row_sums = np.asarray(weights.sum(axis=1)).ravel()
    return (0.5 * (sp.diags(row_sums) - weights)).tocsr()
