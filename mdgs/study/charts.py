"""The study's charts, drawn from ``results.jsonl`` alone: speed against accuracy, stability, resolution.

- ``speed_accuracy.png`` / ``.svg``: per scene, position MSE at t = 110 (log) against the cost of a
  simulated frame of one trajectory (ms, log); one point per model (mean over seeds, error bars
  = std over seeds), MuJoCo at its timestep factors as a connected curve, the constant-twist
  reference, the sensitivity floor as a band, the Pareto front (no other point both cheaper
  and more accurate) circled. A model that failed on some trajectory at t = 110 is drawn hollow
  with its mean over the survivors and says so in the legend.
- ``stability.png``: per scene, the fraction of long test trajectories still within the failure
  threshold against the rollout length, then the energy error and the joint separation of the
  surviving trajectories (means over seeds).
- ``resolution.png``: MDGS error at t = 40 and cost against the element resolution, beside the
  constant-twist reference on each partition (dashed): errors average over element centroids, so
  the partition alone moves them.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from mdgs.runs import atomic_savefig
from mdgs.study.tables import (
    _pareto,
    _points,
    _resolution_base,
    _run_mean,
    _scenes,
    default_partition,
)

__all__ = ["draw_charts"]


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _floor(lines, scene, t=110):
    vals = [_run_mean(ln, "test", t)[0] for ln in lines if ln["scene"] == scene and ln["kind"] == "sensitivity"]
    vals = [v for v in vals if v is not None]
    return (float(np.mean(vals)), float(np.std(vals))) if vals else None


def _grid(n):
    cols = min(n, 3)
    return math.ceil(n / cols), cols


#: Legend type size (pt): the charts are shown at a page's column width (about half their width),
#: where this still reads as about 6 pt.
LEGEND_FONTSIZE = 13


def _legend_below(fig, handles: dict, ncol: int, panels_height: float) -> None:
    """One legend for the figure under its panels: the figure grows by the legend's measured height
    (``panels_height`` inches stay for the panels), so the legend never overlaps an axis."""
    leg = fig.legend(list(handles.values()), list(handles.keys()), loc="lower center", ncol=ncol,
                     fontsize=LEGEND_FONTSIZE, frameon=False, handlelength=2.6, columnspacing=1.6)
    for line in leg.get_lines():
        line.set_linewidth(max(line.get_linewidth(), 2.2))
    fig.canvas.draw()
    height = leg.get_window_extent().height / fig.dpi + 0.25  # inches
    fig.set_size_inches(fig.get_figwidth(), panels_height + height)
    fig.tight_layout(rect=(0, height / (panels_height + height), 1, 1))


#: Markers of the non-learned references other than MuJoCo (grey), so each can be told apart.
_REF_MARKERS = {"constant twist": "s", "constant twist + joints": "D", "constant twist + motors": "^",
                "constant twist + motors + joints": "v", "rigid tree + joints": "P",
                "rigid tree + joints, trapezoidal": "X", "rigid tree + joints, trapezoidal, push-out": "h",
                "rigid tree + joints, trapezoidal, push-out, 4 substeps": "*"}
#: Markers for references not named above, handed out in the order the labels are first drawn.
_MORE_MARKERS = ("p", "d", "<", ">", "8", "H", "1", "2")
_more_given: dict[str, str] = {}  # label -> its marker from _MORE_MARKERS, so a label keeps it in every panel


def _ref_marker(label: str) -> str:
    """A reference's marker: its own from ``_REF_MARKERS``, else the next of ``_MORE_MARKERS``."""
    if label in _REF_MARKERS:
        return _REF_MARKERS[label]
    return _more_given.setdefault(label, _MORE_MARKERS[len(_more_given) % len(_MORE_MARKERS)])


def _eager_rows(lines, scene) -> set[str]:
    """Labels of the scene's learned rows that ``--recost`` timed eagerly because their step does not
    compile (drawn as squares beside the compiled rows' circles); none without recosted rows."""
    return {ln["label"] for ln in lines if ln["scene"] == scene and ln["kind"] == "learned"
            and ln.get("cost", {}).get("recost") and ln["cost"].get("compiled") == "none"}


