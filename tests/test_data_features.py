"""MJCF features at generation: each is recorded faithfully or refused in one sentence.

A walk over a list of small MJCF models, one feature each (includes and relative assets,
tendons spatial and fixed, limits, damping, equality constraints, fluid forces, planar
models, no moving body, many contacts). For each, ``generate`` (tiny preset) either
refuses with a :class:`SceneError` naming the feature and writes no data, or writes data
on which :func:`validation.data_checks.check_dataset` finds Newton holding (and Eq. (11)
with MuJoCo's accelerations for free-floating systems), with no MuJoCo warning.

The dm_control suite's models are tried too when ``MDGS_DM_CONTROL_SUITE`` names their
folder (``pip download dm-control --no-deps`` and unzip ``dm_control/suite``).
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import h5py
import mujoco
import numpy as np
import pytest

from mdgs.data import GenerateConfig, generate, model_from_dataset, open_dataset
from mdgs.data.engine import load_scene, simulate
from mdgs.data.record import SceneError
from mdgs.data.schema import DatasetError
from mdgs.scenes import user_scene
from validation.data_checks import check_dataset

# --- the feature list -------------------------------------------------------------------

_ARM = """
    <body name="upper" pos="0 0 1">
      <joint name="shoulder" type="hinge" axis="0 1 0" {shoulder}/>
      <geom type="capsule" fromto="0 0 0 0.3 0 0" size=".03" mass="0.3" {col}/>
      <site name="s_upper" pos="0.3 0 0"/>
      <body name="fore" pos="0.3 0 0">
        <joint name="elbow" type="hinge" axis="0 1 0" {elbow}/>
        <geom type="capsule" fromto="0 0 0 0.25 0 0" size=".025" mass="0.2" {col}/>
        <site name="s_fore" pos="0.25 0 0"/>
      </body>
    </body>"""
_NOCOL = 'contype="0" conaffinity="0"'


def _arm(shoulder="", elbow="", col=_NOCOL) -> str:
    return _ARM.format(shoulder=shoulder, elbow=elbow, col=col)


def _model(body: str, extra: str = "", option: str = "", floor: bool = False) -> str:
    plane = '<geom name="floor" type="plane" size="3 3 .1"/>' if floor else ""
    return f"""<mujoco>
  <option timestep="0.002" {option}/>
  <worldbody>{plane}{body}
    <body name="post" pos="0 0.6 1"><joint name="post" type="hinge" axis="0 1 0"/>
      <geom type="box" size=".02 .02 .2" mass=".5" {_NOCOL}/><site name="s_post" pos="0 0 -.2"/></body>
  </worldbody>
  {extra}
