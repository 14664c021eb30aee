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


COMMITTED = ROOT / "docs" / "results" / "validation" / "full-report.json"


def _hooks():
    """docs/hooks.py as a module (mkdocs loads it by path)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("mdgs_docs_hooks", DOCS / "hooks.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def committed():
    """The committed report of the full run that the site shows."""
    import json

    return json.loads(COMMITTED.read_text(encoding="utf-8"))


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    """The site built once, strictly, as a reader gets it: from the committed full report."""
    if not _MKDOCS:
        pytest.skip("mkdocs not installed")
    site = tmp_path_factory.mktemp("site") / "site"
    run = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(site)],
        cwd=ROOT, capture_output=True, text=True, timeout=600,
        env={**{k: v for k, v in os.environ.items() if k != "MDGS_REPORT"}, "NO_MKDOCS_2_WARNING": "1"},
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


def test_home_has_the_findings_table_and_the_exit_code(site, committed):
    """Home's claim -> verdict -> why -> what holds instead table: one row per claim of the paper,
    its verdict and the corrected statement's verdict those of the committed full report."""
    home = _pages(site[0])["index.html"]
    from kane.claims import CLAIMS

    verdicts = {c["id"]: c["verdict"] for c in committed["claims"]}
    rows = 0
    for cid in (c for c in _hooks()._PAPER_ORDER if c in verdicts):
        row = re.search(rf'<tr><td[^>]*><a href="theory/#{re.escape(cid)}".*?</tr>', home, re.S)
        assert row, cid
        badges = re.findall(r'class="verdict v-([a-z-]+)"', row.group(0))
        assert badges[0] == verdicts[cid].replace(" ", "-"), (cid, badges)
        cc = CLAIMS[cid].corrected_id
        if cc in verdicts:
            assert cc.replace(".", "-") in row.group(0) and badges[1] == verdicts[cc].replace(" ", "-"), (cid, badges)
        rows += 1
    assert rows >= 12
    for cid in ("eq23", "eq11", "eq30", "eq34", "eq35", "eq36", "eq37", "eq12"):  # refuted on the full run
        assert verdicts[cid] == "refuted", cid
    assert "exit code is 1" in home


def test_no_stale_summary_line(site, committed, live_quick):
    """Every summary line on the site is the committed full run's; none is typed into the sources;
    the README quotes the full run or a live quick run."""
    from validation.report import summarize, summary_line

    line = summary_line(committed["summary"])
    assert committed["summary"] == summarize(committed["checks"])
    seen = []
    for name, html in _pages(site[0]).items():
        for m in _SUMMARY.findall(html):
            assert m == line, f"{name} shows '{m}', the committed full report says '{line}'"
            seen.append(name)
    assert "index.html" in seen and "report/index.html" in seen
    for src in [*DOCS.glob("*.md"), *(ROOT / "kane").rglob("*.py"), *(ROOT / "validation").rglob("*.py"),
                *(ROOT / "mdgs").rglob("*.py")]:
        found = _SUMMARY.findall(src.read_text(encoding="utf-8"))
        assert not found, f"{src.relative_to(ROOT)} types a summary line {found}: generate it instead"
    readme = _SUMMARY.findall((ROOT / "README.md").read_text(encoding="utf-8"))
    assert all(m in (line, live_quick[0]) for m in readme), readme


def _key(row: dict) -> tuple:
    return row["id"], row["case"], row["route"], row["clause"]


