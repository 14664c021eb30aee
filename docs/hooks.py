"""MkDocs hooks: fill the docs' placeholders from :mod:`kane`, :mod:`validation` and the CLI at build time.

Placeholders (in any ``docs/*.md``)::

    {{ latex:eq34 }}   display math of the claim (:func:`validation.render.statement_latex`)
    {{ claim:eq34 }}   the claim: statement, verdict and scope, its equation (compact vector
                       form, the checked component form folded away), the checks, each
                       counterexample as a table with one sentence of physics, and the
                       corrected statement with its clauses and checks
    {{ findings }}     Home: one row per claim of the paper: verdict, why, what holds instead
    {{ summary }}      the summary line of the report this site was built from, and its source
    {{ report }}       the validation report grouped by claim, refutations first
    {{ normalisation }} how residuals and margins are normalised
    {{ cli }}          the reference of every ``mdgs`` command, read from the typer app
    {{ exit_codes }}   the exit-code table of every command
    {{ results_status }} what the committed study holds: cells per model and scene, seeds
    {{ results_verdict }} the committed study's "Who wins, per scene" table
    {{ mjcf:PATH }}    Kane's equations of the MJCF file PATH (relative to the repository
                       root) derived by ``kane.mjcf.from_mjcf``, with the engine residuals
    {{ bench:PATH }}   the fixed-width table a script under ``benchmarks/`` printed into the
                       committed file PATH, as an HTML table (its comment, caption and legend
                       lines as text), so that no figure is retyped

The LaTeX comes from the very sympy expressions the checks evaluate (the compact vector forms
are compared with them at build time: a disagreement stops the build). Verdicts and numbers come
from the JSON report of the full run committed at :data:`COMMITTED_REPORT` (``mdgs validate
--json docs/results/validation/full-report.json``), or from the report named by the environment
variable ``MDGS_REPORT``; a checkout without either runs ``kane.claims.run_checks(quick=True)``
once per build. A report whose claims differ from kane's (:func:`stale_report`) stops a strict
build, as do an unknown id and an unfilled placeholder. The HTML also loses sphinx roles (``:func:``) that
mkdocstrings leaves in docstrings (:func:`on_page_content`).
"""

from __future__ import annotations

import html
import json
import logging
import os
import re
import time

from mkdocs.exceptions import PluginError

log = logging.getLogger("mkdocs.hooks.mdgs")

_PLACEHOLDER = re.compile(r"\{\{\s*(latex|claim):([A-Za-z0-9_.]+)\s*\}\}|\{\{\s*(report|findings|summary|cli|exit_codes|normalisation|results_status|results_verdict)\s*\}\}")
_state: dict = {}

# --------------------------------------------------------------------------- sources


def _claims() -> dict:
    from kane.claims import CLAIMS

    return CLAIMS


#: the committed report of the full run that the site shows (``mdgs validate --json`` this path)
COMMITTED_REPORT = os.path.join("docs", "results", "validation", "full-report.json")
_ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def stale_report(rep: dict) -> list[str]:
    """How a report disagrees with the current claims of :mod:`kane` (empty: it does not).

    Cheap (no check is run): every claim entry of the report must name a current claim with the
    same title, statement and clauses, and every current claim that has checks must be in it."""
    from kane.claims import CHECKS

    claims, out = _claims(), []
    seen = {c["id"]: c for c in rep.get("claims", [])}
    for cid, c in seen.items():
        claim = claims.get(cid)
        if claim is None:
            out.append(f"{cid} is no claim of kane any more")
            continue
        if c.get("title") != claim.title or c.get("statement") != claim.statement:
            out.append(f"{cid}: title or statement changed")
        if [(x["key"], x["text"]) for x in c.get("clauses", [])] != list(claim.clause_list()):
            out.append(f"{cid}: clauses changed")
    for cid in dict.fromkeys(s.claim_id for s in CHECKS):
        if cid not in seen:
            out.append(f"{cid} has checks but is not in the report")
    return out


