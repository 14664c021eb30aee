"""The study's tables, built from ``results.jsonl`` alone: the paper's Tables 1-4 plus stability, speed, resolution.

Conventions (stated under every table): position MSE in 10^-3 m^2 at t = 40 and t = 110
(t = 1 the given frame); a learned row is the mean +- sample std over seeds of each seed's mean
over the test trajectories it did not fail on, with ``(k/n)`` when it failed on some; references
are deterministic (no std) except the sensitivity floor (std over perturbation seeds). A
diverged rollout counts as failed, never as a large number in a mean. Best learned row of each
column in bold, second underlined. The "x constant twist" tables divide each learned run's mean
by the constant-twist reference's mean over **the same trajectories** (those the run did not
fail on), so model and reference are always averaged over the same trajectories.

Table 4 (the ablation) is left out where Table 1 already holds its scenes, since every learned row
is in Table 1 (it would repeat it row for row). In the stability and speed tables each scene lists
the references first, then the learned rows in the order of Table 1.
"""

from __future__ import annotations

import csv
import io
import math
from collections import defaultdict

import numpy as np

__all__ = ["PAPER_TABLES", "build_tables", "Table"]

#: The paper's table layout: which scenes (in order) each table holds.
PAPER_TABLES = {
    "Table 1": ("cubli-single", "cubli-double", "cubli-triple", "rotational-none", "rotational-side",
                "rotational-center", "space-single", "space-double", "space-strike"),
    "Table 2": ("vehicle-original", "vehicle-fixed-obstacle", "vehicle-damaged", "vehicle-movable-obstacle",
                "ur5husky-original", "ur5husky-interaction"),
    "Table 4": ("cubli-triple", "rotational-center"),
}
TIMES = (40, 110)
SCALE = 1e3  # m^2 -> 10^-3 m^2


class Table:
    """A rendered table: title, header, rows of strings (markdown emphasis in ``md``), note."""

    def __init__(self, title: str, header: list[str], rows: list[list[str]], note: str, plain: list[list[str]]):
        self.title, self.header, self.rows, self.note, self.plain = title, header, rows, note, plain

    def markdown(self) -> str:
        out = [f"### {self.title}", "", "| " + " | ".join(self.header) + " |",
               "|" + "|".join("---" for _ in self.header) + "|"]
        out += ["| " + " | ".join(r) + " |" for r in self.rows]
        return "\n".join(out + ["", self.note, ""])

    def csv_rows(self) -> list[list[str]]:
        return [[self.title], self.header, *self.plain, []]

    def latex(self) -> str:
        def esc(s: str) -> str:
            s = s.replace("**", "").replace("<u>", "").replace("</u>", "")
            return s.replace("_", r"\_").replace("%", r"\%").replace("+-", r"$\pm$").replace("^2", r"$^2$")
        cols = "l" * len(self.header)
        body = [" & ".join(esc(h) for h in self.header) + r" \\ \hline"]
        body += [" & ".join(esc(c) for c in r) + r" \\" for r in self.rows]
        return "\n".join([rf"% {self.title}", rf"\begin{{tabular}}{{{cols}}}", *body, r"\end{tabular}", ""])


def _scenes(lines):
    out = []
    for ln in lines:
        if ln["scene"] not in out:
            out.append(ln["scene"])
    return out


def _run_mean(ln, set_name="test", t=110):
    """(mean over the trajectories not failed, whether any failed) of one cell at ``t``."""
    vals = [v for v in ln["sets"][set_name][f"pos_mse_t{t}"] if v is not None]
    return (float(np.mean(vals)) if vals else None), len(vals) < ln["sets"][set_name]["trajectories"]


