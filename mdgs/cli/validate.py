"""``mdgs validate``: every check of :mod:`kane` (or of a dataset, or one counterexample replayed), one verdict each.

``mdgs validate`` runs every check of :mod:`kane` on every case it applies to, prints one
table row per check and the summary line (``N checks: H hold, R refuted, E errors``).
Exit codes: 0 every check holds, 1 some claim is refuted (a finding), 2 usage error or a
check that could not decide (``error``). User errors end in one sentence on stderr, never a
traceback. ``python -m mdgs.cli.validate`` runs this command alone.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import typer
from rich.console import Console
from rich.table import Table
from rich.text import Text

from mdgs.cli import EXIT_ERROR, EXIT_HOLDS, app, main
from mdgs.data.io import output_problem
from mdgs.data.schema import DatasetError
from validation import report as _report
from validation.report import counterexample_line, format_number


class UsageError(Exception):
    """A user-caused problem (bad flag value, bad file); its message is one sentence."""


def _err(sentence: str) -> None:
    """One sentence on stderr."""
    print(sentence, file=sys.stderr)


_VERDICT_STYLE = {"holds": "green", "refuted": "bold red", "error": "yellow"}


def render_table(rows: list[dict], console: Console) -> None:
    """The report table, one scope line per claim (its verdict per clause), then one line per
    refuted check (counterexample, corrected statement) and one per error (why nothing was decided)."""
    table = Table(show_lines=False, header_style="bold")
    table.add_column("claim", no_wrap=True)
    table.add_column("in a few words", min_width=14, max_width=30)
    table.add_column("case", min_width=12, max_width=34)
    table.add_column("route", no_wrap=True)
    table.add_column("residual / margin", justify="right", no_wrap=True)
    table.add_column("tolerance", justify="right", no_wrap=True)
    table.add_column("verdict", no_wrap=True, min_width=7)
    for r in rows:
        table.add_row(
            r["id"],
            r["claim"],
            r["case"],
            r["route"],
            format_number(r["residual"]),
            format_number(r["tolerance"]),
            Text(r["verdict"], style=_VERDICT_STYLE.get(r["verdict"], "")),
        )
    console.print(table)
    for cid, (title, scope) in {r["id"]: (r["claim"], r.get("scope")) for r in rows if r.get("scope")}.items():
        console.print(Text(f"{cid} ", style="bold") + Text(f"{title}: {scope}"), soft_wrap=True)
    for r in rows:
        where = f"{r['id']} on {r['case']} ({r['route']})"
        if r["verdict"] == "refuted":
            line = Text(f"{where} refuted: ", style="red")
            cex = counterexample_line(r["counterexample"])
            line.append(f"counterexample {cex}" if cex else (r["detail"] or "no counterexample recorded"))
            console.print(line, soft_wrap=True)
            c = r["corrected"]
            if c:
                verdict = c["verdict"] or "not run"
                stmt = c["statement"] or c["id"]
                console.print(
                    Text("  corrected ", style="dim")
                    + Text(f"{c['id']}: {stmt} ")
                    + Text(f"[{verdict}]", style=_VERDICT_STYLE.get(verdict, "")),
                    soft_wrap=True,
                )
        elif r["verdict"] == "error":
            console.print(Text(f"{where} could not be decided: ", style="yellow") + Text(r["detail"] or "no reason given"), soft_wrap=True)


# --------------------------------------------------------------------------- running


def _claims() -> dict:
    """``kane.claims.CLAIMS`` (empty when that module cannot be imported)."""
    try:
        from kane import claims
    except ImportError:
        return {}
    return dict(getattr(claims, "CLAIMS", {}))


def _run_kane(check: list[str] | None, case: list[str] | None, quick: bool, seed: int, progress_console: Console) -> list:
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    try:
        from kane import claims
    except ImportError as e:
        raise UsageError(f"kane.claims cannot be imported ({e}); reinstall with `pip install -e .`.") from e
    with Progress(
        TextColumn("[bold]checking"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TextColumn("{task.description}"),
        console=progress_console,
        transient=True,
    ) as progress:
        task = progress.add_task("", total=None)

        def on_progress(done: int, total: int, label: str) -> None:
            progress.update(task, completed=done, total=total, description=str(label))

        try:
            return claims.run_checks(claim_ids=check or None, cases=case or None, quick=quick, seed=seed, on_progress=on_progress)
        except ValueError as e:  # unknown claim id or case: a usage error
            raise UsageError(str(e)) from e


def _run_data(path: str, check: list[str] | None, case: list[str] | None) -> list[dict]:
    if Path(path).is_dir():
        raise UsageError(f"--data {path} is a folder; pass one of its dataset files, e.g. {Path(path) / 'test.h5'}.")
    if not Path(path).is_file():
        raise UsageError(f"--data {path}: no such file; pass a dataset file written by `mdgs generate`.")
    try:
        from validation import data_checks
    except ImportError as e:
        raise UsageError(f"--data needs validation.data_checks, which cannot be imported ({e}).") from e
    try:
        rows = list(data_checks.check_dataset(path))
    except (ValueError, OSError, DatasetError) as e:  # DatasetError names the file and the fix
        raise UsageError(str(e) if isinstance(e, DatasetError) else f"--data {path}: {e}") from e
    return [r for r in rows if (not check or r.get("claim_id") in check) and (not case or r.get("case") in case)]


def _load_counterexample(path: str, check: list[str] | None) -> dict:
    """The counterexample in ``path``: a counterexample object, one report entry, or a whole
    report (the first entry with a counterexample, among ``--check`` ids when given)."""
    p = Path(path)
    if not p.is_file():
        what = "is a folder, not a file" if p.is_dir() else "no such file"
        raise UsageError(f"--replay {path}: {what}; pass a counterexample or a report written by `mdgs validate --json`.")
    try:
        data = json.loads(p.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise UsageError(f"--replay {path}: not valid JSON ({e}).") from e
    if isinstance(data, dict) and isinstance(data.get("checks"), list):
        candidates = [c for c in data["checks"] if isinstance(c, dict) and c.get("counterexample") and (not check or c.get("id") in check)]
        if not candidates:
            raise UsageError(f"--replay {path}: the report holds no counterexample" + (f" for {', '.join(check)}." if check else "."))
        data = candidates[0]
    if isinstance(data, dict) and "counterexample" in data and isinstance(data["counterexample"], dict):
        data = data["counterexample"]
    if not isinstance(data, dict):
        raise UsageError(f"--replay {path}: expected a JSON object with a counterexample, found {type(data).__name__}.")
    return data


def _replay(path: str, check: list[str] | None) -> int:
    cex = _load_counterexample(path, check)
    try:
        from kane import counterexamples
    except ImportError as e:
        raise UsageError(f"--replay needs kane.counterexamples, which cannot be imported ({e}).") from e
    try:
        rep = counterexamples.replay(cex)
    except ValueError as e:
        raise UsageError(f"--replay {path}: {str(e).rstrip('.')}.") from e
    print(str(rep))
    return EXIT_HOLDS


@app.command()
def validate(
    quick: bool = typer.Option(False, "--quick", help="Run the fast subset of checks (under 15 s)."),
    check: list[str] | None = typer.Option(None, "--check", metavar="ID", help="Only this claim id (eq34, lemmaA1, eq34.corrected, ...); repeatable."),
    case: list[str] | None = typer.Option(None, "--case", metavar="NAME", help="Only this case (system or setting); repeatable."),
    json_path: str | None = typer.Option(None, "--json", metavar="PATH", help="Write the JSON report to PATH ('-' for stdout; the table then goes to stderr)."),
    seed: int = typer.Option(0, "--seed", help="Seed of the adversarial searches (hypothesis, CasADi multistart)."),
    replay: str | None = typer.Option(None, "--replay", metavar="FILE", help="Re-run one recorded counterexample (a counterexample, a report entry or a whole --json report) and print both sides of its claim."),
    data: str | None = typer.Option(None, "--data", metavar="FILE", help="Check a dataset file against Kane's equations instead of the claims of kane."),
    mjcf: str | None = typer.Option(None, "--mjcf", metavar="FILE", help="Derive Kane's equations of your MJCF tree and run every claim check that applies to it."),
) -> None:
    """Run every check of `kane` on every case it applies to and print a verdict per check.

    Exit code 0 when every check holds, 1 when any claim is refuted, 2 for usage errors and checks that could not decide.
    """
    try:
        code = _validate(quick, check, case, json_path, seed, replay, data, mjcf)
    except UsageError as e:
        _err(str(e))
        code = EXIT_ERROR
    raise typer.Exit(code)


def _validate(quick, check, case, json_path, seed, replay, data, mjcf=None) -> int:
    if not 0 <= seed < 2**32:  # numpy's and CasADi's seeds
        raise UsageError(f"--seed {seed} must be an integer from 0 to 2**32 - 1.")
    if replay is not None:
        return _replay(replay, check)
    if json_path is not None and json_path != "-":
        folder = Path(json_path).parent
        if not folder.is_dir():
            what = "is a file, not a folder" if folder.exists() else "does not exist"
            raise UsageError(f"--json {json_path}: folder {folder} {what}; create it or pick another path.")
        problem = output_problem(json_path, "--json", "file", "report.json")
        if problem:
            raise UsageError(problem + ".")
    to_stdout = json_path == "-"
    console = Console(stderr=to_stdout, soft_wrap=False)
    if not console.is_terminal:  # a pipe or a file: no terminal width to respect
        console = Console(stderr=to_stdout, soft_wrap=False, width=max(console.width, 150))
    stderr_console = Console(stderr=True)
    claims = _claims()
    if mjcf is not None:
        from validation.mjcf import MjcfError, check_mjcf

        try:
            rep = check_mjcf(mjcf, check, case, quick, seed, claims)
        except MjcfError as e:
            raise UsageError(str(e)) from e
    else:
        results = _run_data(data, check, case) if data is not None else _run_kane(check, case, quick, seed, stderr_console)
        rep = _report.build_report(results, claims)
    if not rep["checks"]:
        raise UsageError("No check matches the selection; see `mdgs validate --help` for --check and --case.")
    render_table(rep["checks"], console)
    console.print(_report.summary_line(rep["summary"]), highlight=False)
    if json_path is not None:
        try:
            _report.write_json(rep, json_path)
        except OSError as e:
            raise UsageError(f"--json {json_path}: cannot write the report ({e.strerror or e}).") from e
    return _report.exit_code(rep["summary"])


def validate_main() -> None:
    """Entry point of ``python -m mdgs.cli.validate`` (``mdgs validate`` alone)."""
    sys.exit(main(sys.argv[1:], prog_name="python -m mdgs.cli.validate", subcommand="validate"))


if __name__ == "__main__":
    validate_main()