def _report() -> dict:
    """The report dict (see :mod:`validation.report`), read or computed once per build: the
    report named by ``MDGS_REPORT``, else the committed full run (:data:`COMMITTED_REPORT`),
    else a live ``mdgs validate --quick`` (a checkout without the committed file)."""
    if "report" not in _state:
        path = os.environ.get("MDGS_REPORT")
        committed = os.path.join(_ROOT, COMMITTED_REPORT)
        if path or os.path.isfile(committed):
            name = path or committed
            try:
                with open(name, encoding="utf-8") as f:
                    _state["report"] = json.load(f)
            except (OSError, json.JSONDecodeError) as e:
                what = f"MDGS_REPORT={path}" if path else COMMITTED_REPORT
                raise PluginError(f"{what}: cannot read the report ({e}); write it with `mdgs validate --json {name}`.") from e
            if path:
                _state["source"] = (f"the report <code>{html.escape(os.path.basename(path))}</code> named by "
                                    "<code>MDGS_REPORT</code> (written by <code>mdgs validate --json</code>)")
            else:
                _state["source"] = (f"the committed report <code>{COMMITTED_REPORT}</code>, written by "
                                    f"<code>mdgs validate --json {COMMITTED_REPORT}</code>")
            stale = stale_report(_state["report"])
            if stale:  # a warning stops a --strict build
                log.warning("mdgs: the report %s is stale against kane's claims (%s); rewrite it with "
                            "`mdgs validate --json %s`.", path or COMMITTED_REPORT, "; ".join(stale[:5]), path or COMMITTED_REPORT)
        else:
            from kane.claims import run_checks
            from validation.report import build_report

            t0 = time.perf_counter()
            _state["report"] = build_report(run_checks(quick=True), _claims())
            _state["source"] = "<code>mdgs validate --quick</code>, run while this site was built"
            log.info("mdgs: quick validation for the docs took %.1f s", time.perf_counter() - t0)
        _state["quick"] = is_quick(_state["report"])
    return _state["report"]


def is_quick(rep: dict) -> bool:
    """Whether a report is of the quick subset: it lacks checks that only the full run makes
    (those of the specs that :mod:`kane.claims` marks not quick, e.g. the hypothesis routes)."""
    from kane.claims import CHECKS

    full_only = {(s.claim_id, s.route) for s in CHECKS if not s.quick} - {(s.claim_id, s.route) for s in CHECKS if s.quick}
    have = {(r["id"], r["route"]) for r in rep["checks"]}
    return bool(full_only) and not (full_only & have)


def on_pre_build(config, **kwargs) -> None:
    """Start every build afresh (``mkdocs serve`` rebuilds)."""
    _state.clear()


def _summaries() -> dict:
    """Claim id -> the report's ``claims`` entry (computed from the rows for older reports)."""
    rep = _report()
    if "claims" not in rep:
        from validation.report import claim_summaries

        rep["claims"] = claim_summaries(rep["checks"], _claims())
    return {c["id"]: c for c in rep["claims"]}


# --------------------------------------------------------------------------- HTML pieces

_MATH = re.compile(r"\\\((.+?)\\\)")


def _h(text: str) -> str:
    """Text with ``\\(...\\)`` math, ``<code>`` tags, `backticks` and **bold** as HTML."""
    out, pos = [], 0
    for m in _MATH.finditer(text):
        out.append(_plain(text[pos:m.start()]))
        out.append(f'<span class="arithmatex">\\({html.escape(m.group(1), quote=False)}\\)</span>')
        pos = m.end()
    out.append(_plain(text[pos:]))
    return "".join(out)


def _plain(s: str) -> str:
    s = html.escape(s, quote=False).replace("&lt;code&gt;", "<code>").replace("&lt;/code&gt;", "</code>")
    s = re.sub(r"`([^`]+)`", r"<code>\1</code>", s)
    s = re.sub(r"\*\*([^*]+)\*\*", r"<strong>\1</strong>", s)
    return s.replace("*", "&#42;").replace("_", "&#95;")  # no Markdown emphasis inside admonitions


def _badge(verdict: str | None) -> str:
    v = verdict or "not run"
    return f'<span class="verdict v-{v.replace(" ", "-")}">{html.escape(v)}</span>'


def _num(x) -> str:
    return "&ndash;" if x is None else f"{x:.3g}"


def _case(case: str) -> str:
    """A case name: an identifier (``--case NAME``) as code, a description as text."""
    s = re.sub(r"\b(\w+_\w+)\b", r"<code>\1</code>", html.escape(case))
    return re.sub(r"\b(Psi|tau|omega|alpha|gamma|delta)\b", lambda m: f'<span class="arithmatex">\\(\\{m.group(1)}\\)</span>', s)


def _table(head: list[str], rows: list[list[str]], cls: str = "") -> str:
    """A raw HTML table (:func:`mdgs.cli.reference.table`, the one table writer of the docs)."""
    from mdgs.cli.reference import table

    return table(rows, head, cls)