def _points(lines, scene):
    """{label: (kind, cost mean, cost std, err mean, err std, any failed)} for one scene."""
    groups: dict = {}
    for ln in lines:
        if ln["scene"] == scene and ln["kind"] in ("learned", "reference"):
            groups.setdefault(ln["label"], []).append(ln)
    pts = {}
    for label, lns in groups.items():
        errs, failed = [], any(ln.get("status") == "failed" for ln in lns)
        lns = [ln for ln in lns if ln.get("status", "ok") == "ok"]
        if not lns:
            continue
        for ln in lns:
            m, f = _run_mean(ln)
            failed |= f or m is None
            if m is not None:
                errs.append(m)
        costs = [ln["cost"]["single"]["ms_per_frame"] for ln in lns]
        if not errs:  # failed on every trajectory by t = 110 in every seed: drawn at the top edge
            pts[label] = (lns[0]["kind"], float(np.mean(costs)), float(np.std(costs)), None, 0.0, True)
            continue
        pts[label] = (lns[0]["kind"], float(np.mean(costs)), float(np.std(costs)), float(np.mean(errs)),
                      float(np.std(errs, ddof=1)) if len(errs) > 1 else 0.0, failed)
    return pts


def _pareto(pts) -> set:
    """Labels of the points no other (not failed) point beats on both cost and error: the Pareto front;
    a point that failed on some trajectory is never on it."""
    front = set()
    for a, (_, ca, _, ea, _, fa) in pts.items():
        if fa or ea is None:
            continue
        if not any(eb is not None and cb <= ca and eb <= ea and (cb < ca or eb < ea) and not fb
                   for b, (_, cb, _, eb, _, fb) in pts.items() if b != a):
            front.add(a)
    return front


def _mean_valid(vals) -> tuple[float | None, int]:
    ok = [v for v in vals if v is not None and math.isfinite(v)]
    return (float(np.mean(ok)) if ok else None), len(ok)


def _fmt(mean, std, n_ok=None, n=None, scale=SCALE) -> str:
    if mean is None:
        return "failed"
    s = f"{mean * scale:.3g}"
    if std is not None:
        s += f" +- {std * scale:.2g}"
    if n is not None and n_ok is not None and n_ok < n:
        s += f" ({n_ok}/{n})"
    return s


def _rows_by_label(lines: list[dict], kinds=("learned",)) -> dict:
    """{(label, kind): {scene: [line, ...]}} in first-seen order."""
    out: dict = {}
    for ln in lines:
        if ln["kind"] in kinds:
            out.setdefault((ln["label"], ln["kind"]), defaultdict(list))[ln["scene"]].append(ln)
    return out


def _cell(lns: list[dict], set_name: str, t: int):
    """(mean over seeds, std over seeds, trajectories ok (summed), trajectories (summed)) of one table cell."""
    means, ok, tot = [], 0, 0
    for ln in lns:
        if ln.get("status") == "failed":  # training diverged: failed on every trajectory
            means.append(None)
            continue
        s = ln["sets"].get(set_name)
        if s is None:
            continue
        m, k = _mean_valid(s[f"pos_mse_t{t}"])
        ok, tot = ok + k, tot + s["trajectories"]
        means.append(m)
    if not means:
        return None
    if any(m is None for m in means):
        return (None, None, ok, tot)
    arr = np.array(means)
    std = float(arr.std(ddof=1)) if len(arr) > 1 else None
    return float(arr.mean()), std, ok, tot


def _ratios(lns, refs, set_name, t) -> list[float | None] | None:
    """Per seed: the run's mean / the plain constant-twist reference's mean over the run's surviving
    trajectories (None where the seed failed everywhere); None without that reference."""
    ref = next((r for r in refs if r["model"] == "constant-twist" and not r.get("settings")), None)  # the plain one
    if ref is None or set_name not in ref["sets"]:
        return None
    rv = ref["sets"][set_name][f"pos_mse_t{t}"]
    ratios = []
    for ln in lns:
        if ln.get("status") == "failed":
            ratios.append(None)
            continue
        s = ln["sets"].get(set_name)
        if s is None:
            continue
        pairs = [(a, b) for a, b in zip(s[f"pos_mse_t{t}"], rv, strict=True) if a is not None and b is not None]
        ratios.append(float(np.mean([a for a, _ in pairs]) / max(np.mean([b for _, b in pairs]), 1e-300))
                      if pairs else None)
    return ratios


