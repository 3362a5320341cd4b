"""Make the gallery: one figure per capability, drawn by the `ddgjax` command line from built-in shapes.

    python docs/make_gallery.py            # every figure, then docs/gallery.md
    python docs/make_gallery.py geodesic   # only the named entries (the page is written anew either way)

Each entry of `GALLERY` is one command line, run as `ddgjax ARGS --output docs/gallery/NAME.png` in this process
(`ddgjax.cli.main`, so JAX starts once); the figures are committed, so the site and the README show them without
running anything. `docs/gallery.md` is generated from the same list: the command under each figure is the one
that drew it. Rerun the script after changing a command's figure.
"""

from __future__ import annotations

import contextlib
import io
import pathlib
import sys
from typing import NamedTuple

DOCS = pathlib.Path(__file__).resolve().parent
FIGURES = DOCS / "gallery"
PAGE = DOCS / "gallery.md"


class Entry(NamedTuple):
    name: str  # the figure's file name, docs/gallery/NAME.png
    title: str
    args: tuple[str, ...]  # the command line, without --output
    caption: str


GALLERY = (
    Entry(
        "flow",
        "Curve-shortening flows",
        ("flow",),
        "The reading report's Figure 3: one non-convex polygon evolved by the A, B and D discrete curve-shortening "
        "flows, and the quantities each keeps (total curvature, centroid, cyclic residual). `ddgjax.curves`.",
    ),
    Entry(
        "curvature",
        "Curvature",
        ("info", "--output", "curvature.png"),
        "The pointwise Gaussian and mean curvature of a torus (angle defects and dihedral angles over Voronoi areas): "
        "positive outside, negative inside, summing to `2 pi chi = 0`. `ddgjax.mesh`.",
    ),
    Entry(
        "poisson",
        "A Poisson problem",
        ("poisson",),
        "`-Delta phi = 1` on the unit disk with `phi = 0` on its boundary, beside its error against `(1 - r^2) / 4`. "
        "`ddgjax.pde.solve_poisson`.",
    ),
    Entry(
        "poisson_sphere",
        "Poisson on a closed surface",
        ("poisson", "sphere", "--rho", "y2"),
        "A degree-2 spherical harmonic right-hand side on the unit sphere, whose exact solution is `-rho / 6`. "
        "`ddgjax.pde.solve_poisson`.",
    ),
    Entry(
        "poisson_ball",
        "Poisson in a solid",
        ("poisson", "ball"),
        "`-Delta phi = 1` in the unit ball (a tet mesh) with `phi = 0` on its sphere, drawn on the slice `z = 0` beside "
        "its error against `(1 - r^2) / 6`. `ddgjax.pde.solve_poisson` on a `ddgjax.volume.TetMesh`.",
    ),
    Entry(
        "harmonic",
        "Harmonic interpolation",
        ("poisson", "--harmonic"),
        "A harmonic function on the disk interpolating boundary values. `ddgjax.pde.harmonic_interpolation`.",
    ),
    Entry(
        "geodesic",
        "Geodesic distance",
        ("geodesic",),
        "The heat method's distance from one vertex of a torus, with isolines. `ddgjax.geodesics.heat_distance`.",
    ),
    Entry(
        "geodesic_log_map",
        "Log map",
        ("geodesic", "--log-map"),
        "The logarithmic map at one vertex of a torus drawn as a polar-grid decal, by the vector heat method. "
        "`ddgjax.geodesics.log_map`.",
    ),
    Entry(
        "geodesic_signed",
        "Signed distance to a broken curve",
        ("geodesic", "--signed", "--gap", "5"),
        "The signed distance to the loop bounding a geodesic ball on a torus, five of its edges removed: the signed "
        "heat method closes the gap. `ddgjax.geodesics.signed_heat_distance`.",
    ),
    Entry(
        "fluid",
        "Fluid on a sphere",
        ("fluid",),
        "A pair of opposite vortices travelling east on the unit sphere, stirring latitude bands of dye: incompressible "
        "Euler flow in 64 Laplacian eigenfunctions, energy and enstrophy kept to round-off. `ddgjax.fluids.euler_flow`.",
    ),
    Entry(
        "spectrum",
        "Laplacian eigenfunctions",
        ("spectrum",),
        "The first eigenfunctions of the cotan Laplacian on a torus. `ddgjax.spectral.eigenpairs`.",
    ),
    Entry(
        "param",
        "Parametrisation",
        ("param",),
        "Boundary first flattening of a hemisphere: the surface textured through the map, the map, and its "
        "quasi-conformal distortion. `ddgjax.param.boundary_first_flattening`.",
    ),
    Entry(
        "param_lscm",
        "Least-squares conformal map",
        ("param", "--method", "lscm"),
        "The same hemisphere flattened by LSCM with two pinned vertices. `ddgjax.param.lscm`.",
    ),
    Entry(
        "fields",
        "Direction fields",
        ("fields",),
        "The globally smoothest cross field of a sphere and its eight index +1/4 singularities. `ddgjax.fields.smoothest_field`.",
    ),
    Entry(
        "fields_vector",
        "A smoothest vector field",
        ("fields", "-n", "1"),
        "The smoothest vector field of the same sphere: two +1 singularities (Poincare-Hopf). `ddgjax.fields`.",
    ),
    Entry(
        "deform",
        "Deformation from handles",
        ("deform", "--method", "both"),
        "A cylinder's top ring turned a quarter turn, its bottom ring fixed: as-rigid-as-possible modelling keeps "
        "the tube round where the biharmonic deformation pinches its middle. `ddgjax.deform.arap`, "
        "`ddgjax.deform.biharmonic_deformation`.",
    ),
    Entry(
        "match",
        "Shape correspondence",
        ("match",),
        "Two meshes of one lumpy surface (an icosphere and a UV sphere, the second bent by ARAP) matched by functional "
        "maps with the orientation-aware term and ZoomOut: a checkerboard on the source pulled back to the target "
        "through the map, next to the same through the true map. `ddgjax.matching.match_shapes`.",
    ),
    Entry(
        "optimize_willmore",
        "Willmore flow",
        ("optimize", "--example", "willmore", "--no-progress"),
        "A bumpy sphere rounded by minimising its Willmore energy at fixed volume with Large Steps, and the energy "
        "going down to `4 pi`. `ddgjax.optim.minimize_shape`.",
    ),
    Entry(
        "optimize_catenoid",
        "Minimal surface",
        ("optimize", "--example", "catenoid", "--no-progress"),
        "A cylinder between two fixed rings relaxed to the catenoid `a cosh(z / a)` by area minimisation. `ddgjax.optim`.",
    ),
    Entry(
        "optimize_fit",
        "Mesh fitting",
        ("optimize", "--example", "fit", "--no-progress"),
        "A sphere deformed to fit a target shape by Chamfer distance and PyTorch3D's regularisers. "
        "`ddgjax.optim.mesh_fitting_loss`.",
    ),
    Entry(
        "reconstruct",
        "Poisson surface reconstruction",
        ("reconstruct", "--depth", "6"),
        "20,000 oriented points sampled from a torus, and the closed genus-1 surface reconstructed from them by a "
        "screened spectral Poisson solve and marching cubes, coloured by the sample density at its vertices. "
        "`ddgjax.reconstruct.poisson_reconstruction`.",
    ),
)