def _eq(claim) -> str:
    return f"Eq. {claim.equation}" if claim.equation[:1] == "(" else claim.equation


def _title(cid: str) -> str:
    from validation.render import TEXT

    return _h(TEXT[cid]["title"]) if cid in TEXT else html.escape(_claims()[cid].title)


def _statement(cid: str) -> str:
    from validation.render import TEXT

    return _h(TEXT[cid]["statement"]) if cid in TEXT else html.escape(_claims()[cid].statement)


def _scope(cid: str) -> str:
    from validation.render import scope_tex

    c = _summaries().get(cid)
    line = scope_tex(c) if c else None
    return _h(line) if line else "not checked in this report"


# --------------------------------------------------------------------------- equations

_NARROW = 26  # glyphs (validation.render._visible) of a display row: about 330 px of a 390 px phone's column


def _display(cid: str) -> str:
    """``$$...$$`` of a claim's statement, over rows of at most :data:`_NARROW` glyphs
    (:func:`validation.render.relation_lines`)."""
    import sympy as sp

    from validation import render

    claims = _claims()
    if cid not in claims:
        raise PluginError(f"docs placeholder names unknown claim '{cid}'; known: {', '.join(sorted(claims))}.")
    c = claims[cid]
    if cid in render.COMPACT:
        lhs, rhs = render.COMPACT[cid]
        rel = "=" if cid.startswith("eq30") else r"\le"
    else:
        e = c.expression()
        if e is None:
            return "*No single sympy expression: this claim is decided numerically (the checks below).*"
        if not isinstance(e, sp.Eq):
            return "$$\n" + render.latex(e) + "\n$$"
        rel, lhs, rhs = "=", e.lhs, e.rhs
    rows = render.relation_lines(lhs, rhs, rel, _NARROW)
    if len(rows) == 1:
        return f"$$\n{rows[0][2:]}\n$$"
    return "$$\n\\begin{aligned}\n" + " \\\\\n".join(rows) + "\n\\end{aligned}\n$$"


def _expanded(cid: str) -> list[str]:
    """The folded admonition with the component form the checks evaluate (compact claims)."""
    from validation import render

    if cid not in render.COMPACT:
        return []
    worst = render.compact_agrees(cid)
    if worst > 1e-12:  # round-off of ~100 products is ~1e-15
        raise PluginError(f"{cid}: the compact form on the docs differs from the checked expression by {worst:.2e}.")
    c = _claims()[cid]
    suffix = "" if cid.startswith("eq30") else r" \le 0"
    what = ("the difference \\(\\Psi(s\\,\\mathbf r) - s\\,\\Psi(\\mathbf r)\\) that the symbolic check simplifies"
            if cid == "eq30" else "\\(\\Psi(s\\,\\mathbf r)\\) minus the closed form, which the symbolic check simplifies to 0"
            if cid == "eq30.corrected" else "the margin \\(\\text{lhs} - \\text{rhs}\\) that CasADi maximises and hypothesis samples")
    expr = c.expression() if cid == "eq30" else (render.expand_compact(cid) if cid == "eq30.corrected" else c.expression())
    lines = render.expanded_lines(expr, suffix, label=r"\text{margin}" if suffix else r"\Delta")
    body = "\\begin{aligned}\n" + " \\\\\n".join(lines) + "\n\\end{aligned}"
    return [f'??? info "Written out in components ({len(lines)} lines)"', "",
            f"    This is {what}{_parts(lines)}, {_variables(expr)}. "
            f"The compact form above expands to it (largest relative difference {worst:.0e} on random states, checked when this page was built).",
            "", "    $$", *("    " + x for x in body.splitlines()), "    $$", ""]


def _parts(lines: list[str]) -> str:
    r"""What the rows after the margin name: the common parts \(x_k\) and the inner sums \(z_k\)."""
    names = [n for n, mark in (("x_k", "x_{"), ("z_k", "z_{")) if any(x.startswith(mark) for x in lines)]
    if not names:
        return ""
    return " (its parts " + " and ".join(f"\\({n}\\)" for n in names) + " are written out below it)"