def _ratio_cell(lns, refs, set_name, t):
    """Mean +- std over seeds of run mean / constant-twist mean over the run's surviving trajectories."""
    ratios = _ratios(lns, refs, set_name, t)
    if ratios is None:
        return None
    if not ratios:  # no finished cell of this row on this scene yet
        return "-"
    if any(r is None for r in ratios):
        return "failed"
    arr = np.array(ratios)
    return f"{arr.mean():.3g}" + (f" +- {arr.std(ddof=1):.2g}" if len(arr) > 1 else "")


def _full_seeds(learned: dict, scene: str) -> int:
    """The most seeds any learned row of ``learned`` (:func:`_rows_by_label`) has run on ``scene``: a row with
    fewer is still running (or was never finished) and is not yet a row to rank."""
    return max((len({ln["seed"] for ln in by_scene.get(scene, [])}) for by_scene in learned.values()), default=0)


def _partial(lns: list[dict], full: int) -> str:
    """``" [k of n seeds]"`` for a learned cell of ``lns`` with fewer seeds than ``full``; else ``""``."""
    k = len({ln["seed"] for ln in lns})
    return f" [{k} of {full} seeds]" if 0 < k < full else ""


def _mark_best(rows: list[list[str]], values: list[list[float | None]], n_learned: int) -> None:
    """Bold the best, underline the second-best learned value of each column (lower is better)."""
    for j in range(len(values[0]) if values else 0):
        col = [(values[i][j], i) for i in range(n_learned) if values[i][j] is not None]
        col.sort()
        if col:
            i = col[0][1]
            rows[i][j + 1] = f"**{rows[i][j + 1]}**"
        if len(col) > 1:
            i = col[1][1]
            rows[i][j + 1] = f"<u>{rows[i][j + 1]}</u>"


def _reference_order(label: str) -> tuple[int, int, int]:
    """Where a reference's row goes: by partition (the default first, then ``"... refine 2"`` etc.),
    within one: constant twist and its variants (shortest label first), then MuJoCo by timestep
    factor, then the rest (the sensitivity floor)."""
    base, _, refine = label.partition(" refine ")
    r = int(refine) if refine.isdigit() else 1
    if base.startswith("constant twist"):
        return (r, 0, len(base))
    if base.startswith("mujoco dt x"):
        return (r, 1, int(base.split("x")[-1]))
    return (r, 2, 0)


def default_partition(lines: list[dict]) -> list[dict]:
    """The lines compared in the paper's tables, who-wins, speed and the speed-accuracy chart: every
    row on the default partition (refine 1) and the resolution rows; the references on finer
    partitions (same trajectories, other nodes, so other errors) appear only beside the resolution
    rows (the Resolution and Stability tables)."""
    return [ln for ln in lines if ln["kind"] == "resolution" or ln.get("refine", 1) == 1]


def _row_order(lines):
    """Sort key of a per-(scene, label) row of the stability and speed tables: scenes in study order;
    within a scene the references first (in :func:`_reference_order`), then the learned rows in the
    order of Table 1 (first seen)."""
    scenes = {sc: i for i, sc in enumerate(_scenes(lines))}
    learned = {label: i for i, (label, _) in enumerate(_rows_by_label(lines))}

    def key(ln):
        if ln["kind"] == "learned":
            return (scenes[ln["scene"]], 1, (learned.get(ln["label"], len(learned)), 0, 0))
        return (scenes[ln["scene"]], 0, _reference_order(ln["label"]))
    return key


def _reference_rows(lines, scenes, set_name="test"):
    """Rows of the references: constant twist, MuJoCo at each dt factor, sensitivity floor."""
    refs = [ln for ln in lines if ln["kind"] in ("reference", "sensitivity")]
    labels = []
    for ln in refs:
        if ln["label"] not in labels:
            labels.append(ln["label"])
    out = []
    for lbl in sorted(labels, key=_reference_order):
        row, plain = [f"{lbl} (reference)"], [lbl]
        for t in TIMES:
            for sc in scenes:
                lns = [ln for ln in refs if ln["label"] == lbl and ln["scene"] == sc]
                c = _cell(lns, set_name, t)
                txt = "-" if c is None else _fmt(c[0], c[1], c[2], c[3])
                row.append(txt)
                plain.append(txt)
        out.append((row, plain))
    return out


