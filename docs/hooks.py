"""mkdocs hooks of the documentation site (mkdocs.yml: `hooks:`); not a page (`exclude_docs`).

The notebooks' kernels inherit this process's environment: `PLOTLY_RENDERER` makes `ddgjax.plot.show`'s figures
HTML that loads plotly.js from its CDN (plotly >= 6 otherwise writes only a mimetype nbconvert cannot render,
and `"notebook"` would embed ~5 MB of plotly.js in every page with a figure). The site then serves that
script itself: the plotly package's own `plotly.min.js` is copied into the site once, and each page's CDN
address becomes that copy's (with the MathJax loader plotly adds for axis labels, which none here has), so
the 3-D views work offline.

Search ranks the API reference and the guides above the notebooks: a notebook page's code cells and
outputs carry Material's `data-search-exclude` and its entries a lower boost (`_NOTEBOOK_SEARCH_BOOST`),
so a query such as "heat distance" finds the API entry first, not a cell that happens to call it
(Material's parser still files some cells' code under a notebook's first entry, hence the boost).

Maths is typeset when the site is built, not in the reader's browser: `$...$` (inline) and `$$...$$`
(display) in the text of a page (notebook Markdown cells, Markdown pages, docstrings) become MathML by
`latex2mathml`, which every current browser renders natively. So a page needs no script and no CDN,
works offline and prints as it shows; code, preformatted text and scripts are left alone, and
nbconvert's empty MathJax loader is dropped.
"""

from __future__ import annotations

import os
import pathlib
import re
import shutil

import bs4
import plotly
from latex2mathml.converter import convert

os.environ.setdefault("PLOTLY_RENDERER", "notebook_connected")

# `$$...$$` first (it may span lines), then `$...$` that opens before and closes after a non-space (so
# prices and shell prompts in prose stay text), never an escaped `\$`.
_MATH = re.compile(r"\$\$(?P<display>.+?)\$\$|(?<![\\$])\$(?P<inline>[^\s$](?:[^$]*?[^\s\\$])?)\$(?!\$)", re.DOTALL)
_LEAVE_ALONE = {"code", "pre", "script", "style", "textarea", "math"}
_NOTEBOOK_SEARCH_BOOST = 0.25
_PLOTLY_CDN = re.compile(r"^https://cdn\.plot\.ly/plotly-[\w.-]+\.min\.js$")
_PLOTLY_COPY = "assets/javascripts/plotly.min.js"  # where the site keeps plotly.js, from its root


def typeset(text: str) -> str | None:
    """`text` with its TeX as MathML (an HTML fragment), or None when it holds no maths."""
    if "$" not in text:
        return None
    pieces, end = [], 0
    for match in _MATH.finditer(text):
        display = match.group("display") is not None
        tex = match.group("display") if display else match.group("inline")
        pieces += [_escape(text[end : match.start()]), convert(tex.strip(), display="block" if display else "inline")]
        end = match.end()
    if not pieces:
        return None
    return "".join(pieces) + _escape(text[end:])


def self_contained(html: str, root: str = "") -> str:
    """The page with its maths typeset (`typeset`, outside code, scripts and existing MathML) and its
    scripts served by the site: plotly.js from `root + _PLOTLY_COPY`, no MathJax loader."""
    soup = bs4.BeautifulSoup(html, "html.parser")
    for script in soup.find_all("script", src=""):  # nbconvert's MathJax loader without a URL
        script.decompose()
    for script in soup.find_all("script", type="text/x-mathjax-config"):
        script.decompose()
    for script in soup.find_all("script", src=True):
        if _PLOTLY_CDN.match(script["src"]):
            script.attrs = {"charset": "utf-8", "src": root + _PLOTLY_COPY}
        elif "mathjax" in script["src"].lower():
            script.decompose()
    for node in list(soup.find_all(string=True)):
        if isinstance(node, bs4.element.PreformattedString) or any(p.name in _LEAVE_ALONE for p in node.parents):
            continue
        fragment = typeset(str(node))
        if fragment is not None:
            node.replace_with(bs4.BeautifulSoup(fragment, "html.parser"))
    return str(soup)


def searchable_prose(html: str) -> str:
    """A notebook page's code cells and outputs excluded from the search index (`data-search-exclude`)."""
    soup = bs4.BeautifulSoup(html, "html.parser")
    for block in soup.select(".jp-InputArea, .jp-OutputArea, .jp-Cell-outputWrapper"):
        block["data-search-exclude"] = ""
    return str(soup)


def on_page_content(html: str, page, config, files) -> str:
    """Notebook pages: their code and outputs left out of search, their entries ranked lower (MkDocs event,
    before search indexes the page)."""
    if not page.file.src_uri.endswith(".ipynb"):
        return html
    page.meta.setdefault("search", {}).setdefault("boost", _NOTEBOOK_SEARCH_BOOST)
    return searchable_prose(html)


def on_post_page(output: str, page, config) -> str:
    """Typeset each page's maths and serve its scripts from the site (MkDocs event)."""
    if not (_MATH.search(output) or "cdn.plot.ly" in output or '<script src="">' in output):
        return output
    return self_contained(output, root="../" * page.url.count("/"))


def on_post_build(config) -> None:
    """Copy the plotly package's plotly.js into the site, where `self_contained` points the pages (MkDocs event)."""
    target = pathlib.Path(config["site_dir"]) / _PLOTLY_COPY
    target.parent.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(pathlib.Path(plotly.__file__).parent / "package_data" / "plotly.min.js", target)


def _escape(text: str) -> str:
    return text.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")
