"""Checks on the built site's HTML that `mkdocs build --strict` does not make (CI runs it after the build).

`python docs/check_site.py SITE_DIR` exits 1 naming each page where maths was left as typed (a `$...$`, or a
stray `$$` that Markdown split from its formula, in a text node outside code: `docs/hooks.py` missed it), a notebook page without typeset maths where
its notebook has some, a `<script src="">` (a loader without a URL), or a script loaded from another
site (the pages work offline: plotly.js is served by the site, `docs/hooks.py`), or a link within the site to a
page or an anchor that does not exist (the hooks' cross-links are made after mkdocs checks its own), or an
entry of `ENTRY_POINTS` whose reference entry shows no Examples section with a `>>>` example or no typeset
formula (`<math>`, its key formula written as LaTeX in its docstring). Not a page
(`exclude_docs`).
"""

from __future__ import annotations

import json
import pathlib
import sys

import bs4

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from hooks import _LEAVE_ALONE, _MATH

DOCS = pathlib.Path(__file__).resolve().parent

#: The entry points a user meets first, one list for the docstring test and this check: each one's docstring has an
#: `Examples:` section whose doctest the test suite runs (tests/test_docstring_examples.py), and its entry on the
#: built reference page (`reference/<package>/`, id the dotted name) shows it.
ENTRY_POINTS = (
    "ddgjax.mesh.Mesh",
    "ddgjax.mesh.icosphere",
    "ddgjax.mesh.vertex_angle_defects",
    "ddgjax.curves.Curve",
    "ddgjax.curves.curvature",
    "ddgjax.curves.curve_shortening_flow",
    "ddgjax.dec.d0",
    "ddgjax.dec.hodge1",
    "ddgjax.laplacian.cotan_laplacian",
    "ddgjax.laplacian.mass_matrix",
    "ddgjax.laplacian.laplacian_and_mass",
    "ddgjax.laplacian.intrinsic_delaunay",
    "ddgjax.discretization.discretize",
    "ddgjax.solve.linear_solve",
    "ddgjax.solve.factorize",
    "ddgjax.pde.solve_poisson",
    "ddgjax.pde.harmonic_interpolation",
    "ddgjax.pde.hodge_decomposition",
    "ddgjax.pde.mean_curvature_flow",
    "ddgjax.spectral.eigenpairs",
    "ddgjax.spectral.heat_kernel_signature",
    "ddgjax.geodesics.heat_distance",
    "ddgjax.geodesics.heat_distance_solver",
    "ddgjax.geodesics.signed_heat_distance",
    "ddgjax.geodesics.vector_heat_solver",
    "ddgjax.geodesics.parallel_transport",
    "ddgjax.geodesics.log_map",
    "ddgjax.param.lscm",
    "ddgjax.param.tutte_embedding",
    "ddgjax.param.harmonic_map",
    "ddgjax.param.spectral_conformal_map",
    "ddgjax.param.boundary_first_flattening",
    "ddgjax.fields.smoothest_field",
    "ddgjax.fields.field_singularities",
    "ddgjax.deform.arap",
    "ddgjax.deform.biharmonic_deformation",
    "ddgjax.matching.functional_map",
    "ddgjax.matching.match_shapes",
    "ddgjax.fluids.fluid_basis",
    "ddgjax.fluids.euler_flow",
    "ddgjax.graph.graph_laplacian",
    "ddgjax.graph.knn_graph",
    "ddgjax.graph.tutte_layout",
    "ddgjax.pointcloud.point_cloud_laplacian",
    "ddgjax.pointcloud.point_cloud_heat_distance",
    "ddgjax.pointcloud.point_cloud_heat_solver",
    "ddgjax.batch.MeshBatch",
    "ddgjax.batch.laplacian_apply",
    "ddgjax.volume.tet_ball",
    "ddgjax.volume.cotan_laplacian",
    "ddgjax.volume.mass_matrix",
    "ddgjax.optim.minimize_shape",
    "ddgjax.optim.minimize_energy",
    "ddgjax.optim.large_steps",
    "ddgjax.learn.diffusion_operators",
    "ddgjax.learn.DiffusionNet",
)