def _model_table(title, lines, scenes, note_extra="") -> list[Table]:
    learned = _rows_by_label([ln for ln in lines if ln["scene"] in scenes])
    header = ["model"] + [f"{sc} t={t}" for t in TIMES for sc in scenes]
    rows, plain, values = [], [], []
    ratio_rows = []
    refs_by_scene = {sc: [ln for ln in lines if ln["kind"] == "reference" and ln["scene"] == sc] for sc in scenes}
    full = {sc: _full_seeds(learned, sc) for sc in scenes}
    for (label, _), by_scene in learned.items():
        row, pl, vals, rr = [label], [label], [], [label]
        for t in TIMES:
            for sc in scenes:
                c = _cell(by_scene.get(sc, []), "test", t)
                part = _partial(by_scene.get(sc, []), full[sc])  # a row still running: shown, never ranked
                txt = "-" if c is None else _fmt(c[0], c[1], c[2], c[3]) + part
                row.append(txt)
                pl.append(txt)
                vals.append(None if c is None or part else c[0])
                ratio = _ratio_cell(by_scene.get(sc, []), refs_by_scene[sc], "test", t)
                rr.append(ratio + part if ratio and ratio != "-" else ratio or "-")
        rows.append(row)
        plain.append(pl)
        values.append(vals)
        ratio_rows.append(rr)
    _mark_best(rows, values, len(rows))
    for row, pl in _reference_rows(lines, scenes):
        rows.append(row)
        plain.append(pl)
    note = ("Position MSE in 10^-3 m^2 over moving nodes; mean +- std over seeds; (k/n): trajectories not "
            "failed / all, summed over seeds; [k of n seeds]: a row that has run fewer seeds than the others "
            "(still running), never marked best; best learned row in bold, second underlined; references "
            "below. " + note_extra)
    t1 = Table(title, header, rows, note, plain)
    t2 = Table(f"{title}, x constant twist on the same trajectories", header, ratio_rows,
               "Each run's mean MSE divided by the constant-twist reference's mean over the same test "
               "trajectories (those the run did not fail on); below 1: better than every body keeping its twist.",
               ratio_rows)
    return [t1, t2]


def _generalization_table(lines) -> list[Table]:
    variant_sets = sorted({s for ln in lines if ln["kind"] == "learned" for s in ln["sets"] if s not in ("test", "long")})
    if not variant_sets:
        return []
    learned = _rows_by_label(lines)
    header = ["model"] + [f"{v} t={t}" for t in TIMES for v in variant_sets]
    rows, delta_rows = [], []
    for (label, _), by_scene in learned.items():
        lns = [ln for v in by_scene.values() for ln in v if any(s in ln["sets"] for s in variant_sets)]
        if not lns:
            continue
        row, deltas = [label], []
        for t in TIMES:
            for v in variant_sets:
                c = _cell(lns, v, t)
                base = _cell(lns, "test", t)
                row.append("-" if c is None else _fmt(c[0], c[1], c[2], c[3]))
                deltas.append("-" if c is None or base is None or c[0] is None or base[0] is None
                              else f"{(c[0] - base[0]) * SCALE:+.3g}")
        rows.append(row)
        delta_rows.append([label, *deltas])
    note = ("Table 3: models trained on the original scene, evaluated on its test variants; delta = variant "
            "minus the original test set (10^-3 m^2).")
    # values and deltas in two tables, so that each fits a page's column
    return [Table("Table 3 (generalization)", header, rows, note, rows),
            Table("Table 3 (generalization), delta = variant minus the original test set",
                  ["model"] + [f"delta {h}" for h in header[1:]], delta_rows, note, delta_rows)]


