"""MkDocs hooks: fill the docs' placeholders from :mod:`kane` at build time.

Placeholders (in any ``docs/*.md``)::

    {{ latex:eq34 }}   display math: ``kane.claims.CLAIMS["eq34"].latex()``
    {{ claim:eq34 }}   the claim's equation, statement, scope line, verdict table,
                       counterexample (if refuted) and its corrected statement with its own
                       equation, scope line, the verdict and cases of each clause, and table
    {{ report }}       the validation report: summary line, one row per check, environment
    {{ mjcf:PATH }}    Kane's equations of the MJCF file PATH (relative to the repository
                       root) derived by ``kane.mjcf.from_mjcf``: coordinates, speeds, partial
                       velocities, F_r, F*_r, mass matrix, forcing, parameters, and the
                       residuals against MuJoCo, Pinocchio and sympy's KanesMethod

The LaTeX comes from ``sympy.latex`` of the very expression the checks verify, so the pages
cannot drift from the code. Verdicts come from the JSON report named by the environment
variable ``MDGS_REPORT`` (written by ``mdgs validate --json PATH``); without it the hook runs
``kane.claims.run_checks(quick=True)`` once per build. An unknown id or an unfilled
placeholder stops the build.
"""

from __future__ import annotations

import json
import logging
import os
import re
import time

from mkdocs.exceptions import PluginError

log = logging.getLogger("mkdocs.hooks.mdgs")

_PLACEHOLDER = re.compile(r"\{\{\s*(latex|claim):([A-Za-z0-9_.]+)\s*\}\}|\{\{\s*report\s*\}\}")
_state: dict = {}


def _claims() -> dict:
    from kane.claims import CLAIMS

    return CLAIMS


def _report() -> dict:
    """The report dict (see :mod:`validation.report`), computed or read once per build."""
    if "report" not in _state:
        path = os.environ.get("MDGS_REPORT")
        if path:
            try:
                with open(path, encoding="utf-8") as f:
                    _state["report"] = json.load(f)
            except (OSError, json.JSONDecodeError) as e:
                raise PluginError(f"MDGS_REPORT={path}: cannot read the report ({e}).") from e
            _state["source"] = f"`mdgs validate --json` report `{os.path.basename(path)}`"
        else:
            from kane.claims import run_checks
            from validation.report import build_report

            t0 = time.perf_counter()
            _state["report"] = build_report(run_checks(quick=True), _claims())
            _state["source"] = "`mdgs validate --quick`, run while this site was built"
            log.info("mdgs: quick validation for the docs took %.1f s", time.perf_counter() - t0)
    return _state["report"]


def on_pre_build(config, **kwargs) -> None:
    """Start every build afresh (``mkdocs serve`` rebuilds)."""
    _state.clear()


def _fmt(x) -> str:
    return "&ndash;" if x is None else f"{x:.3g}"


def _escape(s: str) -> str:
    """Plain text (statements, details) safe inside Markdown and its tables."""
    s = str(s).replace("\\", "\\\\")
    for ch in "*_`[]":
        s = s.replace(ch, "\\" + ch)
    return s.replace("|", "&#124;").replace("<", "&lt;").replace(">", "&gt;").replace("\n", " ")


_BADGE = {"holds": "**holds**", "refuted": "**refuted**", "error": "*error*"}


_LONG = 250  # characters of LaTeX above which a sum is broken over aligned lines
_LINE = 140  # target characters of LaTeX per line


def _display_latex(claim) -> str:
    """``claim.latex()``; a long sum is split over lines of ``aligned`` (MathJax 3 does not
    break lines), each line ``sympy.latex`` of consecutive terms of the same expression."""
    import sympy as sp

    full = claim.latex().strip()
    expr = claim.expression() if callable(getattr(claim, "expression", None)) else None
    if len(full) <= _LONG or not isinstance(expr, sp.Add):
        return full
    head = sp.latex(expr)
    if not full.startswith(head):
        return full
    suffix = full[len(head) :]  # e.g. " \\le 0" for margins
    lines, cur = [], ""
    for i, term in enumerate(expr.as_ordered_terms()):
        t = sp.latex(term)
        if i and not t.startswith("-"):
            t = "+ " + t
        if cur and len(cur) + len(t) > _LINE:
            lines.append(cur)
            cur = ""
        cur += (" " if cur else "") + t
    lines.append(cur + suffix)
    return "\\begin{aligned}\n& " + " \\\\\n& ".join(lines) + "\n\\end{aligned}"


