"""How the claims and the validation report are written for readers (the docs site).

The docs (``docs/hooks.py``) take everything from here, and everything here comes from
:mod:`kane` and :mod:`validation.report`:

* :func:`statement_latex` prints the sympy expression of a claim with the symbols named for
  reading (:class:`Printer`: :math:`v^{t+1}_{\\gamma,i}`, bold vectors, dot and cross products);
* :data:`COMPACT` writes each Appendix A.2 inequality and Eq. (30) in vector form; its
  component expansion (:func:`expand_compact`) is compared with the very margin the checks
  maximise (:func:`compact_agrees`), so the compact form cannot drift from the checked one;
* :func:`expanded_lines` breaks the checked (component) expression over short lines;
* :data:`TEXT` holds the claims' titles, statements and clause texts marked up in LaTeX (the
  ASCII versions in :mod:`kane.claims` are what the terminal prints); :func:`scope_tex`
  composes the scope line from the report's clause verdicts with
  :func:`validation.report.scope_line`, as the command line does;
* :func:`counterexample_view` turns a recorded counterexample into the quantities that matter,
  both sides of the claim, the absolute and the relative margin (the report's number, see
  :data:`NORMALISATION`) and one sentence of physics. Element and geom counterexamples are
  evaluated by :func:`kane.counterexamples.replay`, so the numbers are those that
  ``mdgs validate --replay`` prints.
"""

from __future__ import annotations

import math
import re
from functools import lru_cache

import numpy as np
import sympy as sp
from sympy.printing.latex import LatexPrinter

from validation.report import scope_line

__all__ = [
    "Printer",
    "latex",
    "statement_latex",
    "COMPACT",
    "compact_latex",
    "expand_compact",
    "compact_agrees",
    "expanded_lines",
    "relation_lines",
    "TEXT",
    "scope_tex",
    "NORMALISATION",
    "WHY",
    "counterexample_view",
    "fmt",
]

# --------------------------------------------------------------------------- printing

#: sympy symbol name -> LaTeX, for every symbol of kane's displayed expressions
SYMBOL_NAMES = {
    "K_gamma": r"K_{\gamma}", "K^*_gamma": r"K^{*}_{\gamma}", "Psi": r"\Psi", "delta": r"\delta", "u_g": r"u_{\gamma}",
    "L_cst": r"\mathcal{L}_{\mathrm{cst}}", "S": r"S", "B": r"B", "s": "s", "tau": r"\tau", "M": "M",
    "r_l": r"\mathbf{r}_l", "F_l": r"\mathbf{F}_l", "omega": r"\boldsymbol{\omega}", "alpha": r"\boldsymbol{\alpha}",
    "I": r"\mathbf{I}", "e_z": r"\mathbf{e}_z", "L": "L",
}
#: IndexedBase name -> LaTeX template of its element ``{i}`` (the index)
INDEXED = {
    "F_gamma": r"F_{\gamma,{i}}", "M": r"M_{{i}}", "v_next": r"v^{t+1}_{\gamma,{i}}", "v": r"v^{t}_{\gamma,{i}}",
    "R_norm": r"\lvert\mathbf{R}_{{i}}\rvert", "wdot": r"\lvert\boldsymbol{\alpha}_{{i}}\rvert",
    "F_abs_sum": r"\textstyle\sum_l \lvert\mathbf{F}_{{i},l}\rvert", "w_abs": r"\lvert\boldsymbol{\omega}_{{i}}\rvert",
    "tau": r"\tau_{{i}}", "w_g": r"\lvert\boldsymbol{\omega}_{{i},\gamma}\rvert",
    "F": r"\mathbf{F}_{{i}}", "r": r"\mathbf{r}_{{i}}", "a": r"\mathbf{a}_{{i}}", "m": r"m_{{i}}",
}
_VEC = re.compile(r"\\vec\{(\\?[A-Za-z]+)\}")


class Printer(LatexPrinter):
    """sympy's LaTeX printer with kane's symbols named for reading: bold vectors (``\\vec{u}``
    -> :math:`\\mathbf u`), ``dot``/``cross`` as :math:`\\cdot`/:math:`\\times`, indexed
    quantities by :data:`INDEXED`, and terms in the order they were built."""

    def __init__(self, settings=None):
        super().__init__({"order": "none", **(settings or {})})

    def _print_Symbol(self, expr, style="plain"):
        name = expr.name
        if name in SYMBOL_NAMES:
            return SYMBOL_NAMES[name]
        if "\\vec" in name:
            return _VEC.sub(lambda m: (r"\boldsymbol{%s}" if m.group(1).startswith("\\") else r"\mathbf{%s}") % m.group(1), name)
        return super()._print_Symbol(expr, style=style)

    def _print_Indexed(self, expr):
        base = str(expr.base.label)
        idx = ",".join(self._print(i) for i in expr.indices)
        if base in INDEXED:
            return INDEXED[base].replace("{i}", idx)
        return super()._print_Indexed(expr)

    def _wrap(self, e) -> str:
        s = self._print(e)
        return rf"\left({s}\right)" if isinstance(e, sp.Add) else s

    def _print_Function(self, expr, exp=None):
        name = expr.func.__name__
        if name == "dot":
            return rf"{self._wrap(expr.args[0])} \cdot {self._wrap(expr.args[1])}"
        if name == "cross":
            return rf"{self._wrap(expr.args[0])} \times {self._wrap(expr.args[1])}"
        if name == "norm":
            tex = rf"\left\lvert {self._print(expr.args[0])} \right\rvert"
            return tex if exp is None else rf"{tex}^{{{exp}}}"
        return super()._print_Function(expr, exp)

    def _print_Abs(self, expr, exp=None):
        tex = rf"\left\lvert {self._print(expr.args[0])} \right\rvert"
        return tex if exp is None else rf"{tex}^{{{exp}}}"


def latex(expr) -> str:
    """LaTeX of ``expr`` by :class:`Printer`."""
    return Printer().doprint(expr)


def statement_latex(claim) -> str:
    """The display LaTeX of a claim: its compact vector form where :data:`COMPACT` has one,
    else its sympy expression printed by :class:`Printer` ("" when it has none)."""
    if claim.id in COMPACT:
        return compact_latex(claim.id)
    e = claim.expression()
    return "" if e is None else latex(e)


# --------------------------------------------------------------------------- compact forms

dot, cross, norm = sp.Function("dot"), sp.Function("cross"), sp.Function("norm")
_l = sp.Symbol("l", integer=True)
_L = sp.Symbol("L", integer=True)
_r, _F = sp.Symbol("r_l", commutative=False), sp.Symbol("F_l", commutative=False)
_w, _a = sp.Symbol("omega", commutative=False), sp.Symbol("alpha", commutative=False)
_I, _ez = sp.Symbol("I", commutative=False), sp.Symbol("e_z", commutative=False)
_tau, _M, _s = sp.Symbol("tau"), sp.Symbol("M"), sp.Symbol("s")


