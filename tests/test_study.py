"""``mdgs study``: study files are checked, the grid runs resumably, tables and charts come from results.jsonl alone."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
from typer.testing import CliRunner

from mdgs.cli import app
from mdgs.models import MODELS
from mdgs.study import StudyError, cells_of, load_study, read_results
from mdgs.study.tables import build_tables

ROOT = Path(__file__).resolve().parents[1]
TINY = ROOT / "studies" / "tiny.toml"
runner = CliRunner()


def _write(tmp_path, text: str) -> Path:
    p = tmp_path / "s.toml"
    p.write_text(text)
    return p


GOOD = """
[study]
name = "t"
preset = "tiny"
seeds = [0]
[[scenes]]
name = "cubli-single"
[[models]]
name = "mdgs"
"""


@pytest.mark.parametrize(("text", "phrase"), [
    ("[study\nname=", "not valid TOML"),
    (GOOD.replace('name = "mdgs"', 'name = "nosuch"'), "model 'nosuch' is unknown"),
    (GOOD.replace('name = "cubli-single"', 'name = "moon-base"'), "scene 'moon-base' is unknown"),
    (GOOD.replace("seeds = [0]", "seeds = [0]\nsedes = [1]"), "unknown key 'sedes'"),
    (GOOD.replace("seeds = [0]", 'seeds = "0"'), "should be of type list"),
    (GOOD.replace("seeds = [0]", "seeds = [0]\ntrajectories = 2"), "trajectories must be 0"),
    (GOOD.replace('[[models]]\nname = "mdgs"', '[[models]]\nname = "mdgs"\nset = { hiden = 3 }'), "no setting 'hiden'"),
    (GOOD.replace('[[models]]\nname = "mdgs"', '[[models]]\nname = "mujoco"'), "is a reference"),
    (GOOD.replace('preset = "tiny"', 'preset = "huge"'), "preset 'huge' is unknown"),
    (GOOD + '[budget]\nselect = "best"\n', "select = 'best' is not one of"),
    (GOOD + '[budget]\nselect_frames = 1100\n', "needs select = \"rollout\""),
    (GOOD + '[budget]\nselect = "rollout"\nselect_frames = 1\n', "at least 2 frames"),
    (GOOD + '[budget]\nema = 1\n', "ema = 1.0 must be from 0"),
    (GOOD + '[budget]\nema = "0.99"\n', "should be of type int or float"),
    (GOOD + "[references]\nmotors = 1\n", "should be of type bool"),
])
def test_malformed_study_file_is_one_sentence_and_exit_2(tmp_path, text, phrase):
    path = _write(tmp_path, text)
    with pytest.raises(StudyError, match=phrase.replace("(", r"\(")):
        load_study(path)
    res = runner.invoke(app, ["study", str(path), "--out", str(tmp_path / "o")])
    assert res.exit_code == 2 and "Traceback" not in res.output
    assert phrase in res.output and len(res.output.strip().splitlines()) == 1, res.output
    assert not (tmp_path / "o").exists()  # nothing written for a bad study file


def test_output_folder_of_another_study_is_refused(tmp_path):
    out = tmp_path / "o"
    out.mkdir()
    (out / "study.json").write_text(json.dumps({"name": "other"}))
    res = runner.invoke(app, ["study", str(_write(tmp_path, GOOD)), "--out", str(out)])
    assert res.exit_code == 2 and "holds results of study 'other'" in res.output
    (out / "study.json").unlink()
    (out / "stray.txt").write_text("x")
    res = runner.invoke(app, ["study", str(_write(tmp_path, GOOD)), "--out", str(out)])
    assert res.exit_code == 2 and "not empty" in res.output


def test_threads_option_sets_torch_threads_and_refuses_a_nonpositive_count(tmp_path):
    """``--threads N`` sets this process's torch threads before the study is read (so two shares on one machine
    need not oversubscribe it); 0 is one sentence, exit 2, nothing written."""
    import torch

    before = torch.get_num_threads()
    try:
        res = runner.invoke(app, ["study", str(_write(tmp_path, "[study\n")), "--out", str(tmp_path / "o"),
                                  "--threads", str(before + 1)])
        assert res.exit_code == 2  # the malformed file, read after the threads were set
        assert torch.get_num_threads() == before + 1
    finally:
        torch.set_num_threads(before)
    res = runner.invoke(app, ["study", str(_write(tmp_path, GOOD)), "--out", str(tmp_path / "o"), "--threads", "0"])
    assert res.exit_code == 2 and "--threads 0: give a positive number" in res.output and "Traceback" not in res.output
    assert not (tmp_path / "o").exists()


def test_cells_cover_the_grid_once_and_shares_partition_it():
    study = load_study(TINY)
    cells = cells_of(study)
    keys = [c.key(study) for c in cells]
    assert len(set(keys)) == len(keys)
    n_ref = len(study.scenes) * (1 + len(study.mujoco_dt_factors) + len(study.sensitivity_seeds))
    assert len(cells) == n_ref + len(study.scenes) * len(study.models) * len(study.seeds)
    # a job array of 3 shares runs every cell exactly once
    shares = [[c.key(study) for k, c in enumerate(cells) if k % 3 == i] for i in range(3)]
    assert sorted(sum(shares, [])) == sorted(keys)


def test_motor_twist_reference_is_one_more_cell_per_scene_and_not_the_ratio_base(tmp_path):
    plain = load_study(_write(tmp_path, GOOD))
    study = load_study(_write(tmp_path, GOOD + "[references]\nmotors = true\n"))
    extra = [c for c in cells_of(study) if c.key(study) not in {k.key(plain) for k in cells_of(plain)}]
    assert [(c.kind, c.model, c.label, dict(c.settings)) for c in extra] == [
        ("reference", "constant-twist", "constant twist + motors", {"motors": True})]
    # the "x constant twist" tables divide by the plain reference, whichever line comes first
    base = {"kind": "reference", "model": "constant-twist", "scene": "s", "seed": 0, "status": "ok", "refine": 1}
    sets = lambda v: {"test": {"pos_mse_t40": [v, v], "pos_mse_t110": [v, v]}}  # noqa: E731
    motors = {**base, "label": "constant twist + motors", "settings": {"motors": True}, "sets": sets(1.0)}
    twist_ = {**base, "label": "constant twist", "settings": {}, "sets": sets(4.0)}
    run = {**base, "kind": "learned", "model": "mdgs", "label": "mdgs", "settings": {}, "sets": sets(2.0)}
    from mdgs.study.tables import _ratio_cell
    assert _ratio_cell([run], [motors, twist_], "test", 40) == "0.5"  # 2 / 4, not 2 / 1
    # a row with no finished cell on a scene yet is not a failed row
    assert _ratio_cell([], [motors, twist_], "test", 40) == "-"
    assert _ratio_cell([{**run, "status": "failed"}], [motors, twist_], "test", 40) == "failed"


def test_joint_twist_references_add_the_projected_rows_and_leave_the_ratio_base_plain(tmp_path):
    plain = load_study(_write(tmp_path, GOOD + "[references]\nmotors = true\n"))
    study = load_study(_write(tmp_path, GOOD + "[references]\nmotors = true\njoints = true\n"))
    extra = [c for c in cells_of(study) if c.key(study) not in {k.key(plain) for k in cells_of(plain)}]
    assert [(c.label, dict(c.settings)) for c in extra] == [
        ("constant twist + joints", {"joints": True}),
        ("constant twist + motors + joints", {"joints": True, "motors": True})]
    base = {"kind": "reference", "model": "constant-twist", "scene": "s", "seed": 0, "status": "ok", "refine": 1}
    sets = lambda v: {"test": {"pos_mse_t40": [v, v], "pos_mse_t110": [v, v]}}  # noqa: E731
    joints = {**base, "label": "constant twist + joints", "settings": {"joints": True}, "sets": sets(1.0)}
    twist_ = {**base, "label": "constant twist", "settings": {}, "sets": sets(4.0)}
    run = {**base, "kind": "learned", "model": "mdgs", "label": "mdgs", "settings": {}, "sets": sets(2.0)}
    from mdgs.study.tables import _ratio_cell
    assert _ratio_cell([run], [joints, twist_], "test", 40) == "0.5"
    with pytest.raises(StudyError, match="joints"):
        load_study(_write(tmp_path, GOOD + "[references]\njoints = 1\n"))


def test_rigid_tree_reference_is_one_more_cell_per_scene_and_earlier_cells_keep_their_keys(tmp_path):
    plain = load_study(_write(tmp_path, GOOD + "[references]\nmotors = true\njoints = true\n"))
    study = load_study(_write(tmp_path, GOOD + "[references]\nmotors = true\njoints = true\nrigid_tree = true\n"))
    old = {k.key(plain) for k in cells_of(plain)}
    extra = [c for c in cells_of(study) if c.key(study) not in old]
    assert [(c.kind, c.model, c.label, dict(c.settings)) for c in extra] == [
        ("reference", "constant-twist", "rigid tree + joints", {"dynamics": True, "joints": True})]
    assert old <= {c.key(study) for c in cells_of(study)}  # a committed study without it resumes unchanged
    ct = MODELS["constant-twist"]
    from mdgs.evaluate import reference_label
    assert reference_label(ct(ct.Config(**dict(extra[0].settings)))) == extra[0].label
    with pytest.raises(StudyError, match="rigid_tree"):
        load_study(_write(tmp_path, GOOD + "[references]\nrigid_tree = 1\n"))
    both = load_study(_write(tmp_path, GOOD + "[references]\nmotors = true\njoints = true\nrigid_tree = true\n"
                                              "rigid_tree_trapezoidal = true\n"))
    more = [c for c in cells_of(both) if c.key(both) not in {k.key(study) for k in cells_of(study)}]
    assert [(c.label, dict(c.settings)) for c in more] == [
        ("rigid tree + joints, trapezoidal", {"dynamics": True, "joints": True, "trapezoidal": True})]
    assert reference_label(ct(ct.Config(**dict(more[0].settings)))) == more[0].label
    pushed = load_study(_write(tmp_path, GOOD + "[references]\nmotors = true\njoints = true\nrigid_tree = true\n"
                                                "rigid_tree_trapezoidal = true\nrigid_tree_push_out = true\n"))
    last = [c for c in cells_of(pushed) if c.key(pushed) not in {k.key(both) for k in cells_of(both)}]
    assert [(c.label, dict(c.settings)) for c in last] == [("rigid tree + joints, trapezoidal, push-out", {
        "dynamics": True, "joints": True, "push_out": True, "trapezoidal": True})]
    assert reference_label(ct(ct.Config(**dict(last[0].settings)))) == last[0].label
    sub = load_study(_write(tmp_path, GOOD + "[references]\nmotors = true\njoints = true\nrigid_tree = true\n"
                                             "rigid_tree_trapezoidal = true\nrigid_tree_push_out = true\n"
                                             "rigid_tree_substeps = [4]\n"))
    four = [c for c in cells_of(sub) if c.key(sub) not in {k.key(pushed) for k in cells_of(pushed)}]
    assert [c.label for c in four] == ["rigid tree + joints, trapezoidal, push-out, 4 substeps"]
    assert reference_label(ct(ct.Config(**dict(four[0].settings)))) == four[0].label
    with pytest.raises(StudyError, match="rigid_tree_substeps"):
        load_study(_write(tmp_path, GOOD + "[references]\nrigid_tree_substeps = [1]\n"))


def _changes_only_learned_keys(tmp_path, text: str, line: str, name: str):
    """The study ``text`` with the budget ``line`` added: its learned cells' keys differ from those of
    ``text`` alone, its references' do not, and without the line no cell's budget holds ``name`` (so
    studies run before the setting existed keep their keys). Returns the study with the line."""
    plain = load_study(_write(tmp_path, text))
    other = load_study(_write(tmp_path, text + line))
    kp, ko = ({c.kind: c.key(s) for c in cells_of(s)} for s in (plain, other))
    assert kp["learned"] != ko["learned"] and kp["reference"] == ko["reference"]
    assert all(name not in c.spec(plain).get("budget", {}) for c in cells_of(plain))
    return other


def test_select_frames_trains_on_the_same_data_and_scores_longer_validation_trajectories(tmp_path):
    """``[budget] select_frames = N``: the learned cells' keys change (another rule), the references' do
    not, a study without it keeps the keys it had, and a cell trains with its rollout rule scored on the
    validation trajectories run for N frames (a dataset of its own, ``long_trajectories`` of them)."""
    from mdgs.data.split import load_split
    from mdgs.study.runner import _cell_model, _dataset

    budget = "\n[budget]\nepochs = 1\nmax_steps = 1\nbatch_size = 4\nvalid_max_pairs = 4\nselect = \"rollout\"\n"
    text = GOOD.replace("seeds = [0]", "seeds = [0]\nlong_trajectories = 2\nsensitivity = 0") + budget
    longer = _changes_only_learned_keys(tmp_path, text, "select_frames = 150\n", "select_frames")
    cell = next(c for c in cells_of(longer) if c.kind == "learned")
    out = tmp_path / "out"
    data = _dataset(longer, out, cell.scene)
    _, info = _cell_model(longer, out, cell, data, torch.device("cpu"), lambda e: None)
    assert info["select"] == "rollout" and info["select_frames"] == 150
    lv = load_split(out / "data" / f"{cell.scene.name}-valid150" / "valid.h5")
    assert lv.x.shape[:2] == (2, 150)


def test_ema_changes_only_the_learned_cells_keys_and_trains_their_runs_with_it(tmp_path):
    """``[budget] ema = D``: the learned cells' keys change (other weights are evaluated), the references'
    do not, a study without it keeps the keys it had, and the cell's run trains with that decay (its
    checkpoint keeps the optimiser's weights beside the average, which the cell evaluates)."""
    from mdgs.study.runner import _cell_model, _dataset

    budget = "\n[budget]\nepochs = 1\nmax_steps = 2\nbatch_size = 4\nvalid_max_pairs = 4\n"
    text = GOOD.replace("seeds = [0]", "seeds = [0]\nsensitivity = 0") + budget
    ema = _changes_only_learned_keys(tmp_path, text, "ema = 0.9\n", "ema")
    cell = next(c for c in cells_of(ema) if c.kind == "learned")
    out = tmp_path / "out"
    _, info = _cell_model(ema, out, cell, _dataset(ema, out, cell.scene), torch.device("cpu"), lambda e: None)
    assert info["ema"] == 0.9
    state = torch.load(out / "runs" / cell.key(ema) / "checkpoint.pt", weights_only=False)
    assert state["train_fingerprint"]["ema"] == 0.9 and state["n_averaged"] == 2 and "trained_model" in state


