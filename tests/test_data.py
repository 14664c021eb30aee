"""Recording, file format and checks of datasets (mdgs.data, validation.data_checks)."""

from __future__ import annotations

import shutil

import h5py
import mujoco
import numpy as np
import pytest

from mdgs.data.engine import load_scene, simulate, static_arrays
from mdgs.data.generate import GenerateConfig, generate
from mdgs.data.io import open_dataset
from mdgs.data.record import SceneError, instrument
from mdgs.data.schema import FRAME_ARRAYS, DatasetError
from mdgs.scenes import get_scene
from validation.data_checks import check_dataset


@pytest.fixture(scope="module")
def cubli():
    return load_scene(get_scene("cubli-triple"))


@pytest.fixture(scope="module")
def cubli_frames(cubli):
    return simulate(cubli, "train", range(3), seed=7, n_frames=40)


@pytest.fixture(scope="module")
def tiny_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("tiny") / "cubli-triple"
    generate(GenerateConfig(scene="cubli-triple", out=str(out), preset="tiny"))
    return out


def test_fields_recorded_at_step_zero_describe_the_initial_state(cubli):
    """The batch records, for step s, fields computed at the state before the step (the frame convention)."""
    import mujoco.batch

    from mdgs.data.record import RECORD_FIELDS

    m = cubli.inst.model
    d = mujoco.MjData(m)
    cubli.spec.builder.initial_state(m, d, np.random.default_rng(0))
    b = mujoco.batch.Batch(m, nsim=1, nthread=1)
    mujoco.mj_getState(m, d, b.state[0], mujoco.mjtState.mjSTATE_INTEGRATION)
    rec = b.rollout(3, control=np.zeros((1, 3, m.nu)), record=RECORD_FIELDS)
    mujoco.mj_forward(m, d)
    mujoco.mj_rnePostConstraint(m, d)
    for name in RECORD_FIELDS:
        np.testing.assert_array_equal(rec[name][0, 0], getattr(d, name), err_msg=name)


def test_recorded_loads_equal_mass_times_mujoco_acceleration(cubli, cubli_frames):
    """Newton per body, frame means: m g + contact + actuator + joint = m a (MuJoCo's a), to round-off."""
    fr, st = cubli_frames, static_arrays(cubli)
    m, g = st["body_mass"], cubli.inst.model.opt.gravity
    loads = (
        m[None, None, :, None] * g
        + fr["body_contact_force"]
        + fr["body_actuator_force"]
        + fr["body_joint_force"]
    )
    ma = m[None, None, :, None] * fr["body_acc"]
    assert np.abs(loads - ma).max() < 1e-9 * np.abs(ma).max()
    assert np.abs(fr["body_contact_force"]).max() > 1.0  # the cube does touch the floor


def test_root_body_newton_holds_against_finite_differences(cubli, cubli_frames):
    """Euler is exact for the free root (origin at its com): FD acceleration matches the loads to 1e-9."""
    fr, st = cubli_frames, static_arrays(cubli)
    m, g, dt = st["body_mass"][0], cubli.inst.model.opt.gravity, cubli.spec.frame_dt
    loads = (
        m * g
        + fr["body_contact_force"][:, :, 0]
        + fr["body_actuator_force"][:, :, 0]
        + fr["body_joint_force"][:, :, 0]
    )
    fd = m * np.diff(fr["body_linvel"][:, :, 0], axis=1) / dt
    assert np.abs(loads[:, :-1] - fd).max() < 1e-9 * np.abs(loads).max()


def test_node_loads_sum_to_body_loads(cubli, cubli_frames):
    fr, st = cubli_frames, static_arrays(cubli)
    for bi, b in enumerate(st["body_id"]):
        sel = st["node_body"] == b
        np.testing.assert_allclose(
            fr["node_contact_force"][:, :, sel].sum(2),
            fr["body_contact_force"][:, :, bi],
            atol=1e-10,
        )
        np.testing.assert_allclose(
            fr["node_joint_force"][:, :, sel].sum(2),
            fr["body_joint_force"][:, :, bi] + fr["body_actuator_force"][:, :, bi],
            atol=1e-10,
        )
    assert fr["contact_overflow"].sum() == 0


