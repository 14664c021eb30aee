"""Tests of the documentation site (mkdocs.yml, docs/): it builds strictly, its placeholders are
all filled from ``kane`` and every Python example on its pages runs."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
_BLOCK = re.compile(r"^```python\n(.*?)^```", re.S | re.M)


def _python_blocks():
    for page in sorted(DOCS.glob("*.md")):
        for i, block in enumerate(_BLOCK.findall(page.read_text(encoding="utf-8"))):
            yield pytest.param(page.name, block, id=f"{page.stem}-{i}")


@pytest.mark.parametrize("page, code", list(_python_blocks()))
def test_python_example_runs(page, code, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    exec(compile(code, f"docs/{page}", "exec"), {"__name__": f"docs_{page}"})


def test_every_page_has_an_executed_example_or_none_claimed():
    pages = {p.name for p in DOCS.glob("*.md")}
    assert {"index.md", "kane-primer.md", "theory.md", "report.md", "api.md"} <= pages
    assert len(list(_python_blocks())) >= 3


@pytest.mark.skipif(
    shutil.which("mkdocs") is None and not (Path(sys.executable).parent / "mkdocs").exists(),
    reason="mkdocs not installed",
)
def test_mkdocs_build_strict(tmp_path):
    site = tmp_path / "site"
    run = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(site)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=600,
        env={**__import__("os").environ, "NO_MKDOCS_2_WARNING": "1"},
    )
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    theory = (site / "theory" / "index.html").read_text(encoding="utf-8")
    report = (site / "report" / "index.html").read_text(encoding="utf-8")
    for html in (theory, report, (site / "index.html").read_text(encoding="utf-8")):
        assert "{{" not in html, "an unfilled placeholder reached the site"
    # every claim of the derivation is rendered from kane's sympy expression, next to a verdict
    from kane.claims import CLAIMS

    for claim_id in (
        "eq3",
        "eq17",
        "eq19",
        "eq11",
        "eq30",
        "eq34",
        "eq35",
        "eq36",
        "eq37",
        "eq12",
        "eq15",
    ):
        assert f"Eq. {CLAIMS[claim_id].equation}." in theory, claim_id
    assert theory.count('class="arithmatex"') >= 11
    assert re.search(r"\d+ checks?: \d+ holds?, \d+ refuted, \d+ errors?", report)
    assert (site / "javascripts" / "mathjax" / "tex-chtml-full.js").is_file()