def _stability_table(lines) -> Table | None:
    rows = []
    key = _row_order(lines)
    groups = sorted(_group(lines, lambda ln: "long" in ln["sets"]), key=lambda g: key(g[0]))  # per scene: references, then learned
    for ln_group in groups:
        lns = ln_group
        ttf_all, n_all, never, joint, frames = [], 0, 0, [], None
        for ln in lns:
            s = ln["sets"]["long"]
            frames = s["frames"]
            n_all += s["trajectories"]
            ttf_all += [f for f in s["time_to_failure"] if f is not None]
            never += sum(f is None for f in s["time_to_failure"])
            if s.get("joint_separation_max_m") is not None:
                joint.append(s["joint_separation_max_m"])
        med = "-" if not ttf_all else f"{int(np.median(ttf_all))}"
        rows.append([lns[0]["scene"], lns[0]["label"], str(len(lns)), f"{frames}", med,
                     f"{never}/{n_all} ({100 * never / max(n_all, 1):.0f} %)",
                     "-" if not joint else f"{1e3 * max(joint):.3g}"])
    if not rows:
        return None
    header = ["scene", "model", "runs", "frames", "median time to failure (frames)", "never failed",
              "max joint separation before failure (mm)"]
    note = ("Long test trajectories (10x the training horizon where the study says so). Failure: position MSE "
            "above failure_factor x the position variance of the moving nodes in the set; time to failure is "
            "the first frame past it (the median over failed trajectories, all seeds). The sensitivity floor "
            "is MuJoCo at the data's own timestep from initial velocities perturbed by the study's "
            "sensitivity: how many trajectories chaos alone takes past the threshold.")
    return Table("Stability", header, rows, note, rows)


def _ratio_mean(lns, refs, t):
    """Mean over seeds of :func:`_ratios` on the test set; None if any seed failed everywhere."""
    ratios = _ratios(lns, refs, "test", t)
    return None if not ratios or any(r is None for r in ratios) else float(np.mean(ratios))


def _verdict_table(lines) -> Table | None:
    """Per scene, who wins: the Pareto front, the best learned row at each horizon against constant
    twist, the learned rows that beat doing nothing, and the cheapest MuJoCo that beats them all."""
    rows = []
    for scene in _scenes(lines):
        lns = [ln for ln in lines if ln["scene"] == scene]
        learned = _rows_by_label([ln for ln in lns if ln.get("status") in ("ok", "failed", None)])
        refs = [ln for ln in lns if ln["kind"] == "reference" and ln.get("status", "ok") == "ok"]
        if not learned or not refs:
            continue
        pts = _points(lines, scene)
        front = sorted(_pareto(pts), key=lambda k: pts[k][1])
        best, beats = {}, {}
        full = _full_seeds(learned, scene)
        for t in TIMES:
            cand = []
            for (label, _), by_scene in learned.items():
                c = _cell(by_scene[scene], "test", t)
                if c is None or c[0] is None or c[2] < c[3] or _partial(by_scene[scene], full):
                    continue  # failed somewhere, or still running: not a winner at t
                cand.append((c[0], label, _ratio_mean(by_scene[scene], refs, t)))
            best[t] = min(cand) if cand else None
            beats[t] = {label for _, label, r in cand if r is not None and r < 1.0}
        both = [label for (label, _) in learned if label in beats[40] and label in beats[110]]
        mj = sorted((pts[k][1], k) for k in pts if k.startswith("mujoco dt x") and pts[k][3] is not None
                    and not pts[k][5] and best[110] is not None and pts[k][3] <= best[110][0])

        def fmt(b):
            if b is None:
                return "none finished every trajectory"
            m, label, r = b
            return f"{label}: {m * SCALE:.3g}" + (f" ({r:.2g}x constant twist)" if r is not None else "")
        rows.append([scene, ", ".join(front) or "-", fmt(best[40]), fmt(best[110]),
                     ", ".join(both) or "none",
                     "-" if not mj else f"{mj[0][1]} ({mj[0][0]:.3g} ms per frame)"])
    if not rows:
        return None
    header = ["scene", "Pareto front (t=110 error against ms per frame)", "best learned, t=40",
              "best learned, t=110", "learned rows below constant twist at t=40 and t=110",
              "coarsest MuJoCo as accurate as the best learned row at t=110"]
    note = ("Read from the tables above and the speed-accuracy chart: the Pareto front holds the rows no other "
            "row beats on both cost (one trajectory, ms per simulated frame) and t=110 error (a row that failed on "
            "some trajectory is never on it); a best learned row is the lowest mean among the learned rows that "
            "finished every test trajectory with every seed the others ran; \"below constant twist\": the mean over seeds of the ratio to the "
            "plain constant-twist reference on the same trajectories is below 1 at both horizons.")
    return Table("Who wins, per scene", header, rows, note, rows)


