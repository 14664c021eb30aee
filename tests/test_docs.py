"""Tests of the documentation site (mkdocs.yml, docs/): it builds strictly, its placeholders are
all filled from ``kane`` and every Python example on its pages runs."""

from __future__ import annotations

import os
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


_MKDOCS = shutil.which("mkdocs") is not None or (Path(sys.executable).parent / "mkdocs").exists()
_SUMMARY = re.compile(r"\d+ checks?: \d+ holds?, \d+ refuted, \d+ errors?")


@pytest.fixture(scope="module")
def live_quick(tmp_path_factory):
    """A live ``mdgs validate --quick`` run: its last line, and its JSON report."""
    out = tmp_path_factory.mktemp("quick") / "report.json"
    run = subprocess.run([sys.executable, "-m", "mdgs.cli", "validate", "--quick", "--json", str(out)],
                         cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert run.returncode == 1, run.stderr[-2000:]  # 1: the paper's claims are refuted (a finding)
    return run.stdout.strip().splitlines()[-1], out


@pytest.fixture(scope="module")
def site(live_quick, tmp_path_factory):
    """The site built once, strictly, from the live quick report (no second validation run)."""
    if not _MKDOCS:
        pytest.skip("mkdocs not installed")
    site = tmp_path_factory.mktemp("site") / "site"
    run = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(site)],
        cwd=ROOT, capture_output=True, text=True, timeout=600,
        env={**os.environ, "NO_MKDOCS_2_WARNING": "1", "MDGS_REPORT": str(live_quick[1])},
    )
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    return site, run.stdout + run.stderr


def _pages(site: Path) -> dict[str, str]:
    return {str(p.relative_to(site)): p.read_text(encoding="utf-8") for p in sorted(site.rglob("index.html"))
            if "assets" not in p.parts and p.parent.name != "search"}


def _prose(html: str) -> str:
    """The text a reader sees outside code and rendered math."""
    body = html.split('<article', 1)[-1].split("</article>", 1)[0]
    for tag in ("pre", "code", "script", "style"):
        body = re.sub(rf"<{tag}\b.*?</{tag}>", " ", body, flags=re.S)
    body = re.sub(r'<(span|div) class="arithmatex">.*?</\1>', " ", body, flags=re.S)
    body = re.sub(r"<[^>]+>", " ", body)
    return __import__("html").unescape(body)


def test_mkdocs_build_strict(site):
    site, _ = site
    pages = _pages(site)
    for name, html in pages.items():
        assert "{{" not in html, f"an unfilled placeholder reached {name}"
    theory = pages["theory/index.html"]
    from kane.claims import CLAIMS

    for claim_id in ("eq3", "eq17", "eq19", "eq23", "eq11", "eq30", "eq34", "eq35", "eq36", "eq37", "eq12", "eq15"):
        assert f"Eq. {CLAIMS[claim_id].equation}:" in theory, claim_id
        assert f'id="{claim_id}"' in theory, claim_id
    assert theory.count('class="arithmatex"') >= 40
    assert (site / "javascripts" / "mathjax" / "tex-chtml-full.js").is_file()


def test_home_has_the_findings_table_and_the_exit_code(site):
    home = _pages(site[0])["index.html"]
    from kane.claims import CLAIMS

    for cid in ("eq23", "eq11", "eq30", "eq34", "eq35", "eq36", "eq37", "eq12"):  # refuted on the quick run
        row = re.search(rf'href="theory/#{re.escape(cid)}".*?</tr>', home, re.S)
        assert row and "v-refuted" in row.group(0), cid
        assert CLAIMS[cid].corrected_id.replace(".", "-") in row.group(0), cid
    assert "exit code is 1" in home


def test_no_stale_summary_line(site, live_quick):
    """Every summary line on the site is the live quick run's; none is typed into the sources."""
    line, _ = live_quick
    seen = []
    for name, html in _pages(site[0]).items():
        for m in _SUMMARY.findall(html):
            assert m == line, f"{name} shows '{m}', a live quick run prints '{line}'"
            seen.append(name)
    assert "index.html" in seen and "report/index.html" in seen
    for src in [*DOCS.glob("*.md"), *(ROOT / "kane").rglob("*.py"), *(ROOT / "validation").rglob("*.py"),
                *(ROOT / "mdgs").rglob("*.py")]:
        found = _SUMMARY.findall(src.read_text(encoding="utf-8"))
        assert not found, f"{src.relative_to(ROOT)} types a summary line {found}: generate it instead"
    readme = _SUMMARY.findall((ROOT / "README.md").read_text(encoding="utf-8"))
    assert all(m == line or m == _README_FULL for m in readme), readme


_README_FULL = "125 checks: 105 hold, 20 refuted, 0 errors"  # checked by test_readme_full_run_line (slow)