def test_a_trajectory_count_makes_its_own_data_and_cells_and_leaves_the_presets_keys(tmp_path):
    """``trajectories = N``: every cell key changes (other data), the data has N trajectories in the
    paper's proportions, and a study that does not set it keeps the keys it had before it existed."""
    from mdgs.data.split import load_split
    from mdgs.study.runner import _dataset

    plain = load_study(_write(tmp_path, GOOD))
    more = load_study(_write(tmp_path, GOOD.replace("seeds = [0]", "seeds = [0]\ntrajectories = 5")))
    assert not {c.key(plain) for c in cells_of(plain)} & {c.key(more) for c in cells_of(more)}
    assert all("trajectories" not in c.spec(plain) for c in cells_of(plain))
    folder = _dataset(more, tmp_path / "out", more.scenes[0])
    counts = [load_split(folder / f"{s}.h5").x.shape[0] for s in ("train", "valid", "test")]
    assert sum(counts) == 5 and counts[0] >= counts[1] >= 1 and counts[2] >= 1


def _accuracy_tables(lines):
    # tables that hold timings (the Pareto front is read against cost) differ between two runs
    return [t.markdown() for t in build_tables(lines) if t.title not in ("Speed", "Resolution", "Who wins, per scene")]


def _study(out: Path, *extra) -> subprocess.Popen:
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    return subprocess.Popen([sys.executable, "-m", "mdgs.cli", "study", str(TINY), "--out", str(out), *extra],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, env=env, start_new_session=True)