def _add(*terms):
    return sp.Add(*terms, evaluate=False)


def _sum(e):
    return sp.Sum(e, (_l, 1, _L))


_MOMENT = dot(_ez, _sum(cross(_r, _F)))                      # e_z . sum_l r_l x F_l
_LSTAR = dot(_ez, _add(_I * _a, cross(_w, _I * _w)))          # e_z . (I alpha + omega x I omega)
_PSI = dot(_ez, _add(_sum(cross(_r, _F)), -(_I * _a), -cross(_w, _I * _w)))
_rr = sp.Symbol(r"\mathbf{r}", commutative=False)
_PSI_SR = sp.Function("Psi")(_s * _rr)
_HALF, _TWO5 = sp.Rational(1, 2), sp.Rational(2, 5)
_GYRO = _M * _tau**2 * norm(_w) ** 2 * _HALF

#: claim id -> (lhs, rhs) in vector form; the claim reads ``lhs <= rhs`` (``lhs = rhs`` for
#: eq30) for one element of L point masses about its centroid, rotational speed about e_z
COMPACT: dict[str, tuple] = {
    "eq34": (_MOMENT, _tau * norm(_sum(_F))),
    "eq34.corrected": (_MOMENT, _tau * _sum(norm(_F))),
    "eq35": (_LSTAR, norm(_I * _a)),
    "eq35.corrected": (_LSTAR, _add(norm(_I * _a), _GYRO)),
    "eq36": (dot(_ez, _I * _ez), _TWO5 * _M * _tau**2),
    "eq36.corrected": (dot(_ez, _I * _ez), _M * _tau**2),
    "eq37": (_LSTAR, _TWO5 * _M * _tau**2 * norm(_a)),
    "eq37.corrected": (_LSTAR, _M * _tau**2 * _add(norm(_a), norm(_w) ** 2 * _HALF)),
    "eq12": (_PSI, _add(_tau * norm(_sum(_F)), _TWO5 * _M * _tau**2 * norm(_a))),
    "eq12.corrected": (_PSI, _add(_tau * _sum(norm(_F)), _M * _tau**2 * _add(norm(_a), norm(_w) ** 2 * _HALF))),
    # Psi(s r) - s Psi(r): the claim says it is 0; it is s (1 - s) times the inertia torque
    "eq30": (_add(_PSI_SR, -_s * sp.Function("Psi")(_rr)), _s * (1 - _s) * _LSTAR),
    "eq30.corrected": (_PSI_SR, _add(_s * _MOMENT, -(_s**2) * _LSTAR)),
}
_EQUALITY = {"eq30", "eq30.corrected"}


def compact_latex(claim_id: str) -> str:
    """``lhs \\le rhs`` of :data:`COMPACT` (``lhs = rhs`` for Eq. 30)."""
    lhs, rhs = COMPACT[claim_id]
    rel = "=" if claim_id in _EQUALITY else r"\le"
    return f"{latex(lhs)} {rel} {latex(rhs)}"


def _evaluate(x, env: dict, l_index: int | None = None):
    """Component (sympy Matrix / scalar) value of a compact expression on the generic element."""
    if isinstance(x, sp.Sum):
        terms = [_evaluate(x.function, env, k) for k in range(len(env["r_l"]))]
        out = terms[0]
        for t in terms[1:]:
            out = out + t
        return out
    if isinstance(x, sp.Symbol):
        v = env.get(x.name, x)
        return v[l_index] if isinstance(v, tuple) else v
    if isinstance(x, sp.Number):
        return x
    args = [_evaluate(a, env, l_index) for a in x.args]
    name = getattr(x.func, "__name__", "")
    if name == "dot":
        return (args[0].T * args[1])[0]
    if name == "cross":
        return args[0].cross(args[1])
    if name == "norm":
        return sp.sqrt(args[0].dot(args[0]))
    if isinstance(x, sp.Add):
        out = args[0]
        for a in args[1:]:
            out = out + a
        return out
    if isinstance(x, sp.Mul):
        out = sp.S.One
        for a in args:
            out = out * a
        return out
    if isinstance(x, sp.Pow):
        return args[0] ** args[1]
    raise TypeError(f"cannot evaluate {x!r} on the element")


def expand_compact(claim_id: str):
    """The margin ``lhs - rhs`` of :data:`COMPACT` written out in components on kane's generic
    element (:func:`kane.element_claims.element_model`); eq30: ``Psi(s r) - s Psi(r) - rhs``."""
    from kane.element_claims import element_model

    e = element_model()
    env = {"r_l": e.r, "F_l": e.F, "omega": e.omega, "alpha": e.alpha, "I": e.I, "e_z": sp.Matrix([0, 0, 1]),
           "tau": e.tau, "M": e.M}
    lhs, rhs = COMPACT[claim_id]
    if claim_id == "eq30":  # the check's expression Psi(s r) - s Psi(r), minus its closed form
        from kane.claims import _psi_scaling

        return _psi_scaling(False) - _evaluate(rhs, env)
    if claim_id == "eq30.corrected":  # Psi(s r) minus the closed form
        return e.psi.xreplace({c: _s * c for v in e.r for c in v}) - _evaluate(rhs, env)
    return _evaluate(lhs, env) - _evaluate(rhs, env)


def compact_agrees(claim_id: str, n: int = 5, seed: int = 0) -> float:
    """Largest relative difference, over ``n`` random element states, between the expansion of
    the compact form and the margin the checks evaluate (:func:`kane.element_claims.margin_expression`;
    eq30 and its correction: zero, since the compact right-hand side is the closed form of the
    check's scaled :math:`\\Psi`). Round-off only: below 1e-12."""
    from kane.element_claims import element_model, margin_expression

    e = element_model()
    args = [*e.args, _s]
    mine = sp.lambdify(args, expand_compact(claim_id), "numpy")
    ref = (lambda *a: 0.0) if claim_id.startswith("eq30") else sp.lambdify(args, margin_expression(claim_id), "numpy")
    rng = np.random.default_rng(seed)
    worst = 0.0
    for _ in range(n):
        vals = list(rng.uniform(-1, 1, len(e.args)))
        vals[:4] = np.abs(vals[:4]) + 0.1                        # masses
        offs = np.array(vals[4:16]).reshape(4, 3)
        vals[-1] = float(np.linalg.norm(offs, axis=1).max())    # tau
        vals.append(1.7)                                        # s
        a, b = float(mine(*vals)), float(ref(*vals))
        worst = max(worst, abs(a - b) / (1.0 + abs(b)))
    return worst


