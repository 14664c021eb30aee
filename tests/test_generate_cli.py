"""``mdgs generate``: determinism, resume, shards, user MJCF files and input errors."""

from __future__ import annotations

import hashlib
from pathlib import Path

import pytest
from typer.testing import CliRunner

from mdgs.cli import app
from mdgs.data.generate import GenerateConfig, _part_path, generate, plan
from mdgs.data.presets import PRESETS
from mdgs.scenes import SCENES
from validation.data_checks import check_dataset

runner = CliRunner()


def _digest(out: Path) -> dict[str, str]:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(out.glob("*.h5"))}


def _cli(*args: str):
    return runner.invoke(app, ["generate", *args])


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> dict[str, str]:
    out = tmp_path_factory.mktemp("ref") / "ds"
    res = _cli("cubli-single", "--out", str(out), "--preset", "tiny", "--seed", "3")
    assert res.exit_code == 0, res.output
    return _digest(out)


def test_tiny_generation_is_bit_identical_by_seed_and_across_workers(reference, tmp_path):
    res = _cli(
        "cubli-single",
        "--out",
        str(tmp_path / "b"),
        "--preset",
        "tiny",
        "--seed",
        "3",
        "--workers",
        "2",
    )
    assert res.exit_code == 0, res.output
    assert _digest(tmp_path / "b") == reference
    assert set(reference) == {"train.h5", "valid.h5", "test.h5"}
    other = _cli("cubli-single", "--out", str(tmp_path / "c"), "--preset", "tiny", "--seed", "4")
    assert other.exit_code == 0 and _digest(tmp_path / "c") != reference


def test_resume_after_interruption_gives_the_uninterrupted_file(reference, tmp_path):
    """A run killed midway leaves whole parts (atomic writes) and maybe a temporary file;
    rerunning the command finishes the dataset bit-identical to an uninterrupted run."""
    out = tmp_path / "r"
    cfg = GenerateConfig(scene="cubli-single", out=str(out), preset="tiny", seed=3, shard=(0, 2))
    first = generate(cfg)  # half of the batches, as if interrupted
    assert not first.merged and first.trajectories > 0
    jobs = plan(PRESETS["tiny"].counts(SCENES["cubli-single"].splits), PRESETS["tiny"].batch)
    done = [j for j in jobs if _part_path(out, *j).exists()]
    assert 0 < len(done) < len(jobs)
    # debris of a killed writer: a temporary file next to a part
    (_part_path(out, *done[0]).parent / ".junk.h5.tmp123").write_bytes(b"partial")
    res = _cli("cubli-single", "--out", str(out), "--preset", "tiny", "--seed", "3")
    assert res.exit_code == 0, res.output
    assert _digest(out) == reference
    assert not (out / ".parts").exists()


def test_shards_merge_into_the_same_dataset(reference, tmp_path):
    out = tmp_path / "s"
    for i in range(3):
        res = _cli(
            "cubli-single",
            "--out",
            str(out),
            "--preset",
            "tiny",
            "--seed",
            "3",
            "--shard",
            f"{i}/3",
        )
        assert res.exit_code == 0, res.output
    assert _digest(out) == reference


def test_settings_mismatch_in_the_same_out_is_refused(reference, tmp_path):
    out = tmp_path / "m"
    assert _cli("cubli-single", "--out", str(out), "--seed", "3").exit_code == 0
    res = _cli("cubli-single", "--out", str(out), "--seed", "5")
    assert res.exit_code == 2 and "different settings" in res.stderr