@pytest.fixture(scope="module")
def clean_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("study") / "clean"
    p = _study(out)
    log = p.communicate(timeout=900)[0].decode()
    assert p.returncode == 0, log
    return out


def test_tiny_study_writes_results_tables_and_charts(clean_run):
    lines = read_results(clean_run)
    study = load_study(TINY)
    assert {ln["cell"] for ln in lines} == {c.key(study) for c in cells_of(study)}
    for ln in lines:
        assert ln["sets"]["test"]["trajectories"] >= 1 and ln["cost"]["single"]["ms_per_frame"] > 0
        assert ln["versions"]["torch"] and ln["data_fingerprint"]
    # MuJoCo at the data's own timestep replays the data: its error is at round-off level
    mj1 = [ln for ln in lines if ln["label"] == "mujoco dt x1"]
    assert mj1 and all(v < 1e-8 for ln in mj1 for v in ln["sets"]["test"]["pos_mse_t40"])
    for f in ("tables.md", "tables.csv", "tables.tex", "speed_accuracy.png", "speed_accuracy.svg", "stability.png"):
        assert (clean_run / f).stat().st_size > 200, f
    md = (clean_run / "tables.md").read_text()
    assert "### Table 1" in md and "constant twist (reference)" in md and "sensitivity floor" in md


def test_sensitivity_floor_is_measured_on_the_long_set_and_reaches_the_stability_table(clean_run):
    """The chaos floor of the stability test: MuJoCo from perturbed initial velocities is rolled out
    over the long test trajectories like every other row, and the Stability table lists it."""
    lines = [ln for ln in read_results(clean_run) if ln["kind"] == "sensitivity"]
    study = load_study(TINY)
    assert len(lines) == len(study.scenes) * len(study.sensitivity_seeds)
    for ln in lines:
        long = ln["sets"]["long"]
        assert long["frames"] == study.long_frames and len(long["time_to_failure"]) == study.long_trajectories
        assert ln["revision"] == 1
    stab = next(t for t in build_tables(read_results(clean_run)) if t.title == "Stability")
    assert {(r[0], r[1]) for r in stab.rows if r[1] == "sensitivity floor"} == {
        (sc.name, "sensitivity floor") for sc in study.scenes}


def test_report_redraws_from_results_alone(clean_run, tmp_path):
    copy = tmp_path / "copy"
    copy.mkdir()
    for f in ("results.jsonl", "study.json"):
        (copy / f).write_bytes((clean_run / f).read_bytes())
    res = runner.invoke(app, ["study", "--report", str(copy)])
    assert res.exit_code == 0, res.output
    assert (copy / "tables.md").read_text() == (clean_run / "tables.md").read_text()  # same lines, same tables
    assert (copy / "speed_accuracy.png").stat().st_size > 1000


def test_a_folder_holding_only_data_hosts_a_study_that_reuses_those_datasets(clean_run, tmp_path):
    """``--out`` holding only ``data`` (here a symlink to another run of the same study's datasets) is
    accepted, its datasets are used as they are (no file rewritten), and the accuracy tables are that
    run's; anything else in the folder is still refused (test_output_folder_of_another_study_is_refused)."""
    out = tmp_path / "reuse"
    out.mkdir()
    (out / "data").symlink_to(clean_run / "data")
    before = {p: p.stat().st_mtime_ns for p in (clean_run / "data").rglob("*.h5")}
    p = _study(out, "--no-report")
    log = p.communicate(timeout=900)[0].decode()
    assert p.returncode == 0, log
    assert before and {p: p.stat().st_mtime_ns for p in (clean_run / "data").rglob("*.h5")} == before
    assert _accuracy_tables(read_results(out)) == _accuracy_tables(read_results(clean_run))


def test_killed_study_resumes_with_each_cell_once_and_the_same_tables(clean_run, tmp_path):
    out = tmp_path / "killed"
    p = _study(out)
    results = out / "results.jsonl"
    t0 = time.time()
    while time.time() - t0 < 600:  # kill -9 once a few cells have finished, in the middle of the next
        if results.exists() and results.read_text().count("\n") >= 3:
            time.sleep(1.5)
            break
        time.sleep(0.2)
    os.killpg(p.pid, signal.SIGKILL)
    p.wait()
    n_before = results.read_text().count("\n")
    assert 1 <= n_before < len(read_results(clean_run))
    p = _study(out)
    log = p.communicate(timeout=900)[0].decode()
    assert p.returncode == 0, log
    keys = [json.loads(x)["cell"] for x in results.read_text().splitlines()]
    assert len(keys) == len(set(keys)) == len(read_results(clean_run))  # each cell exactly once
    assert _accuracy_tables(read_results(out)) == _accuracy_tables(read_results(clean_run))


def test_recost_times_each_row_once_resumes_and_the_speed_table_says_how_each_step_ran(clean_run, tmp_path):
    """``--recost``: one line per table row (sensitivity rows aside) in costs.jsonl, every seed of the row
    reads it as its cost (the cost timed in the run kept beside), a rerun times nothing again, MuJoCo is
    timed as it is and says why, the speed table names how each step ran, and no run is trained or
    checked against today's settings (a run trained before a config field existed is timed as it is).
    Eager here ("none"): the ahead-of-time path is tests/test_train.py's and test_compiled_cost_*."""
    import shutil

    out = tmp_path / "copy"
    shutil.copytree(clean_run, out)
    runs = {p: p.read_bytes() for p in (out / "runs").rglob("checkpoint.pt")}
    res = runner.invoke(app, ["study", str(TINY), "--out", str(out), "--recost", "none"])
    assert res.exit_code == 0, res.output
    assert runs and {p: p.read_bytes() for p in (out / "runs").rglob("checkpoint.pt")} == runs  # none trained
    recs = [json.loads(x) for x in (out / "costs.jsonl").read_text().splitlines()]
    lines = read_results(out)
    rows = {(ln["scene"], ln["label"]) for ln in lines if ln["kind"] != "sensitivity"}
    assert sorted((r["scene"], r["label"]) for r in recs) == sorted(rows)
    assert all(r["single"]["ms_per_frame"] > 0 and r["compiled"] == "none" for r in recs)
    assert all("not torch code" in r["note"] for r in recs if r["label"].startswith("mujoco"))
    for ln in lines:
        if ln["kind"] == "sensitivity":
            assert "cost_in_run" not in ln
        else:
            rec = next(r for r in recs if (r["scene"], r["label"]) == (ln["scene"], ln["label"]))
            assert ln["cost"]["single"] == rec["single"] and ln["cost_in_run"]["single"]["ms_per_frame"] > 0
    again = runner.invoke(app, ["study", str(TINY), "--out", str(out), "--recost", "none", "--no-report"])
    assert again.exit_code == 0 and f"0 of {len(rows)} rows timed now" in again.output, again.output
    md = (out / "tables.md").read_text()
    assert "`mdgs study --recost none`" in md and "| step |" in md
    res = runner.invoke(app, ["study", str(TINY), "--out", str(out), "--recost", "jit"])
    assert res.exit_code == 2 and "give aot" in res.output
    res = runner.invoke(app, ["study", str(TINY), "--out", str(out), "--recost", "aot", "--cells", "0/2"])
    assert res.exit_code == 2 and "leave out --cells" in res.output
    # a results line whose run folder is not there (copied without it): named, with what to do, no traceback
    shutil.rmtree(next((out / "runs").iterdir()))
    (out / "costs.jsonl").unlink()
    res = runner.invoke(app, ["study", str(TINY), "--out", str(out), "--recost", "none", "--no-report"])
    assert res.exit_code == 0 and "its weights are not in" in res.output and "Traceback" not in res.output
    assert "1 could not be" in res.output, res.output
    fresh = tmp_path / "fresh"
    res = runner.invoke(app, ["study", str(TINY), "--out", str(fresh), "--recost", "none"])
    assert res.exit_code == 2 and "holds no study yet" in res.output and not fresh.exists()