def test_node_kinematics_are_rigid_body_motion(cubli, cubli_frames):
    """Element centroids keep their distances, and v_i = v_com + w x (x_i - com)."""
    fr, st = cubli_frames, static_arrays(cubli)
    sel = np.flatnonzero(st["node_body"] == st["body_id"][0])
    x = fr["node_pos"][:, :, sel]
    d = np.linalg.norm(x[:, :, :, None] - x[:, :, None], axis=-1)
    np.testing.assert_allclose(d, np.broadcast_to(d[:, :1], d.shape), atol=1e-12)
    mean_v = (st["node_mass"][sel][None, None, :, None] * fr["node_vel"][:, :, sel]).sum(2) / st[
        "node_mass"
    ][sel].sum()
    np.testing.assert_allclose(mean_v, fr["body_linvel"][:, :, 0], atol=1e-12)


def test_a_trajectory_does_not_depend_on_its_batch(cubli, cubli_frames):
    alone = simulate(cubli, "train", [2], seed=7, n_frames=40)
    for k, v in alone.items():
        np.testing.assert_array_equal(v[0], cubli_frames[k][2], err_msg=k)


def test_recorded_loads_explain_mujoco_accelerations_but_finite_differences_leave_O_h(tiny_dir):
    """Loads vs MuJoCo's accelerations: nine digits (newton, eq11.corrected). The paper's
    finite-difference Eq. (11) is off by the integrator's O(h) for the multibody Cubli."""
    results = {r["claim_id"]: r for r in check_dataset(tiny_dir / "train.h5")}
    assert set(results) == {"newton", "eq11", "eq11.corrected"}
    assert results["newton"]["verdict"] == "holds"
    assert results["eq11.corrected"]["verdict"] == "holds"
    assert results["eq11"]["verdict"] == "refuted"
    assert results["eq11"]["residual"] > 1e3 * results["eq11.corrected"]["residual"]
    for r in results.values():
        assert r["route"] == "mujoco" and r["case"] == "cubli-triple"
        assert set(r) == {
            "claim_id",
            "case",
            "route",
            "residual",
            "tolerance",
            "verdict",
            "assumptions",
            "detail",
        }


def test_dataset_is_self_describing(tiny_dir):
    with open_dataset(tiny_dir / "train.h5", verify=True) as ds:
        assert ds.scene == "cubli-triple" and ds.n_frames == 110 and ds.n_traj == 2
        assert (
            ds.attrs["integrator"] == "EULER" and ds.attrs["mujoco_version"] == mujoco.__version__
        )
        m = mujoco.MjModel.from_xml_string(ds.mjcf)  # the stored MJCF rebuilds the scene
        assert m.nbody == len(ds.static["body_id"]) + 1
        assert ds.frames("node_pos").shape == (2, 110, len(ds.static["node_body"]), 3)


def _copy(src, tmp_path, name="x.h5"):
    dst = tmp_path / name
    shutil.copy(src, dst)
    return dst


