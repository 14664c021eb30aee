"""Tests of ``mdgs validate`` (mdgs/cli/validate.py) and its JSON report (validation/report.py).

``kane.claims`` and ``kane.counterexamples`` are replaced by small fakes returning fixed
:class:`kane.results.CheckResult` records, so these tests decide the CLI's behaviour (table,
summary line, exit codes, JSON schema, one-sentence errors) independently of the checks.
"""

from __future__ import annotations

import json
import sys
import types
from dataclasses import dataclass

import pytest

from kane.results import CheckResult
from mdgs.cli import validate as cli
from validation import report


@dataclass(frozen=True)
class _Claim:
    id: str
    title: str
    statement: str
    equation: str
    corrected_id: str | None = None

    def latex(self) -> str:
        return r"a \leq b"


_CLAIMS = {
    "eq3": _Claim("eq3", "Kane's equations", "K + K* = 0 for every generalized speed.", "(3)"),
    "eq34": _Claim(
        "eq34", "moment bound", "|sum r x F . w| <= tau sum |R| w.", "(34)", "eq34.corrected"
    ),
    "eq34.corrected": _Claim(
        "eq34.corrected", "moment bound (corrected)", "|sum r x F . w| <= tau sum |F| w.", "(34)"
    ),
}

_CEX = {
    "claim_id": "eq34",
    "masses": [1.0, 1.0],
    "offsets": [[1.0, 0, 0], [-1.0, 0, 0]],
    "forces": [[0, 1.0, 0], [0, -1.0, 0]],
}


def _holds(claim_id="eq3", case="free_box", route="pinocchio"):
    return CheckResult(claim_id, case, route, "holds", 1e-13, 1e-9, {"n": 3}, None, None, "", 0.01)


def _refuted():
    return CheckResult(
        "eq34",
        "couple",
        "casadi",
        "refuted",
        2.0,
        1e-9,
        {"L": 2},
        _CEX,
        "eq34.corrected",
        "couple with zero resultant",
        0.1,
    )


def _error():
    return CheckResult(
        "eq3",
        "cubli",
        "mujoco",
        "error",
        float("nan"),
        1e-9,
        {},
        None,
        None,
        "MuJoCo model failed to load",
        0.0,
    )


def _install_fake_kane(monkeypatch, results, replay=None):
    """Put fake ``kane.claims`` (and ``kane.counterexamples``) modules in ``sys.modules``."""
    calls = {}

    def run_checks(claim_ids=None, cases=None, quick=False, seed=0, on_progress=None):
        calls.update(claim_ids=claim_ids, cases=cases, quick=quick, seed=seed)
        if claim_ids and "nope" in claim_ids:
            raise ValueError("Unknown claim id 'nope'; known ids are eq3, eq34.")
        out = [r for r in results if not claim_ids or r.claim_id in claim_ids]
        for i, r in enumerate(out, 1):
            if on_progress:
                on_progress(i, len(out), r.claim_id)
        return out

    claims = types.ModuleType("kane.claims")
    claims.CLAIMS = _CLAIMS
    claims.run_checks = run_checks
    monkeypatch.setitem(sys.modules, "kane.claims", claims)
    import kane

    monkeypatch.setattr(kane, "claims", claims, raising=False)

    cexm = types.ModuleType("kane.counterexamples")

    def _replay(cex):
        if replay is not None:
            return replay(cex)
        if "claim_id" not in cex:
            raise ValueError("the counterexample has no claim_id")
        return f"{cex['claim_id']}: lhs = 2.0 (MuJoCo), rhs = 0.0 (Pinocchio)"

    cexm.replay = _replay
    monkeypatch.setitem(sys.modules, "kane.counterexamples", cexm)
    monkeypatch.setattr(kane, "counterexamples", cexm, raising=False)
    return calls


def _run(capsys, *args):
    code = cli.main(["validate", *args])
    out, err = capsys.readouterr()
    return code, out, err


def test_all_hold_exit_0_and_summary_line(monkeypatch, capsys):
    _install_fake_kane(monkeypatch, [_holds(), _holds("eq34.corrected", "couple", "casadi")])
    code, out, err = _run(capsys)
    assert code == 0
    assert out.strip().splitlines()[-1] == "2 checks: 2 hold, 0 refuted, 0 errors"
    assert "Kane's equations" in out and "free_box" in out and "pinocchio" in out
    assert "passed" not in out and "failed" not in out


def test_refuted_exit_1_shows_counterexample_and_corrected_verdict(monkeypatch, capsys):
    _install_fake_kane(
        monkeypatch, [_holds(), _refuted(), _holds("eq34.corrected", "couple", "casadi")]
    )
    code, out, err = _run(capsys)
    assert code == 1
    assert out.strip().splitlines()[-1] == "3 checks: 2 hold, 1 refuted, 0 errors"
    cex_lines = [line for line in out.splitlines() if "counterexample" in line]
    assert len(cex_lines) == 1 and "masses=[1, 1]" in cex_lines[0]
    corrected = [line for line in out.splitlines() if "corrected eq34.corrected" in line]
    assert corrected and "[holds]" in corrected[0] and "sum |F|" in corrected[0]