@pytest.mark.parametrize("name", sorted(p.stem for p in (ROOT / "studies").glob("*.toml")))
def test_shipped_study_files_load(name):
    study = load_study(ROOT / "studies" / f"{name}.toml")
    assert study.name == name and cells_of(study)


def test_a_cell_with_an_internal_error_is_recorded_and_retried(tmp_path, monkeypatch):
    import mdgs.study.runner as runner_mod
    from mdgs.study import run_study

    path = _write(tmp_path, GOOD.replace('seeds = [0]', 'seeds = [0]\nlong_frames = 0\nsensitivity = 0')
                  + "\n[budget]\nepochs = 1\nmax_steps = 1\nbatch_size = 4\nvalid_max_pairs = 4\n"
                  + "[references]\nmujoco_dt_factors = [1]\n")
    study = load_study(path)
    real = runner_mod._run_cell

    def broken(study_, out, cell, progress, t0, wait=True):
        if cell.model == "constant-twist":
            raise RuntimeError("a bug in one cell")
        return real(study_, out, cell, progress, t0, wait)

    monkeypatch.setattr(runner_mod, "_run_cell", broken)
    res = run_study(study, tmp_path / "o")
    assert res["ran"] == 3  # the study went on past the broken cell
    lines = read_results(tmp_path / "o")
    bad = [ln for ln in lines if ln["status"] == "error"]
    assert len(bad) == 1 and "a bug in one cell" in bad[0]["reason"]
    monkeypatch.setattr(runner_mod, "_run_cell", real)
    res = run_study(study, tmp_path / "o")
    assert res["ran"] == 1  # only the errored cell is retried
    lines = read_results(tmp_path / "o")
    assert len(lines) == 3 and all(ln["status"] == "ok" for ln in lines)


def test_a_cell_whose_run_another_share_trains_goes_last_and_runs_once(tmp_path, monkeypatch):
    """While another share holds the learned cell's run (its lock), this share runs its other cells
    first and comes back to it, waiting only when it is the last cell left; each cell once."""
    import mdgs.study.runner as runner_mod
    from mdgs.runs import folder_lock
    from mdgs.study import run_study

    path = _write(tmp_path, GOOD.replace('seeds = [0]', 'seeds = [0, 1]\nlong_frames = 0\nsensitivity = 0')
                  + "\n[budget]\nepochs = 1\nmax_steps = 1\nbatch_size = 4\nvalid_max_pairs = 4\n"
                  + "[references]\nmujoco_dt_factors = [1]\n")
    study = load_study(path)
    learned = next(c for c in cells_of(study) if c.kind == "learned")  # seed 0; seed 1 follows it
    assert cells_of(study).index(learned) < len(cells_of(study)) - 1  # not last in the study's own order
    (tmp_path / "o").mkdir()
    (tmp_path / "o" / "study.json").write_text(json.dumps({"name": study.name}))  # another share made it
    run = tmp_path / "o" / "runs" / learned.key(study)
    held = folder_lock(run, "another share")
    lock = held.__enter__()
    real, calls = runner_mod._run_cell, []

    def spy(study_, out, cell, progress, t0, wait=True):
        calls.append((cell.kind, cell.seed, wait))
        if cell == learned and wait:  # the other share finishes: release the run
            held.__exit__(None, None, None)
        return real(study_, out, cell, progress, t0, wait)

    monkeypatch.setattr(runner_mod, "_run_cell", spy)
    res = run_study(study, tmp_path / "o")
    assert lock is not None and res["ran"] == len(cells_of(study))
    tries = [c for c in calls if c[:2] == ("learned", 0)]
    assert tries == [("learned", 0, False), ("learned", 0, True)] and calls[-1] == ("learned", 0, True)
    keys = [ln["cell"] for ln in read_results(tmp_path / "o")]
    assert keys[-1] == learned.key(study) and len(keys) == len(set(keys)) == len(cells_of(study))


def test_a_dataset_another_share_is_generating_is_waited_for_not_generated_twice(tmp_path, monkeypatch):
    """Two shares needing one dataset: while one holds its generation lock the other waits, then
    finds it made; generation runs once (two runs at once once removed a parts folder the other was
    still writing into, which failed a cell)."""
    import threading

    import mdgs.study.runner as runner_mod
    from mdgs.runs import LOCK_NAME, folder_lock

    study = load_study(_write(tmp_path, GOOD))
    sc = study.scenes[0]
    made = []

    class Done:
        merged = True

    monkeypatch.setattr(runner_mod, "generate", lambda cfg: made.append(cfg.out) or Done())
    monkeypatch.setattr(runner_mod, "DATA_WAIT_SECONDS", 0.02)
    out = tmp_path / "o"
    held = folder_lock(out / "data", "another share", name=f"{LOCK_NAME}-data-{sc.name}")
    held.__enter__()
    got = []
    waiter = threading.Thread(target=lambda: got.append(runner_mod._dataset(study, out, sc)))
    waiter.start()
    time.sleep(0.3)
    assert waiter.is_alive() and made == []  # waiting, not generating beside the other share
    held.__exit__(None, None, None)
    waiter.join(10)
    assert not waiter.is_alive() and got == [out / "data" / sc.name] and len(made) == 1


def test_processes_with_overlapping_shares_never_run_a_cell_twice(tmp_path, monkeypatch):
    """Another process holds cell b (its cell lock) while this one runs a, and finishes b meanwhile:
    this process defers b, then finds b's line and skips it; every cell has one line."""
    import mdgs.study.runner as runner_mod
    from mdgs.runs import LOCK_NAME, folder_lock
    from mdgs.study import run_study

    path = _write(tmp_path, GOOD.replace('seeds = [0]', 'seeds = [0]\nlong_frames = 0\nsensitivity = 0')
                  + "\n[budget]\nepochs = 1\nmax_steps = 1\nbatch_size = 4\nvalid_max_pairs = 4\n"
                  + "[references]\nmujoco_dt_factors = [1, 2]\n")
    study = load_study(path)
    out = tmp_path / "o"
    out.mkdir()
    (out / "study.json").write_text(json.dumps({"name": study.name}))
    a, b = cells_of(study)[:2]
    held = folder_lock(out, "another process", name=f"{LOCK_NAME}-cell-{b.key(study)}")
    held.__enter__()
    real, ran = runner_mod.run_cell, []

    def spy(study_, out_, cell, progress, wait=True):
        ran.append(cell.key(study))
        line = real(study_, out_, cell, progress, wait)
        if cell == a:  # meanwhile the other process finishes b and lets it go
            runner_mod._append(out_ / "results-3-of-4.jsonl", real(study_, out_, b, lambda e: None))
            held.__exit__(None, None, None)
        return line

    monkeypatch.setattr(runner_mod, "run_cell", spy)
    res = run_study(study, out)
    keys = [ln["cell"] for ln in read_results(out)]
    assert b.key(study) not in ran and ran[0] == a.key(study)
    assert sorted(keys) == sorted(c.key(study) for c in cells_of(study))  # each once
    assert res == {"cells": len(cells_of(study)), "done": 1, "ran": len(cells_of(study)) - 1}