</mujoco>"""


_MOTORS = '<actuator><motor joint="shoulder" gear=".5" ctrlrange="-1 1"/><motor joint="elbow" gear=".3" ctrlrange="-1 1"/></actuator>'

HOLDS = {
    "joint limits": _model(
        _arm('limited="true" range="-0.3 0.3"', 'limited="true" range="-0.2 0.2"'), _MOTORS
    ),
    "joint damping (implicit, eulerdamp)": _model(_arm('damping="0.5"', 'damping="0.3"'), _MOTORS),
    "joint springs, friction loss, armature": _model(
        _arm('stiffness="20" frictionloss="0.05"', 'armature="0.01" stiffness="5"'), _MOTORS
    ),
    "fixed tendon with limits and a spring": _model(
        _arm(),
        '<tendon><fixed name="coupling" limited="true" range="-0.1 0.1" stiffness="3">'
        '<joint joint="shoulder" coef="1"/><joint joint="elbow" coef="-1"/></fixed></tendon>'
        + _MOTORS,
    ),
    "fixed tendon as actuator transmission": _model(
        _arm(),
        '<tendon><fixed name="drive"><joint joint="shoulder" coef="1"/><joint joint="elbow" coef=".5"/>'
        '</fixed></tendon><actuator><motor tendon="drive" gear=".3" ctrlrange="-1 1"/></actuator>',
    ),
    "spatial tendon that exerts no force": _model(
        _arm(),
        '<tendon><spatial name="marker"><site site="s_fore"/><site site="s_post"/></spatial></tendon>'
        + _MOTORS,
    ),
    "planar model (slide x, slide z, hinge y) on a floor": _model(
        """
    <body name="hopper" pos="0 0 0.3">
      <joint name="rootx" type="slide" axis="1 0 0"/><joint name="rootz" type="slide" axis="0 0 1"/>
      <joint name="rooty" type="hinge" axis="0 1 0" damping="0.1"/>
      <geom type="capsule" fromto="0 0 0 0 0 0.3" size=".05" mass="2"/>
    </body>""",
        floor=True,
    ),
    "free body with many contacts (slot overflow)": _model(
        """
    <body name="raft" pos="0 0 0.06"><freejoint/>"""
        + "".join(
            f'<geom type="sphere" size=".05" pos="{x} {y} 0" mass=".1"/>'
            for x in (-0.2, 0, 0.2)
            for y in (-0.2, 0.2)
        )
        + "</body>",
        floor=True,
    ),
}
"""Models that must yield data on which Newton holds."""

REFUSED = {
    "spatial tendon with a length limit": (
        _model(
            _arm(),
            '<tendon><spatial name="string" limited="true" range="0 0.5"><site site="s_fore"/>'
            '<site site="s_post"/></spatial></tendon>',
        ),
        r"spatial tendon 'string' has a length limit",
    ),
    "spatial tendon with a spring": (
        _model(
            _arm(),
            '<tendon><spatial name="band" stiffness="40"><site site="s_upper"/><site site="s_post"/>'
            "</spatial></tendon>",
        ),
        r"spatial tendon 'band' has stiffness",
    ),
    "spatial tendon actuator": (
        _model(
            _arm(),
            '<tendon><spatial name="cable"><site site="s_fore"/><site site="s_post"/></spatial></tendon>'
            '<actuator><motor tendon="cable"/></actuator>',
        ),
        r"spatial tendon 'cable' has an actuator",
    ),
    "equality constraint": (
        _model(_arm(), '<equality><connect body1="fore" body2="post" anchor="0.25 0 0"/></equality>'),
        r"equality constraints",
    ),
    "fluid forces": (_model(_arm(), option='density="1.2" viscosity="1e-5"'), r"fluid forces"),
    "no moving body": (
        '<mujoco><worldbody><geom type="plane" size="1 1 .1"/><body name="shelf" pos="0 0 1">'
        '<geom type="box" size=".1 .1 .1"/></body></worldbody></mujoco>',
        r"no moving body",
    ),
    "unstable with explicit damping (eulerdamp disabled by the model)": (
        '<mujoco><option timestep="0.01"><flag eulerdamp="disable"/></option><worldbody>'
        '<body name="flick"><joint name="j" type="hinge" damping="50"/>'
        '<geom type="capsule" fromto="0 0 0 .05 0 0" size=".005" mass="0.001"/></body>'
        "</worldbody></mujoco>",
        r"MuJoCo warned .*(QACC|QVEL|QPOS).*no data was written",
    ),
    "constraint arena too small": (
        '<mujoco><size memory="12K"/><worldbody><geom type="plane" size="3 3 .1"/>'
        + "".join(
            f'<body pos="{0.12 * i} 0 0.05"><freejoint/><geom type="box" size=".05 .05 .05"/></body>'
            for i in range(12)
        )
        + "</worldbody></mujoco>",
        r"(arena|memory)",
    ),
}
"""Models that must be refused with one sentence naming the feature (regex)."""


def _write(tmp_path: Path, xml: str, name: str = "model.xml") -> Path:
    f = tmp_path / name
    f.write_text(xml)
    return f


def _h5_files(out: Path) -> list[Path]:
    return sorted(out.rglob("*.h5")) if out.exists() else []


@pytest.mark.parametrize("feature", sorted(HOLDS))
def test_accepted_feature_yields_data_where_newton_holds(feature, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # MUJOCO_LOG.TXT would land here
    f = _write(tmp_path, HOLDS[feature])
    res = generate(GenerateConfig(scene="", out=str(tmp_path / "out"), mjcf=str(f)), on_warning=None)
    assert not any("MuJoCo" in w for w in res.warnings), res.warnings
    for split in ("train", "test"):
        rows = {r["claim_id"]: r for r in check_dataset(tmp_path / "out" / f"{split}.h5")}
        assert rows["newton"]["verdict"] == "holds", rows["newton"]["detail"]
        if "eq11.corrected" in rows:
            assert rows["eq11.corrected"]["verdict"] == "holds"
    assert not (tmp_path / "MUJOCO_LOG.TXT").exists()


@pytest.mark.parametrize("feature", sorted(REFUSED))
def test_unrecordable_feature_is_refused_in_one_sentence(feature, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    xml, pattern = REFUSED[feature]
    f = _write(tmp_path, xml)
    out = tmp_path / "out"
    with pytest.raises(SceneError) as e:
        generate(GenerateConfig(scene="", out=str(out), mjcf=str(f)), on_warning=None)
    msg = str(e.value)
    assert re.search(pattern, msg), msg
    assert "\n" not in msg.strip() and "Traceback" not in msg
    assert _h5_files(out) == []  # no data, not even a part
    assert not (tmp_path / "MUJOCO_LOG.TXT").exists()
    assert "WARNING" not in capsys.readouterr().err  # MuJoCo printed nothing of its own


# --- single defects ---------------------------------------------------------------------


def test_generation_keeps_the_models_implicit_damping(tmp_path):
    """MuJoCo integrates joint damping implicitly (eulerdamp); generation must not switch it off."""
    f = _write(tmp_path, HOLDS["joint damping (implicit, eulerdamp)"])
    sc = load_scene(user_scene(str(f)))
    assert not sc.inst.model.opt.disableflags & int(mujoco.mjtDisableBit.mjDSBL_EULERDAMP)
    assert sc.inst.implicit_damping and sc.inst.notes == ()


def test_generation_simulates_the_model_as_mujoco_does(tmp_path):
    """The refused unstable model with eulerdamp left on (MuJoCo's default) is stable, and
    every stored frame is what plain MuJoCo gives from the stored initial state (no contacts
    or limits, so no solver warm start to carry): bit for bit, since the recorder only adds
    sensors. Before, generation switched eulerdamp off and wrote the blown-up (reset) run."""
    xml = REFUSED["unstable with explicit damping (eulerdamp disabled by the model)"][0]
    f = _write(tmp_path, xml.replace('<flag eulerdamp="disable"/>', ""))
    generate(GenerateConfig(scene="", out=str(tmp_path / "out"), mjcf=str(f)), on_warning=None)
    m = mujoco.MjModel.from_xml_path(str(f))
    d = mujoco.MjData(m)
    with open_dataset(tmp_path / "out" / "train.h5", verify=True) as ds:
        qpos, qvel, k = ds.frames("qpos", 0), ds.frames("qvel", 0), int(ds.attrs["substeps"])
    d.qpos[:], d.qvel[:] = qpos[0], qvel[0]
    for t in range(1, len(qpos)):
        for _ in range(k):
            mujoco.mj_step(m, d)
        np.testing.assert_array_equal(d.qvel, qvel[t], err_msg=f"frame {t}")
        np.testing.assert_array_equal(d.qpos, qpos[t], err_msg=f"frame {t}")
    assert d.warning.number.sum() == 0 and np.abs(qvel).max() < 1.0


def test_implicit_damping_loads_are_newton_euler_at_the_integrated_acceleration(tmp_path):
    """Recorded frame loads and accelerations equal, per step, MuJoCo's own Newton-Euler pass
    (mj_rnePostConstraint) run with the acceleration the step integrated,
    ``(qvel[s+1] - qvel[s]) / h``, not with the pre-step ``qacc`` (they differ by
    ``(M + h B)^-1 h B qacc``). No contacts or limits, so replaying each stored frame start
    reproduces the steps (no solver warm start). Tolerance 1e-9 of the largest load:
    the finite difference of qvel carries about eps |qvel| / h ~ 1e-13."""
    f = _write(tmp_path, HOLDS["joint damping (implicit, eulerdamp)"])
    sc = load_scene(user_scene(str(f)))
    fr = simulate(sc, "train", [0], seed=3, n_frames=12)
    m, k = sc.inst.model, sc.spec.substeps
    h = m.opt.timestep
    d, e = mujoco.MjData(m), mujoco.MjData(m)
    par = m.body_parentid
    want_f = np.zeros((12, m.nbody - 1, 3))
    want_a = np.zeros((12, m.nbody - 1, 3))
    naive_f = np.zeros((12, m.nbody - 1, 3))
    for t in range(12):
        d.qpos[:], d.qvel[:], d.ctrl[:] = fr["qpos"][0, t], fr["qvel"][0, t], fr["ctrl"][0, t]
        for _ in range(k):
            mujoco.mj_forward(m, d)
            e.qpos[:], e.qvel[:], e.ctrl[:] = d.qpos, d.qvel, d.ctrl
            mujoco.mj_forward(m, e)
            mujoco.mj_rnePostConstraint(m, e)
            own0 = e.cfrc_int[:, 3:].copy()
            for b in range(m.nbody - 1, 0, -1):
                own0[par[b]] -= e.cfrc_int[b, 3:]
            qv = d.qvel.copy()
            mujoco.mj_step(m, d)
            e.qacc[:] = (d.qvel - qv) / h
            mujoco.mj_rnePostConstraint(m, e)
            own = e.cfrc_int[:, 3:].copy()
            for b in range(m.nbody - 1, 0, -1):
                own[par[b]] -= e.cfrc_int[b, 3:]
            # classical com acceleration: spatial cacc moved to the com, + w x v_com, minus
            # cacc's gravity offset
            r = e.xipos - e.subtree_com[m.body_rootid]
            w, v = e.cvel[:, :3], e.cvel[:, 3:] + np.cross(e.cvel[:, :3], r)
            lin = e.cacc[:, 3:] + np.cross(e.cacc[:, :3], r) + np.cross(w, v) + m.opt.gravity
            want_f[t] += own[1:] / k
            want_a[t] += lin[1:] / k
            naive_f[t] += own0[1:] / k
        np.testing.assert_array_equal(d.qvel, fr["qvel"][0, t + 1] if t < 11 else d.qvel)
    got = fr["body_joint_force"][0] + fr["body_actuator_force"][0]
    scale = np.abs(want_f).max()
    assert np.abs(got - want_f).max() < 1e-9 * scale
    assert np.abs(fr["body_acc"][0] - want_a).max() < 1e-9 * np.abs(want_a).max()
    assert np.abs(naive_f - want_f).max() > 1e-6 * scale  # the correction matters here


def test_contact_slot_overflow_is_reported(tmp_path):
    f = _write(tmp_path, HOLDS["free body with many contacts (slot overflow)"])
    lines = []
    res = generate(GenerateConfig(scene="", out=str(tmp_path / "out"), mjcf=str(f)), on_warning=lines.append)
    assert lines == list(res.warnings)
    assert any("more than 4 contacts" in w for w in lines)
    with open_dataset(tmp_path / "out" / "train.h5") as ds:
        assert int(ds.attrs["contact_overflow"]) == int(ds.frames("contact_overflow").sum()) > 0


def test_mujoco_warnings_go_to_the_output_and_the_dataset_not_to_a_log_file(tmp_path, monkeypatch):
    """A deprecated compiler attribute makes MuJoCo warn at load time."""
    monkeypatch.chdir(tmp_path)
    xml = HOLDS["joint limits"].replace("<mujoco>", '<mujoco><compiler settotalmass="2"/>')
    f = _write(tmp_path, xml)
    lines = []
    generate(GenerateConfig(scene="", out=str(tmp_path / "out"), mjcf=str(f)), on_warning=lines.append)
    assert any("settotalmass" in w for w in lines)
    with open_dataset(tmp_path / "out" / "test.h5") as ds:
        assert "settotalmass" in ds.attrs["mujoco_warnings"]
    assert not (tmp_path / "MUJOCO_LOG.TXT").exists()


def _include_model(root: Path) -> Path:
    """A model split over an include file and a mesh in sub-folders, read relative to it."""
    (root / "parts").mkdir(parents=True)
    (root / "meshes").mkdir()
    (root / "meshes" / "wedge.obj").write_text(
        "v 0 0 0\nv .2 0 0\nv 0 .2 0\nv 0 0 .2\nv .2 .2 .1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 5\nf 2 5 4\nf 3 4 5\n"
    )
    (root / "parts" / "body.xml").write_text(
        '<mujoco><worldbody><body name="wedge" pos="0 0 .5"><freejoint/>'
        '<geom type="mesh" mesh="wedge" density="800"/></body></worldbody></mujoco>'
    )
    main = root / "scene.xml"
    main.write_text(
        '<mujoco><compiler meshdir="meshes"/><asset><mesh name="wedge" file="wedge.obj"/></asset>'
        '<worldbody><geom type="plane" size="2 2 .1"/></worldbody>'
        '<include file="parts/body.xml"/></mujoco>'
    )
    return main


def test_dataset_rebuilds_a_model_with_includes_and_assets_elsewhere(tmp_path):
    main = _include_model(tmp_path / "src")
    want = mujoco.MjModel.from_xml_path(str(main))
    generate(GenerateConfig(scene="", out=str(tmp_path / "out"), mjcf=str(main)), on_warning=None)
    moved = tmp_path / "elsewhere" / "test.h5"
    moved.parent.mkdir()
    (tmp_path / "out" / "test.h5").rename(moved)
    for p in sorted((tmp_path / "src").rglob("*"), reverse=True):  # the model is gone
        p.unlink() if p.is_file() else p.rmdir()
    with open_dataset(moved) as ds:
        with pytest.raises(ValueError):  # what training did before: no base directory
            mujoco.MjModel.from_xml_string(ds.mjcf)
        got = model_from_dataset(ds)
    for name in ("body_mass", "body_inertia", "mesh_vert", "geom_size", "body_pos"):
        np.testing.assert_array_equal(getattr(got, name), getattr(want, name), err_msg=name)
    assert model_from_dataset(moved).nbody == want.nbody
    rows = {r["claim_id"]: r for r in check_dataset(moved)}
    assert rows["newton"]["verdict"] == "holds" and rows["eq11.corrected"]["verdict"] == "holds"


def test_stale_temporaries_of_dead_processes_are_removed_on_rerun(tmp_path):
    f = _write(tmp_path, HOLDS["joint limits"])
    out = tmp_path / "out"
    cfg = GenerateConfig(scene="", out=str(out), mjcf=str(f))
    generate(cfg, on_warning=None)
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    alive = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        stale = [out / f".train.h5.tmp{dead.pid}", out / ".parts" / "test" / f".x.h5.tmp{dead.pid}"]
        live = out / f".valid.h5.tmp{alive.pid}"
        for p in [*stale, live]:
            p.parent.mkdir(parents=True, exist_ok=True)
            p.write_bytes(b"half a file")
        generate(cfg, on_warning=None)
        assert not any(p.exists() for p in stale)
        assert live.exists()  # another live process may still be writing it
    finally:
        alive.kill()
        alive.wait()


# --- public models (optional) -----------------------------------------------------------

_SUITE = os.environ.get("MDGS_DM_CONTROL_SUITE", "")


@pytest.mark.slow
@pytest.mark.skipif(not Path(_SUITE).is_dir(), reason="set MDGS_DM_CONTROL_SUITE to dm_control/suite")
@pytest.mark.parametrize(
    "name", sorted(p.stem for p in Path(_SUITE).glob("*.xml")) if Path(_SUITE).is_dir() else []
)
def test_dm_control_model_is_recorded_or_refused(name, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    out = tmp_path / "out"
    try:
        generate(GenerateConfig(scene="", out=str(out), mjcf=str(Path(_SUITE) / f"{name}.xml")), on_warning=None)
    except SceneError as e:
        assert "\n" not in str(e).strip()
        assert _h5_files(out) == []
        return
    rows = {r["claim_id"]: r for r in check_dataset(out / "test.h5")}
    assert rows["newton"]["verdict"] == "holds"
    with h5py.File(out / "test.h5") as fh:
        assert np.isfinite(fh["frames/qvel"][()]).all()
    assert not (tmp_path / "MUJOCO_LOG.TXT").exists()


def test_dataset_error_is_raised_for_unusable_files(tmp_path):
    """Empty, foreign (valid HDF5, other schema) and directory paths name the file and the fix."""
    empty = tmp_path / "empty.h5"
    empty.write_bytes(b"")
    foreign = tmp_path / "foreign.h5"
    with h5py.File(foreign, "w") as fh:
        fh["x"] = np.arange(3)
    for p, pattern in ((empty, "is empty"), (foreign, "not an MDGS dataset"), (tmp_path, "is a folder")):
        with pytest.raises(DatasetError, match=pattern):
            check_dataset(p)
