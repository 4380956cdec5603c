"""The documentation site builds with --strict and its API reference holds every public name.

``mkdocs build --strict`` fails on a broken link, a page missing from the nav or a docstring
that does not render; here the built HTML is also checked for what the issue asks of it: the
sections, every public function and class of ``jointseg`` with its docstring, and every route
of the job service's OpenAPI schema.
"""

from __future__ import annotations

import ast
import html
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

#: the whole site built by mkdocs: not for `make test-fast`
pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[2]
PAGES = (
    "index.html",
    "getting-started/install/index.html",
    "getting-started/first-scan/index.html",
    "getting-started/job-service/index.html",
    "getting-started/viewer/index.html",
    "guide/formats/index.html",
    "guide/scans-arrive/index.html",
    "guide/cli/index.html",
    "guide/job-service/index.html",
    "guide/many-machines/index.html",
    "guide/big-scans/index.html",
    "guide/viewer/index.html",
    "guide/networks/index.html",
    "guide/training/index.html",
    "guide/presets/index.html",
    "guide/objects/index.html",
    "reference/index.html",
    "reference/rest/index.html",
    "benchmarks/index.html",
    "ARCHITECTURE/index.html",
    "contributing/index.html",
    "changelog/index.html",
)


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("site")
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}
    mkdocs = [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(out)]
    done = subprocess.run(mkdocs, cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, f"mkdocs build --strict failed:\n{done.stderr[-4000:]}"
    return out


def words(text: str) -> str:
    """Letters-only words joined by one space: markup and punctuation do not matter."""
    return " ".join(re.findall(r"[A-Za-z]+", text))


def public_names() -> list[tuple[str, str]]:
    """(dotted name, first docstring line) of every public top-level function and class."""
    found = []
    for path in sorted((ROOT / "jointseg").rglob("*.py")):
        module = ".".join(path.relative_to(ROOT).with_suffix("").parts)
        module = module.removesuffix(".__init__")
        for node in ast.parse(path.read_text()).body:
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
                if not node.name.startswith("_"):
                    doc = ast.get_docstring(node) or ""
                    found.append((f"{module}.{node.name}", doc.strip().split("\n")[0]))
    return found


def test_site_has_every_section(site: Path) -> None:
    missing = [page for page in PAGES if not (site / page).is_file()]
    assert not missing
    start = (site / "index.html").read_text()
    for section in ("Getting started", "User guide", "API reference", "Benchmarks"):
        assert section in start, section
    # no placeholder left from the skeleton
    stubs = [p for p in site.rglob("*.html") if "(to be written)" in p.read_text()]
    assert not stubs


def test_reference_documents_every_public_name(site: Path) -> None:
    pages = "\n".join(p.read_text() for p in (site / "reference").rglob("*.html"))
    anchors = set(re.findall(r'id="(jointseg\.[\w.]+)"', pages))
    text = words(html.unescape(re.sub(r"<[^>]+>", " ", pages)))
    names = public_names()
    assert len(names) > 500  # the walk itself found the package
    undocumented = [name for name, doc in names if not doc]
    assert not undocumented, f"public names without a docstring: {undocumented}"
    absent = [name for name, _ in names if name not in anchors]
    assert not absent, f"not in the API reference: {absent}"
    unrendered = [name for name, doc in names if " ".join(words(doc).split()[:6]) not in text]
    assert not unrendered, f"docstrings not rendered: {unrendered}"


def test_rest_reference_lists_every_route(site: Path) -> None:
    from server.api.app import create_app

    page = html.unescape((site / "reference" / "rest" / "index.html").read_text())
    schema = create_app().openapi()
    for path, item in schema["paths"].items():
        for method in item:
            assert f"{method.upper()} {path}" in page, (method, path)
    for name in schema["components"]["schemas"]:
        assert f'id="{name.lower()}"' in page, name
    assert (site / "reference" / "openapi.json").read_text().startswith("{")