def test_a_model_that_trains_as_another_shares_its_run(tmp_path):
    """sgnn-snap trains to sgnn's weights (the snap acts at rollout only): the study trains once."""
    text = GOOD.replace('[[models]]\nname = "mdgs"', '[[models]]\nname = "sgnn"\nset = { hidden = 8, p_step = 1 }\n'
                        '[[models]]\nname = "sgnn-snap"\nset = { hidden = 8, p_step = 1 }')
    text += "[budget]\nepochs = 1\nmax_steps = 2\nbatch_size = 2\nvalid_max_pairs = 8\n"
    text = text.replace("[study]", "[study]\nlong_frames = 0\nsensitivity = 0.0")
    study = load_study(_write(tmp_path, text))
    res = runner.invoke(app, ["study", str(study.path), "--out", str(tmp_path / "o"), "--no-report"])
    assert res.exit_code == 0, res.output
    lines = {ln["model"]: ln for ln in read_results(tmp_path / "o") if ln["kind"] == "learned"}
    assert lines["sgnn"]["status"] == lines["sgnn-snap"]["status"] == "ok"
    assert lines["sgnn-snap"]["train"]["trained_as"] == {"model": "sgnn", "cell": lines["sgnn"]["cell"]}
    assert [p.name for p in (tmp_path / "o" / "runs").iterdir()] == [lines["sgnn"]["cell"]]  # one run
    assert lines["sgnn"]["one_step_mse"] == lines["sgnn-snap"]["one_step_mse"]  # same weights, same one step
    assert lines["sgnn"]["sets"]["test"]["pos_mse_t40"] != lines["sgnn-snap"]["sets"]["test"]["pos_mse_t40"]


def test_a_selection_rule_trains_its_own_cells_and_says_which_epoch_it_evaluated(tmp_path):
    """[budget] select = "rollout": the learned cell's key differs from the same study's at "last"
    (another comparison), its line names the evaluated epoch, and that epoch is the run's lowest
    validation rollout score."""
    import dataclasses

    text = GOOD + "[budget]\nepochs = 3\nmax_steps = 2\nbatch_size = 2\nvalid_max_pairs = 8\nselect = \"rollout\"\n"
    text = text.replace("[study]", "[study]\nlong_frames = 0\nsensitivity = 0.0")
    study = load_study(_write(tmp_path, text))
    last = dataclasses.replace(study, budget=dataclasses.replace(study.budget, select="last"))
    learned = [c for c in cells_of(study) if c.kind == "learned"]
    assert [c.key(study) for c in learned] != [c.key(last) for c in learned]
    res = runner.invoke(app, ["study", str(study.path), "--out", str(tmp_path / "o"), "--no-report"])
    assert res.exit_code == 0, res.output
    (ln,) = [ln for ln in read_results(tmp_path / "o") if ln["kind"] == "learned"]
    hist = json.loads((tmp_path / "o" / "runs" / ln["cell"] / "metrics.json").read_text())
    assert ln["train"]["select"] == "rollout"
    assert ln["train"]["evaluated_epoch"] == min(hist, key=lambda h: h["valid_rollout"])["epoch"]


def test_a_model_revision_makes_its_cells_stale_and_no_others(monkeypatch):
    from mdgs.models import MODELS

    study = load_study(TINY)
    before = {c: c.key(study) for c in cells_of(study)}
    monkeypatch.setattr(MODELS["mdgs"], "revision", MODELS["mdgs"].revision + 1)
    changed = {c.model for c, k in before.items() if c.key(study) != k}
    # the variants inherit MDGS's revision (same code); the references and peers keep their keys
    assert "mdgs" in changed and changed <= {"mdgs", "mdgs-nc", "mdgs-sc"}
    assert any(c.model not in changed for c in before)


def test_a_forward_dynamics_revision_makes_only_the_cells_that_step_it_stale(monkeypatch):
    """Bumping ``mdgs.actuation.FORWARD_DYNAMICS_REVISION`` re-keys MDGS on the "dynamics" prior, GNS on the tree
    prior and the rigid-tree references, and nothing else (plain MDGS, constant twist, MuJoCo keep their keys); at
    revision 0 the keys are those of cells run before the revision existed (no ``revision`` for a
    reference)."""
    import mdgs.study.runner as study_runner
    from mdgs.study.runner import Cell

    study = load_study(TINY)
    sc = study.scenes[0]
    dyn = [Cell("reference", sc, "constant-twist", "rigid tree + joints", (("dynamics", True), ("joints", True))),
           Cell("learned", sc, "mdgs", "mdgs + dynamics prior", (("actuation", "dynamics"),)),
           Cell("learned", sc, "gns", "gns + tree prior", (("prior", "tree"),))]
    other = [Cell("learned", sc, "mdgs", "mdgs + motor prior", (("actuation", "prior"),)),
             Cell("learned", sc, "gns", "gns, no noise", (("noise_std", 0.0),)), *cells_of(study)]
    now = study_runner.FORWARD_DYNAMICS_REVISION
    assert dyn[0].spec(study)["revision"] == now >= 1
    monkeypatch.setattr(study_runner, "FORWARD_DYNAMICS_REVISION", 0)
    assert "revision" not in dyn[0].spec(study)
    before = {c: c.key(study) for c in dyn + other}
    monkeypatch.setattr(study_runner, "FORWARD_DYNAMICS_REVISION", 1)
    assert [c for c in before if c.key(study) != before[c]] == dyn
    assert dyn[0].spec(study)["revision"] == 1


def test_a_soft_contact_revision_makes_only_the_soft_contact_cells_stale(monkeypatch):
    """Bumping ``mdgs.actuation.SOFT_CONTACT_REVISION`` re-keys the rigid tree with ``contact = "soft"`` and MDGS with
    ``prior_contact = "soft"``, GNS on the tree prior (whose contact is soft unless set), not the rigid-contact tree,
    MDGS or GNS on it, plain GNS (whose unused ``prior_contact`` defaults to "soft") or anything else."""
    import mdgs.study.runner as study_runner
    from mdgs.study.runner import Cell

    study = load_study(TINY)
    sc = study.scenes[0]
    soft = [Cell("reference", sc, "constant-twist", "soft tree", (("contact", "soft"), ("dynamics", True))),
            Cell("learned", sc, "mdgs", "mdgs + soft tree", (("actuation", "dynamics"), ("prior_contact", "soft"))),
            Cell("learned", sc, "gns", "gns + soft tree", (("prior", "tree"),))]
    rigid = [Cell("reference", sc, "constant-twist", "rigid tree + joints", (("dynamics", True), ("joints", True))),
             Cell("learned", sc, "mdgs", "mdgs + dynamics prior", (("actuation", "dynamics"),)),
             Cell("learned", sc, "gns", "gns + rigid tree", (("prior", "tree"), ("prior_contact", "rigid"))),
             Cell("learned", sc, "gns", "gns", ()), *cells_of(study)]
    now = study_runner.SOFT_CONTACT_REVISION
    assert now >= 1
    assert soft[0].spec(study)["revision"] == study_runner.FORWARD_DYNAMICS_REVISION + now
    monkeypatch.setattr(study_runner, "SOFT_CONTACT_REVISION", 0)
    before = {c: c.key(study) for c in soft + rigid}
    monkeypatch.setattr(study_runner, "SOFT_CONTACT_REVISION", now)
    assert [c for c in before if c.key(study) != before[c]] == soft