def _variables(expr) -> str:
    r"""The element variables that ``expr`` contains, named as they print (\(r_{1 x}\): offset
    of mass 1 along x), from its free symbols; the rotational speed is about \(\mathbf e_z\)."""
    names = {str(x) for x in expr.free_symbols}
    n = len({x.split("_")[1] for x in names if re.fullmatch(r"[mrF]_\d+(_[xyz])?", x)})

    def comps(base: str) -> list[str]:
        return [a for a in "xyz" if any(re.fullmatch(rf"{base}_\d+_{a}", x) for x in names)]

    out = []
    if any(re.fullmatch(r"m_\d+", x) for x in names):
        out.append("masses \\(m_l\\)")
    if comps("r"):
        out.append("offsets from the centroid with components " + ", ".join(f"\\(r_{{l\\,{a}}}\\)" for a in comps("r")))
    if comps("F"):
        out.append("forces with components " + ", ".join(f"\\(F_{{l\\,{a}}}\\)" for a in comps("F")))
    for base, what in (("omega", "angular velocity"), ("alpha", "angular acceleration")):
        c = [a for a in "xyz" if f"{base}_{a}" in names]
        if c:
            out.append(f"{what} components " + ", ".join(f"\\(\\{base}_{a}\\)" for a in c))
    if "tau" in names:
        out.append("radius \\(\\tau\\)")
    if not out:
        return "with no element variables left"
    listed = ", ".join(out[:-1]) + (" and " if len(out) > 1 else "") + out[-1]
    return f"in the variables of \\(L = {n}\\) point masses (\\(l = 1, \\dots, {n}\\)): {listed}; the speed is the rotation about \\(\\mathbf e_z\\)"


# --------------------------------------------------------------------------- claim blocks


def _checks_table(rows: list[dict]) -> str:
    """One row per check, refuted first; a clause column when the checks try several clauses."""
    from validation.render import TEXT

    rows = sorted(rows, key=lambda r: {"refuted": 0, "error": 1}.get(r["verdict"], 2))
    clauses = {r.get("clause") or "" for r in rows}
    head = ["case", "route", "verdict", "residual or relative margin", "tolerance"]
    body = [[_case(r["case"]), html.escape(r["route"]), _badge(r["verdict"]), _num(r["residual"]), _num(r["tolerance"])]
            for r in rows]
    if len(clauses) > 1:
        texts = {r["id"]: TEXT.get(r["id"], {}).get("clauses", {}) for r in rows}
        head.insert(0, "clause")
        for b, r in zip(body, rows, strict=True):
            t = texts[r["id"]].get(r.get("clause") or "", r.get("clause") or "")
            b.insert(0, _h(t.split(")", 1)[0] + ")" if t.startswith("(") else t))
    return _table(head, body, "checks")


def _cex_block(r: dict, indent: str = "") -> list[str]:
    from validation.render import counterexample_view

    v = counterexample_view(r)
    if v is None:
        return []
    rows = [[_h(k), _h(x)] for k, x in v["quantities"]] + [[f"<strong>{_h(k)}</strong>", f"<strong>{_h(x)}</strong>"] for k, x in v["sides"]]
    out = [f'!!! failure "Counterexample: {html.escape(r["case"])} ({r["route"]})"', "",
           f"    {_h(v['sentence'])}", "", "    " + _table(["quantity", "value"], rows, "cex"), "",
           f"    Numbers: {_h(v['replay'])}; rounded to 4 digits, round-off shown as 0. "
           f"Replay: <code>mdgs validate --json r.json --check {html.escape(r['id'])}</code>, then "
           f"<code>mdgs validate --replay r.json --check {html.escape(r['id'])}</code>.", ""]
    return [indent + x if x else "" for x in out]


def _claim_head(cid: str) -> list[str]:
    c = _claims()[cid]
    summ = _summaries().get(cid)
    return [f'<a id="{cid.replace(".", "-")}"></a>', "",
            f"<p><strong>{_eq(c)}: {_title(cid)}.</strong> {_statement(cid)}</p>", "",
            f'<p class="scope">{_badge(summ["verdict"] if summ else None)} <strong>Scope:</strong> {_scope(cid)}.</p>', ""]


def _clause_table(cid: str) -> str | None:
    from validation.render import TEXT

    c = _summaries().get(cid)
    if not c or len(c["clauses"]) < 2:
        return None
    texts = TEXT.get(cid, {}).get("clauses", {})
    return _table(["clause", "verdict", "checked on"],
                  [[_h(texts.get(cl["key"], cl["text"])), _badge(cl["verdict"]),
                    "<br>".join(_case(x) for x in cl["cases"]) or "&ndash;"] for cl in c["clauses"]], "clauses")


