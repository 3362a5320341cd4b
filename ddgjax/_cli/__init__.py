"""The `ddgjax` command line: `ddgjax flow` (curve-shortening flows, the reading report's Figure 3),
`ddgjax info` (topology and curvature report of a mesh), `ddgjax poisson` (a Poisson or harmonic
problem solved on a mesh, with a picture of the solution), `ddgjax geodesic` (a heat-method distance
field; a log map, parallel transport, a signed distance or a point-cloud distance), `ddgjax spectrum`
(Laplacian eigenvalues and eigenfunctions), `ddgjax param` (flattenings), `ddgjax fields` (direction
fields), `ddgjax optimize` (shape-optimisation examples), `ddgjax deform` (ARAP and k-harmonic
deformation from handles), `ddgjax match` (a point map between two meshes), `ddgjax reconstruct` (Poisson surface reconstruction from points), `ddgjax fluid`
(incompressible Euler flow on a closed surface, frames or an animation written to disk) and `ddgjax
warmup` (the common entry points compiled into the caches for a set of meshes, ahead of time).

Kept apart from the mathematics (DESIGN.md, layout): the packages `ddgjax.curves` and `ddgjax.mesh`
know nothing of argparse, files or figures; this package parses options, reads files, prints and
plots. The console script `ddgjax` runs `ddgjax.cli.main`, which is `main` here.

Start-up: ddgjax's kernels are kept across processes by the library itself (`ddgjax._program_store`,
in `$XDG_CACHE_HOME/ddgjax/programs`); a command also runs with JAX's persistent compilation cache in
`$XDG_CACHE_HOME/ddgjax/jax` (`~/.cache/ddgjax/...` without `XDG_CACHE_HOME`, `$DDGJAX_CACHE_DIR/...`
with it), which keeps the command's other programs, so a second run on inputs of a size seen before
reads its compiled programs from disk instead of compiling them. `--no-compilation-cache` or
`DDGJAX_COMPILATION_CACHE=0` turns both off; a cache directory the user already gave JAX
(`JAX_COMPILATION_CACHE_DIR`) is used as it is.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
from collections.abc import Iterator

import jax
from jax.experimental.compilation_cache import compilation_cache

from .._program_store import SWITCH_VARIABLE as CACHE_VARIABLE
from .._program_store import cache_root, switched_on
from . import deform, fields, flow, fluid, geodesic, info, match, optimize, param, poisson, reconstruct, spectral, warmup

# ddgjax's kernels compile in 0.05-0.5 s each, under JAX's default threshold of 1 s for caching a
# program: cache every program, whatever its compile time and size.
_CACHE_SETTINGS = {"jax_persistent_cache_min_compile_time_secs": 0.0, "jax_persistent_cache_min_entry_size_bytes": -1}


def cache_directory() -> str:
    """`jax` in ddgjax's cache folder (`ddgjax._program_store.cache_root`: `$DDGJAX_CACHE_DIR`, else
    `$XDG_CACHE_HOME/ddgjax`, `~/.cache/ddgjax` when that variable is unset or relative)."""
    return str(cache_root() / "jax")


@contextlib.contextmanager
def persistent_compilation_cache(directory: str | None) -> Iterator[None]:
    """Run the body with JAX's persistent compilation cache in `directory` (`None`: leave JAX as it is).

    JAX's own settings are restored afterwards, so `main` called from Python leaves the process
    as it found it. A cache directory already configured in JAX is kept, and one that cannot be
    created is skipped with a note on stderr (the command still runs, compiling as usual).
    """
    if directory is None or jax.config.jax_compilation_cache_dir:
        yield
        return
    try:
        os.makedirs(directory, exist_ok=True)
    except OSError as error:
        print(f"ddgjax: note: no compilation cache ({error})", file=sys.stderr)
        yield
        return
    settings = {"jax_compilation_cache_dir": directory, **_CACHE_SETTINGS}
    previous = {name: getattr(jax.config, name) for name in settings}
    for name, value in settings.items():
        jax.config.update(name, value)
    try:
        yield
    finally:
        for name, value in previous.items():
            jax.config.update(name, value)
        # JAX opens its cache once per process at the first compile; forget it so a later one reopens.
        compilation_cache.reset_cache()


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="ddgjax",
        description="Discrete differential geometry in JAX. Run a subcommand with --help for its options.",
    )
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument(
        "--no-compilation-cache",
        action="store_true",
        help=f"compile every program afresh instead of keeping compiled programs in {cache_directory()} "
        f"(same as {CACHE_VARIABLE}=0)",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    flow.add_arguments(
        sub.add_parser(
            "flow",
            parents=[common],
            help="discrete curve-shortening flows A, B, D on a polygon (the report's Figure 3)",
            description="Evolve one polygon by the discrete curve-shortening flows and plot the invariants.",
        )
    )
    info.add_arguments(
        sub.add_parser(
            "info",
            parents=[common],
            help="topology, area, volume, Gauss-Bonnet and curvature statistics of a mesh",
            description="Print the topology report and curvature statistics of a mesh.",
        )
    )
    poisson.add_arguments(
        sub.add_parser(
            "poisson",
            parents=[common],
            help="solve a Poisson or harmonic problem on a mesh and draw the solution",
            description="Solve Delta phi = rho (Delta = -M^{-1} L) or a harmonic interpolation problem on a mesh, "
            "print the solver's numbers and write a figure of the solution.",
        )
    )
    geodesic.add_arguments(
        sub.add_parser(
            "geodesic",
            parents=[common],
            help="geodesic distance from a vertex (heat method), or its log map, parallel transport, a signed "
            "distance to a curve, or the distance on a point cloud, drawn on the mesh",
            description="Compute the heat-method distance from one vertex and draw it with isolines; or, with "
            "--log-map, --transport, --signed or --point-cloud, the vector heat method's log map or parallel "
            "transport, the signed heat method's distance to a loop of edges, or the point-cloud heat method.",
        )
    )
    spectral.add_spectrum_arguments(
        sub.add_parser(
            "spectrum",
            parents=[common],
            help="the smallest Laplacian eigenvalues and the first eigenfunctions, drawn on the mesh",
            description="Compute the smallest eigenpairs of L phi = lambda M phi and draw the first eigenfunctions.",
        )
    )
    param.add_arguments(
        sub.add_parser(
            "param",
            parents=[common],
            help="flatten a disk-topology mesh (BFF, LSCM, harmonic, Tutte) and draw it with a checkerboard",
            description="Flatten a disk-topology mesh into the plane, print its distortion and flipped faces, and "
            "draw the surface textured through the map, the map and its quasi-conformal distortion.",
        )
    )
    fields.add_arguments(
        sub.add_parser(
            "fields",
            parents=[common],
            help="the smoothest vector / line / cross field of a mesh, drawn with its singularities",
            description="Compute the globally smoothest n-direction field (Knoeppel et al. 2013), optionally aligned to "
            "the principal curvature directions, print its energy and singularities and draw it.",
        )
    )
    optimize.add_arguments(
        sub.add_parser(
            "optimize",
            parents=[common],
            help="run a shape-optimisation example (Willmore flow to a sphere, catenoid, mesh fitting) and draw it",
            description="Run one shape-optimisation example on built-in shapes, compare with its analytic answer and "
            "write a figure of the shape before and after and the loss curve.",
        )
    )
    deform.add_arguments(
        sub.add_parser(
            "deform",
            parents=[common],
            help="move handles of a mesh and deform the rest by ARAP or k-harmonic deformation, drawn side by side",
            description="Fix the lowest vertices of a mesh, turn / lift / shift the highest, deform the rest as rigidly "
            "as possible (ARAP) or by a k-harmonic displacement, print the solvers' numbers and draw the shapes.",
        )
    )
    match.add_arguments(
        sub.add_parser(
            "match",
            parents=[common],
            help="a point-to-point map between two meshes by functional maps, drawn as a texture carried through it",
            description="Match two meshes (default: a built-in pair with known ground truth) by functional maps with "
            "ZoomOut refinement, print the map's size, time and (with ground truth) its mean geodesic error, and draw "
            "a checkerboard on the source pulled back to the target through the map.",
        )
    )
    fluid.add_arguments(
        sub.add_parser(
            "fluid",
            parents=[common],
            help="incompressible Euler flow on a closed surface (a vortex pair, a Rossby-Haurwitz wave), drawn or animated",
            description="Run the spectral Euler flow of ddgjax.fluids from a vortex pair (default; on the built-in sphere "
            "or a closed mesh file) or a Rossby-Haurwitz wave on the rotating sphere, with a passive dye; print energy and "
            "enstrophy drift (and the wave's measured rate against Haurwitz's closed form) and write a figure, one PNG "
            "per saved state or a GIF.",
        )
    )
    reconstruct.add_arguments(
        sub.add_parser(
            "reconstruct",
            parents=[common],
            help="Poisson surface reconstruction of a point cloud (sampled from a mesh by default), drawn beside the points",
            description="Reconstruct a closed surface from oriented points (a point file, or points sampled from a mesh "
            "or the built-in torus) by a screened spectral Poisson solve and marching cubes; print the mesh's topology, "
            "its distance to the sampled surface and the time, and draw the points beside the reconstruction.",
        )
    )
    warmup.add_arguments(
        sub.add_parser(
            "warmup",
            parents=[common],
            help="compile the common entry points for a set of meshes (files or folders) into the caches, ahead of time",
            description="Run the Laplacian, curvatures, Poisson, heat distance, eigenpairs and log map once per distinct "
            "mesh size, so that later processes (notebooks, training runs) read their compiled programs from disk.",
        )
    )
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the `ddgjax` console script; returns the exit status."""
    # Geometry wants float64; the CLI, like tests and notebooks, enables it explicitly (DESIGN.md).
    jax.config.update("jax_enable_x64", True)
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 0
    off = args.no_compilation_cache or not switched_on()
    with persistent_compilation_cache(None if off else cache_directory()), _program_store_off(args.no_compilation_cache):
        return int(args.run(args) or 0)


@contextlib.contextmanager
def _program_store_off(off: bool) -> Iterator[None]:
    """`--no-compilation-cache` switches ddgjax's program store off too, for the command only."""
    if not off:
        yield
        return
    previous = os.environ.get(CACHE_VARIABLE)
    os.environ[CACHE_VARIABLE] = "0"
    try:
        yield
    finally:
        if previous is None:
            del os.environ[CACHE_VARIABLE]
        else:
            os.environ[CACHE_VARIABLE] = previous