def test_truncated_file_gives_dataset_error(tiny_dir, tmp_path):
    p = _copy(tiny_dir / "train.h5", tmp_path)
    data = p.read_bytes()
    p.write_bytes(data[: len(data) // 2])
    with pytest.raises(DatasetError, match="truncated or corrupted"):
        open_dataset(p)


def test_corrupted_chunk_gives_dataset_error(tiny_dir, tmp_path):
    p = _copy(tiny_dir / "train.h5", tmp_path)
    with h5py.File(p, "r") as f:
        offset = f["frames/node_pos"].id.get_chunk_info(0).byte_offset
    with open(p, "r+b") as fh:
        fh.seek(offset + 100)
        fh.write(b"\x00\xff" * 8)
    with pytest.raises(DatasetError, match="corrupted"):
        open_dataset(p, verify=True)
    with pytest.raises(DatasetError, match="corrupted"):
        check_dataset(p)


def test_mismatched_schema_gives_dataset_error(tiny_dir, tmp_path):
    p = _copy(tiny_dir / "train.h5", tmp_path)
    with h5py.File(p, "r+") as f:
        f.attrs["schema_version"] = 999
    with pytest.raises(DatasetError, match="schema version 999"):
        open_dataset(p)
    p2 = _copy(tiny_dir / "train.h5", tmp_path, "y.h5")
    with h5py.File(p2, "r+") as f:
        del f["frames/node_vel"]
    with pytest.raises(DatasetError, match="node_vel"):
        open_dataset(p2)
    with pytest.raises(DatasetError, match="does not exist"):
        open_dataset(tmp_path / "missing.h5")


def test_schema_documents_every_recorded_array(cubli_frames):
    assert {s.name for s in FRAME_ARRAYS} == set(cubli_frames)


def test_unrecordable_model_is_one_clear_error():
    xml = '<mujoco><worldbody><body name="a"><freejoint/><geom size=".1"/></body><body name="b" pos="1 0 0"><freejoint/><geom size=".1"/></body></worldbody><equality><weld body1="a" body2="b"/></equality></mujoco>'
    with pytest.raises(SceneError, match="equality constraints"):
        instrument(xml)


def test_nan_or_inf_in_a_dataset_is_reported(tiny_dir, tmp_path):
    for bad in (np.nan, np.inf):
        p = _copy(tiny_dir / "train.h5", tmp_path, f"bad{bad}.h5")
        with h5py.File(p, "r+") as f:
            f["frames/body_joint_force"][1, 7, 0, 2] = bad
        with pytest.raises(DatasetError, match=r"body_joint_force holds NaN or Inf \(trajectory 1\)"):
            check_dataset(p)


@pytest.mark.parametrize("kind", ["empty", "foreign", "truncated", "nan"])
def test_validate_data_on_an_unusable_file_is_one_sentence_and_exit_2(kind, tiny_dir, tmp_path, capsys):
    from mdgs.cli import main

    p = tmp_path / f"{kind}.h5"
    if kind == "empty":
        p.write_bytes(b"")
    elif kind == "foreign":
        with h5py.File(p, "w") as f:
            f["data"] = np.arange(4.0)
    else:
        shutil.copy(tiny_dir / "train.h5", p)
        if kind == "truncated":
            p.write_bytes(p.read_bytes()[:5000])
        else:
            with h5py.File(p, "r+") as f:
                f["frames/qvel"][0, 3, 0] = np.nan
    for args in (["validate", "--data", str(p)], ["validate", "--data", str(p), "--json", "-"]):
        assert main(args) == 2
        err = capsys.readouterr().err.strip()
        assert str(p) in err and "Traceback" not in err and len(err.splitlines()) == 1


def test_newton_tolerance_is_set_by_the_model_not_by_the_data(tiny_dir, tmp_path):
    """A missing load of 1e-5 N on the cube must be refuted even when another frame holds a
    huge (balanced) force: the tolerance is 1e-9 x moving mass x |g|, from the static table."""
    from validation.data_checks import force_scale

    p = _copy(tiny_dir / "train.h5", tmp_path)
    with open_dataset(p) as ds:
        st, g = ds.static, np.asarray(ds.attrs["gravity"])
    with h5py.File(p, "r+") as f:
        jf = f["frames/body_joint_force"]
        jf[0] = jf[0] + np.array([1e-5, 0, 0])  # a load the file lacks, on every body
        acc = f["frames/body_acc"]
        a = acc[1]
        a[5, 0, 0] += 1e7  # a blown-up frame, balanced by an equally huge joint force
        acc[1] = a
        j1 = jf[1]
        j1[5, 0, 0] += st["body_mass"][0] * 1e7
        jf[1] = j1
    rows = {r["claim_id"]: r for r in check_dataset(p)}
    scale = force_scale(st, g)
    assert scale == pytest.approx(st["body_mass"][~st["body_static"]].sum() * np.linalg.norm(g))
    assert rows["newton"]["tolerance"] == pytest.approx(1e-9 * scale)
    assert rows["newton"]["verdict"] == "refuted" and rows["newton"]["residual"] >= 1e-5 * 0.999


def test_a_dataset_without_moving_bodies_is_a_dataset_error(tiny_dir, tmp_path):
    """Not an empty report that blames --check and --case, which were not given."""
    p = _copy(tiny_dir / "train.h5", tmp_path)
    with h5py.File(p, "r+") as f:
        f["static/body_static"][...] = True
    with pytest.raises(DatasetError, match="no moving body"):
        check_dataset(p)


def test_one_split_alone_gets_every_trajectory_asked_for():
    """``--n-traj N`` with one split (a long test or validation set) gives that split N trajectories;
    with several, the paper's proportions (held-out splits 100/2200 each, at least one)."""
    from mdgs.data.presets import split_counts

    for split in ("train", "valid", "test"):
        assert split_counts(10, (split,)) == {split: 10}
    assert split_counts(440, ("train", "valid", "test")) == {"train": 400, "valid": 20, "test": 20}
    assert split_counts(3, ("train", "valid", "test")) == {"train": 1, "valid": 1, "test": 1}