def _claim_block(cid: str) -> str:
    claims = _claims()
    if cid not in claims:
        raise PluginError(f"docs placeholder names unknown claim '{cid}'; known: {', '.join(sorted(claims))}.")
    c = claims[cid]
    rows = [r for r in _report()["checks"] if r["id"] == cid]
    out = [*_claim_head(cid), _display(cid), "", *_expanded(cid)]
    out += [_checks_table(rows), ""] if rows else ["*Not checked in this report.*", ""]
    for r in rows:
        if r["verdict"] == "refuted":
            out += _cex_block(r)
        elif r["verdict"] == "error":
            out += [f"<p>Could not decide on {_case(r['case'])}: {html.escape(r['detail'])}</p>", ""]
    cc = c.corrected_id
    if cc and cc in claims:
        crow = [r for r in _report()["checks"] if r["id"] == cc]
        inner = [*_claim_head(cc), _display(cc), "", *_expanded(cc)]
        ct = _clause_table(cc)
        if ct:
            inner += [ct, ""]
        inner += [_checks_table(crow), ""] if crow else ["*Not checked in this report.*", ""]
        for r in crow:
            if r["verdict"] == "refuted":
                inner += _cex_block(r)
        out += [f'!!! success "What holds instead: {_eq(claims[cc])}"', ""] + ["    " + x if x else "" for x in "\n".join(inner).splitlines()]
    return "\n".join(out)


# --------------------------------------------------------------------------- pages


def _summary_block() -> str:
    """The report's summary line, which run it is (full or quick) and how to reproduce it."""
    from validation.report import summary_line

    rep = _report()
    secs = sum(r.get("seconds") or 0.0 for r in rep["checks"])
    what = ("the quick subset (<code>mdgs validate --quick</code>)" if _state.get("quick") else
            "the full run (<code>mdgs validate</code>: every case, the hypothesis searches included)")
    return (f"<p><code>{summary_line(rep['summary'])}</code> &mdash; {what}, from {_state.get('source', 'the report')}; "
            f"its checks took {secs:.0f} s in all.</p>")


_PAPER_ORDER = ("eq3", "lemmaA1", "eq17", "eq19", "eq23", "eq11", "eq30", "eq34", "eq35", "eq36", "eq37", "eq12", "eq15")


def _findings_block() -> str:
    from validation.render import WHY

    claims, summ = _claims(), _summaries()
    rows = []
    for cid in _PAPER_ORDER:
        if cid not in summ:
            continue
        c, s = claims[cid], summ[cid]
        why = (_h(WHY[cid]) + " " if s["verdict"] == "refuted" and cid in WHY else "") + f"<em>Scope:</em> {_scope(cid)}."
        cc = c.corrected_id
        instead = "&ndash;"
        if cc and cc in claims:
            instead = f'<a href="theory/#{cc.replace(".", "-")}">{_eq(claims[cc])}</a>: {_title(cc)} {_badge(summ.get(cc, {}).get("verdict"))}'
        rows.append([f'<a href="theory/#{cid}">{_eq(c)}</a> {_title(cid)}', _badge(s["verdict"]), why, instead])
    return _table(["claim of the paper", "verdict", "why", "what holds instead"], rows, "stack findings")


def _report_block() -> str:
    from validation.report import environment

    claims, summ, rep = _claims(), _summaries(), _report()
    paper = [cid for cid in summ if not cid.endswith(".corrected")]
    rank = {"refuted": 0, "error": 1, "holds": 2}
    paper.sort(key=lambda cid: (rank.get(summ[cid]["verdict"], 3), _PAPER_ORDER.index(cid) if cid in _PAPER_ORDER else 99))
    out = [_summary_block(), ""]
    for cid in paper:
        group = [cid] + [x for x in (claims[cid].corrected_id,) if x and x in summ] if cid in claims else [cid]
        for g in group:
            c = claims.get(g)
            rows = [r for r in rep["checks"] if r["id"] == g]
            title = _title(g) if c else html.escape(g)
            out += [f"### {_eq(c) if c else g} &mdash; {summ[g]['verdict']}", "",
                    f"<p><strong>{title}.</strong> {_badge(summ[g]['verdict'])} <strong>Scope:</strong> {_scope(g)}. "
                    f'<a href="../theory/#{g.replace(".", "-")}">Derivation and counterexamples</a>.</p>', "",
                    _checks_table(rows), ""]
    env = rep.get("environment") or environment()
    out += ["### Environment", "", _table(["package", "version"], [[html.escape(k), html.escape(str(v or "not installed"))] for k, v in env.items()]), ""]
    return "\n".join(out)


