"""The documentation site's structure stays whole as the library grows.

Every public package has its API reference page in `mkdocs.yml`'s navigation, every notebook is on the site,
every page the navigation names exists, and the gallery page and figures match `docs/make_gallery.py`'s list
(one figure per command that draws one). Rendering itself (docstrings, references, notebooks) is checked by
`mkdocs build --strict`, which CI runs after the tests.
"""

from __future__ import annotations

import importlib.util
import pathlib
import pkgutil
import re

import pytest

import ddgjax
from ddgjax._cli import build_parser

REPO = pathlib.Path(__file__).resolve().parents[1]
DOCS = REPO / "docs"


def _navigation() -> list[str]:
    """The Markdown and notebook paths named in mkdocs.yml's `nav:` (read as text: mkdocs.yml holds a YAML tag)."""
    text = (REPO / "mkdocs.yml").read_text()
    nav = text.split("\nnav:\n", 1)[1].split("\n\n", 1)[0]
    return re.findall(r"([\w./-]+\.(?:md|ipynb))\s*$", nav, flags=re.MULTILINE)


def _gallery():
    spec = importlib.util.spec_from_file_location("make_gallery", DOCS / "make_gallery.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_every_page_in_the_navigation_exists():
    pages = _navigation()
    assert len(pages) > 20
    missing = [page for page in pages if not (DOCS / page).is_file()]
    assert not missing, f"mkdocs.yml names pages that do not exist under docs/: {missing}"


def test_every_public_package_has_a_reference_page():
    # ddgjax.cli is the console script's entry point, not an API for users.
    packages = sorted(
        info.name for info in pkgutil.iter_modules(ddgjax.__path__) if not info.name.startswith("_") and info.name != "cli"
    )
    assert {"mesh", "solve", "geodesics", "plot", "io"} <= set(packages)
    pages = set(_navigation())
    for name in packages:
        page = f"reference/{name}.md"
        assert page in pages, f"ddgjax.{name} has no API page: add docs/{page} with `::: ddgjax.{name}` to mkdocs.yml's nav"
        assert f"::: ddgjax.{name}" in (DOCS / page).read_text()


def test_each_reference_page_lists_its_package_in_its_own_order():
    # The pages list their members explicitly, entry points first (mkdocstrings renders them in that order); a
    # public name added to a package and not to its page would be missing from the site, and links to it broken.
    spec = importlib.util.spec_from_file_location("docs_hooks", DOCS / "hooks.py")
    hooks = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(hooks)
    entries = {entry for targets in hooks.public_names().values() for entry in targets}
    for page in sorted((DOCS / "reference").glob("*.md")):
        if page.stem == "index":
            continue
        listed = re.findall(r"^ {8}- (\w+)$", page.read_text(), flags=re.MULTILINE)
        documented = {entry.rsplit(".", 1)[1] for entry in entries if entry.startswith(f"reference/{page.stem}/#")}
        assert len(listed) == len(set(listed)), f"{page.name} lists a member twice"
        assert set(listed) == documented, (
            f"docs/reference/{page.name}: add {sorted(documented - set(listed))} to its members, "
            f"remove {sorted(set(listed) - documented)}"
        )


def test_every_notebook_is_on_the_site():
    pages = set(_navigation())
    for notebook in sorted((REPO / "notebooks").glob("*.ipynb")):
        assert f"notebooks/{notebook.name}" in pages, f"{notebook.name} is not in mkdocs.yml's nav"


def test_the_gallery_page_and_figures_match_the_script():
    gallery = _gallery()
    assert (DOCS / "gallery.md").read_text() == gallery.page(), "docs/gallery.md is stale: run python docs/make_gallery.py"
    for entry in gallery.GALLERY:
        figure = gallery.FIGURES / f"{entry.name}.png"
        assert figure.is_file(), f"missing {figure.relative_to(REPO)}: run python docs/make_gallery.py {entry.name}"
        assert figure.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        build_parser().parse_args([*entry.args, "--output", "x.png"])  # every command line is still valid
    assert len({entry.name for entry in gallery.GALLERY}) == len(gallery.GALLERY)


def test_every_command_that_draws_is_in_the_gallery():
    parser = build_parser()
    commands = next(action for action in parser._actions if action.dest == "command").choices
    drawing = {name for name, sub in commands.items() if any("--output" in action.option_strings for action in sub._actions)}
    assert drawing >= {"flow", "poisson", "geodesic", "spectrum", "param", "fields", "optimize"}
    shown = {entry.args[0] for entry in _gallery().GALLERY}
    assert drawing <= shown, f"commands without a gallery figure: {sorted(drawing - shown)}"


@pytest.mark.parametrize("name", ["flow", "geodesic", "param", "fields"])
def test_the_readme_shows_gallery_figures(name):
    assert f"docs/gallery/{name}.png" in (REPO / "README.md").read_text()