def _latex_block(claim_id: str) -> str:
    claims = _claims()
    if claim_id not in claims:
        raise PluginError(f"docs placeholder names unknown claim '{claim_id}'; known: {', '.join(sorted(claims))}.")
    tex = _display_latex(claims[claim_id])
    if not tex:
        return "*No single sympy expression: this claim is decided numerically (routes below).*"
    return "$$\n" + tex + "\n$$"


def _verdict_table(rows: list[dict]) -> str:
    lines = ["| case | route | verdict | residual / margin | tolerance |", "|---|---|---|---:|---:|"]
    for r in rows:
        lines.append(
            f"| {_escape(r['case'])} | {r['route']} | {_BADGE.get(r['verdict'], r['verdict'])} | {_fmt(r['residual'])} | {_fmt(r['tolerance'])} |"
        )
    return "\n".join(lines)


def _summaries() -> dict:
    """Claim id -> the report's ``claims`` entry (computed from the rows for older reports)."""
    rep = _report()
    if "claims" not in rep:
        from validation.report import claim_summaries

        rep["claims"] = claim_summaries(rep["checks"], _claims())
    return {c["id"]: c for c in rep["claims"]}


def _scope(claim_id: str) -> str:
    c = _summaries().get(claim_id)
    return f"**Scope:** {_escape(c['scope'])}." if c else "**Scope:** not run in this report."


def _clause_table(claim_id: str) -> list[str]:
    c = _summaries().get(claim_id)
    if not c or len(c["clauses"]) < 2:
        return []
    lines = ["| clause | verdict | checked on |", "|---|---|---|"]
    for cl in c["clauses"]:
        cases = "<br>".join(_escape(x) for x in cl["cases"]) or "&ndash;"
        lines.append(f"| {_escape(cl['text'])} | {_BADGE.get(cl['verdict'], cl['verdict'])} | {cases} |")
    return lines


def _cex_line(r: dict) -> str:
    from validation.report import counterexample_line

    return counterexample_line(r["counterexample"], width=400)


def _claim_block(claim_id: str) -> str:
    claims = _claims()
    if claim_id not in claims:
        raise PluginError(f"docs placeholder names unknown claim '{claim_id}'; known: {', '.join(sorted(claims))}.")
    c = claims[claim_id]
    rows = [r for r in _report()["checks"] if r["id"] == claim_id]
    out = [f"**{_escape(c.title)}** &mdash; Eq. {c.equation}. {_escape(c.statement)}", "", _scope(claim_id), "", _latex_block(claim_id), ""]
    if rows:
        out += [_verdict_table(rows), ""]
    else:
        out += ["*Not checked in this report.*", ""]
    for r in rows:
        if r["verdict"] == "refuted" and r["counterexample"]:
            out += [f"Counterexample ({_escape(r['case'])}, {r['route']}): `{_cex_line(r)}`", ""]
        elif r["verdict"] == "error":
            out += [f"Could not decide on {_escape(r['case'])}: {_escape(r['detail'])}", ""]
    cid = getattr(c, "corrected_id", None)
    if cid and cid in claims:
        cc = claims[cid]
        crow = [r for r in _report()["checks"] if r["id"] == cid]
        out += [
            f'!!! note "Corrected statement ({cid}): {_escape(cc.title)}"',
            "",
            f"    {_escape(cc.statement)}",
            "",
            f"    {_scope(cid)}",
            "",
            *("    " + line for line in _latex_block(cid).splitlines()),
            "",
        ]
        clause_rows = _clause_table(cid)
        if clause_rows:
            out += ["    " + line for line in clause_rows] + [""]
        if crow:
            out += ["    " + line for line in _verdict_table(crow).splitlines()]
            out.append("")
    return "\n".join(out)