def test_sensitivity_lines_of_revision_0_give_way_to_those_measured_on_the_long_set(tmp_path):
    """Sensitivity cells of revision 0 were evaluated on the test set only; a folder holding them beside
    revision-1 lines (test and long sets) tables only the new ones, and the cells' keys changed, so a
    rerun of an old study measures them again instead of keeping the old lines."""
    study = load_study(TINY)
    sens = [c for c in cells_of(study) if c.kind == "sensitivity"]
    assert sens and all(c.spec(study)["revision"] == 1 for c in sens)
    assert all("revision" not in c.spec(study) for c in cells_of(study) if c.kind == "reference")
    base = {"kind": "sensitivity", "scene": "s", "model": "mujoco", "label": "sensitivity floor", "seed": 0,
            "refine": 1, "preset": "tiny", "status": "ok",
            "settings": {"dt_factor": 1, "noise_seed": 0, "velocity_noise": 1e-3}}
    old = [{**base, "cell": "a"}, {**base, "cell": "b", "seed": 1}]
    new = {**base, "cell": "c", "revision": 1}
    (tmp_path / "results.jsonl").write_text("".join(json.dumps(x) + "\n" for x in (*old, new)))
    assert [ln["cell"] for ln in read_results(tmp_path)] == ["c"]


def test_report_keeps_only_the_newest_revision_of_a_row(tmp_path):
    """A folder holding a row's lines from before and after its model's revision bump tables only the
    new revision's: the rerun seed 0, not seed 1 of the old revision beside it (a mean over two
    versions of the model); another row with only old lines keeps them."""
    base = {"kind": "learned", "scene": "s", "model": "mdgs", "label": "mdgs", "settings": {}, "seed": 0,
            "refine": 1, "preset": "tiny", "status": "ok"}
    old = {**base, "cell": "a", "one_step_mse": 1.0}
    new = {**base, "cell": "b", "revision": 1, "one_step_mse": 2.0}
    stale = {**base, "cell": "c", "seed": 1, "one_step_mse": 3.0}  # same row, old revision: dropped
    other = {**base, "cell": "d", "label": "mdgs hidden 50", "seed": 1}  # another row, old only: kept
    (tmp_path / "results.jsonl").write_text("".join(json.dumps(x) + "\n" for x in (old, new, stale, other)))
    assert sorted(ln["cell"] for ln in read_results(tmp_path)) == ["b", "d"]
    # the identity the report uses is every key of a cell's spec but its revision
    import dataclasses

    from mdgs.study.runner import _SPEC_KEYS

    study = dataclasses.replace(load_study(TINY), trajectories=12)  # every optional key present
    assert {k for c in cells_of(study) for k in c.spec(study)} - {"revision"} == set(_SPEC_KEYS)


def _line(kind, model, label, seed, t40, t110, ms, settings=None):
    return {"kind": kind, "scene": "s", "model": model, "label": label, "settings": settings or {}, "seed": seed,
            "status": "ok", "cost": {"single": {"ms_per_frame": ms}},
            "sets": {"test": {"trajectories": len(t40), "pos_mse_t40": t40, "pos_mse_t110": t110}}}


def test_who_wins_names_the_front_the_winners_and_the_coarsest_mujoco_that_beats_them():
    """A learned row that beats constant twist on both horizons but costs more than MuJoCo at its own
    timestep is a winner among learned rows and off the Pareto front; a row that failed on one
    trajectory is never the best, however low its mean; the coarsest MuJoCo as accurate as the best
    learned row is named (x2; x5 is not: 1.5 > 1.0)."""
    from mdgs.study.tables import _verdict_table

    lines = [_line("reference", "constant-twist", "constant twist", 0, [1.0, 1.0], [2.0, 2.0], 0.4),
             _line("reference", "mujoco", "mujoco dt x1", 0, [1e-6, 1e-6], [1e-5, 1e-5], 0.1, {"dt_factor": 1}),
             _line("reference", "mujoco", "mujoco dt x2", 0, [0.1, 0.1], [0.5, 0.5], 0.05, {"dt_factor": 2}),
             _line("reference", "mujoco", "mujoco dt x5", 0, [0.1, 0.1], [1.5, 1.5], 0.02, {"dt_factor": 5})]
    lines += [_line("learned", "a", "a", s, [0.5, 0.5], [1.0, 1.0], 1.0) for s in (0, 1)]
    lines += [_line("learned", "b", "b", s, [0.4, None], [0.3, None], 1.0) for s in (0, 1)]
    t = _verdict_table(lines)
    (row,) = t.rows
    assert row[1] == "mujoco dt x5, mujoco dt x2, mujoco dt x1"  # by cost; a and b are dominated or failed
    assert row[2].startswith("a: 500 (0.5x") and row[3].startswith("a: 1e+03 (0.5x")  # in 10^-3 m^2
    assert row[4] == "a"
    assert row[5].startswith("mujoco dt x2 ")  # x1 is as accurate too, but finer


def test_a_row_with_fewer_seeds_than_the_others_is_shown_as_partial_and_never_ranked():
    """A learned row that has run one seed where the others ran two (a row still running) has the lowest mean,
    yet it is not bold in Table 1's layout, its cells say "[1 of 2 seeds]", and "Who wins" names the complete
    row as the best learned one."""
    from mdgs.study.tables import _model_table, _verdict_table

    lines = [_line("reference", "constant-twist", "constant twist", 0, [1.0, 1.0], [2.0, 2.0], 0.4)]
    lines += [_line("learned", "a", "a", s, [0.5, 0.5], [1.0, 1.0], 1.0) for s in (0, 1)]
    lines += [_line("learned", "b", "b", 0, [0.1, 0.1], [0.2, 0.2], 1.0)]
    table = _model_table("Table", lines, ["s"])[0]
    a, b = table.rows[0], table.rows[1]
    assert a[1].startswith("**") and not b[1].startswith("**") and "<u>" not in b[1]
    assert b[1].endswith("[1 of 2 seeds]") and b[2].endswith("[1 of 2 seeds]") and "seeds]" not in a[1]
    (row,) = _verdict_table(lines).rows
    assert row[2].startswith("a: ") and row[3].startswith("a: ") and row[4] == "a"


def _committed_small_tables():
    folder = Path(__file__).resolve().parents[1] / "docs" / "results" / "small"
    return {t.title: t for t in build_tables(read_results(folder, usable=True))}


def test_committed_small_study_has_no_table_4_repeating_table_1():
    """Every learned row is in Table 1, whose scenes hold Table 4's: a Table 4 there would repeat Table 1
    row for row, so it is left out (it was once drawn as an identical copy)."""
    tables = _committed_small_tables()
    assert "Table 1" in tables
    assert not [title for title in tables if title.startswith("Table 4")]


@pytest.mark.parametrize("title", ["Stability", "Speed"])
def test_stability_and_speed_rows_group_references_before_learned_rows_per_scene(title):
    """Per scene (in study order): every reference row (the default partition's, then each finer
    partition's, MuJoCo by timestep factor within each), then the learned rows in Table 1's order."""
    tables = _committed_small_tables()
    rows = tables[title].rows
    learned_order = [r[0] for r in tables["Table 1"].rows if not r[0].endswith("(reference)")]
    learned_order = [re.sub(r"\*\*|</?u>", "", x) for x in learned_order]
    scenes = []
    for r in rows:
        if r[0] not in scenes:
            scenes.append(r[0])
    assert [r[0] for r in rows] == sorted((r[0] for r in rows), key=scenes.index)  # one block per scene
    for sc in scenes:
        labels = [r[1] for r in rows if r[0] == sc]
        is_learned = [lbl in learned_order for lbl in labels]
        assert is_learned == sorted(is_learned), (title, sc, labels)  # references, then learned
        learned = [lbl for lbl in labels if lbl in learned_order]
        assert learned == sorted(learned, key=learned_order.index), (title, sc, learned)
        refs = [lbl for lbl in labels if lbl not in learned_order]
        parts = [int(lbl.partition(" refine ")[2] or 1) for lbl in refs]
        assert parts == sorted(parts), (title, sc, refs)
        for part in set(parts):
            mujoco = [int(lbl.partition(" refine ")[0].split("x")[-1]) for lbl, q in zip(refs, parts, strict=True)
                      if q == part and lbl.startswith("mujoco dt x")]
            assert mujoco == sorted(mujoco), (title, sc, part, mujoco)