def _visible(tex: str) -> int:
    """Rough count of the glyphs a LaTeX string renders (commands count 1, braces 0)."""
    t = re.sub(r"\\(left|right|operatorname|mathbf|boldsymbol|frac)\b", "", tex)
    t = re.sub(r"\\[A-Za-z]+", "x", t)
    small = sum(len(re.sub(r"\s", "", m)) for m in re.findall(r"[_^]\{([^{}]*)\}", t))
    t = re.sub(r"[_^]\{[^{}]*\}", "", t)  # sub/superscripts render at about 70 %
    return len(re.sub(r"[{}\s]", "", t)) + int(0.7 * small + 0.5)


def _split(tex_terms: list[str], width: int) -> list[str]:
    lines, cur = [], ""
    for t in tex_terms:
        if cur and _visible(cur) + _visible(t) > width:
            lines.append(cur)
            cur = ""
        cur += (" " if cur else "") + t
    return lines + [cur]


def _terms(expr) -> list:
    """The terms of ``expr``, products of sums multiplied out (sqrt arguments kept)."""
    return list(sp.Add.make_args(sp.expand_mul(expr, deep=False)))


def _tex_terms(terms) -> list[str]:
    out = []
    for i, term in enumerate(terms):
        t = sp.latex(term)
        out.append(t if i == 0 or t.startswith("-") else "+ " + t)
    return out


def _abbreviate(term, width: int, named: list) -> object:
    """``term`` with its widest inner sums and roots named ``z_k`` (appended to ``named``)
    until it prints in about ``width`` glyphs."""
    while _visible(sp.latex(term)) > width:
        inner = [x for x in sp.preorder_traversal(term) if x != term and (isinstance(x, sp.Add) or
                 (isinstance(x, sp.Pow) and x.exp == sp.S.Half))]
        if not inner:
            break
        big = max(inner, key=lambda x: (_visible(sp.latex(x)), sp.default_sort_key(x)))
        if _visible(sp.latex(big)) < 6:
            break
        z = sp.Symbol(f"z_{len(named) + 1}")
        named.append((z, big))
        term = term.xreplace({big: z})
    return term


def expanded_lines(expr, suffix: str = "", width: int = 26, label: str = r"\text{margin}") -> list[str]:
    """The component form of ``expr`` over lines of about ``width`` glyphs (``aligned`` rows).

    Common subexpressions (``sympy.cse``) are named :math:`x_k`, and the inner sums or roots of
    a term still too wide are named :math:`z_k`; each is written out after the margin, so that
    no line is wider than a phone's column. The rows align at ``=``, so every row is as wide as
    the widest name plus its terms: the terms get ``width`` minus that name. Every row is
    ``sympy.latex`` of terms of the very expression the checks evaluate.
    """
    reps, (red,) = sp.cse(expr)
    named: list = []
    todo = [(sp.Symbol("margin"), red)] + list(reps)
    head_w = max([_visible(label)] + [_visible(sp.latex(sym)) for sym, _ in reps] + [_visible("z_{99}")]) + 2  # "={}"
    body_w = max(width - head_w, 12)
    lines: list[str] = []
    while todo:
        sym, val = todo.pop(0)
        n0 = len(named)
        terms = [_abbreviate(t, body_w, named) for t in _terms(val)]
        body = _split(_tex_terms(terms), body_w)
        if sym.name == "margin":
            body[-1] += suffix
            head = f"{label} ={{}} & " if (reps or named) else "& "
        else:
            head = f"{sp.latex(sym)} ={{}} & "
        lines.append(head + body[0])
        lines += [f"& {b}" for b in body[1:]]
        todo += named[n0:]
    return lines


def _side_lines(expr, width: int) -> list[str]:
    r"""``expr`` printed by :class:`Printer` over lines of about ``width`` glyphs: split at the
    terms of a sum, and inside a sum over ``i`` of a sum (``\sum_i \Big( a - b \Big)``)."""
    tex = latex(expr)
    if _visible(tex) <= width:
        return [tex]
    if isinstance(expr, sp.Add):
        out: list[str] = []
        for i, term in enumerate(expr.args):
            parts = _side_lines(term, width)
            if i and not parts[0].startswith("-"):
                parts[0] = "+ " + parts[0]
            if out and _visible(out[-1]) + _visible(parts[0]) <= width:
                out[-1] += " " + parts.pop(0)
            out += parts
        return out
    if isinstance(expr, sp.Sum) and isinstance(expr.function, sp.Add):
        hole = sp.Symbol("HOLE")
        prefix = latex(sp.Sum(hole, *expr.limits)).replace(latex(hole), "").strip() + r" \Bigg("
        inner = _side_lines(expr.function, width - 2)
        if _visible(prefix) + _visible(inner[0]) > width:  # terms one per line
            inner = [x for i, t in enumerate(expr.function.args)
                     for x in [(latex(t) if i == 0 or latex(t).startswith("-") else "+ " + latex(t))]]
        inner[0] = f"{prefix} {inner[0]}"
        inner[-1] += r" \Bigg)"
        return inner
    return [tex]


def relation_lines(lhs, rhs, rel: str = "=", width: int = 26) -> list[str]:
    r"""``lhs rel rhs`` as rows of an ``aligned`` environment, none wider than about ``width``
    glyphs (:func:`_visible`): one row when it fits, else ``lhs`` then ``rel rhs``, each side
    broken at its terms (:func:`_side_lines`); the rows after the first are indented."""
    lt, rt = latex(lhs), latex(rhs)
    if _visible(lt) + _visible(rt) + 1 <= width:
        return [f"& {lt} {rel} {rt}"]
    left = _side_lines(lhs, width)
    right = _side_lines(rhs, width - 4)
    return ([f"& {left[0]}"] + [rf"& \quad {x}" for x in left[1:]] + [rf"& \quad {rel} {right[0]}"]
            + [rf"& \qquad {x}" for x in right[1:]])


# --------------------------------------------------------------------------- texts