def test_error_exit_2_says_why(monkeypatch, capsys):
    _install_fake_kane(monkeypatch, [_holds(), _refuted(), _error()])
    code, out, err = _run(capsys)
    assert code == 2
    assert "MuJoCo model failed to load" in out
    assert out.strip().splitlines()[-1] == "3 checks: 1 holds, 1 refuted, 1 error"


def test_selection_quick_and_seed_reach_run_checks(monkeypatch, capsys):
    calls = _install_fake_kane(monkeypatch, [_holds(), _refuted()])
    code, out, _ = _run(
        capsys, "--check", "eq3", "--case", "free_box", "--case", "cubli", "--quick", "--seed", "7"
    )
    assert calls == {"claim_ids": ["eq3"], "cases": ["free_box", "cubli"], "quick": True, "seed": 7}
    assert code == 0


def test_unknown_claim_is_one_sentence_exit_2(monkeypatch, capsys):
    _install_fake_kane(monkeypatch, [_holds()])
    code, out, err = _run(capsys, "--check", "nope")
    assert code == 2
    assert err.strip() == "Unknown claim id 'nope'; known ids are eq3, eq34."
    assert "Traceback" not in err


@pytest.mark.parametrize("args", [["--bogus"], ["--seed", "x"], ["--json"]])
def test_bad_flag_is_one_sentence_exit_2(monkeypatch, capsys, args):
    _install_fake_kane(monkeypatch, [_holds()])
    code, out, err = _run(capsys, *args)
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("mdgs") and lines[0].endswith(".")
    assert "Traceback" not in err


def test_json_report_schema(monkeypatch, capsys, tmp_path):
    _install_fake_kane(
        monkeypatch, [_holds(), _refuted(), _holds("eq34.corrected", "couple", "casadi")]
    )
    path = tmp_path / "report.json"
    code, out, err = _run(capsys, "--json", str(path))
    assert code == 1
    rep = json.loads(path.read_text())
    assert set(rep) == {"checks", "claims", "summary", "environment"}
    keys = {
        "id",
        "claim",
        "case",
        "route",
        "verdict",
        "residual",
        "tolerance",
        "assumptions",
        "counterexample",
        "corrected",
    }
    assert all(keys <= set(c) for c in rep["checks"])
    assert rep["summary"] == {"checks": 3, "hold": 2, "refuted": 1, "errors": 0}
    assert {"sympy", "pin", "mujoco", "casadi", "torch", "mdgs"} <= set(rep["environment"])
    refuted = rep["checks"][1]
    assert refuted["counterexample"] == _CEX
    assert refuted["corrected"] == {
        "id": "eq34.corrected",
        "title": _CLAIMS["eq34.corrected"].title,
        "statement": _CLAIMS["eq34.corrected"].statement,
        "verdict": "holds",
        "scope": "holds for every case tried",
    }
    # one scope line per claim, in the rows and in the claims section, from the verdicts
    assert refuted["scope"] == "refuted for every case tried"
    assert [(c["id"], c["verdict"], c["scope"]) for c in rep["claims"]] == [
        ("eq3", "holds", "holds for every case tried"),
        ("eq34", "refuted", "refuted for every case tried"),
        ("eq34.corrected", "holds", "holds for every case tried"),
    ]
    assert rep["checks"][0]["counterexample"] is None and rep["checks"][0]["corrected"] is None
    assert [p.name for p in tmp_path.iterdir()] == ["report.json"]  # no temp file left behind


def test_json_to_stdout_keeps_stdout_pure_json(monkeypatch, capsys):
    _install_fake_kane(monkeypatch, [_holds(), _error()])
    code, out, err = _run(capsys, "--json", "-")
    assert code == 2
    rep = json.loads(out)  # the table and summary went to stderr
    assert rep["checks"][1]["residual"] is None  # NaN is not JSON
    assert "1 holds, 0 refuted, 1 error" in err


def test_json_into_missing_folder_is_exit_2(monkeypatch, capsys, tmp_path):
    _install_fake_kane(monkeypatch, [_holds()])
    code, out, err = _run(capsys, "--json", str(tmp_path / "no" / "r.json"))
    assert code == 2 and len(err.strip().splitlines()) == 1 and "does not exist" in err


def test_replay_accepts_the_reports_counterexample(monkeypatch, capsys, tmp_path):
    _install_fake_kane(monkeypatch, [_holds(), _refuted()])
    path = tmp_path / "report.json"
    _run(capsys, "--json", str(path))
    code, out, err = _run(capsys, "--replay", str(path))
    assert code == 0 and "eq34: lhs = 2.0 (MuJoCo), rhs = 0.0 (Pinocchio)" in out
    single = tmp_path / "cex.json"
    single.write_text(json.dumps(json.loads(path.read_text())["checks"][1]["counterexample"]))
    code, out, err = _run(capsys, "--replay", str(single))
    assert code == 0 and "lhs = 2.0" in out


