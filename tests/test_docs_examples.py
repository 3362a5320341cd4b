"""Execute the ```python code blocks of every Markdown page under `docs/`, so the documentation never lies.

One test per page (`docs/**/*.md`, and the README): its blocks run in order in one shared namespace, as a reader
pasting them one after another into one Python session would (a doctest session). A block whose first
line is a comment `# not run: <reason>` is shown on the page and not executed: it is for code of a
peer library that cannot be installed beside ddgjax (PyTorch3D), whose other side the page checks in
blocks that do run. A failing block fails its page's test with the page, the block's line number and
the traceback, whose line numbers are those of the Markdown file.

Each page starts with JAX's default `jax_enable_x64 = False` (restored afterwards), so a page must turn
float64 on itself, as the README's quick start does: a reader copies the page, not the test suite's
configuration. Each page runs in a fresh temporary working directory (for the files it writes), with
matplotlib's non-interactive backend.
"""

from __future__ import annotations

import pathlib
import re
import textwrap
import traceback

import jax
import pytest

DOCS = pathlib.Path(__file__).resolve().parents[1] / "docs"
README = DOCS.parent / "README.md"

# Pages whose blocks take more than about 2 s together, listed so the tiers are decided statically, not
# by timing: the home page's tour eigensolves and compiles its first kernels; the guides differentiate through
# solves, eigensolves and flows, and compare with libigl, potpourri3d and PyTorch3D's formulas.
SLOW_PAGES = frozenset(
    {
        "index.md",
        "tour.md",
        "README.md",
        "guides/differentiating.md",
        "guides/from-libigl.md",
        "guides/from-potpourri3d.md",
        "guides/from-pytorch3d.md",
    }
)

_FENCE = re.compile(r"^(?P<indent>[ \t]*)(?P<fence>```+|~~~+)\s*(?P<info>[^`\s]*)")
_NOT_RUN = re.compile(r"^#\s*not run\s*:")


def python_blocks(text: str) -> list[tuple[int, str]]:
    """`(line, code)` of each ```python fenced block of a Markdown text, `line` the 1-based line of its
    first code line; blocks indented under an admonition or a list are dedented."""
    blocks, lines, i = [], text.splitlines(), 0
    while i < len(lines):
        opening = _FENCE.match(lines[i])
        if opening is None:
            i += 1
            continue
        indent, fence, info = opening["indent"], opening["fence"], opening["info"].lower()
        start, i = i + 1, i + 1
        while i < len(lines) and not (lines[i].strip().startswith(fence) and lines[i].strip().strip(fence[0]) == ""):
            i += 1
        if info in ("python", "py", "python3"):
            body = [line[len(indent) :] if line.startswith(indent) else line.lstrip() for line in lines[start:i]]
            blocks.append((start + 1, textwrap.dedent("\n".join(body))))
        i += 1
    return blocks


def _pages() -> list[pathlib.Path]:
    """Every page of the site, and the README (its ten-line example is the first code a newcomer runs)."""
    return [*sorted(DOCS.glob("**/*.md")), README]


def _page_id(path: pathlib.Path) -> str:
    return "README.md" if path == README else path.relative_to(DOCS).as_posix()


def _params():
    return [
        pytest.param(path, id=_page_id(path), marks=[pytest.mark.slow] if _page_id(path) in SLOW_PAGES else [])
        for path in _pages()
    ]


def test_block_parser_finds_python_blocks_and_their_lines():
    text = "# Title\n\n```python\nx = 1\n```\n\n!!! note\n    ```python\n    y = x + 1\n    ```\n```bash\nls\n```\n"
    assert python_blocks(text) == [(4, "x = 1"), (9, "y = x + 1")]


@pytest.mark.parametrize("page", _params())
def test_page_code_blocks_run(page, tmp_path, monkeypatch):
    """Run the page's ```python blocks in order in one namespace; `# not run:` blocks are skipped."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("MPLBACKEND", "Agg")
    namespace = {"__name__": "__docs__"}
    x64 = jax.config.jax_enable_x64
    jax.config.update("jax_enable_x64", False)  # JAX's default: the page must enable float64 itself
    try:
        for line, code in python_blocks(page.read_text(encoding="utf-8")):
            if _NOT_RUN.match(code.lstrip()):
                continue
            # Padding keeps the Markdown file's line numbers in the traceback.
            program = compile("\n" * (line - 1) + code, str(page), "exec")
            try:
                exec(program, namespace)
            except Exception:
                pytest.fail(
                    f"{page.relative_to(DOCS.parent)}, block at line {line} failed:\n{traceback.format_exc()}", pytrace=False
                )
    finally:
        jax.config.update("jax_enable_x64", x64)