def _group(lines, pred):
    groups: dict = {}
    for ln in lines:
        if pred(ln):
            groups.setdefault((ln["scene"], ln["label"]), []).append(ln)
    return list(groups.values())


def _speed_table(lines) -> Table | None:
    rows = []
    key = _row_order(lines)
    recost = any(ln.get("cost", {}).get("recost") for ln in lines)
    for lns in sorted(_group(lines, lambda ln: ln["kind"] in ("learned", "reference") and ln.get("status", "ok") == "ok"),
                      key=lambda g: key(g[0])):  # per scene: references, then learned
        ln = lns[0]
        single = np.median([x["cost"]["single"]["ms_per_frame"] for x in lns])
        batched = np.median([x["cost"]["batched"]["ms_per_trajectory_frame"] for x in lns])
        tr = [x["train"].get("train_seconds") for x in lns if x["train"]]
        row = [ln["scene"], ln["label"], f"{ln['parameters']}", f"{single:.3g}",
               f"{batched:.3g} (batch {ln['cost']['batched']['batch']})"]
        if recost:
            c = ln["cost"]
            row.append({"none": "eager", None: "eager, while the study ran"}.get(c.get("compiled"), c.get("compiled")))
            row.append(f"{np.median([x.get('cost_in_run', x['cost'])['single']['ms_per_frame'] for x in lns]):.3g}")
        rows.append(row + ["-" if not tr else f"{np.median(tr):.0f}"])
    if not rows:
        return None
    header = ["scene", "model", "parameters", "ms per frame, 1 trajectory", "ms per trajectory-frame, batched"]
    if recost:
        header += ["step", "ms per frame, 1 trajectory, eager while the study ran"]
        modes = sorted({ln["cost"]["requested"] for ln in lines if ln.get("cost", {}).get("recost")})
        note = (f"Measured again after the study by `mdgs study --recost {'/'.join(modes)}` "
                "(mdgs.evaluate.cost.compiled_cost), one row after another, each in a process of its own, one seed per row "
                "(a row's seeds share its architecture and scene); \"step\": how each step ran: compiled ahead "
                "of time (aot), by torch.compile (inductor), or eager where the model does not compile "
                "(MuJoCo is C code, nothing to compile). Median of 3 timed repeats each. The last column: "
                "the eager step timed by each cell while the study ran, medians over seeds, while other work "
                "may have shared the machine.")
    else:
        note = ("Medians over seeds of the median of 3 timed repeats (mdgs.evaluate.cost.step_cost) on the machine "
                "that ran each cell, while other work may have shared it (benchmarks/bench_models.py times models "
                "side by side on an idle machine; `mdgs study --recost aot` measures every row again, compiled, "
                "one after another).")
    return Table("Speed", header + ["training s (median over seeds)"], rows, note, rows)