def test_only_runs_the_named_rows_and_scenes_and_the_whole_study_counts_them_finished(tmp_path):
    """--only runs a selection of cells (row labels, scene names) into a results file of its own; the
    same cells are then finished for any other selection and for the whole study (keys do not depend
    on the selection); a name that is neither a row nor a scene is one clear error, exit 2."""
    from mdgs.study import run_study
    from mdgs.study.runner import select_cells

    path = _write(tmp_path, GOOD.replace('seeds = [0]', 'seeds = [0]\nlong_frames = 0\nsensitivity = 0')
                  + "\n[budget]\nepochs = 1\nmax_steps = 1\nbatch_size = 4\nvalid_max_pairs = 4\n"
                  + "[references]\nmujoco_dt_factors = [1, 2]\n")
    study = load_study(path)
    out = tmp_path / "o"
    res = run_study(study, out, only=("mujoco dt x2",))
    assert (res["cells"], res["ran"]) == (1, 1)
    assert [ln["label"] for ln in read_results(out)] == ["mujoco dt x2"]
    assert not (out / "results.jsonl").exists() and len(list(out.glob("results-only-*.jsonl"))) == 1
    # a row and a scene combine (row AND scene); the cell already run is not run again
    res = run_study(study, out, only=("mujoco dt x1", "mujoco dt x2", "cubli-single"))
    assert (res["cells"], res["done"], res["ran"]) == (2, 1, 1)
    assert [c.label for c in select_cells(study, ("cubli-single",))] == [c.label for c in cells_of(study)]
    res = run_study(study, out)  # the whole study: only the two cells never selected run
    assert (res["cells"], res["ran"]) == (len(cells_of(study)), 2)
    assert sorted(ln["label"] for ln in read_results(out)) == ["constant twist", "mdgs", "mujoco dt x1", "mujoco dt x2"]
    with pytest.raises(StudyError, match="names no row or scene.*rows: constant twist, mujoco dt x1"):
        select_cells(study, ("mujoco dt x3",))
    for extra, phrase in [(["--only", "gnss"], "'gnss' names no row or scene"),
                          (["--only", "mdgs", "--recost", "aot"], "leave out --cells and --only")]:
        res = runner.invoke(app, ["study", str(path), "--out", str(out), "--no-report", *extra])
        assert res.exit_code == 2 and phrase in res.output and "Traceback" not in res.output, res.output


def test_speed_chart_marks_learned_rows_whose_recosted_step_ran_eagerly(tmp_path):
    """After --recost, a learned row whose step did not compile is timed eagerly: the chart draws it
    as a square (its cost is not comparable to a compiled row's at face value); rows timed while the
    study ran (no recost) and references are never marked; the chart is still drawn."""
    from mdgs.study.charts import _eager_rows, speed_accuracy

    lines = [_line("reference", "constant-twist", "constant twist", 0, [1.0], [2.0], 0.4),
             _line("learned", "a", "a", 0, [0.5], [1.0], 1.0), _line("learned", "b", "b", 0, [0.5], [1.0], 9.0),
             _line("learned", "c", "c", 0, [0.5], [1.0], 9.0)]
    for ln, mode in zip(lines, ["none", "aot", "none", None], strict=True):
        if mode:
            ln["cost"].update(recost=True, compiled=mode, requested="aot")
    assert _eager_rows(lines, "s") == {"b"}
    speed_accuracy(lines, tmp_path / "chart")
    assert (tmp_path / "chart.png").stat().st_size > 0


def test_resolution_cells_refine_a_named_row_with_its_settings_and_report_its_stability(tmp_path):
    """[resolution] model may name a [[models]] row: its cells train that row's model with its settings
    at each refinement (label "<row> refine <r>"); a name that is neither a registry model nor a row is
    one clear error. The Resolution table sets them beside the study's own row of that label (refine 1)
    and, where the cells ran the long set, counts the trajectories that never failed."""
    from mdgs.study.charts import _styles
    from mdgs.study.tables import _resolution_table

    text = GOOD + '[[models]]\nname = "mdgs"\nlabel = "mdgs + motor prior"\nset = { actuation = "prior" }\n'
    study = load_study(_write(tmp_path, text + '[resolution]\nmodel = "mdgs + motor prior"\nrefine = [2]\nseeds = [0, 1]\n'))
    res = [c for c in cells_of(study) if c.kind == "resolution"]
    assert [(c.model, c.label, dict(c.settings), c.seed, c.refine) for c in res] == [
        ("mdgs", "mdgs + motor prior refine 2", {"actuation": "prior"}, s, 2) for s in (0, 1)]
    plain = load_study(_write(tmp_path, GOOD + '[resolution]\nmodel = "mdgs"\nrefine = [2]\n'))
    (cell,) = [c for c in cells_of(plain) if c.kind == "resolution"]
    assert (cell.label, cell.settings) == ("mdgs refine 2", ())  # the key of studies run before rows could be named
    with pytest.raises(StudyError, match="neither a model of the registry nor the label"):
        load_study(_write(tmp_path, text + '[resolution]\nmodel = "mdgs + prior"\nrefine = [2]\n'))

    def line(label, kind, refine, ttf):
        ln = _line(kind, "mdgs", label, 0, [1.0], [2.0], 0.5)
        ln.update(refine=refine, parameters=10, sets={**ln["sets"], "long": {"time_to_failure": ttf}})
        return ln
    lines = [line("mdgs + motor prior", "learned", 1, [None, 5]), line("mdgs", "learned", 1, [None, None]),
             line("mdgs + motor prior refine 2", "resolution", 2, [None, None])]
    t = _resolution_table(lines)
    assert [(r[1], r[-1]) for r in t.rows] == [("1", "1/2"), ("2", "2/2")]  # plain mdgs is not the base row
    assert _styles(lines)["mdgs + motor prior refine 2"]["ls"] == "-"  # the charts draw resolution rows in colour


def test_finer_partitions_get_their_own_references_and_the_resolution_ratio_uses_them(tmp_path):
    """Position MSE averages over element centroids, so a refine-2 row is divided by the constant-twist
    reference on refine-2 nodes: the study adds every reference at each [resolution] refinement (cells
    of refine 2, labels ending in " refine 2", default cells' keys unchanged), the Resolution table's
    ratio uses the reference of the row's own partition, and the paper tables leave the refined
    references out."""
    from mdgs.study.tables import _reference_order, _resolution_table, build_tables

    text = GOOD + "[references]\nmotors = true\nmujoco_dt_factors = [10]\n"
    plain = load_study(_write(tmp_path, text))
    study = load_study(_write(tmp_path, text + '[resolution]\nmodel = "mdgs"\nrefine = [2]\n'))
    assert {c.key(plain) for c in cells_of(plain)} <= {c.key(study) for c in cells_of(study)}
    refined = [(c.kind, c.label, c.refine) for c in cells_of(study) if c.refine == 2]
    assert refined == [("resolution", "mdgs refine 2", 2), ("reference", "constant twist refine 2", 2),
                       ("reference", "constant twist + motors refine 2", 2), ("reference", "mujoco dt x10 refine 2", 2)]
    keys = [c.key(plain) for c in cells_of(plain)]  # appended last: earlier cells keep their index (their share)
    assert [c.key(study) for c in cells_of(study)][:len(keys)] == keys
    assert sorted(["mujoco dt x10 refine 2", "constant twist refine 2", "mujoco dt x2", "constant twist"],
                  key=_reference_order) == ["constant twist", "mujoco dt x2", "constant twist refine 2",
                                            "mujoco dt x10 refine 2"]

    def line(kind, model, label, refine, v):
        ln = _line(kind, model, label, 0, [v, v], [2 * v, 2 * v], 0.5)
        ln.update(refine=refine, parameters=10, train={})
        ln["cost"]["batched"] = {"ms_per_trajectory_frame": 0.1, "batch": 2}
        return ln
    lines = [line("reference", "constant-twist", "constant twist", 1, 4.0),
             line("reference", "constant-twist", "constant twist refine 2", 2, 8.0),
             line("learned", "mdgs", "mdgs", 1, 2.0), line("resolution", "mdgs", "mdgs refine 2", 2, 2.0)]
    t = _resolution_table(lines)
    col = t.header.index("x constant twist, same partition, t=40")
    assert [(r[1], r[col]) for r in t.rows] == [("1", "0.5"), ("2", "0.25")]  # 2 / 4 and 2 / 8, not 2 / 4 twice
    table1 = next(t for t in build_tables(lines) if t.title == "Other scenes")
    assert [r[0] for r in table1.rows] == ["mdgs", "constant twist (reference)"]
    assert _resolution_table(lines[:1] + lines[2:]).rows[1][col] == "-"  # no refine-2 reference yet: no ratio


