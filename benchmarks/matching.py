"""Shape matching, the whole pipeline: ddgjax `match_shapes` against pyFM's `FunctionalMapping`, one process.

Pairs with known ground truth (`--pairs`, comma-separated):

- `lumpy(s)`: the CLI's built-in pair (`ddgjax._cli.match.built_in_pair(s)`): a lumpy sphere on an
  icosphere of `s` subdivisions (source; 10,242 vertices at 5, 40,962 at 6) and on a UV sphere of
  about as many vertices bent by ARAP (target); the truth is the nearest source vertex in direction.
- a file in `../shared/meshes` (`kitten.obj`, 9.4k vertices; `armadillo.obj`, 43k): the mesh
  against a copy bent by ARAP (the lowest 5% held, the highest 5% moved sideways) with its vertices
  shuffled, as `tests/test_matching_pipeline.py` does; above `--bend-max-vertices` the copy is only
  shuffled. The truth is the permutation.

Both run their defaults for the usual pipeline: 100 eigenpairs, 100 WKS descriptors, a 50 x 50 map,
ZoomOut to 100 one function a step, the point map. ddgjax: `match_shapes(source, target)`; its
stages `spectral_shape(mesh, 100)`, `descriptors`, `functional_map(k_source=k_target=50,
orientation_weight=1)` (match_shapes' default), `zoomout_refine(k_final=100)`, `point_map`. pyFM:
`TriMesh.process` (through `preprocess(n_descr=100, descr_type="WKS", k_process=100)`, which
raises `k_process` to its `k_descr=128`), the descriptors (`preprocess` on processed meshes),
`fit(K=(50, 50))`, `zoomout_refine(nit=50, step=1)`, `get_p2p`.

Times in seconds: "first" is each library's first whole pipeline on the pair in this process
(ddgjax compiles its kernels for these sizes then); the stages and "warm" are the best of
`--repeats` later runs. Both maps' mean geodesic error over `sqrt(area)` (`ddgjax.matching.geodesic_error`,
on `--error-samples` target vertices). Run: `python benchmarks/matching.py [--pairs
"lumpy(5),kitten.obj,lumpy(6),armadillo.obj"] [--repeats 2]` (~10 min on 2 cores).
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import time

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from solve import SHARED, optional, run_sections  # noqa: E402

from ddgjax._cli.match import built_in_pair  # noqa: E402
from ddgjax.deform import arap  # noqa: E402
from ddgjax.io import load_mesh  # noqa: E402
from ddgjax.matching import (  # noqa: E402
    descriptors,
    functional_map,
    geodesic_error,
    match_shapes,
    point_map,
    spectral_shape,
    zoomout_refine,
)
from ddgjax.mesh import Mesh  # noqa: E402

pyfm_functional = optional("pyFM.functional")
pyfm_mesh = optional("pyFM.mesh")
STAGES = ("eigenpairs", "descriptors", "fit", "zoomout", "p2p")
K, K_FINAL, N_DESCRIPTORS = 50, 100, 100


def bent_and_shuffled(mesh: Mesh, bend: bool) -> tuple[Mesh, np.ndarray]:
    """`(target, truth)`: the mesh bent by ARAP (feet held, top moved sideways) when `bend`, vertices permuted."""
    V, F = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    if bend:
        low, high = np.flatnonzero(V[:, 2] < np.quantile(V[:, 2], 0.05)), np.flatnonzero(V[:, 2] > np.quantile(V[:, 2], 0.95))
        fixed = np.concatenate([low, high])
        values = V[fixed] + np.where(np.isin(fixed, high), 0.3, 0.0)[:, None] * np.array([1.0, 0.0, 0.0])
        # A near-isometric bend is all the pair needs: ARAP's last iterate, converged to 1e-4 or not.
        V = np.asarray(arap(mesh, fixed_vertices=fixed, fixed_values=values, rtol=1e-4, throw=False).value)
    perm = np.random.default_rng(0).permutation(len(V))
    return Mesh.from_arrays(V[perm], np.argsort(perm)[F]), perm


def pair(name: str, args) -> tuple[Mesh, Mesh, np.ndarray, str]:
    """`(source, target, truth, how the target was made)`."""
    if name.startswith("lumpy("):
        source, target, truth = built_in_pair(int(name[len("lumpy(") : -1]))
        return source, target, truth, "UV sphere bent by ARAP"
    source = load_mesh(SHARED / name)
    bend = source.n_vertices <= args.bend_max_vertices
    target, truth = bent_and_shuffled(source, bend)
    return source, target, truth, "bent by ARAP, shuffled" if bend else "shuffled"


def timed(fn, *args):
    """`(result, seconds)` of one call, its arrays ready."""
    start = time.perf_counter()
    result = jax.block_until_ready(fn(*args))
    return result, time.perf_counter() - start


def ddgjax_stages(source_mesh: Mesh, target_mesh: Mesh) -> tuple[dict, np.ndarray]:
    """Seconds per stage of the pipeline `match_shapes` runs, and its point map."""
    times = {}
    (source, target), times["eigenpairs"] = timed(
        lambda: (spectral_shape(source_mesh, K_FINAL), spectral_shape(target_mesh, K_FINAL))
    )
    (F_s, F_t), times["descriptors"] = timed(lambda: (descriptors(source), descriptors(target)))
    C, times["fit"] = timed(lambda: functional_map(source, target, F_s, F_t, k_source=K, k_target=K, orientation_weight=1.0))
    C, times["zoomout"] = timed(lambda: zoomout_refine(C, source, target, k_final=K_FINAL))
    p2p, times["p2p"] = timed(lambda: point_map(C, source, target))
    return times, np.asarray(p2p)


def pyfm_pipeline(source_mesh: Mesh, target_mesh: Mesh) -> tuple[dict, np.ndarray]:
    """Seconds per stage of pyFM's pipeline, and its point map."""
    meshes = [pyfm_mesh.TriMesh(np.asarray(m.vertices), np.asarray(m.faces)) for m in (source_mesh, target_mesh)]
    times = {}
    # preprocess's own eigensolve: k_process raised to k_descr (128); then preprocess skips it.
    _, times["eigenpairs"] = timed(lambda: [m.process(max(K_FINAL, 128)) for m in meshes])
    model = pyfm_functional.FunctionalMapping(*meshes)
    _, times["descriptors"] = timed(lambda: model.preprocess(n_descr=N_DESCRIPTORS, descr_type="WKS", k_process=K_FINAL))
    _, times["fit"] = timed(lambda: model.fit(K=(K, K)))
    C, times["zoomout"] = timed(lambda: model.zoomout_refine(nit=K_FINAL - K, step=1))
    p2p, times["p2p"] = timed(lambda: model.get_p2p(C))
    return times, np.asarray(p2p)