def _normalisation_block() -> str:
    from validation.render import NORMALISATION

    return _h(NORMALISATION)


def _exit_codes_block() -> str:
    """The exit codes of every command, from their one source (:data:`mdgs.cli.EXIT_CODES`)."""
    from mdgs.cli import EXIT_CODES

    def html(text: str) -> str:
        return re.sub(r"`([^`]+)`", r"<code>\1</code>", text)
    return _table(["exit code", "meaning"], [[f"<code>{c}</code>", html(t)] for c, t in EXIT_CODES.items()],
                  "exit-codes")


def _cli_block() -> str:
    """Every command of the typer app (:func:`mdgs.cli.reference.markdown`: value types, defaults and
    "required" read from the click help records that ``mdgs COMMAND --help`` prints)."""
    from mdgs.cli.reference import markdown

    return markdown()


_DIRS = re.compile(r"(?<![\w.])/(?:[^\s/;,]+/)+")  # the folders of an absolute path in a cell's reason


def _results_status(root: str) -> str:
    """Which cells the committed study (``docs/results/small/results*.jsonl``) holds, per model.

    Counted as the tables count them (:func:`mdgs.study.report`): a cell whose status is ``ok``
    or ``failed`` is finished and in the tables; the others (``not applicable``, an internal
    ``error``) are listed under the table with their reason."""
    import glob

    lines = []
    for f in sorted(glob.glob(os.path.join(root, "docs", "results", "small", "results*.jsonl"))):
        with open(f, encoding="utf-8") as fh:
            lines += [json.loads(x) for x in fh if x.strip()]
    if not lines:
        return "<p><strong>No results are committed yet</strong>: the tables and charts below appear once the study has finished its first cells.</p>"
    finished = [d for d in lines if d.get("status", "ok") in ("ok", "failed")]
    others = [d for d in lines if d.get("status", "ok") not in ("ok", "failed")]
    kinds = {"learned": "learned", "reference": "reference", "sensitivity": "reference (sensitivity floor)"}
    models: dict = {}
    for d in finished:
        kind = d.get("kind", "learned")
        m = models.setdefault((kind != "learned", kind, d["model"]), {"scenes": set(), "seeds": set(), "n": 0})
        m["scenes"].add(d["scene"])
        m["seeds"].add(d["seed"])
        m["n"] += 1
    rows = [[f"<code>{html.escape(name)}</code>", html.escape(kinds.get(kind, kind)), str(v["n"]),
             ", ".join(sorted(v["scenes"])), ", ".join(str(x) for x in sorted(v["seeds"]))]
            for (_, kind, name), v in sorted(models.items())]
    out = (f"<p>The committed study holds <strong>{len(finished)} finished cells</strong>, read when this site was built:</p>\n"
           + _table(["model", "kind", "cells", "scenes", "seeds"], rows, "stack"))
    if others:
        items = "".join(f"<li><code>{html.escape(str(d.get('label', d['model'])))}</code> on {html.escape(d['scene'])}, "
                        f"seed {d['seed']}: {html.escape(str(d.get('status')))} ({html.escape(_DIRS.sub('', str(d.get('reason', '')))[:200])})</li>"
                        for d in others)
        out += f"\n<p>Not in the tables ({len(others)}):</p>\n<ul>{items}</ul>"
    return out


def _results_verdict(root: str) -> str:
    """The committed study's "Who wins, per scene" table (:mod:`mdgs.study.tables`), as a stacked
    HTML table (one card per scene on a phone)."""
    from mdgs.study.runner import read_results
    from mdgs.study.tables import _verdict_table

    folder = os.path.join(root, "docs", "results", "small")
    t = _verdict_table(read_results(folder, usable=True)) if os.path.isdir(folder) else None
    if t is None:
        return "<p>No finished learned and reference cells are committed yet.</p>"
    return _table(t.header, [[html.escape(c) for c in r] for r in t.rows], "stack") + f"\n<p>{html.escape(t.note)}</p>"


# --------------------------------------------------------------------------- benchmark outputs


_BENCH = re.compile(r"\{\{\s*bench:([A-Za-z0-9_./-]+)\s*\}\}")