def test_rigid_tree_momentum_adds_the_last_rigid_tree_row_projected_by_impulses(tmp_path):
    """``[references] rigid_tree_momentum = true`` adds, per scene, the last rigid-tree row with its twists projected
    onto the joints by impulses (``ConstantTwistConfig.joint_velocities = "momentum"``), labelled as the reference
    names itself; it needs ``rigid_tree`` and ``joints``. MDGS takes the rule for its prior's tree only with
    substeps and joints."""
    from mdgs.evaluate import reference_label

    base = GOOD + ("[references]\njoints = true\nrigid_tree = true\nrigid_tree_trapezoidal = true\n"
                   "rigid_tree_push_out = true\nrigid_tree_substeps = [4]\n")
    study = load_study(_write(tmp_path, base))
    more = load_study(_write(tmp_path, base + "rigid_tree_momentum = true\n"))
    new = [c for c in cells_of(more) if c.key(more) not in {k.key(study) for k in cells_of(study)}]
    assert {c.label for c in new} == {"rigid tree + joints, trapezoidal, push-out, 4 substeps, momentum projection"}
    assert len(new) == len(study.scenes)
    ct = MODELS["constant-twist"]
    for c in new:
        assert reference_label(ct(ct.Config(**dict(c.settings)))) == c.label
    with pytest.raises(StudyError, match="set rigid_tree = true and joints = true"):
        load_study(_write(tmp_path, GOOD + "[references]\nrigid_tree = true\nrigid_tree_momentum = true\n"))
    md = MODELS["mdgs"]
    md.Config(actuation="dynamics", prior_substeps=4, joint_velocities="momentum")
    with pytest.raises(ValueError, match="prior_substeps above 1 and joints = true"):
        md.Config(actuation="dynamics", joint_velocities="momentum")
    with pytest.raises(ValueError, match="prior_substeps above 1 and joints = true"):
        md.Config(actuation="dynamics", prior_substeps=4, joints=False, joint_velocities="momentum")


def test_rigid_tree_coordinates_adds_the_last_rigid_tree_row_stepped_in_joint_coordinates(tmp_path):
    """``[references] rigid_tree_coordinates = true`` adds, per scene, the last rigid-tree row (not the momentum one)
    stepped in its joint coordinates (``ConstantTwistConfig.joint_velocities = "coordinates"``), labelled as the
    reference names itself; it needs ``rigid_tree`` and ``joints``."""
    from mdgs.evaluate import reference_label

    base = GOOD + ("[references]\njoints = true\nrigid_tree = true\nrigid_tree_trapezoidal = true\n"
                   "rigid_tree_push_out = true\nrigid_tree_substeps = [4]\nrigid_tree_momentum = true\n")
    study = load_study(_write(tmp_path, base))
    more = load_study(_write(tmp_path, base + "rigid_tree_coordinates = true\n"))
    new = [c for c in cells_of(more) if c.key(more) not in {k.key(study) for k in cells_of(study)}]
    assert {c.label for c in new} == {"rigid tree + joints, trapezoidal, push-out, 4 substeps, joint coordinates"}
    assert len(new) == len(study.scenes)
    ct = MODELS["constant-twist"]
    for c in new:
        assert reference_label(ct(ct.Config(**dict(c.settings)))) == c.label
    with pytest.raises(StudyError, match="set rigid_tree = true and joints = true"):
        load_study(_write(tmp_path, GOOD + "[references]\nrigid_tree = true\nrigid_tree_coordinates = true\n"))


def test_rigid_tree_soft_adds_the_last_rigid_tree_row_with_soft_contact_in_place_of_push_out(tmp_path):
    """``[references] rigid_tree_soft = true`` adds, per scene, the last rigid-tree row (not the momentum one) with
    MuJoCo's soft contact (``ConstantTwistConfig.contact = "soft"``) and without the push-out that would undo it,
    labelled as the reference names itself; it needs ``rigid_tree``."""
    from mdgs.evaluate import reference_label

    base = GOOD + ("[references]\njoints = true\nrigid_tree = true\nrigid_tree_trapezoidal = true\n"
                   "rigid_tree_push_out = true\nrigid_tree_substeps = [4]\nrigid_tree_momentum = true\n"
                   "rigid_tree_coordinates = true\n")
    study = load_study(_write(tmp_path, base))
    more = load_study(_write(tmp_path, base + "rigid_tree_soft = true\n"))
    new = [c for c in cells_of(more) if c.key(more) not in {k.key(study) for k in cells_of(study)}]
    assert {c.label for c in new} == {"rigid tree + joints, trapezoidal, 4 substeps, joint coordinates, soft contact"}
    assert len(new) == len(study.scenes)
    ct = MODELS["constant-twist"]
    for c in new:
        assert dict(c.settings)["contact"] == "soft" and "push_out" not in dict(c.settings)
        assert reference_label(ct(ct.Config(**dict(c.settings)))) == c.label
    with pytest.raises(StudyError, match="set rigid_tree = true with it"):
        load_study(_write(tmp_path, GOOD + "[references]\nrigid_tree_soft = true\n"))


def test_rigid_tree_gyroscopic_adds_the_last_rigid_tree_row_with_each_rule_of_the_gyroscopic_terms(tmp_path):
    """``[references] rigid_tree_gyroscopic = ["implicit", "midpoint"]`` adds, per scene, the last rigid-tree row with
    each rule (``ConstantTwistConfig.gyroscopic``), labelled as the reference names itself; the other cells keep
    their keys; it needs ``rigid_tree`` and known, distinct rules."""
    from mdgs.evaluate import reference_label

    base = GOOD + ("[references]\njoints = true\nrigid_tree = true\nrigid_tree_trapezoidal = true\n"
                   "rigid_tree_push_out = true\nrigid_tree_substeps = [4]\n")
    study = load_study(_write(tmp_path, base))
    more = load_study(_write(tmp_path, base + 'rigid_tree_gyroscopic = ["implicit", "midpoint"]\n'))
    new = [c for c in cells_of(more) if c.key(more) not in {k.key(study) for k in cells_of(study)}]
    last = "rigid tree + joints, trapezoidal, push-out, 4 substeps"
    assert {c.label for c in new} == {f"{last}, implicit gyroscopic", f"{last}, midpoint gyroscopic"}
    assert len(new) == 2 * len(study.scenes)
    ct = MODELS["constant-twist"]
    for c in new:
        assert reference_label(ct(ct.Config(**dict(c.settings)))) == c.label
    for bad in ('rigid_tree_gyroscopic = ["sideways"]\n', 'rigid_tree_gyroscopic = ["explicit"]\n',
                'rigid_tree_gyroscopic = ["implicit", "implicit"]\n'):
        with pytest.raises(StudyError, match="rigid_tree_gyroscopic"):
            load_study(_write(tmp_path, base + bad))
    with pytest.raises(StudyError, match="set rigid_tree = true"):
        load_study(_write(tmp_path, GOOD + '[references]\nrigid_tree_gyroscopic = ["implicit"]\n'))
