"""``mdgs study``: a grid of scenes x models x seeds run resumably into ``results.jsonl``, then tables and charts.

:func:`~mdgs.study.config.load_study` reads a study file, :func:`~mdgs.study.runner.run_study`
runs (a share of) its cells, :func:`~mdgs.study.runner.recost_study` times every row's step again
(compiled, one row after another), :func:`report` rebuilds ``tables.md/.csv/.tex`` and the charts from
the results files alone.
"""

from __future__ import annotations

import os
from pathlib import Path

from mdgs.study.charts import draw_charts
from mdgs.study.config import StudyConfig, StudyError, load_study
from mdgs.study.runner import cells_of, read_results, recost_study, run_study
from mdgs.study.tables import render

__all__ = ["StudyConfig", "StudyError", "load_study", "run_study", "recost_study", "cells_of", "read_results", "report"]


def report(out: str | os.PathLike, name: str | None = None) -> list[str]:
    """Rebuild the tables and charts of the study in ``out`` from its results files; returns the files written."""
    import json

    from mdgs.data.io import output_problem
    from mdgs.runs import atomic_write

    out = Path(out)
    if not out.is_dir():
        raise StudyError(f"--report {out} " + ("is a file, not a study folder" if out.exists() else "does not exist")
                         + "; pass the --out folder of `mdgs study FILE --out DIR`")
    problem = output_problem(out, "--report")
    if problem:
        raise StudyError(problem)
    everything = read_results(out)
    lines = [ln for ln in everything if ln.get("status", "ok") in ("ok", "failed")]
    errors = [ln for ln in everything if ln.get("status") == "error"]
    if errors:
        import warnings

        warnings.warn(f"{len(errors)} cells of {out} ended in an internal error and are left out of the tables "
                      f"(rerun the study to retry them): " + "; ".join(f"{e['scene']} {e['label']} seed {e['seed']}: "
                                                                        f"{e['reason'][:160]}" for e in errors[:3]),
                      stacklevel=2)
    if not lines:
        raise StudyError(f"{out} holds no finished cell yet (no results*.jsonl lines); run the study first")
    if name is None:
        marker = out / "study.json"
        name = json.loads(marker.read_text())["name"] if marker.exists() else lines[0].get("study", "?")
    files = []
    for fname, text in render(lines, name).items():
        atomic_write(out / fname, lambda p, text=text: p.write_text(text))
        files.append(fname)
    return files + draw_charts(lines, out)
