"""Bounded memory over a stream of meshes of new sizes (issue 22; figures: benchmarks/memory.py)."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

# Runs in a fresh process: the programs other tests compiled must not count. Each kernel keeps 2
# programs here (8 by default) so the caches fill after a few meshes and the rest of the stream
# measures the growth per new mesh once they are full.
_STREAM = """
import gc, json
import jax, numpy as np, psutil, scipy.spatial
jax.config.update("jax_enable_x64", True)
import ddgjax
from ddgjax import _compile
from ddgjax.laplacian import cotan_laplacian, mass_matrix
_compile.PROGRAMS_PER_KERNEL = 2
rng = np.random.default_rng(0)
rss = []
for n in rng.permutation(np.arange(200, 800, 15))[:36]:
    points = rng.normal(size=(int(n), 3))
    points /= np.linalg.norm(points, axis=1, keepdims=True)
    mesh = ddgjax.Mesh.from_arrays(points, scipy.spatial.ConvexHull(points).simplices)
    L, M = cotan_laplacian(mesh), mass_matrix(mesh)
    jax.block_until_ready((L.values, M.values, (M + 0.01 * L).values, L @ np.ones(mesh.n_vertices)))
    del mesh, L, M
    gc.collect()
    rss.append(psutil.Process().memory_info().rss / 2**20)
print(json.dumps(rss))
"""


@pytest.mark.slow
def test_a_stream_of_meshes_of_new_sizes_grows_the_process_by_under_a_megabyte_per_mesh():
    """Laplacian, mass matrix, their sum and a product for 36 meshes of distinct sizes: once the
    kernels' bounded program caches are full, the process grows by less than 1 MB per new mesh
    (about 9 MB per mesh when every size's programs were kept)."""
    result = subprocess.run([sys.executable, "-c", _STREAM], capture_output=True, text=True, timeout=900)
    assert result.returncode == 0, result.stderr[-3000:]
    rss = np.array(json.loads(result.stdout.strip().splitlines()[-1]))
    steady = rss[12:]
    growth_per_mesh = np.polyfit(np.arange(steady.size), steady, 1)[0]
    assert growth_per_mesh < 1.0, f"{growth_per_mesh:.2f} MB per new mesh; RSS (MB): {np.round(rss).tolist()}"
