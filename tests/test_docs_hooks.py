"""The documentation site's build hooks (docs/hooks.py): maths typeset to MathML, scripts served by the site."""

from __future__ import annotations

import importlib.util
import pathlib

import bs4
import plotly.graph_objects as go
import plotly.io as pio

_SPEC = importlib.util.spec_from_file_location("docs_hooks", pathlib.Path(__file__).resolve().parents[1] / "docs" / "hooks.py")
hooks = importlib.util.module_from_spec(_SPEC)
_SPEC.loader.exec_module(hooks)


def test_inline_and_display_maths_become_mathml_and_code_stays_as_typed():
    page = (
        "<p>Solve $-\\Delta u = 1$ on the disk; the answer is $$u = \\frac{1 - r^2}{4}.$$</p>"
        "<p>It costs $5 and $ 6, and \\$HOME stays.</p><pre><code>x = '$a$'</code></pre><code>$b$</code>"
    )
    soup = bs4.BeautifulSoup(hooks.self_contained(page), "html.parser")
    maths = soup.find_all("math")
    assert [m["display"] for m in maths] == ["inline", "block"]
    assert maths[0].get_text() == "−Δu=1"  # MathML holds the symbols, not the TeX
    assert maths[1].find("mfrac") is not None
    text = soup.get_text()
    assert "$5 and $ 6" in text and "\\$HOME" in text  # no maths: a price, a lone dollar, an escaped one
    assert soup.find("pre").get_text() == "x = '$a$'" and soup.find_all("code")[-1].get_text() == "$b$"


def test_plotly_figures_load_plotly_js_from_the_site_and_no_mathjax_loader_remains():
    figure_html = pio.renderers["notebook_connected"].to_mimebundle(go.Figure(go.Scatter(x=[0, 1], y=[0, 1])).to_dict())[
        "text/html"
    ]
    assert "https://cdn.plot.ly/" in figure_html and "mathjax" in figure_html.lower()
    page = f'<script src=""> </script><script type="text/x-mathjax-config">MathJax.Hub.Config({{}})</script>{figure_html}'
    soup = bs4.BeautifulSoup(hooks.self_contained(page, root="../../"), "html.parser")
    sources = [script["src"] for script in soup.find_all("script", src=True)]
    assert sources == ["../../assets/javascripts/plotly.min.js"]
    assert "x-mathjax-config" not in str(soup) and "Plotly.newPlot" in str(soup)  # the figure's own script is kept


def test_a_page_without_maths_or_foreign_scripts_is_left_byte_for_byte():
    class Page:
        url = "guides/x/"

    page = "<html><body><p>No maths &amp; no scripts here.</p><br></body></html>"
    assert hooks.on_post_page(page, Page(), {}) is page


def test_public_names_written_as_code_link_to_their_reference_entries():
    page = (
        "<article><p>Call <code>linear_solve</code>, <code>ddgjax.solve.factorize()</code> or <code>ddgjax.Mesh</code>;"
        " a call <code>pde.solve_poisson(m, rho)</code>, <code>x(1)</code>;"
        " a shared name <code>cotan_laplacian</code>, a package <code>ddgjax.spectral</code>, not a name <code>x + 1</code>."
        '</p><pre><code>linear_solve</code></pre><a href="#"><code>factorize</code></a><h2><code>eigenpairs</code></h2></article>'
    )
    soup = bs4.BeautifulSoup(hooks.crosslink(page, "guides/x/"), "html.parser")
    links = {a.get_text(): a["href"] for a in soup.find_all("a") if a["href"] != "#"}
    assert links == {
        "linear_solve": "../../reference/solve/#ddgjax.solve.linear_solve",
        "ddgjax.solve.factorize()": "../../reference/solve/#ddgjax.solve.factorize",
        "ddgjax.Mesh": "../../reference/mesh/#ddgjax.mesh.Mesh",  # where it is documented, not where re-exported
        "ddgjax.spectral": "../../reference/spectral/",
        "pde.solve_poisson(m, rho)": "../../reference/pde/#ddgjax.pde.solve_poisson",
    }  # the shared short name, code blocks, existing links and headings are left alone
    # On a reference page, a shared short name is that package's own.
    on_volume = bs4.BeautifulSoup(
        hooks.crosslink("<article><code>cotan_laplacian</code></article>", "reference/volume/"), "html.parser"
    )
    assert on_volume.find("a")["href"] == "../../reference/volume/#ddgjax.volume.cotan_laplacian"


def test_a_notebook_table_of_contents_points_at_its_headings_ids():
    class AnchorLink:  # mkdocs' table-of-contents entry, as far as the hook reads it (mkdocs is the docs extra's)
        def __init__(self, title: str, id: str, level: int):
            self.title, self.id, self.level, self.children = title, id, level, []

        @property
        def url(self) -> str:
            return "#" + self.id

    entry, kept = AnchorLink("7. Batching with", "7-batching-with", 1), AnchorLink("Intro", "intro", 1)
    html = '<h2 id="intro">Intro</h2><h2 id="7-batching-with-vmap">7. Batching with <code>vmap</code></h2>'
    hooks.repaired_headings(html, [entry, kept])
    assert (entry.url, kept.url) == ("#7-batching-with-vmap", "#intro")


def test_the_site_check_names_broken_links_and_anchors(tmp_path):
    spec = importlib.util.spec_from_file_location("check_site", pathlib.Path(hooks.__file__).parent / "check_site.py")
    check_site = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(check_site)
    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "index.html").write_text('<h2 id="here">x</h2><a href="../b/#there">b</a><a href="#here">ok</a>')
    (tmp_path / "b").mkdir()
    (tmp_path / "b" / "index.html").write_text('<a href="../a/#here">a</a><a href="../c/">c</a><a href="https://x.org">x</a>')
    pages = {page: page.read_text() for page in sorted(tmp_path.rglob("*.html"))}
    ids = {page: {tag["id"] for tag in bs4.BeautifulSoup(text, "html.parser").find_all(id=True)} for page, text in pages.items()}
    found = [
        check_site._broken(link["href"], page, tmp_path, ids)
        for page, text in pages.items()
        for link in bs4.BeautifulSoup(text, "html.parser").find_all("a", href=True)
    ]
    assert [item for item in found if item] == ["../b/#there (no such anchor)", "../c/ (no such file)"]