def _bench_block(rel: str, root: str) -> str:
    """The committed output ``rel`` of ``benchmarks/bench_models.py`` (``{{ bench:PATH }}``) as a table.

    The header line starts with ``model``; its labels (separated by two or more spaces) end where
    the right-aligned figures under them end, so each figure of a row goes to the column whose label
    ends nearest to where the figure ends, and a row's empty columns stay empty. Lines before the
    header (the ``#`` command line, the scene caption) and after the rows (the legend) become text.
    """
    path = os.path.join(root, rel)
    if not os.path.isfile(path):
        raise PluginError(f"{{{{ bench:{rel} }}}}: no such file under {root}.")
    lines = [ln.rstrip() for ln in open(path, encoding="utf-8") if ln.strip()]
    try:
        h = next(i for i, ln in enumerate(lines) if ln.startswith("model "))
    except StopIteration:
        raise PluginError(f"{{{{ bench:{rel} }}}}: no header line starting with 'model'.") from None
    labels = list(re.finditer(r"\S+(?: \S+)*", lines[h]))
    ends = [m.end() for m in labels]
    rows, k = [], h + 1
    while k < len(lines) and re.match(r"\S.*? {2,}\S", lines[k]) and not lines[k].startswith(("ms/", "#")):
        fields = list(re.finditer(r"\S+(?: \S+)*", lines[k]))
        row = [""] * len(labels)
        row[0] = fields[0].group()
        for f in fields[1:]:
            col = min(range(1, len(labels)), key=lambda c: abs(ends[c] - f.end()))
            col = len(labels) - 1 if f.end() > ends[-1] + 2 else col  # a trailing note: the last column
            row[col] = (row[col] + " " + f.group()).strip()
        rows.append([html.escape(c) for c in row])
        k += 1
    command = [f"<code>{html.escape(ln.lstrip('# '))}</code>" for ln in lines[:h] if ln.startswith("#")]
    caption = [html.escape(ln) for ln in lines[:h] if not ln.startswith("#")]
    legend = [html.escape(ln) for ln in lines[k:]]
    return "\n\n".join([" ".join(command + caption), _table([html.escape(m.group()) for m in labels], rows, "stack bench"),
                         " ".join(legend)])


# --------------------------------------------------------------------------- MJCF


_MJCF = re.compile(r"\{\{\s*mjcf:([A-Za-z0-9_./-]+)\s*\}\}")


def _mjcf_block(rel: str, root: str) -> str:
    """Derived equations and engine residuals of one MJCF file (``{{ mjcf:PATH }}``)."""
    import sympy as sp

    from kane.mjcf import crosscheck_mjcf, from_mjcf

    path = os.path.join(root, rel)
    if not os.path.isfile(path):
        raise PluginError(f"{{{{ mjcf:{rel} }}}}: no such file under {root}.")
    mm = from_mjcf(path)
    sm = mm.explicit
    res = crosscheck_mjcf(mm, n_states=20, seed=0)

    def lx(e) -> str:
        return sp.latex(e)

    def rows(mat, name: str) -> str:
        """One entry per speed, each over lines of about 26 glyphs (a phone's column)."""
        from validation.render import _split, _terms

        out = []
        n = mat.shape[1]
        for k, x in enumerate(mat):
            r = f"{k // n + 1}{k % n + 1}" if n > 1 else f"{k + 1}"
            terms = [sp.latex(t) for t in _terms(x)]
            terms = [t if i == 0 or t.startswith("-") else "+ " + t for i, t in enumerate(terms)]
            body = _split(terms, 26)
            out.append(f"{name}_{{{r}}} &= {body[0]}")
            out += [f"&\\quad {b}" for b in body[1:]]
        return "\\begin{aligned}\n" + " \\\\\n".join(out) + "\n\\end{aligned}"

    with open(path, encoding="utf-8") as f:
        xml = f.read()
    out = [f"```xml\n{xml.strip()}\n```", "", "**Coordinates and speeds** (MuJoCo `qpos` / `qvel` order):", "",
           "| coordinate | speed | rate |", "|---|---|---|"]
    for qq, uu, qd in zip(sm.q, sm.u, sm.qdot, strict=False):
        out.append(f"| ${lx(qq)}$ | ${lx(uu)}$ | ${lx(qd)}$ |")
    out += ["", "**Partial velocities** of each mass centre \\(V\\) and partial angular velocities \\(W\\) "
            "(column \\(r\\): speed \\(u_r\\); components in the body's own frame):", ""]
    for name, V, W in mm.partial_velocities:
        out += [f"- body `{name}`:", "", "    $$", f"    V = {lx(V.applyfunc(sp.trigsimp))}", "    $$", "", "    $$", f"    W = {lx(W)}", "    $$", ""]
    out += ["**Generalized active forces** \\(F_r\\) (gravity, damping, springs, actuator force symbols), one line per speed:", "",
            "$$", rows(sm.fr, "F"), "$$", "", "**Generalized inertia forces** \\(F^*_r\\) (after `trigsimp`):", "",
            "$$", rows(sm.frstar.applyfunc(sp.trigsimp), "F^*"), "$$", "",
            "**Mass matrix and forcing**, \\(M \\dot u = f\\), the mass matrix row by row:", "",
            "$$", rows(sm.mass_matrix.applyfunc(sp.trigsimp), "M"), "$$", "", "$$", rows(sm.forcing, "f"), "$$", "",
            "**Parameters** (MuJoCo's compiled values, SI units):", "", "| symbol | value |", "|---|---|"]
    for k, v in sorted(mm.system.params.items()):
        out.append(f"| ${lx(sp.Symbol(k))}$ | {v:.6g} |")
    keys = [k for k in ("mujoco_mass", "mujoco_bias", "mujoco_actuator", "mujoco_inverse", "pinocchio_crba", "pinocchio_rnea", "kanes_method") if k in res]
    out += ["", f"**Residuals** on {res['n_states']} random states (largest difference / largest term; tolerance 1e-10):", "",
            "| compared with | residual |", "|---|---|"]
    out += [f"| {k.replace('_', ' ')} | {res[k]:.1e} |" for k in keys]
    timing = mm.timing
    out += ["", f"Derivation while this page was built: explicit partial velocities {timing.get('explicit', 0):.2f} s, "
            f"sympy `KanesMethod` {timing.get('kanes_method', 0):.2f} s; Pinocchio read {res.get('pinocchio_source', '-')}.", ""]
    return "\n".join(out)