_g = r"\(\gamma\)"
#: claim id -> title, statement and clause texts (by clause key) marked up in LaTeX
TEXT: dict[str, dict] = {
    "eq3": {"title": "Kane's equation",
            "statement": r"\(K_\gamma + K^*_\gamma = 0\) for every generalized speed \(\gamma\)."},
    "lemmaA1": {"title": "elements give the same equations of motion",
                "statement": "Dividing rigid bodies into elements of point masses gives the same equations of motion "
                             "as the undivided system."},
    "eq17": {"title": r"\(K_\gamma\) as a sum over elements",
             "statement": r"\(K_\gamma = \sum_i \mathbf R_i\cdot\mathbf u_{i,\gamma} + \mathbf M_i\cdot\boldsymbol\omega_{i,\gamma}\)."},
    "eq19": {"title": r"\(K^*_\gamma\) as a sum over elements",
             "statement": r"\(K^*_\gamma = -\sum_i M_i\,\mathbf a_i\cdot\mathbf u_{i,\gamma} + \mathbf L^*_i\cdot\boldsymbol\omega_{i,\gamma}\)."},
    "eq23": {"title": "one-hot partial velocities",
             "statement": "The partial velocity of every element centroid with respect to every independent speed is a one-hot vector.",
             "clauses": {"rot": "rotational and joint speeds", "trans": "the world-axis translational speeds of a free base"}},
    "eq23.corrected": {
        "title": "one-hot exactly for world-axis translations of a base carrying every element",
        "statement": r"At any configuration, \(\mathbf u_{i,\gamma} = \pm\mathbf e_k\) (the same \(k\) for every element "
                     r"\(i\)) and \(\boldsymbol\omega_{i,\gamma} = \mathbf 0\) if and only if \(\gamma\) is the speed of a "
                     "translation along a world coordinate axis by a joint that carries every element: (a) such speeds "
                     "(MuJoCo's free-joint <code>qvel[0:3]</code>, which are world axes; a slide joint whose axis is a world "
                     "axis) are one-hot; (b) no other speed is: rotations, joints of a subtree, and translations along "
                     "non-coordinate or body-fixed axes (Pinocchio's free-flyer velocity is in the body frame, one-hot only "
                     "while the base is axis-aligned).",
        "clauses": {"a": "(a) world-axis translations of a joint carrying every element are one-hot",
                    "b": "(b) no other speed is one-hot (rotations, subtree joints, oblique or body-frame axes)"}},
    "eq11": {"title": "Theorem 3.1",
             "statement": r"\(\sum_i F_{\gamma,i} - \sum_i M_i\,(v^{t+1}_{\gamma,i} - v^{t}_{\gamma,i})/\delta + \Psi = 0\) "
                          r"for every independent speed \(\gamma\).",
             "clauses": {"rot": "rotational speeds",
                         "trans": r"translational speeds (\(\Psi = 0\)) of a single free body centred on its joint origin (Euler)",
                         "fd": r"translational speeds of off-centre or articulated bodies (Euler, \(O(\delta)\)) or with contact (RK4)"}},
    "eq11.corrected": {
        "title": "Newton's law for translational speeds; when the forward difference is exact",
        "statement": r"For the world-axis translational speeds \(\gamma\) of a free base carrying every body (Eq. 23*), "
                     r"\(\boldsymbol\omega_{i,\gamma} = \mathbf 0\), so \(\Psi = 0\) and (a) \(\sum_i F_{\gamma,i} = \sum_i "
                     r"M_i a_{\gamma,i}\) exactly with the elements' true accelerations (single, off-centre and articulated "
                     r"free bodies, with contact). With the forward difference \((v^{t+1} - v^t)/\delta\) for \(a\) on MuJoCo "
                     "data: (b) semi-implicit Euler is exact to round-off for a single free rigid body whose joint origin is "
                     "its centre of mass, with or without contact; (c) Euler leaves a residual that shrinks like "
                     r"\(\delta\), nonzero while the body spins, when the joint origin is off the centre of mass or the body "
                     "is articulated; (d) RK4 is exact to round-off without contact (gravity only), off-centre and "
                     "articulated bodies included; (e) RK4 with contact is not exact, and its residual, made at contact "
                     r"onset, does not shrink like \(\delta\).",
        "clauses": {"a": "(a) Newton exact with true accelerations",
                    "b": "(b) Euler forward difference exact for a centred single free body",
                    "c": r"(c) Euler forward difference \(O(\delta)\), nonzero, for spinning off-centre or articulated bodies",
                    "d": "(d) RK4 forward difference exact without contact",
                    "e": r"(e) RK4 forward difference with contact not exact, not \(O(\delta)\)"}},
    "eq30": {"title": r"\(\Psi\) proportional to the radii",
             "statement": r"\(\Psi\) is proportional to \(\sum_i\sum_l \lvert\mathbf r_{i,l}\rvert\)."},
    "eq30.corrected": {
        "title": r"\(\Psi = s\) (moment term) \(-\,s^2\) (inertia term) under \(\mathbf r \to s\,\mathbf r\)",
        "statement": r"Under the scaling \(\mathbf r \to s\,\mathbf r\) of the elements, \(\Psi = s\,(\text{moment term}) - "
                     r"s^2\,(\text{inertia term})\): linear plus quadratic, vanishing as \(\tau \to 0\)."},
    "eq15": {"title": r"\(\mathcal L_{\mathrm{cst}} = 0\) on ground truth",
             "statement": r"The constraint loss \(\mathcal L_{\mathrm{sup}} + \mathcal L_{\mathrm{inf}}\) of Eqs. (13)-(15) "
                          "is zero on exact ground-truth data.",
             "clauses": {"": "the paper's translational x, y, z constraints on a centred free body (Euler)"}},
    "eq34": {"title": "bound on the moment of the forces",
             "statement": r"\(\lvert\sum_l (\mathbf r_l\times\mathbf F_l)\cdot\boldsymbol\omega_{\gamma}\rvert \le "
                          r"\tau\,\lvert\mathbf R_i\rvert\,\omega_\gamma\)."},
    "eq34.corrected": {"title": r"moment of the forces \(\le \tau\sum_l\lvert\mathbf F_l\rvert\)",
                       "statement": r"\(\lvert\sum_l (\mathbf r_l\times\mathbf F_l)\cdot\boldsymbol\omega_{i,\gamma}\rvert \le "
                                    r"\lvert\boldsymbol\omega_{i,\gamma}\rvert\,\tau_i\sum_l\lvert\mathbf F_l\rvert\) "
                                    "(magnitudes summed, not the resultant)."},
    "eq35": {"title": r"inertia torque \(\le I\,\omega'\)",
             "statement": r"\(\sum_l (\mathbf r_l\times m_l\mathbf a_l)\cdot\boldsymbol\omega_\gamma \le I_i\,\omega'_i\)."},
    "eq35.corrected": {"title": "inertia torque bounded with the gyroscopic term",
                       "statement": r"\(\lvert\mathbf L^*_i\cdot\boldsymbol\omega_{i,\gamma}\rvert \le "
                                    r"\lvert\boldsymbol\omega_{i,\gamma}\rvert\,(\lvert\mathbf I_i\boldsymbol\alpha_i\rvert + "
                                    r"M_i\tau^2\lvert\boldsymbol\omega_i\rvert^2/2)\) (gyroscopic term included)."},
    "eq36": {"title": r"\(I_i \le \tfrac25 M_i\tau^2\)",
             "statement": r"The element's moment of inertia is at most that of a solid sphere of radius \(\tau\): "
                          r"\(I_i \le \tfrac25 M_i\tau^2\).",
             "clauses": {"flat": "flat solids (a disc) and point-mass elements",
                         "solid": "uniform solid boxes, tetrahedra and spheres"}},
    "eq36.corrected": {
        "title": r"\(I_i \le M_i\tau^2\) (tight: a ring); \(\tfrac13 M_i\tau^2\) for uniform solid boxes only",
        "statement": r"(a) \(I_i \le M_i\tau^2\) for any mass distribution within radius \(\tau\) of the centroid, attained "
                     r"by a ring; (b) a uniform solid (continuum) box has \(I_i \le \tfrac13 M_i\tau^2\); (c) boxes of point "
                     "masses, the element model of the paper and of <code>partition_box</code>, do not: 8 corner masses give "
                     r"\(\tfrac23 M_i\tau^2\) for a cube and flat cells approach \(M_i\tau^2\).",
        "clauses": {"a": r"(a) \(I \le M\tau^2\) for any distribution, attained by a ring",
                    "b": r"(b) \(I \le \tfrac13 M\tau^2\) for uniform solid boxes",
                    "c": r"(c) point-mass boxes reach \(\tfrac23 M\tau^2\) (cube) and approach \(M\tau^2\) (flat)"}},
    "eq37": {"title": "sphere bound on the inertia torque",
             "statement": r"\(\lvert\sum_l (\mathbf r_l\times m_l\mathbf a_l)\cdot\boldsymbol\omega_\gamma\rvert \le "
                          r"\tfrac25 M_i\tau^2\,\omega'_i\)."},
    "eq37.corrected": {"title": r"inertia torque \(\le M\tau^2(\lvert\boldsymbol\alpha\rvert + \lvert\boldsymbol\omega\rvert^2/2)\)",
                       "statement": r"\(\lvert\mathbf L^*_i\cdot\boldsymbol\omega_{i,\gamma}\rvert \le "
                                    r"\lvert\boldsymbol\omega_{i,\gamma}\rvert\,M_i\tau^2(\lvert\boldsymbol\alpha_i\rvert + "
                                    r"\lvert\boldsymbol\omega_i\rvert^2/2)\)."},
    "eq12": {"title": "Theorem 3.2",
             "statement": r"\(\lvert\Psi\rvert \le \tau\sum_i\lvert\mathbf R_i\rvert\,\omega_\gamma + "
                          r"\sum_i \tfrac25 M_i\tau^2\omega'_i\).",
             "clauses": {"rot": r"rotational speeds, external loads only in \(\Psi\)",
                         "internal": r"rotational speeds with the inter-element forces in \(\Psi\) (\(\Psi = 0\))",
                         "trans": r"the translational speeds MDGS trains with (\(\Psi = 0\); true but loose)"}},
    "eq12.corrected": {
        "title": r"\(\lvert\Psi\rvert \le\) force magnitudes plus gyroscopic inertia terms; zero for translational speeds",
        "statement": r"(a) \(\lvert\Psi\rvert \le \sum_i \lvert\boldsymbol\omega_{i,\gamma}\rvert\,(\tau_i\sum_l"
                     r"\lvert\mathbf F_{i,l}\rvert + M_i\tau_i^2(\lvert\boldsymbol\alpha_i\rvert + "
                     r"\lvert\boldsymbol\omega_i\rvert^2/2))\) for every speed, with external loads in \(\Psi\); (b) for the "
                     r"world-axis translational speeds (Eq. 23*) \(\boldsymbol\omega_{i,\gamma} = \mathbf 0\), so \(\Psi = 0\) "
                     "and the bound is 0: the constraint of Eqs. (13)-(15) becomes the equality of Eq. (11)*.",
        "clauses": {"a": "(a) the bound for rotational speeds",
                    "b": r"(b) \(\Psi = 0 =\) bound for world-axis translational speeds"}},
}
for _cid in ("eq34", "eq34.corrected", "eq35", "eq35.corrected", "eq37", "eq37.corrected"):
    TEXT[_cid].setdefault("clauses", {"": "a rotational speed of a generic element of 4 point masses"})

