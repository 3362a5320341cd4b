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

Every public name written as code (`linear_solve`, `ddgjax.solve.linear_solve`, `solve.linear_solve`,
`linear_solve()`, or a call `linear_solve(A, b)`) links to its entry in the API reference, on every page: guides, the conventions table,
notebooks' prose and the docstrings themselves (`crosslink`). A short name that two packages share
(`cotan_laplacian` in `laplacian` and `volume`) links only where it is qualified, or on the reference
page of a package that has it.
"""

from __future__ import annotations

import functools
import importlib
import inspect
import os
import pathlib
import pkgutil
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
_CALL = re.compile(r"^-?\s*([A-Za-z_][\w.]*)\(")
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


@functools.cache
def public_names() -> dict[str, tuple[str, ...]]:
    """`{written form: (reference entry, ...)}` of every public object of ddgjax's packages and top level.

    Each object has one entry, where its reference page documents it: the package it is defined in (a re-export
    such as `ddgjax.Mesh` or `ddgjax.io.Mesh` links there too), else the top level's page (the errors, results
    and vocabularies). Its forms: `ddgjax.solve.linear_solve`, `solve.linear_solve`, the re-exports' paths, and
    the short name `linear_solve`, which may map to several entries (`cotan_laplacian`)."""
    import ddgjax

    exported = [("", name, getattr(ddgjax, name)) for name in dir(ddgjax) if not name.startswith("_")]
    for module in pkgutil.iter_modules(ddgjax.__path__):
        if not module.name.startswith("_") and module.name != "cli":
            package = importlib.import_module(f"ddgjax.{module.name}")
            exported += [(module.name, name, value) for name, value in vars(package).items() if not name.startswith("_")]
    exported = [item for item in exported if not inspect.ismodule(item[2]) and item[1] != "annotations"]
    found: dict = {}  # id(object), or (package, name) of a constant -> (its entry, the paths it is exported at)
    for package, name, value in exported:  # constants (no home module): where exported, the top level's first
        if name.isupper() and not hasattr(value, "__module__"):
            key = ("", name) if hasattr(ddgjax, name) else (package, name)
            found.setdefault(
                key, (f"reference/{package + '/' if key[0] else ''}#{'.'.join(filter(None, ('ddgjax', key[0], name)))}", [])
            )
    exported = [item for item in exported if hasattr(item[2], "__module__")]
    for package, name, value in exported:  # first where each object is defined
        home = value.__module__ or ""
        if package and (home == f"ddgjax.{package}" or home.startswith(f"ddgjax.{package}.")):
            found.setdefault(id(value), (f"reference/{package}/#ddgjax.{package}.{name}", []))
    for package, name, value in exported:  # the top level's own: errors, results, vocabularies
        if not package and id(value) not in found and (name.isupper() or (value.__module__ or "").startswith("ddgjax")):
            found[id(value)] = (f"reference/#ddgjax.{name}", [])
    for package, name, value in exported:
        if id(value) in found:
            found[id(value)][1].append(f"ddgjax.{package}.{name}" if package else f"ddgjax.{name}")
    for key, (_, paths) in found.items():
        if isinstance(key, tuple):
            paths.append(".".join(filter(None, ("ddgjax", *key))))
    names: dict[str, set[str]] = {}
    for entry, paths in found.values():
        for path in paths:
            for form in (path, path.removeprefix("ddgjax."), path.rsplit(".", 1)[1]):
                names.setdefault(form, set()).add(entry)
    for module in pkgutil.iter_modules(ddgjax.__path__):  # the packages themselves: `ddgjax.solve`
        if not module.name.startswith("_") and module.name != "cli":
            names.setdefault(f"ddgjax.{module.name}", set()).add(f"reference/{module.name}/")
    return {form: tuple(sorted(entries)) for form, entries in names.items()}


def crosslink(html: str, page_url: str) -> str:
    """`<code>` holding a public name, outside links, code blocks and headings, made a link to its reference entry.

    `page_url` is the page's site-relative URL (`reference/solve/`), for relative links and for picking a
    shared short name's own package on its reference page."""
    names = public_names()
    soup = bs4.BeautifulSoup(html, "html.parser")
    content = soup.find("article") or soup
    root = "../" * page_url.count("/")
    changed = False
    for code in content.find_all("code"):
        text = code.get_text().strip()
        if not text or code.find_parent(["a", "pre", "h1", "h2", "h3", "h4", "h5", "h6"]) is not None:
            continue
        if code.find_parent(class_=["doc-signature", "doc-heading"]) is not None:
            continue
        call = _CALL.match(text)  # `name(...)`, a call as the guides' tables write it: the name's entry
        targets = names.get(text.removesuffix("()")) or (names.get(call.group(1)) if call else None)
        if not targets:
            continue
        if len(targets) > 1:  # a short name several packages share: this page's own, else none
            targets = tuple(t for t in targets if t.startswith(page_url + "#")) if page_url.startswith("reference/") else ()
            if len(targets) != 1:
                continue
        link = soup.new_tag("a", href=root + targets[0])
        code.wrap(link)
        changed = True
    return str(soup) if changed else html


def repaired_headings(html: str, toc) -> None:
    """Point the table of contents of a notebook page at its headings' ids: mkdocs-jupyter's entries drop a
    heading's code spans from the slug (`...-batching-with`) where nbconvert's id keeps them (`...-with-vmap`).
    An entry whose id the page lacks takes the one heading id that extends it."""
    ids = re.findall(r'\bid="([^"]+)"', html)
    stack = list(toc)
    while stack:
        entry = stack.pop()
        stack.extend(entry.children)
        if entry.id in ids:
            continue
        extending = [i for i in ids if i.startswith(entry.id + "-")]
        if len(extending) == 1:
            entry.id = extending[0]  # the entry's `url` is `"#" + id`


def on_page_content(html: str, page, config, files) -> str:
    """Notebook pages: their table of contents pointed at their headings, their code and outputs left out of
    search, their entries ranked lower (MkDocs event, before search indexes the page)."""
    if not page.file.src_uri.endswith(".ipynb"):
        return html
    repaired_headings(html, page.toc)
    page.meta.setdefault("search", {}).setdefault("boost", _NOTEBOOK_SEARCH_BOOST)
    return searchable_prose(html)


def on_post_page(output: str, page, config) -> str:
    """Link each page's public names to their entries, typeset its maths and serve its scripts from the site
    (MkDocs event)."""
    output = crosslink(output, page.url)
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