# --------------------------------------------------------------------------- hooks


def on_page_markdown(markdown: str, page, config, files, **kwargs) -> str:
    """Replace the placeholders of one page (see the module docstring)."""

    def fill(m: re.Match) -> str:
        kind, cid, name = m.group(1), m.group(2), m.group(3)
        if kind == "latex":
            return _display(cid)
        if kind == "claim":
            return _claim_block(cid)
        if name == "results_status":
            return _results_status(root)
        if name == "results_verdict":
            return _results_verdict(root)
        return {"report": _report_block, "findings": _findings_block, "summary": _summary_block, "cli": _cli_block,
                "exit_codes": _exit_codes_block, "normalisation": _normalisation_block}[name]()

    root = os.path.dirname(os.path.abspath(config["config_file_path"]))
    markdown = _MJCF.sub(lambda m: _mjcf_block(m.group(1), root), markdown)
    markdown = _BENCH.sub(lambda m: _bench_block(m.group(1), root), markdown)
    return _PLACEHOLDER.sub(fill, markdown)


_ROLE = re.compile(r":(?:py:)?(?:func|class|mod|meth|data|attr|exc|obj|const|math):(?=<code>|`|<span)")


_MATH_ROLE = re.compile(r":math:<code>(.*?)</code>", re.S)
_SUP = str.maketrans("0123456789-", "⁰¹²³⁴⁵⁶⁷⁸⁹⁻")
_CARET = re.compile(r"\b([A-Za-z]|10)\^(-?\d)\b")
_PLUSMINUS = re.compile(r"(?<=\S) \+- (?=\S)")  # the study tables' "mean +- std"
_KEEP = re.compile(r'<pre\b.*?</pre>|<code\b.*?</code>|<script\b.*?</script>|<(span|div) class="arithmatex">.*?</\1>', re.S)


def on_page_content(html_text: str, page, config, files, **kwargs) -> str:
    """Render ``:math:`` roles of docstrings as math, drop the other sphinx roles (``:func:``)
    that docstrings carry before their code span, and
    write the carets of units in docstrings, help texts and the study tables (``m^2``,
    ``10^-3``) as superscripts and their ``+-`` as ``±``, outside code and math."""
    html_text = _MATH_ROLE.sub(lambda m: f'<span class="arithmatex">\\({m.group(1)}\\)</span>', html_text)
    html_text = _ROLE.sub("", html_text)
    def text(t: str) -> str:
        return _PLUSMINUS.sub(" ± ", _CARET.sub(lambda c: c.group(1) + c.group(2).translate(_SUP), t))

    out, pos = [], 0
    for m in _KEEP.finditer(html_text):
        out.append(text(html_text[pos:m.start()]))
        out.append(m.group(0))
        pos = m.end()
    out.append(text(html_text[pos:]))
    return "".join(out)