#: claim id -> why the paper's claim fails, in one sentence (the physics, not the numbers)
WHY = {
    "eq23": r"A rotation moves an element centroid by \(\boldsymbol\omega_{i,\gamma}\times\mathbf r_i\), which depends on "
            "where the element is: no single unit vector describes every element.",
    "eq11": r"For a rotational speed the partial velocities are not one-hot, so the element sum is not Kane's equation; "
            "for translations the forward difference of the elements' velocities is exact only for a centred body "
            "(Euler) or without contact (RK4).",
    "eq30": r"Under \(\mathbf r\to s\,\mathbf r\) the moment of the forces grows like \(s\) but the inertia torque like "
            r"\(s^2\) (\(\mathbf I\propto r^2\)), so \(\Psi\) is not proportional to the radii.",
    "eq34": r"A couple has resultant \(\mathbf R = \mathbf 0\) but a non-zero moment, so \(\tau\lvert\mathbf R\rvert\) "
            "cannot bound the moment of the forces.",
    "eq35": r"The inertia torque \(\mathbf I\boldsymbol\alpha + \boldsymbol\omega\times\mathbf I\boldsymbol\omega\) has a "
            r"gyroscopic part: a steady spin (\(\boldsymbol\alpha = \mathbf 0\)) about a non-principal axis needs a "
            r"torque that \(\lvert\mathbf I\boldsymbol\alpha\rvert = 0\) misses.",
    "eq36": r"A solid sphere is the most compact shape, not the least: a disc has \(I = \tfrac12 M\tau^2\) about its axis "
            r"and a ring \(M\tau^2\).",
    "eq37": "It combines Eqs. (35) and (36) and inherits both failures (the gyroscopic torque and flat elements).",
    "eq12": r"It sums the bounds of Eqs. (34) and (37), so couples, the gyroscopic torque and flat elements each break "
            r"it; with the inter-element forces in \(\Psi\) or for translational speeds it holds.",
}