def test_committed_report_is_the_current_full_run(committed, live_quick):
    """The committed report is a full run of today's claims: the same claims, titles, statements
    and clauses as kane; every check of a live quick run is in it with the same verdict; it holds
    the checks that only the full run makes. Fails when a claim, a case or a verdict changed
    and the report was not rewritten (`mdgs validate --json docs/results/validation/full-report.json`)."""
    import json
    from collections import Counter

    from kane.claims import CHECKS

    hooks = _hooks()
    assert hooks.stale_report(committed) == []
    quick = json.loads(live_quick[1].read_text(encoding="utf-8"))
    full = Counter(_key(r) for r in committed["checks"])
    missing = Counter(_key(r) for r in quick["checks"]) - full
    assert not missing, f"checks of the quick run missing from the committed report: {sorted(missing)[:5]}"
    verdict = {_key(r): r["verdict"] for r in committed["checks"]}
    flipped = [(_key(r), r["verdict"], verdict[_key(r)]) for r in quick["checks"] if verdict[_key(r)] != r["verdict"]]
    assert not flipped, f"verdicts of the quick run differ from the committed report: {flipped[:5]}"
    full_only = {(s.claim_id, s.route) for s in CHECKS if not s.quick}  # e.g. the hypothesis searches
    assert full_only and full_only <= {(r["id"], r["route"]) for r in committed["checks"]}
    assert not hooks.is_quick(committed) and hooks.is_quick(quick)
    assert len(committed["checks"]) > len(quick["checks"])


def test_a_stale_report_is_caught(committed):
    """stale_report names a changed statement, a claim kane no longer has and one it gained."""
    import copy

    hooks = _hooks()
    rep = copy.deepcopy(committed)
    rep["claims"][0]["statement"] += " (changed)"
    rep["claims"].append({**rep["claims"][1], "id": "eq99"})
    dropped = rep["claims"].pop(1)["id"]
    found = " | ".join(hooks.stale_report(rep))
    assert "statement changed" in found and "eq99" in found and dropped in found


def test_theory_page_shows_the_full_runs_numbers(site, committed):
    """Every refuted check of the full run appears on the derivation page with its number."""
    theory = _pages(site[0])["theory/index.html"]
    for r in committed["checks"]:
        if r["verdict"] == "refuted" and not r["id"].endswith(".corrected"):
            assert f"{r['residual']:.3g}" in theory, (r["id"], r["case"], r["residual"])
    assert "the full run" in _pages(site[0])["report/index.html"]


@pytest.mark.slow
def test_readme_full_run_line(committed):
    """A live full run ends with the committed report's summary line (the README quotes it)."""
    from validation.report import summary_line

    run = subprocess.run([sys.executable, "-m", "mdgs.cli", "validate"], cwd=ROOT, capture_output=True, text=True, timeout=1800)
    assert run.stdout.strip().splitlines()[-1] == summary_line(committed["summary"])
    assert summary_line(committed["summary"]) in (ROOT / "README.md").read_text(encoding="utf-8")


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


def test_bench_table_keeps_every_figure_in_its_column(tmp_path):
    """{{ bench:PATH }} turns a benchmark's fixed-width output into a table without retyping it:
    every figure of the committed compile benchmark lands in the cell under its header, and a
    compiled row's absent params / train columns stay empty (not shifted left)."""
    hooks = _hooks()
    rel = "docs/results/benchmarks/bench_models-compile.txt"
    out = hooks._bench_block(rel, str(ROOT))
    lines = (ROOT / rel).read_text().splitlines()
    head = next(ln for ln in lines if ln.startswith("model "))
    labels = re.findall(r"\S+(?: \S+)*", head)
    row = next(ln for ln in lines if ln.startswith("mdgs compiled"))
    b1 = row.split()[2]  # "mdgs compiled <b1> ..."
    cells = re.search(r"<tr><td data-label=\"model\">mdgs compiled</td>(.*?)</tr>", out).group(1)
    assert f'data-label="{labels[1]}"></td>' in cells and f'data-label="{labels[2]}"></td>' in cells
    assert f'data-label="{labels[3]}">{b1}</td>' in cells
    figures = {t for ln in lines[lines.index(head) + 1:] if not ln.startswith("ms/")
               for t in re.findall(r"\d+\.\d+|\d+", ln)}
    assert figures and all(f in out for f in figures)