def draw(entry: Entry) -> None:
    """Run the entry's command line, writing its figure; raise when the command fails."""
    from ddgjax.cli import main

    FIGURES.mkdir(exist_ok=True)
    argv = [*entry.args, "--output", str(FIGURES / f"{entry.name}.png")]
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        status = main(argv)
    if status != 0:
        raise SystemExit(f"ddgjax {' '.join(argv)} exited with {status}:\n{printed.getvalue()}")
    compress(FIGURES / f"{entry.name}.png")
    print(f"{entry.name}: ddgjax {' '.join(entry.args)}")


def compress(path: pathlib.Path) -> None:
    """Rewrite a PNG with a 256-colour palette, dithered so colour ramps stay smooth (about half the size)."""
    from PIL import Image  # Pillow comes with matplotlib

    with Image.open(path) as image:
        rgb = image.convert("RGB")
    palette = rgb.quantize(colors=256, method=Image.Quantize.MEDIANCUT)
    indexed = rgb.quantize(colors=256, palette=palette, dither=Image.Dither.FLOYDSTEINBERG)
    # Pillow maps colours to the palette approximately: the background's entry is set to its exact colour.
    colors = indexed.getpalette()
    background = 3 * indexed.getpixel((0, 0))
    colors[background : background + 3] = rgb.getpixel((0, 0))
    indexed.putpalette(colors)
    indexed.save(path, optimize=True)


def page() -> str:
    """The Markdown of `docs/gallery.md`: every entry's figure under the command that drew it."""
    parts = [
        "# Gallery",
        "",
        "One figure per capability, each drawn by the `ddgjax` command line from a built-in shape (no file needed). "
        "Run the command under a figure to draw it yourself; `ddgjax COMMAND --help` lists its options. "
        "`python docs/make_gallery.py` draws them all again and writes this page.",
    ]
    for entry in GALLERY:
        parts += [
            "",
            f"## {entry.title}",
            "",
            "```bash",
            f"ddgjax {' '.join(entry.args)}",
            "```",
            "",
            f"![{entry.title}](gallery/{entry.name}.png)",
            "",
            entry.caption,
        ]
    return "\n".join(parts) + "\n"


def main(names: list[str]) -> None:
    known = {entry.name: entry for entry in GALLERY}
    unknown = sorted(set(names) - set(known))
    if unknown:
        raise SystemExit(f"unknown gallery entries {unknown}; known: {sorted(known)}")
    for entry in GALLERY:
        if not names or entry.name in names:
            draw(entry)
    PAGE.write_text(page())
    print(f"wrote {PAGE.relative_to(DOCS.parent)}")


if __name__ == "__main__":
    main(sys.argv[1:])