#: how the margins are normalised, for the docs (see kane.adversarial.SCALE_TEXT)
NORMALISATION = (
    r"Equalities report the largest residual relative to the size of their terms. Inequalities report the "
    r"**relative margin** \((\text{lhs} - \text{rhs})/\text{scale}\) (negative: slack): for one element, "
    r"\(\text{scale} = \tau\sum_l\lvert\mathbf F_l\rvert + M\tau^2(\lvert\boldsymbol\alpha\rvert + "
    r"\lvert\boldsymbol\omega\rvert^2 + 1)\), so that one tolerance fits every size; a MuJoCo geom uses "
    r"\(M\tau^2\); trajectories use the force scale \(\sum\lvert\mathbf F\rvert\) or \(\sum_i M_i\tau_i^2(\max"
    r"\lvert\boldsymbol\omega\rvert^2 + 1)\). `mdgs validate --replay` prints lhs, rhs, the absolute margin "
    r"\(\text{lhs} - \text{rhs}\) and the relative one."
)


def scope_tex(summary: dict) -> str | None:
    """The scope line of one ``claims`` entry of the report, its clause texts in LaTeX
    (:data:`TEXT`), composed by :func:`validation.report.scope_line` as on the command line."""
    if not summary.get("scope"):
        return None
    texts = TEXT.get(summary["id"], {}).get("clauses", {})
    pairs = [(texts.get(c["key"], "every case tried" if not c["key"] else c["text"]), c["verdict"]) for c in summary["clauses"]]
    return scope_line(pairs)


# --------------------------------------------------------------------------- counterexamples


def fmt(x: float, digits: int = 4, zero: float = 1e-12) -> str:
    """A number to ``digits`` significant digits; ``0`` below ``zero`` in magnitude (round-off)."""
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "&ndash;"
    x = float(x)
    if abs(x) < zero:
        return "0"
    s = f"{x:.{digits}g}"
    if "e" in s:
        m, e = s.split("e")
        return rf"\({m} \times 10^{{{int(e)}}}\)"
    return s


def _vec(v, digits: int = 3) -> str:
    v = np.asarray(v, float)
    tiny = max(1e-12, 1e-9 * np.abs(v).max())  # round-off: below 1e-12 absolute or 1e-9 relative
    return "(" + ", ".join(fmt(c, digits, tiny) for c in v) + ")"


@lru_cache(maxsize=64)
def _replay(cex_json: str):
    import json

    from kane.counterexamples import replay

    return replay(json.loads(cex_json))


def _element_quantities(s: dict) -> dict:
    m = np.asarray(s["masses"], float)
    r = np.asarray(s["offsets"], float)
    F = np.asarray(s["forces"], float)
    w, a = np.asarray(s["omega"], float), np.asarray(s["alpha"], float)
    c = (m[:, None] * r).sum(0) / m.sum()
    r = r - c
    M, tau = m.sum(), float(np.linalg.norm(r, axis=1).max())
    I = sum(mi * (ri @ ri * np.eye(3) - np.outer(ri, ri)) for mi, ri in zip(m, r, strict=True))
    return {"L": len(m), "M": M, "tau": tau, "R": float(np.linalg.norm(F.sum(0))), "Fsum": float(np.linalg.norm(F, axis=1).sum()),
            "Mz": float(np.cross(r, F).sum(0)[2]), "Izz": float(I[2, 2]), "Ia": float(np.linalg.norm(I @ a)),
            "Iaz": float((I @ a)[2]), "gyro": float(np.cross(w, I @ w)[2]), "w": float(np.linalg.norm(w)),
            "a": float(np.linalg.norm(a)), "omega": w, "alpha": a}


_Q = {  # quantity key -> LaTeX label
    "L": r"point masses \(L\)", "M": r"mass \(M\) (kg)", "tau": r"radius \(\tau\) (m)",
    "R": r"\(\lvert\mathbf R\rvert = \lvert\sum_l\mathbf F_l\rvert\) (N)", "Fsum": r"\(\sum_l\lvert\mathbf F_l\rvert\) (N)",
    "Mz": r"\(\mathbf e_z\cdot\sum_l\mathbf r_l\times\mathbf F_l\) (N m)", "Izz": r"\(I_{zz}\) (kg m²)",
    "ratio": r"\(I_{zz}/(M\tau^2)\)", "Ia": r"\(\lvert\mathbf I\boldsymbol\alpha\rvert\) (N m)",
    "Iaz": r"\((\mathbf I\boldsymbol\alpha)_z\) (N m)", "gyro": r"\((\boldsymbol\omega\times\mathbf I\boldsymbol\omega)_z\) (N m)",
    "w": r"\(\lvert\boldsymbol\omega\rvert\) (rad/s)", "a": r"\(\lvert\boldsymbol\alpha\rvert\) (rad/s²)",
    "omega": r"\(\boldsymbol\omega\) (rad/s)", "alpha": r"\(\boldsymbol\alpha\) (rad/s²)",
}
_ELEMENT_KEYS = {
    "eq34": ("tau", "R", "Fsum", "Mz"),
    "eq35": ("w", "a", "Ia", "Iaz", "gyro"),
    "eq36": ("L", "M", "tau", "Izz", "ratio"),
    "eq37": ("M", "tau", "w", "a", "Iaz", "gyro", "ratio"),
    "eq12": ("M", "tau", "R", "Fsum", "Mz", "Iaz", "gyro", "a"),
}


def _element_sentence(cid: str, q: dict) -> str:
    base = cid.replace(".corrected", "")
    if base == "eq34":
        return (rf"The forces nearly cancel (\(\lvert\mathbf R\rvert\) = {fmt(q['R'], 3)} N of {fmt(q['Fsum'], 3)} N in all) "
                rf"but act as a couple with moment {fmt(q['Mz'], 3)} N m about \(\mathbf e_z\): "
                r"\(\tau\lvert\mathbf R\rvert\) is far too small.")
    if base == "eq35":
        return (rf"The spin \(\lvert\boldsymbol\omega\rvert\) = {fmt(q['w'], 3)} rad/s about a non-principal axis needs the "
                rf"gyroscopic torque {fmt(q['gyro'], 3)} N m about \(\mathbf e_z\), which \(\lvert\mathbf I\boldsymbol\alpha\rvert\) "
                "does not contain.")
    if base == "eq36":
        return (rf"The masses lie far from the \(z\) axis (a ring-like or flat element): \(I_{{zz}}/(M\tau^2)\) = "
                rf"{fmt(q['ratio'], 3)}, above the solid sphere's 2/5.")
    if base == "eq37":
        return (rf"The gyroscopic torque ({fmt(q['gyro'], 3)} N m) and a flat mass distribution (\(I_{{zz}}/(M\tau^2)\) = "
                rf"{fmt(q['ratio'], 3)}) both exceed what \(\tfrac25 M\tau^2\lvert\boldsymbol\alpha\rvert\) allows.")
    return (rf"The moment of the forces ({fmt(q['Mz'], 3)} N m, with \(\lvert\mathbf R\rvert\) = {fmt(q['R'], 3)} N) and the "
            rf"gyroscopic torque ({fmt(q['gyro'], 3)} N m) make \(\lvert\Psi\rvert\) exceed the bound.")