def speed_accuracy(lines, path: Path) -> None:
    """One panel per scene; one legend for the figure, each model in the same colour on every panel.
    Errors far below everything else (MuJoCo at the data's own timestep reproduces the data to
    round-off) are drawn at the bottom edge as a downward triangle, so they do not squash the axis."""
    plt = _plt()
    scenes = _scenes(lines)
    modes = sorted({ln["cost"]["requested"] for ln in lines if ln.get("cost", {}).get("recost")})
    xlabel = "cost: ms per simulated frame, 1 trajectory (log)"
    rows, cols = _grid(len(scenes))
    styles = _styles(lines)
    learned = [lbl for lbl, st in styles.items() if st["ls"] == "-"]
    colour = {lbl: styles[lbl]["color"] for lbl in learned}
    panels_h = 4.6 * rows
    fig, axes = plt.subplots(rows, cols, figsize=(5.6 * cols, panels_h), squeeze=False)
    handles: dict = {}
    eager_note = False
    for ax, scene in zip(axes.flat, scenes, strict=False):
        pts = _points(lines, scene)
        eager = _eager_rows(lines, scene)
        front = _pareto(pts)
        fl = _floor(lines, scene)
        errs = [p[3] for lbl, p in pts.items() if p[3] is not None and p[3] > 0 and lbl != "mujoco dt x1"]
        lo = min(errs + ([max(fl[0] - fl[1], fl[0] * 0.5)] if fl else [])) / 10 if errs else None

        def y(e, lo=lo):
            return e if lo is None or e >= lo else lo
        mj = sorted(((lbl, p) for lbl, p in pts.items() if lbl.startswith("mujoco dt x")),
                    key=lambda kv: int(kv[0].split("x")[-1]))
        if mj:
            (h,) = ax.plot([p[1] for _, p in mj], [y(p[3]) for _, p in mj], "-o", color="0.35", ms=4)
            handles.setdefault("MuJoCo at 1, 2, 5, 10, 20 x its timestep", h)
            for lbl, p in mj:
                clipped = lo is not None and p[3] < lo
                if clipped:
                    ax.plot([p[1]], [lo], "v", color="0.35", ms=7)
                ax.annotate(lbl.split(" ")[-1] + (f" ({p[3]:.0e})" if clipped else ""), (p[1], y(p[3])), fontsize=6,
                            color="0.35", xytext=(3, 3), textcoords="offset points")
        for lbl, (kind, c, cs, e, es, failed) in pts.items():
            if lbl.startswith("mujoco dt x"):
                continue
            if kind == "reference":
                (h,) = ax.plot([c], [y(e)], _ref_marker(lbl), color="0.6", ms=6)
                handles.setdefault(lbl, h)
                continue
            col = colour[lbl]
            mk = "s" if lbl in eager else "o"
            eager_note |= lbl in eager
            if e is None:
                ax.plot([c], [1], marker="x", ms=9, color=col, transform=ax.get_xaxis_transform(), clip_on=False)
                handles.setdefault(f"{lbl} (x at the top: failed on every trajectory by t = 110)", ax.plot([], [], "x", color=col)[0])
                continue
            h = ax.errorbar([c], [y(e)], xerr=[cs], yerr=[[min(es, 0.9 * y(e))], [es]], fmt=mk, color=col,
                            mfc="none" if failed else col)  # on a log axis a spread above the mean stops short of 0
            handles.setdefault(lbl, ax.plot([], [], mk, color=col)[0] if failed else h)
        for lbl in front:
            ax.plot([pts[lbl][1]], [y(pts[lbl][3])], "o", ms=14, mfc="none", mec="k", lw=0.8)
        if fl is not None:
            h = ax.axhspan(max(fl[0] - fl[1], fl[0] * 0.5), fl[0] + fl[1], color="orange", alpha=0.2)
            handles.setdefault("sensitivity floor (MuJoCo from perturbed initial velocities)", h)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_title(scene, fontsize=12)
        ax.set_xlabel(xlabel, fontsize=11)
        ax.set_ylabel("position MSE at t = 110 (m$^2$, log)", fontsize=11)
    handles.setdefault("Pareto front (circled)", plt.Line2D([], [], marker="o", ms=10, mfc="none", mec="k", ls=""))
    handles.setdefault("hollow: failed on some trajectories; \u25bc: below the axis (value in brackets)",
                       plt.Line2D([], [], marker="o", mfc="none", mec="0.3", ls=""))
    if modes:  # the cost axis of recosted rows: say how the steps ran (not in the axis label: panels share a row)
        note = f"cost: steps compiled ({'/'.join(modes)}) where they compile"
        handles.setdefault(note + ("; square: a learned row timed eagerly (it does not)" if eager_note else ""),
                           plt.Line2D([], [], marker="s" if eager_note else "", mfc="none", mec="0.3", ls=""))
    for ax in list(axes.flat)[len(scenes):]:
        ax.axis("off")
    def rank(key):  # learned rows (study order), then the references, then the notes on markers
        base = key.split(" (x at the top")[0]
        return (0, learned.index(base)) if base in learned else (1, 0) if key[0].islower() or key.startswith("MuJoCo") else (2, 0)
    notes = ("sensitivity floor", "Pareto front", "hollow:", "cost:")
    handles = dict(sorted(handles.items(), key=lambda kv: (2, 0) if kv[0].startswith(notes) else rank(kv[0])))
    _legend_below(fig, handles, 2 if cols > 1 else 1, panels_h)
    atomic_savefig(fig, path.with_suffix(".png"), dpi=110)
    atomic_savefig(fig, path.with_suffix(".svg"))
    plt.close(fig)