@pytest.mark.slow
def test_readme_full_run_line():
    run = subprocess.run([sys.executable, "-m", "mdgs.cli", "validate"], cwd=ROOT, capture_output=True, text=True, timeout=1800)
    assert run.stdout.strip().splitlines()[-1] == _README_FULL
    assert _README_FULL in (ROOT / "README.md").read_text(encoding="utf-8")


# ASCII math the issue found beside rendered math: Greek names, x_{...} and x_y subscripts,
# <= and >=, sum_i, carets. Code, rendered math and identifiers in <code> are exempt.
_ASCII_MATH = re.compile(r"\b(tau|omega|gamma|alpha|Psi)\b|\b[A-Za-z]+_\{|\bsum_|<=|>=|\b[A-Za-z]\^[-{0-9]|\b[A-Za-z]_[A-Za-z0-9]\b")


def test_no_ascii_math_outside_code(site):
    bad = {}
    for name, html in _pages(site[0]).items():
        if name == "results/index.html":  # the study's tables.md is plain text by design (also .csv)
            html = html.split('id="tables"', 1)[0]
        hits = sorted({m.group(0) for m in _ASCII_MATH.finditer(_prose(html))})
        if hits:
            bad[name] = hits
    assert not bad, f"ASCII math outside code (write it as \\(...\\) LaTeX or in code): {bad}"


def test_no_truncated_number(site):
    for name, html in _pages(site[0]).items():
        text = __import__("html").unescape(re.sub(r"<[^>]+>", "", html))
        m = re.search(r"\d(\.\.\.|…)", text)
        assert not m, f"{name}: a number is cut off: ...{text[max(0, m.start() - 60):m.end() + 10]}"


def test_every_page_is_in_the_nav(site):
    site, log = site
    assert "not included in the \"nav\"" not in log, log[log.find("not included"):][:500]
    import yaml

    cfg = yaml.safe_load((ROOT / "mkdocs.yml").read_text(encoding="utf-8").split("\nhooks:")[0])

    def walk(nav):
        for item in nav:
            for v in item.values():
                yield from (walk(v) if isinstance(v, list) else [v])

    in_nav = set(walk(cfg["nav"]))
    pages = {str(p.relative_to(DOCS)) for p in DOCS.rglob("*.md") if "results" not in p.parts}
    assert pages <= in_nav, f"pages missing from the nav: {sorted(pages - in_nav)}"


def test_one_h1_per_page(site):
    """A page has one title: an included file (a study's tables.md) brings no H1 of its own."""
    for name, html in _pages(site[0]).items():
        body = html.split('<article', 1)[-1].split("</article>", 1)[0]
        h1 = re.findall(r"<h1\b", body)
        assert len(h1) == 1, f"{name} has {len(h1)} H1 headings"


def test_no_list_swallowed_by_a_paragraph(site):
    """A list written without its blank line or with a 3-space indent renders as text: '2. ...'
    or '- ...' at the start of a line inside a paragraph."""
    bad = {}
    for name, html in _pages(site[0]).items():
        for p in re.findall(r"<p>(.*?)</p>", html, re.S):
            lines = [ln for ln in p.split("\n")[1:] if re.match(r"\s*([-*+]|\d+\.)\s", ln)]
            if lines:
                bad.setdefault(name, []).extend(ln.strip()[:60] for ln in lines)
    assert not bad, f"list items rendered as paragraph text: {bad}"


def test_api_tables_have_descriptions(site):
    """Every parameter, attribute, return and raise row of the API page has its description in
    the description column (a numpy docstring written ``name : text`` puts the text in the type
    column and leaves the description empty)."""
    api = _pages(site[0])["api/index.html"]
    rows = re.findall(r'<tr class="doc-section-item">(.*?)</tr>', api, re.S)
    assert rows
    empty = []
    for row in rows:
        desc = re.search(r'<div class="doc-md-description">(.*?)</div>', row, re.S)
        if not desc or not re.sub(r"<[^>]+>", "", desc.group(1)).strip():
            empty.append(re.sub(r"\s+", " ", re.sub(r"<[^>]+>", " ", row)).strip()[:80])
    assert not empty, f"API rows without a description: {empty}"


_DEV_LOG = re.compile(r"\bissue[- ]\d+|\bthe issue's\b|\bthis session\b|\bon this machine\b|\bclosing note\b", re.I)


def test_no_development_log_in_pages(site):
    """Pages speak to a reader: no pointers to issues, branches or sessions of the development."""
    bad = {}
    for name, html in _pages(site[0]).items():
        hits = sorted({m.group(0) for m in _DEV_LOG.finditer(_prose(html))})
        if hits:
            bad[name] = hits
    assert not bad, f"development-log wording on the site: {bad}"
