"""The house rules of ../shared/architecture.md, checked on the source: import arrows point one way.

The module import graph is read from the AST of every module of ``kane``, ``validation`` and
``mdgs`` (imports inside functions included, since a lazy import is still an arrow; imports
under ``if TYPE_CHECKING:`` left out, since they only name types for annotations), and each
rule below is a test that names the offending arrow.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PKGS = ("kane", "validation", "mdgs")

#: Stages of mdgs in data-flow order; a module may import its own stage or earlier ones only.
STAGES = (
    ("mdgs.scenes", "mdgs.partition"),
    ("mdgs.data",),
    ("mdgs.graphs", "mdgs.structure", "mdgs.rigid", "mdgs.joints", "mdgs.actuation", "mdgs.tree", "mdgs.losses"),
    ("mdgs.models",),
    ("mdgs.runs",),
    ("mdgs.train", "mdgs.evaluate"),
    ("mdgs.study",),
    ("mdgs.cli",),
)


def _modules() -> dict[str, Path]:
    mods = {}
    for pkg in PKGS:
        for f in sorted((ROOT / pkg).rglob("*.py")):
            rel = f.relative_to(ROOT).with_suffix("")
            mods[".".join(rel.parts[:-1] if rel.name == "__init__" else rel.parts)] = f
    return mods


MODULES = _modules()


def _runtime_nodes(tree: ast.AST):
    """Every node of ``tree`` except those under ``if TYPE_CHECKING:`` (annotations, not imports that run)."""
    stack = [tree]
    while stack:
        node = stack.pop()
        yield node
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and ast.unparse(child.test).endswith("TYPE_CHECKING"):
                stack.extend(child.orelse)
                continue
            stack.append(child)


def _imports(name: str, path: Path) -> set[str]:
    """Every absolute module name ``name`` imports at run time (resolving relative imports)."""
    pkg = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out = set()
    for node in _runtime_nodes(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = pkg.split(".")[: len(pkg.split(".")) - node.level + 1]
                base = ".".join(parts + ([base] if base else []))
            out.add(base)
            out |= {f"{base}.{a.name}" for a in node.names}
    return out


def _ours(target: str) -> str | None:
    """The module of ours that ``target`` names (longest known prefix), or None."""
    while target and target not in MODULES:
        target = target.rpartition(".")[0]
    return target or None


RAW = {m: _imports(m, p) for m, p in MODULES.items()}
EDGES = {m: {t for t in map(_ours, imps) if t and t != m and not m.startswith(t + ".")} for m, imps in RAW.items()}


def _stage(mod: str) -> int | None:
    for k, names in enumerate(STAGES):
        if any(mod == n or mod.startswith(n + ".") for n in names):
            return k
    return None


def _cycles() -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index, low, stack, on, out, n = {}, {}, [], set(), [], [0]

    def visit(v):
        index[v] = low[v] = n[0]
        n[0] += 1
        stack.append(v)
        on.add(v)
        for w in EDGES[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in EDGES:
        if v not in index:
            visit(v)
    return out


def test_the_graph_covers_every_package():
    assert {m.split(".")[0] for m in MODULES} == set(PKGS)
    assert sum(len(e) for e in EDGES.values()) > 50  # the reader found the arrows


def test_no_import_cycles():
    assert _cycles() == []


def test_kane_imports_nothing_of_ours():
    bad = [f"{m} -> {t}" for m, ts in EDGES.items() if m.startswith("kane") for t in ts if not t.startswith("kane")]
    assert bad == []


def test_validation_reads_kane_and_mdgs_data_only():
    bad = [f"{m} -> {t}" for m, ts in EDGES.items() if m.startswith("validation")
           for t in ts if not (t.startswith(("kane", "validation", "mdgs.data")))]
    assert bad == []


def test_mdgs_arrows_point_from_later_stages_to_earlier_ones():
    bad = []
    for m, ts in EDGES.items():
        if not m.startswith("mdgs") or m == "mdgs":
            continue
        sm = _stage(m)
        assert sm is not None, f"module {m} belongs to no stage of STAGES; add it where the data flow puts it"
        for t in ts:
            if t.startswith("mdgs") and t != "mdgs":
                st = _stage(t)
                if st > sm:
                    bad.append(f"{m} -> {t}")
    assert bad == []


def test_train_and_evaluate_do_not_import_each_other():
    bad = [f"{m} -> {t}" for m, ts in EDGES.items() for t in ts
           if (m.startswith("mdgs.train") and t.startswith("mdgs.evaluate"))
           or (m.startswith("mdgs.evaluate") and t.startswith("mdgs.train"))]
    assert bad == []


def test_mdgs_and_validation_meet_only_in_the_cli():
    bad = [f"{m} -> {t}" for m, ts in EDGES.items() for t in ts
           if m.startswith("mdgs") and not m.startswith("mdgs.cli") and t.startswith("validation")]
    assert bad == []


@pytest.mark.parametrize(("lib", "allowed"), [
    ("typer", ("mdgs.cli",)), ("rich", ("mdgs.cli",)), ("click", ("mdgs.cli",)),
    ("torch.distributed", ("mdgs.train.distributed",)),
])
def test_framework_imports_stay_in_their_module(lib, allowed):
    bad = [m for m, imps in RAW.items() if any(i == lib or i.startswith(lib + ".") for i in imps)
           and not any(m == a or m.startswith(a + ".") for a in allowed)]
    assert bad == []


def test_tables_and_charts_never_call_a_model():
    readers = [m for m in MODULES if m in ("mdgs.study.tables", "mdgs.study.charts")]
    bad = [f"{m} -> {t}" for m in readers for t in EDGES[m]
           if t.startswith(("mdgs.models", "mdgs.train", "mdgs.evaluate", "mdgs.data"))]  # mdgs.runs: the writer
    assert bad == []


def test_every_module_says_what_it_is_for():
    missing = [m for m, p in MODULES.items() if not (ast.get_docstring(ast.parse(p.read_text())) or "").strip()]
    assert missing == []