@lru_cache(maxsize=64)
def _sides_cached(cex_json: str):
    import json

    from kane.claims import counterexample_sides

    return counterexample_sides(json.loads(cex_json))


def _sides(cex: dict):
    """Both sides of Eq. (11) or Eq. (23) at a recorded counterexample, as ``mdgs validate
    --replay`` prints them (:func:`kane.claims.counterexample_sides`); ``None`` when it records no point."""
    import json

    return _sides_cached(json.dumps(cex, sort_keys=True))


def _yesno(v) -> str:
    """``yes``/``no`` for a real bool only (an index 0 or 1 stays a number)."""
    return {True: "yes", False: "no"}[v] if isinstance(v, bool) else str(v)


def _context_value(v, unit: str) -> str:
    """A context value of :func:`_sides`: a float to 4 digits, ``+e_z`` as math, anything else as text."""
    if isinstance(v, float):
        return fmt(v)
    text = _yesno(v)
    m = re.fullmatch(r"([+-])e_([xyz])", text)
    return rf"\({m.group(1)}\mathbf e_{m.group(2)}\)" if m else text


def _num(x) -> str:
    """A number or a 3-vector to 4 significant digits, as the replay prints them (round-off as 0)."""
    return _vec(x, 4) if np.ndim(x) else fmt(x)


#: the replay's names of the context of an equality counterexample -> the docs' labels
_CONTEXT = {
    "speed (MuJoCo dof)": r"speed \(\gamma\) (MuJoCo dof)", "delta": r"time step \(\delta\) (s)", "time": "time (s)",
    "speed gamma": r"speed \(\gamma\)", "sum_i F_(gamma,i)": r"\(\sum_i F_{\gamma,i}\) (N)", "Psi_gamma": r"\(\Psi_\gamma\) (N m)",
    "recorded": "recorded",
}
_SIDE_LABELS = {  # Side.key -> (lhs label, rhs label) given the counterexample
    "partial_velocity": (lambda cex: r"lhs: partial velocity \(\mathbf u'_{i,\gamma}\) of that element",
                         lambda cex: r"rhs: the nearest one-hot vector \(\pm\mathbf e_k\)"),
    "partial_angular_velocity": (lambda cex: r"lhs: partial angular velocity \(\boldsymbol\omega_{i,\gamma}\)",
                                 lambda cex: r"rhs: \(\mathbf 0\)"),
    "force_balance": (lambda cex: r"lhs: \(\sum_i F_{\gamma,i}\)" + ("" if cex.get("translational", True) else r" \(+\ \Psi_\gamma\)"),
                      lambda cex: r"rhs: \(\sum_i M_i\,a_{\gamma,i}\), " + ("true accelerations" if cex.get("true_acc")
                                                                            else r"\(a = (v^{t+1} - v^{t})/\delta\)")),
}
_SCALE_LABELS = {
    "partial_velocity": r"relative margin (over \(\lvert\mathbf e_k\rvert = 1\))",
    "partial_angular_velocity": r"relative margin (over \(\lvert\mathbf e_k\rvert = 1\))",
    "force_balance": r"relative margin, over \(\max_t\sum_i\lvert\mathbf F_i\rvert\) (the report's number)",
}


def _equality_sentence(cex: dict, context: list, sides: list) -> str:
    """One sentence of physics on why an Eq. (11) or Eq. (23) counterexample fails."""
    if cex["kind"] == "jacobian":
        return (r"This speed turns the body, so each element centroid moves by \(\boldsymbol\omega_{i,\gamma}\times\mathbf r_i\), "
                r"a small vector in a different direction for every element, and the elements turn with "
                r"\(\boldsymbol\omega_{i,\gamma} \ne \mathbf 0\): no unit vector \(\pm\mathbf e_k\) describes it.")
    if not cex.get("translational", True):
        psi = dict((k, v) for k, v, _ in context)["Psi_gamma"]
        sd = sides[0]
        newton = abs(sd.margin - psi) <= 1e-6 * sd.scale  # sum F = sum M a along that axis: the leftover is Psi
        return (r"For a rotational speed the paper's reading takes \(F_{\gamma,i} = \mathbf R_i\cdot\mathbf e_\gamma\), a force"
                + (r", and the forces balance the forward difference along that axis, so lhs − rhs is \(\Psi_\gamma\) itself: "
                   r"the moments minus the inertia torques of the spinning elements, which are not 0." if newton else
                   r"; lhs − rhs holds \(\Psi_\gamma\), the moments minus the inertia torques of the spinning elements, which "
                   r"are not 0."))
    if cex.get("integrator") == "RK4":
        return (r"RK4 takes the contact force at stages inside the step: at contact onset the forces recorded at the step's "
                r"start miss most of the contact impulse that \((v^{t+1} - v^{t})/\delta\) contains.")
    if "flap" in cex.get("case", ""):
        return (r"Semi-implicit Euler steps the joint speeds; the flap's centroid velocity depends on the hinge angle, so "
                r"\((v^{t+1} - v^{t})/\delta\) of the elements misses their true acceleration by \(O(\delta)\).")
    return (r"With the joint origin off the centre of mass the Euler step moves the centre of mass along "
            r"\(\boldsymbol\omega\times\mathbf r\) as well, so \((v^{t+1}-v^t)/\delta\) misses the true "
            r"acceleration by \(O(\delta)\).")