def problems(site: pathlib.Path) -> list[str]:
    """What is wrong, one line per page and problem."""
    found = []
    soups = {page: bs4.BeautifulSoup(page.read_text(encoding="utf-8"), "html.parser") for page in sorted(site.rglob("*.html"))}
    ids = {page: {tag["id"] for tag in soup.find_all(id=True)} for page, soup in soups.items()}
    for page, soup in soups.items():
        name = page.relative_to(site)
        for link in soup.find_all("a", href=True):
            broken = _broken(link["href"], page, site, ids)
            if broken:
                found.append(f"{name}: a link to {broken}")
        raw = [
            str(node).strip()[:80]
            for node in soup.find_all(string=True)
            if not isinstance(node, bs4.element.PreformattedString)
            and not any(parent.name in _LEAVE_ALONE for parent in node.parents)
            and (_MATH.search(str(node)) or "$$" in str(node))
        ]
        if raw:
            found.append(f"{name}: maths left as typed: {raw[:3]}")
        if soup.find("script", src=""):
            found.append(f"{name}: a <script> without a URL")
        for script in soup.find_all("script", src=True):
            source = script["src"]
            if source.startswith(("http:", "https:", "//")):
                found.append(f"{name}: a script from another site: {source}")
            elif source and not ((site if source.startswith("/") else page.parent) / source.split("?")[0].lstrip("/")).is_file():
                found.append(f"{name}: a script the site does not hold: {source}")
    for notebook in sorted((DOCS / "notebooks").glob("*.ipynb")):
        cells = json.loads(notebook.read_text(encoding="utf-8"))["cells"]
        has_math = any(cell["cell_type"] == "markdown" and _MATH.search("".join(cell["source"])) for cell in cells)
        page = site / "notebooks" / notebook.stem / "index.html"
        if has_math and "<math" not in page.read_text(encoding="utf-8"):
            found.append(f"{page.relative_to(site)}: its notebook has maths and the page none typeset")
    found += _entries_without_examples(soups, site)
    return found


def _entries_without_examples(soups: dict, site: pathlib.Path) -> list[str]:
    """One line per `ENTRY_POINTS` entry missing from the reference, or shown without an Examples section or without
    a typeset formula."""
    found = []
    for name in ENTRY_POINTS:
        page = site / "reference" / name.split(".")[1] / "index.html"
        heading = soups[page].find(id=name) if page in soups else None
        if heading is None:  # the reference laid out otherwise: the entry anywhere on the site
            heading = next((tag for tag in (soup.find(id=name) for soup in soups.values()) if tag is not None), None)
        if heading is None:
            found.append(f"{page.relative_to(site)}: no entry {name} (ENTRY_POINTS)")
        else:
            if not has_examples_section(heading):
                found.append(f"{page.relative_to(site)}: the entry {name} shows no Examples section with a >>> example")
            if not has_typeset_maths(heading):
                found.append(f"{page.relative_to(site)}: the entry {name} shows no typeset formula (<math>)")
    return found


def has_typeset_maths(heading: bs4.element.Tag) -> bool:
    """Whether the mkdocstrings entry whose heading is `heading` shows, in its own docstring (not a member's), a
    typeset formula: a `<math>` element, which `docs/hooks.py` makes of the docstring's `$...$` or `$$...$$`."""
    entry = heading.find_parent("div", class_="doc-object")
    return entry is not None and any(math.find_parent("div", class_="doc-object") is entry for math in entry.find_all("math"))


def has_examples_section(heading: bs4.element.Tag) -> bool:
    """Whether the mkdocstrings entry whose heading is `heading` shows, in its own docstring (not a member's), an
    "Examples:" section title followed by a code block with a `>>>` line."""
    entry = heading.find_parent("div", class_="doc-object")
    if entry is None:
        return False
    for title in entry.find_all(class_="doc-section-title"):
        if title.get_text(strip=True).rstrip(":") != "Examples" or title.find_parent("div", class_="doc-object") is not entry:
            continue
        block = title.find_parent("p") or title
        for sibling in block.find_next_siblings():
            if sibling.find(class_="doc-section-title"):
                break  # the next section
            if ">>>" in sibling.get_text():
                return True
    return False


def _broken(href: str, page: pathlib.Path, site: pathlib.Path, ids: dict) -> str | None:
    """What `href` on `page` points at that the site lacks (a page, or an anchor of it), or None."""
    if href.startswith(("http:", "https:", "mailto:", "//", "javascript:")) or href in ("", "#"):
        return None
    path, _, anchor = href.partition("#")
    path = path.split("?")[0]
    target = page if not path else (site if path.startswith("/") else page.parent) / path.lstrip("/")
    target = target.resolve()
    if target.is_dir():
        target = target / "index.html"
    if target.suffix != ".html":
        return None if target.exists() else f"{href} (no such file)"
    if target not in ids:
        return f"{href} (no such page)"
    if anchor and anchor not in ids[target]:
        return f"{href} (no such anchor)"
    return None


if __name__ == "__main__":
    issues = problems(pathlib.Path(sys.argv[1]))
    print("\n".join(issues) or "site checks: maths typeset on every page, every script served by the site")
    sys.exit(1 if issues else 0)