def _resolution_table(lines) -> Table | None:
    res = [ln for ln in lines if ln["kind"] == "resolution"]
    if not res:
        return None
    base = [ln for ln in lines if ln["kind"] == "learned" and ln["label"] == _resolution_base(res)]
    rows = []
    long = any("long" in ln["sets"] for ln in res)
    for lns in _group(base + res, lambda ln: ln.get("status", "ok") == "ok"):
        ln = lns[0]
        refine = ln.get("refine", 1)
        c40, c110 = _cell(lns, "test", 40), _cell(lns, "test", 110)
        cost = np.median([x["cost"]["single"]["ms_per_frame"] for x in lns])
        refs = [r for r in lines if r["kind"] == "reference" and r["scene"] == ln["scene"]
                and r.get("refine", 1) == refine and r.get("status", "ok") == "ok"]
        ratio = [_ratio_cell(lns, refs, "test", t) or "-" for t in TIMES]
        rows.append([ln["scene"], f"{refine}", str(len(lns)), str(ln["parameters"]), _fmt(*c40) if c40 else "-",
                     _fmt(*c110) if c110 else "-", *ratio, f"{cost:.3g}"])
        if long:  # trajectories never past the failure threshold over the long set, all seeds that ran it
            ttf = [f for x in lns if "long" in x["sets"] for f in x["sets"]["long"]["time_to_failure"]]
            rows[-1].append(f"{sum(f is None for f in ttf)}/{len(ttf)}" if ttf else "-")
    rows.sort(key=lambda r: (r[0], int(r[1])))
    header = ["scene", "refine", "runs", "parameters", "t=40 (10^-3 m^2)", "t=110 (10^-3 m^2)",
              *[f"x constant twist, same partition, t={t}" for t in TIMES], "ms per frame"]
    header += ["never failed (long set)"] if long else []
    return Table("Resolution", header, rows, f"{res[0]['model'].upper()} ({_resolution_base(res)}) on the default "
                 "(coarsest adequate) element partition (refine 1) and finer ones: does a finer partition buy "
                 "accuracy for its cost? Refine 1 is the study's own row of that label. Position MSE averages "
                 "over element centroids, so one motion scores differently on two partitions: the ratio divides "
                 "by the constant-twist reference on the same partition and the same trajectories (\"-\" where "
                 "that reference has not run), and the Stability table lists every reference on each partition.",
                 rows)


def _resolution_base(res: list[dict]) -> str:
    """The row label the resolution cells refine (``"mdgs + motor prior"`` of ``"mdgs + motor prior refine 2"``)."""
    return res[0]["label"].rsplit(" refine ", 1)[0]


def build_tables(lines: list[dict]) -> list[Table]:
    """Every table the results support (tables whose scenes are absent are left out)."""
    scenes_present = []
    for ln in lines:
        if ln["scene"] not in scenes_present:
            scenes_present.append(ln["scene"])
    every, lines = lines, default_partition(lines)
    out = []
    covered = set()
    for title, scenes in PAPER_TABLES.items():
        sc = [s for s in scenes if s in scenes_present]
        if not sc:
            continue
        if title == "Table 4":
            # the paper's ablation table holds the MDGS variants beside the peers on scenes of Table 1;
            # here every learned row is in Table 1 already, so a Table 4 over scenes Table 1 covers would
            # repeat it row for row: it is drawn only for scenes no earlier table holds
            if set(sc) <= covered:
                continue
            out += _model_table("Table 4 (ablation: MDGS variants beside the peers)", lines, sc)
            continue
        covered |= set(sc)
        out += _model_table(title, lines, sc)
    other = [s for s in scenes_present if s not in covered and s not in PAPER_TABLES["Table 4"]]
    if other:
        out += _model_table("Other scenes", lines, other)
    out += _generalization_table(lines)
    for t in (_verdict_table(lines), _stability_table(every), _speed_table(lines), _resolution_table(every)):
        if t is not None:
            out.append(t)
    return out


def render(lines: list[dict], study_name: str) -> dict[str, str]:
    """``{"tables.md": ..., "tables.csv": ..., "tables.tex": ...}`` of the results."""
    tables = build_tables(lines)
    md = [f"# Study `{study_name}`: tables", "",
          f"Built from {len(lines)} results lines by `mdgs study --report`. " + __doc__.split("\n\n")[1].replace("\n", " "), ""]
    md += [t.markdown() for t in tables]
    buf = io.StringIO()
    w = csv.writer(buf)
    for t in tables:
        w.writerows(t.csv_rows())
    tex = "\n".join(t.latex() for t in tables)
    return {"tables.md": "\n".join(md), "tables.csv": buf.getvalue(), "tables.tex": tex}
