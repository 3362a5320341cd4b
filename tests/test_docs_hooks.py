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