def _report_block() -> str:
    from validation.report import summary_line

    rep = _report()
    claims = _claims()
    out = [f"**{summary_line(rep['summary'])}** (from {_state.get('source', 'the report')}).", ""]
    out.append("| claim | case | route | verdict | residual / margin | tolerance |")
    out.append("|---|---|---|---|---:|---:|")
    for r in rep["checks"]:
        eq = getattr(claims.get(r["id"]), "equation", "")
        out.append(
            f"| `{r['id']}` {eq}<br>{_escape(r['claim'])} | {_escape(r['case'])} | {r['route']} | "
            f"{_BADGE.get(r['verdict'], r['verdict'])} | {_fmt(r['residual'])} | {_fmt(r['tolerance'])} |"
        )
    out += ["", "### Scope of each verdict", ""]
    out += [f"- `{c['id']}` {_escape(c['title'])}: {_escape(c['scope'])}." for c in _summaries().values()]
    notes = []
    for r in rep["checks"]:
        if r["verdict"] == "refuted":
            note = f"- `{r['id']}` on {_escape(r['case'])} ({r['route']}): counterexample `{_cex_line(r) or 'none recorded'}`"
            if r["corrected"]:
                cc = r["corrected"]
                note += f"; corrected `{cc['id']}`: {_escape(cc['statement'] or '')} ({_BADGE.get(cc['verdict'], 'not run')})"
            notes.append(note)
        elif r["verdict"] == "error":
            notes.append(f"- `{r['id']}` on {_escape(r['case'])} ({r['route']}) could not be decided: {_escape(r['detail'])}")
    if notes:
        out += ["", "### Refuted and undecided checks", "", *notes]
    env = rep.get("environment", {})
    out += ["", "### Environment", "", "| package | version |", "|---|---|"]
    out += [f"| {k} | {v or 'not installed'} |" for k, v in env.items()]
    return "\n".join(out)


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

    with open(path, encoding="utf-8") as f:
        xml = f.read()
    out = [f"```xml\n{xml.strip()}\n```", "", "**Coordinates and speeds** (MuJoCo `qpos` / `qvel` order):", "",
           "| coordinate | speed | dq/dt |", "|---|---|---|"]
    for qq, uu, qd in zip(sm.q, sm.u, sm.qdot, strict=False):
        out.append(f"| ${lx(qq)}$ | ${lx(uu)}$ | ${lx(qd)}$ |")
    out += ["", "**Partial velocities** of each mass centre $V$ and partial angular velocities $W$ "
            "(column $r$: speed $u_r$; components in the body's own frame):", ""]
    for name, V, W in mm.partial_velocities:
        out.append(f"- body `{name}`: $V = {lx(V.applyfunc(sp.trigsimp))}$, $W = {lx(W)}$")
    out += ["", "**Generalized active forces** $F_r$ (gravity, damping, springs, actuator force symbols):", "",
            f"$$F_r = {lx(sm.fr)}$$", "", "**Generalized inertia forces** $F^*_r$ (shown after `trigsimp`):", "",
            f"$$F^*_r = {lx(sm.frstar.applyfunc(sp.trigsimp))}$$", "",
            "**Mass matrix and forcing**, $M \\dot u = f$:", "",
            f"$$M = {lx(sm.mass_matrix.applyfunc(sp.trigsimp))}, \\quad f = {lx(sm.forcing)}$$", "",
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


def on_page_markdown(markdown: str, page, config, files, **kwargs) -> str:
    """Replace the placeholders of one page (see the module docstring)."""

    def fill(m: re.Match) -> str:
        kind, claim_id = m.group(1), m.group(2)
        if kind is None:
            return _report_block()
        return _latex_block(claim_id) if kind == "latex" else _claim_block(claim_id)

    root = os.path.dirname(os.path.abspath(config["config_file_path"]))
    markdown = _MJCF.sub(lambda m: _mjcf_block(m.group(1), root), markdown)
    return _PLACEHOLDER.sub(fill, markdown)