@pytest.mark.parametrize(
    "content, phrase",
    [
        ("{not json", "not valid JSON"),
        ('{"masses": [1.0]}', "no claim_id"),
        ("[1, 2]", "expected a JSON object"),
    ],
)
def test_replay_malformed_file_is_one_sentence_exit_2(
    monkeypatch, capsys, tmp_path, content, phrase
):
    _install_fake_kane(monkeypatch, [_holds()])
    path = tmp_path / "cex.json"
    path.write_text(content)
    code, out, err = _run(capsys, "--replay", str(path))
    assert code == 2
    assert len(err.strip().splitlines()) == 1 and phrase in err and "Traceback" not in err


def test_replay_missing_file_exit_2(monkeypatch, capsys, tmp_path):
    _install_fake_kane(monkeypatch, [_holds()])
    code, out, err = _run(capsys, "--replay", str(tmp_path / "missing.json"))
    assert code == 2 and "no such file" in err


def test_python_m_mdgs_cli_validate_is_mdgs_validate(monkeypatch, capsys):
    _install_fake_kane(monkeypatch, [_holds()])
    monkeypatch.setattr(sys, "argv", ["python -m mdgs.cli.validate", "--quick"])
    with pytest.raises(SystemExit) as exc:
        cli.validate_main()
    assert exc.value.code == 0
    assert "1 check: 1 holds, 0 refuted, 0 errors" in capsys.readouterr().out


def test_summary_line_and_exit_code():
    s = report.summarize([{"verdict": "holds"}] * 12 + [{"verdict": "refuted"}] * 2)
    assert report.summary_line(s) == "14 checks: 12 hold, 2 refuted, 0 errors"
    assert report.exit_code(s) == 1
    assert report.exit_code(report.summarize([{"verdict": "holds"}])) == 0
    assert report.exit_code(report.summarize([{"verdict": "refuted"}, {"verdict": "error"}])) == 2


# --------------------------------------------------------------------------- the docs' command reference


def _help_blocks(args: list[str]) -> dict[str, str]:
    """``mdgs ARGS --help`` as rendered for a terminal: option or argument name -> its row's text
    (continuation lines joined), read from the box-drawn panels."""
    from typer.testing import CliRunner

    from mdgs.cli import app

    out = CliRunner().invoke(app, [*args, "--help"], env={"COLUMNS": "400"}).output
    blocks: dict[str, str] = {}
    last = None
    for line in out.splitlines():
        if not line.startswith("│"):
            last = None
            continue
        body = line.strip("│ ").lstrip("* ").strip()
        first = body.split(" ", 1)[0]
        if first.startswith("-") or (first and first.rstrip(".").isidentifier() and "  " in body):
            last = first.rstrip(".").upper() if not first.startswith("-") else first
            blocks[last] = body
        elif last is not None and body:
            blocks[last] += " " + body
    return blocks


def test_docs_command_reference_matches_help_for_every_parameter():
    """docs/cli.md's tables (mdgs.cli.reference) against the click parameters and the rendered
    ``--help`` of every command and of ``mdgs`` itself: same options, value types, defaults and
    "required" marks."""
    import typer

    from mdgs.cli import app
    from mdgs.cli.reference import reference

    group = typer.main.get_command(app)
    sections = {s.name: s for s in reference()}
    assert list(sections) == ["mdgs", *[f"mdgs {n}" for n in sorted(group.commands)]]
    for name, cmd in [("mdgs", group), *[(f"mdgs {n}", c) for n, c in group.commands.items()]]:
        rows = sections[name].rows
        params = [p for p in cmd.params if not getattr(p, "hidden", False) and p.name != "help"]
        assert len(rows) == len(params), name
        blocks = _help_blocks(name.split()[1:])
        for p, r in zip(params, rows, strict=True):
            key = r.names[0].rstrip(".")
            assert p.required == r.required, (name, key)
            block = blocks[key]
            if r.value != "flag":
                assert r.value in block, (name, key, r.value, block)
            else:
                assert p.is_flag, (name, key)
            assert (f"[default: {r.default}]" in block) == (r.default is not None), (name, key, r.default, block)
            if r.default is not None and not getattr(p, "is_flag", False):
                assert r.default == str(p.default), (name, key)
            assert ("[required]" in block) == r.required, (name, key, block)


def test_docs_command_reference_names_types_defaults_and_required():
    """The cases the site once got wrong: paths and numbers typed, zero defaults shown, train's
    required options marked, ``mdgs --debug`` listed."""
    from mdgs.cli.reference import markdown, reference

    rows = {(s.name, r.names[0]): r for s in reference() for r in s.rows}
    assert rows[("mdgs", "--debug")].value == "flag"
    assert rows[("mdgs train", "--data")].required and rows[("mdgs train", "--out")].required
    assert rows[("mdgs train", "--data")].value == "<path>"
    assert rows[("mdgs train", "--lr")].value == "<float>"
    assert rows[("mdgs generate", "--n-traj")].value == "<int>"
    assert rows[("mdgs generate", "--seed")].default == "0"
    assert rows[("mdgs train", "--max-steps")].default == "0"
    assert rows[("mdgs train", "--lr")].default is None
    page = markdown()
    assert page.index("## mdgs\n") < page.index("## mdgs evaluate")
    assert "TEXT" not in page and "(optional)" not in page