def best(runs: list[dict]) -> dict:
    return {stage: min(run[stage] for run in runs) for stage in runs[0]}


def section_pipeline(args):
    print(
        f"\n# match: {K_FINAL} eigenpairs, {N_DESCRIPTORS} WKS, a {K} x {K} map, ZoomOut to {K_FINAL}, point map "
        f"(seconds; stages and warm: best of {args.repeats} runs after the first)"
    )
    header = ["pair", "n_s / n_t", "library", "first", *STAGES, "warm", "ratio warm", "geodesic error"]
    print("| " + " | ".join(header) + " |")
    print("|" + "---|" * len(header))
    for name in args.pairs:
        _pair_rows(name, args)


def _pair_rows(name, args):
    source, target, truth, how = pair(name, args)
    rows = {}
    # ddgjax: first the whole pipeline as a user calls it (compiles for these sizes), then its stages.
    result, first = timed(lambda: match_shapes(source, target))
    runs = [ddgjax_stages(source, target)[0] for _ in range(args.repeats)]
    warm = min(timed(lambda: match_shapes(source, target).point_map)[1] for _ in range(args.repeats))
    rows["ddgjax"] = (first, best(runs), warm, np.asarray(result.point_map))
    if pyfm_functional is not None:
        runs, maps = zip(*(pyfm_pipeline(source, target) for _ in range(args.repeats + 1)))
        totals = [sum(run.values()) for run in runs]
        rows["pyFM"] = (totals[0], best(runs[1:]), min(totals[1:]), maps[-1])
    reference = rows["pyFM"][2] if "pyFM" in rows else None
    for library, (first, stages, warm, p2p) in rows.items():
        error = geodesic_error(source, p2p, truth, n_samples=args.error_samples)
        line = [
            f"{name} ({how})",
            f"{source.n_vertices:,} / {target.n_vertices:,}",
            library,
            f"{first:.2f}",
            *(f"{stages[stage]:.2f}" for stage in STAGES),
            f"{warm:.2f}",
            f"{warm / reference:.2f}x" if reference else "-",
            f"{error:.4f}",
        ]
        print("| " + " | ".join(line) + " |", flush=True)


SECTIONS = {"pipeline": section_pipeline}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sections", default=",".join(SECTIONS), help=f"comma-separated, of: {', '.join(SECTIONS)}")
    parser.add_argument(
        "--pairs",
        default="lumpy(5),kitten.obj,lumpy(6),armadillo.obj",
        help="comma-separated: lumpy(s) (the CLI's built-in pair at s subdivisions) or mesh files in ../shared/meshes",
    )
    parser.add_argument("--repeats", type=int, default=2, help="warm runs of each pipeline")
    parser.add_argument(
        "--bend-max-vertices", type=int, default=50_000, dest="bend_max_vertices", help="above this, only shuffle"
    )
    parser.add_argument(
        "--error-samples", type=int, default=2000, dest="error_samples", help="target vertices the geodesic error averages"
    )
    args = parser.parse_args(argv)
    if args.repeats < 1:
        parser.error("--repeats: expected at least 1 (the stages and the warm total are timed on those runs)")
    args.pairs = args.pairs.split(",")
    if pyfm_functional is not None:
        from importlib.metadata import version

        print(f"# pyFM {version('pyfmaps')}")
    run_sections(SECTIONS, args)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
