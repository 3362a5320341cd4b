"""Checks on the built site's HTML that `mkdocs build --strict` does not make (CI runs it after the build).

`python docs/check_site.py SITE_DIR` exits 1 naming each page where maths was left as typed (a `$...$`
in a text node outside code: `docs/hooks.py` missed it), a notebook page without typeset maths where
its notebook has some, a `<script src="">` (a loader without a URL), or a script loaded from another
site (the pages work offline: plotly.js is served by the site, `docs/hooks.py`). Not a page (`exclude_docs`).
"""

from __future__ import annotations

import json
import pathlib
import sys

import bs4

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from hooks import _LEAVE_ALONE, _MATH

DOCS = pathlib.Path(__file__).resolve().parent


def problems(site: pathlib.Path) -> list[str]:
    """What is wrong, one line per page and problem."""
    found = []
    for page in sorted(site.rglob("*.html")):
        soup = bs4.BeautifulSoup(page.read_text(encoding="utf-8"), "html.parser")
        name = page.relative_to(site)
        raw = [
            str(node).strip()[:80]
            for node in soup.find_all(string=True)
            if not isinstance(node, bs4.element.PreformattedString)
            and not any(parent.name in _LEAVE_ALONE for parent in node.parents)
            and _MATH.search(str(node))
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
    return found


if __name__ == "__main__":
    issues = problems(pathlib.Path(sys.argv[1]))
    print("\n".join(issues) or "site checks: maths typeset on every page, every script served by the site")
    sys.exit(1 if issues else 0)