@pytest.mark.parametrize(
    "args, message",
    [
        (["nope", "--out", "x"], "unknown scene 'nope'"),
        (["cubli-single"], "--out DIR is required"),
        (["cubli-single", "--out", "x", "--preset", "huge"], "unknown preset 'huge'"),
        (["cubli-single", "--out", "x", "--shard", "2"], "--shard '2' is not of the form I/N"),
        (["cubli-single", "--out", "x", "--workers", "0"], "--workers 0 must be at least 1"),
        (["--mjcf", "missing.xml", "--out", "x"], "--mjcf missing.xml does not exist"),
        (["--out", "x"], "name a SCENE"),
    ],
)
def test_bad_input_is_one_sentence_on_stderr_and_exit_2(args, message, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    res = _cli(*args)
    assert res.exit_code == 2
    assert message in res.stderr
    assert len(res.stderr.strip().splitlines()) == 1 and "Traceback" not in res.output


def test_list_shows_every_scene():
    res = _cli("--list")
    assert res.exit_code == 0
    assert all(name in res.stdout for name in SCENES)


USER_MJCF = """<mujoco>
  <option timestep="0.001" integrator="implicitfast"/>
  <asset><mesh name="wedge" vertex="0 0 0  .2 0 0  0 .2 0  0 0 .1  .2 0 .1  0 .2 .1"/></asset>
  <worldbody>
    <geom type="plane" size="2 2 .1"/>
    <body name="base" pos="0 0 .1"><freejoint/>
      <geom type="box" size=".1 .1 .05"/>
      <body name="arm" pos="0 0 .05"><joint name="j" axis="0 1 0" damping="0.01"/>
        <geom type="capsule" fromto="0 0 0 0 0 .2" size=".02"/>
        <body name="tip" pos="0 0 .2"><joint name="k" axis="1 0 0"/><geom type="mesh" mesh="wedge"/></body>
      </body>
    </body>
  </worldbody>
  <actuator><motor joint="j" ctrlrange="-1 1"/><position joint="k" kp="2"/></actuator>
</mujoco>
"""


def test_user_mjcf_generates_and_the_claims_hold(tmp_path):
    f = tmp_path / "robot.xml"
    f.write_text(USER_MJCF)
    res = _cli("--mjcf", str(f), "--out", str(tmp_path / "u"), "--preset", "tiny")
    assert res.exit_code == 0, res.output
    results = check_dataset(tmp_path / "u" / "train.h5")
    assert {r["claim_id"] for r in results} >= {"newton"}
    for r in results:
        if r["claim_id"] in ("newton", "eq11.corrected"):
            assert r["verdict"] == "holds", r


def test_unsupported_user_mjcf_is_refused_with_the_reason(tmp_path):
    f = tmp_path / "eq.xml"
    f.write_text(
        USER_MJCF.replace(
            "</actuator>",
            '</actuator><equality><connect body1="tip" body2="world" anchor="0 0 .4"/></equality>',
        )
    )
    res = _cli("--mjcf", str(f), "--out", str(tmp_path / "u"))
    assert res.exit_code == 2 and "equality constraints" in res.stderr


@pytest.mark.parametrize("name", list(SCENES))
def test_every_scene_generates_tiny_and_its_claims_hold(name, tmp_path):
    res = _cli(name, "--out", str(tmp_path), "--preset", "tiny")
    assert res.exit_code == 0, res.output
    for split in SCENES[name].splits:
        results = check_dataset(tmp_path / f"{split}.h5")
        assert {r["claim_id"] for r in results} >= {"newton"}
        for r in results:
            if r["claim_id"] in (
                "newton",
                "eq11.corrected",
            ):  # loads vs MuJoCo's accelerations, nine digits
                assert r["verdict"] == "holds", r


def test_shards_on_two_machines_sharing_only_the_output_folder(tmp_path, monkeypatch):
    """Two shards on two hosts (MDGS_HOST stands for the machine's name) that share only the folder:
    neither judges the other's temporaries by process id, and the merged files equal one process's."""
    import subprocess
    import sys

    import h5py
    import numpy as np

    single, shared = tmp_path / "single", tmp_path / "shared"
    generate(GenerateConfig(scene="cubli-single", out=str(single), preset="tiny"))
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()  # a process id that no longer exists here
    shared.mkdir()
    foreign = shared / f".valid.h5.tmp{dead.pid}-machine-b"  # machine b's writer, alive on machine b
    foreign.write_bytes(b"in progress on another machine")
    monkeypatch.setenv("MDGS_HOST", "machine-a")
    r0 = generate(GenerateConfig(scene="cubli-single", out=str(shared), preset="tiny", shard=(0, 2)))
    assert not r0.merged and foreign.exists()  # machine a leaves machine b's temporary alone
    monkeypatch.setenv("MDGS_HOST", "machine-b")  # on machine b that writer has died: its rerun cleans up
    r1 = generate(GenerateConfig(scene="cubli-single", out=str(shared), preset="tiny", shard=(1, 2)))
    assert r1.merged and not foreign.exists()
    for split in ("train", "valid", "test"):
        with h5py.File(single / f"{split}.h5") as a, h5py.File(shared / f"{split}.h5") as b:
            for name in a["frames"]:
                np.testing.assert_array_equal(a["frames"][name][()], b["frames"][name][()], err_msg=name)


def test_a_batch_finished_after_another_run_merged_the_split_is_not_an_error(reference, tmp_path, monkeypatch):
    """Two runs on one OUT (e.g. two shares of a study) both simulate a batch; the one that merges
    removes the parts folder while the other is still writing its part: that write finding its folder
    gone is not an error when the merged split exists (the batch is in it), and the dataset is whole.
    Without the merged split the same failure is still raised."""
    import importlib
    import shutil

    gen = importlib.import_module("mdgs.data.generate")  # the module (mdgs.data's `generate` is the function)

    out = tmp_path / "ds"
    cfg = GenerateConfig(scene="cubli-single", out=str(out), preset="tiny", seed=3)
    generate(cfg)
    assert _digest(out) == reference and not (out / ".parts").exists()
    real = gen.write_file

    def merged_meanwhile(path, *a, **kw):  # the other run removes the parts folder mid-write
        shutil.rmtree(Path(path).parent.parent, ignore_errors=True)
        return real(path, *a, **kw)

    monkeypatch.setattr(gen, "write_file", merged_meanwhile)
    gen._worker_init(cfg)
    job = plan(PRESETS["tiny"].counts(SCENES["cubli-single"].splits), PRESETS["tiny"].batch)[0]
    attrs = {"seed": 3, "n_frames": 3, "preset": "tiny", "config_sha256": "x", "mdgs_version": "x"}
    assert gen._run_job(job, attrs)[:3] == job
    assert _digest(out) == reference
    (out / f"{job[0]}.h5").unlink()  # no merged split: the vanished folder is a real failure
    with pytest.raises(FileNotFoundError):
        gen._run_job(job, attrs)