def counterexample_view(row: dict) -> dict | None:
    """What the docs show of the counterexample of one report row (``checks`` entry).

    Returns ``{"quantities": [(label, value)], "sides": [(label, value)], "sentence": str,
    "replay": str}`` with numbers as text (4 significant digits; margins as the replay prints
    them, 3 digits; round-off shown as 0), or ``None`` when the row has no counterexample.
    """
    import json

    cex = row.get("counterexample")
    if not cex:
        return None
    cid, kind = row["id"], cex.get("kind")
    quantities: list[tuple[str, str]] = []
    sides: list[tuple[str, str]] = []
    sentence = ""
    if kind in ("element", "mujoco_geom"):
        rep = _replay(json.dumps(cex, sort_keys=True))
        eng, lhs, rhs = rep.rows[0]
        if kind == "element":
            q = _element_quantities(cex["sample"])
            q["ratio"] = q["Izz"] / (q["M"] * q["tau"] ** 2)
            for k in _ELEMENT_KEYS.get(cid.replace(".corrected", ""), ()):
                v = q[k]
                quantities.append((_Q[k], _vec(v) if k in ("omega", "alpha") else fmt(v, 4, 1e-12 * (1 + abs(q["Mz"])))))
            sentence = _element_sentence(cid, q)
            if q["L"] != 4:
                sentence = (rf"The {q['L']} corner masses of a cube cell give \(I_{{zz}}/(M\tau^2)\) = {fmt(q['ratio'], 3)}: "
                            "point masses at the corners are farther out than a solid sphere's mass.")
        else:
            quantities = [("element", f"{cex['geom']}, radius {fmt(cex['size'][0])} m, half thickness {fmt(cex['size'][1])} m"),
                          (_Q["M"], fmt(cex["mass"])), (_Q["tau"], fmt(cex["tau"])),
                          (_Q["Izz"], fmt(max(cex["inertia"]))), (_Q["ratio"], fmt(max(cex["inertia"]) / (cex["mass"] * cex["tau"] ** 2)))]
            sentence = (r"A uniform disc has \(I = \tfrac12 M R^2\) about its axis, and its \(\tau\) is barely more than "
                        r"\(R\): a flywheel element exceeds the sphere's \(\tfrac25 M\tau^2\).")
        sides = [("lhs", fmt(lhs)), ("rhs", fmt(rhs)), ("lhs − rhs", f"{lhs - rhs:.3g}")]
        rel = rep.relative(lhs, rhs)
        if rel is not None:
            sides.append(("relative margin (lhs − rhs)/scale", f"{rel:.3g}"))
        src = f"{'MuJoCo' if eng == 'mujoco' else eng}'s side of the replay, as `mdgs validate --replay` prints it"
    elif kind == "scaling":
        from kane.adversarial import Sample
        from kane.element_claims import element_model

        e = element_model()
        psi = sp.lambdify(list(e.args), e.psi, "numpy")
        smp = Sample.from_dict(cex["sample"])
        s = float(cex.get("s", 2.0))
        big = Sample(smp.masses, s * smp.offsets, smp.forces, smp.omega, smp.alpha)
        p1, p2 = float(psi(*smp.flat())), float(psi(*big.flat()))
        quantities = [(r"scale factor \(s\)", fmt(s)), (r"\(\Psi(\mathbf r)\)", fmt(p1)), (r"\(\Psi(s\,\mathbf r)\)", fmt(p2))]
        sides = [(r"lhs \(\Psi(s\,\mathbf r)\)", fmt(p2)), (r"rhs \(s\,\Psi(\mathbf r)\)", fmt(s * p1)),
                 ("lhs − rhs", f"{p2 - s * p1:.3g}"), (r"relative \(\lvert\text{lhs} − \text{rhs}\rvert/\lvert\Psi(\mathbf r)\rvert\)",
                                                     f"{abs(p2 - s * p1) / abs(p1):.3g}")]
        sentence = (rf"Doubling every offset multiplies the moment of the forces by {fmt(s, 2)} but the inertia torque by "
                    rf"{fmt(s * s, 2)}, so \(\Psi(s\,\mathbf r) \ne s\,\Psi(\mathbf r)\).")
        src = "the generic element's sympy \\(\\Psi\\), at the recorded sample"
    elif kind in ("jacobian", "trajectory") and _sides(cex) is not None:
        context, sides_ = _sides(cex)
        quantities = [(_CONTEXT.get(k, k), _context_value(v, unit)) for k, v, unit in context]
        for sd in sides_:
            lhs_label, rhs_label = _SIDE_LABELS[sd.key]
            unit = f" ({sd.unit})" if sd.unit else ""
            sides += [(lhs_label(cex) + unit, _num(sd.lhs)), (rhs_label(cex) + unit, _num(sd.rhs)),
                      ("lhs − rhs" + unit, _num(sd.margin)), (r"absolute margin, largest \(\lvert\text{lhs} − \text{rhs}\rvert\)" + unit,
                                                            fmt(sd.absolute)),
                      (_SCALE_LABELS[sd.key], f"{sd.relative:.3g}")]
        sentence = _equality_sentence(cex, context, sides_)
        src = "`mdgs validate --replay` (its lines \"both sides at the recorded point\"), from the same functions as the check"
    elif kind == "jacobian":
        quantities = [("case", row["case"]), ("speed", str(cex.get("dof", cex.get("speed")))),
                      ("deviation from the nearest one-hot vector", fmt(cex.get("deviation"), 3))]
        sides = [("largest deviation (the report's residual)", f"{row['residual']:.3g}"), ("tolerance", f"{row['tolerance']:.3g}")]
        sentence = (r"This speed turns the body, so each element centroid moves by \(\boldsymbol\omega_{i,\gamma}\times\mathbf r_i\): "
                    "a different direction for every element, not one unit vector.")
        src = "the check, re-run by `mdgs validate --replay` (which prints residual and tolerance)"
    elif kind == "trajectory" and cid.startswith("eq12"):
        psi = np.abs(np.asarray(cex["psi"], float))
        quantities = [("case", row["case"]), ("frame", str(cex.get("frame"))), (_Q["omega"], _vec(cex["omega"])),
                      (_Q["alpha"], _vec(cex["alpha"])), (r"\(\Psi\) per rotational speed \(x, y, z\) (N m)", _vec(cex["psi"]))]
        sides = [(r"lhs \(\max_\gamma\lvert\Psi_\gamma\rvert\)", fmt(psi.max())), ("rhs (the paper's bound)", fmt(cex["rhs"], 4, 1e-12)),
                 ("lhs − rhs", f"{psi.max() - cex['rhs']:.3g}"), ("relative margin (the report's number)", f"{row['residual']:.3g}")]
        sentence = (r"A steady spin about the cube's diagonal with no loads: the bound is 0, but each half-cube spins about "
                    r"a non-principal axis of its own and needs the gyroscopic torque \(\boldsymbol\omega\times\mathbf I_i"
                    r"\boldsymbol\omega\) from the other half, an inter-element force that the paper leaves out of \(\Psi\).")
        src = "the check, re-run by `mdgs validate --replay` (which prints residual and tolerance)"
    elif kind == "trajectory":  # a counterexample with no single point (fitted orders, random systems)
        names = {"integrator": "integrator", "frame": "frame", "gamma": r"speed \(\gamma\) (index)",
                 "translational": "translational speed"}
        quantities = [("case", row["case"])] + [(names[k], _yesno(cex[k])) for k in names if k in cex]
        sides = [("largest relative residual (the report's number)", f"{row['residual']:.3g}"), ("tolerance", f"{row['tolerance']:.3g}")]
        sentence = "The check's residual exceeds its tolerance on this system; its settings are listed above."
        src = "the check, re-run by `mdgs validate --replay` (which prints residual and tolerance)"
    else:
        return None
    return {"quantities": quantities, "sides": sides, "sentence": sentence, "replay": src}
