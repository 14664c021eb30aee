"""``mdgs study``: run a study file's grid resumably into results.jsonl, then draw its tables and charts."""

from __future__ import annotations

from pathlib import Path

import typer

from mdgs.cli import app, fail, parse_share, progress_bar


@app.command("study")
def study_cmd(
    study_file: Path = typer.Argument(None, help="Study file (TOML), e.g. studies/tiny.toml; required unless --report.", show_default=False),
    out: Path = typer.Option(None, "--out", help="Output folder (rerun the same command to resume); required with STUDY_FILE."),
    cells: str = typer.Option("0/1", "--cells", help="Run only share I of N of the cells (a job array): I/N."),
    only: list[str] = typer.Option(None, "--only", metavar="NAME",
                                   help="Run only the cells of this row label (e.g. sgnn, 'mujoco dt x10', "
                                        "'mdgs refine 2') or scene; repeat it for several. Rows and scenes "
                                        "combine: --only gns --only cubli-triple runs GNS on the Cubli."),
    report_only: Path = typer.Option(None, "--report", metavar="DIR",
                                     help="Only rebuild the tables and charts of DIR from its results files."),
    no_report: bool = typer.Option(False, "--no-report", help="Do not draw tables and charts after running."),
    recost: str = typer.Option(None, "--recost", metavar="MODE",
                               help="Instead of running cells: time every finished row's step again, compiled "
                                    "(aot, inductor) or eager (none), one row after another, into OUT/costs.jsonl "
                                    "(run it on an idle machine); the tables and chart then use these costs."),
    threads: int = typer.Option(None, "--threads", metavar="N",
                                help="Torch threads of this process (default: torch's own, one per core). Shares run "
                                     "side by side on one machine should split its cores, e.g. --threads 1 for each "
                                     "of two shares on 2 cores: with torch's default they oversubscribe the cores "
                                     "and train far slower."),
) -> None:
    """Run a grid of (scene, model, seed) cells: Tables 1-4, speed-accuracy chart, stability test."""
    from mdgs.data.schema import DatasetError
    from mdgs.models import ModelError
    from mdgs.runs import RunError
    from mdgs.study import StudyError, load_study, report

    if report_only is not None:
        if study_file is not None:
            fail("give either a study file (to run) or --report DIR (to redraw), not both")
        if only:
            fail("--only selects cells to run; --report redraws everything finished in DIR: leave out --only")
        try:
            files = report(report_only)
        except StudyError as e:
            fail(str(e))
        typer.echo(f"{report_only}: " + ", ".join(files))
        return
    if study_file is None or out is None:
        fail("give a study file and --out DIR (or --report DIR to redraw the tables and charts)")
    if recost is not None and recost not in ("aot", "inductor", "cudagraphs", "none"):
        fail(f"--recost {recost!r}: give aot (ahead of time, AOTInductor), inductor (torch.compile), cudagraphs "
             "(CUDA graphs of inductor's kernels; a study on a CUDA device) or none (eager)")
    if recost is not None and (cells != "0/1" or only):
        fail("--recost times every row one after another (so all are timed alike) and skips the rows "
             "already timed; leave out --cells and --only")
    share = parse_share(cells, "--cells")
    if threads is not None:
        if threads < 1:
            fail(f"--threads {threads}: give a positive number of threads (one per share when shares run side by "
                 "side on one machine)")
        import torch

        torch.set_num_threads(threads)
    try:
        study = load_study(study_file)
    except StudyError as e:
        fail(str(e))
    progress, console = progress_bar()
    try:
        with progress as bar:
            if recost is not None:
                summary = _recost(study, out, recost, bar, console)
            else:
                summary = _run(study, out, share, bar, console, tuple(only or ()))
    except (StudyError, DatasetError, RunError, ModelError, ValueError) as e:
        fail(str(e))
    except KeyboardInterrupt:
        kept = f"{out}/costs.jsonl keeps the rows timed" if recost is not None else "finished cells are kept"
        typer.echo(f"interrupted; rerun the same command to resume {out} ({kept})", err=True)
        raise typer.Exit(130) from None
    typer.echo(summary)
    if not no_report:
        try:
            files = report(out)
        except StudyError as e:
            fail(str(e))
        typer.echo(f"{out}: " + ", ".join(files))


def _run(study, out, share, bar, console, only) -> str:
    """Run the share's cells under a progress bar; returns the summary line."""
    from mdgs.study import run_study

    overall = bar.add_task("cells", total=None)
    inner = bar.add_task("", total=None, visible=False)
    plan = {"done": 0}

    def on(e: dict) -> None:
        if e["kind"] == "plan":
            plan["done"] = e["cells"] - e["todo"]
            bar.update(overall, total=e["cells"], completed=plan["done"])
            sel = f" of {', '.join(only)}" if only else ""
            console.print(f"study {study.name}: {e['cells']} cells{sel} in this share, {e['todo']} to run")
        elif e["kind"] == "cell":  # index: cells of this run finished so far
            bar.update(overall, completed=plan["done"] + e["index"])
            bar.update(inner, description=e["label"], total=None, completed=0, visible=True)
        elif e["kind"] == "defer":
            console.print(f"  {e['label']}: another share is training its run; back to it later")
        elif e["kind"] == "train" and "steps" in e and "step" in e:
            bar.update(inner, description=f"  epoch {e['epoch'] + 1}", total=e["steps"], completed=e["step"])
        elif e["kind"] == "evaluate":
            bar.update(inner, description=f"  evaluating on {e['set']}", total=None)
        elif e["kind"] == "wait":
            bar.update(inner, description=f"  waiting for another share training {e['run']}", total=None)

    res = run_study(study, out, share, progress=on, only=only)
    bar.update(overall, completed=res["done"] + res["ran"])
    return f"{out}: {res['done'] + res['ran']}/{res['cells']} cells finished ({res['ran']} run now)"


def _recost(study, out, mode, bar, console) -> str:
    """Time every finished row again under a progress bar; returns the summary line."""
    from mdgs.study import recost_study

    task = bar.add_task("rows", total=None)
    before = {"done": 0}

    def on(e: dict) -> None:
        if e["kind"] == "plan":
            before["done"] = e["cells"] - e["todo"]
            bar.update(task, total=e["cells"], completed=before["done"])
            console.print(f"study {study.name}: {e['cells']} rows, {e['todo']} to time ({mode})")
        elif e["kind"] == "cell":
            bar.update(task, description=e["label"], completed=before["done"] + e["index"])
        elif e["kind"] == "row failed":
            console.print(f"  could not time {e['reason']}")

    res = recost_study(study, out, mode, progress=on)
    return (f"{out}: {res['measured']} of {res['rows']} rows timed now"
            + (f", {len(res['failed'])} could not be (each said why above)" if res["failed"] else ""))