def _curve_mean(lns, key):
    arrs = [np.array([np.nan if v is None else v for v in ln["sets"]["long"][key]], float) for ln in lns]
    with np.errstate(invalid="ignore"):
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            return np.nanmean(np.stack(arrs), 0)


#: Colours of the learned rows in every chart (no grey: the references are grey).
_PALETTE = ["C0", "C1", "C2", "C3", "C4", "C5", "C6", "C8", "C9", "#7b4173", "#637939", "#843c39"]


def _styles(lines) -> dict:
    """``{label: plot kwargs}`` for every row of the study, the same on every panel: learned rows (and the
    resolution study's rows) in colour (study order), references in grey with their own dash pattern."""
    out, n_learned, n_ref = {}, 0, 0
    for ln in lines:
        lbl = ln["label"]
        if lbl in out:
            continue
        if ln["kind"] in ("learned", "resolution"):  # a resolution row (a finer partition) is a learned row too
            out[lbl] = dict(color=_PALETTE[n_learned % len(_PALETTE)], ls="-", lw=1.5)
            n_learned += 1
        else:  # 3 greys x 4 dash patterns: twelve references told apart
            out[lbl] = dict(color=("0.15", "0.45", "0.65")[n_ref % 3], ls=("--", ":", "-.", (0, (5, 1)))[(n_ref // 3) % 4],
                            lw=1.1)
            n_ref += 1
    return out


def stability(lines, path: Path) -> bool:
    """Per scene: the fraction of long test trajectories within the failure threshold, then the energy
    error and the joint separation of the survivors; one legend for the figure."""
    plt = _plt()
    scenes = [s for s in _scenes(lines) if any(ln["scene"] == s and "long" in ln["sets"] for ln in lines)]
    if not scenes:
        return False
    styles = _styles([ln for ln in lines if "long" in ln["sets"]])
    panels_h = 3.6 * len(scenes)
    fig, axes = plt.subplots(len(scenes), 3, figsize=(15, panels_h), squeeze=False)
    handles: dict = {}
    for row, scene in zip(axes, scenes, strict=True):
        groups: dict = {}
        for ln in lines:
            if ln["scene"] == scene and "long" in ln["sets"]:
                groups.setdefault(ln["label"], []).append(ln)
        for label, lns in groups.items():
            frames = np.array(lns[0]["sets"]["long"]["curve_frames"]) + 1
            style = styles[label]
            (h,) = row[0].plot(frames, _curve_mean(lns, "fraction_within"), **style)
            handles.setdefault(label, h)
            row[1].plot(frames, np.maximum(_curve_mean(lns, "energy_error_J"), 1e-12), **style)
            row[2].plot(frames, np.maximum(1e3 * _curve_mean(lns, "joint_separation_m"), 1e-9), **style)
        thr = lns[0]["sets"]["long"]["failure_threshold_m2"]
        row[0].set_title(f"{scene}: within the failure threshold ({thr:.2g} m$^2$)", fontsize=11)
        row[0].set_ylabel("fraction of trajectories")
        row[0].set_ylim(-0.02, 1.02)
        row[1].set_title("energy error of survivors (J)", fontsize=11)
        row[2].set_title("joint separation of survivors (mm)", fontsize=11)
        for ax in row:
            ax.set_xlabel("time step t")
            ax.axvline(110, color="0.7", ls=":", lw=0.8)
        for ax in row[1:]:
            ax.set_yscale("log")
    handles = dict(sorted(handles.items(), key=lambda kv: styles[kv[0]]["ls"] != "-"))  # learned first
    _legend_below(fig, handles, 4, panels_h)
    atomic_savefig(fig, path, dpi=100)
    plt.close(fig)
    return True


def resolution(lines, path: Path) -> bool:
    res = [ln for ln in lines if ln["kind"] == "resolution"]
    if not res:
        return False
    plt = _plt()
    base = _resolution_base(res)
    use = res + [ln for ln in lines if ln["kind"] == "learned" and ln["label"] == base]
    use = [ln for ln in use if ln.get("status", "ok") == "ok"]
    refs = [ln for ln in lines if ln["kind"] == "reference" and ln.get("status", "ok") == "ok"]
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    for k, scene in enumerate(_scenes(use)):
        by = {}
        for ln in use:
            if ln["scene"] == scene:
                by.setdefault(ln["refine"], []).append(ln)
        rs = sorted(by)
        err = [np.mean([m for m in (_run_mean(ln, "test", 40)[0] for ln in by[r]) if m is not None] or [np.nan]) for r in rs]
        cost = [np.mean([ln["cost"]["single"]["ms_per_frame"] for ln in by[r]]) for r in rs]
        axes[0].plot(rs, err, "-o", color=f"C{k}", label=scene)
        axes[1].plot(rs, cost, "-o", color=f"C{k}", label=scene)
        ct = {ln.get("refine", 1): _run_mean(ln, "test", 40)[0] for ln in refs
              if ln["scene"] == scene and ln["model"] == "constant-twist" and not ln.get("settings")}
        ct = sorted((r, e) for r, e in ct.items() if e is not None)
        if ct:  # the same trajectories' constant twist on each partition: what the partition alone does
            axes[0].plot([r for r, _ in ct], [e for _, e in ct], "--s", color=f"C{k}", ms=4, lw=1,
                         label=f"{scene}: constant twist")
    fig.suptitle(f"{base}: error and cost against the element partition", fontsize=10)
    axes[0].set_ylabel("position MSE at t = 40 (m$^2$)")
    axes[1].set_ylabel("ms per frame, 1 trajectory")
    ticks = sorted({ln.get("refine", 1) for ln in use})
    for ax in axes:
        ax.set_xticks(ticks)  # refinements are whole numbers
        ax.set_xlabel("partition refinement (1: default, coarsest adequate)")
        ax.set_yscale("log")
        ax.legend(fontsize=7)
    fig.tight_layout()
    atomic_savefig(fig, path, dpi=100)
    plt.close(fig)
    return True


def draw_charts(lines: list[dict], out: Path) -> list[str]:
    """Draw every chart the results support into ``out``; returns the file names written."""
    out = Path(out)
    files = []
    every, lines = lines, default_partition(lines)
    if any(ln["kind"] in ("learned", "reference") for ln in lines):
        speed_accuracy(lines, out / "speed_accuracy.png")
        files += ["speed_accuracy.png", "speed_accuracy.svg"]
    if stability(lines, out / "stability.png"):
        files.append("stability.png")
    if resolution(every, out / "resolution.png"):
        files.append("resolution.png")
    return files
