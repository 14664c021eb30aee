"""Generation engine and writer: the ways they save time change no recorded bit.

The engine steps contact-free frames with the instrumented model minus its contact
sensors (``Instrumented.lean_model``) and steps frames with contacts again with them;
it reduces blocks of frames whose size depends on memory; the writer does not store
all-zero chunks. None of this may show in the data.
"""

from __future__ import annotations

import h5py
import mujoco
import mujoco.batch
import numpy as np
import pytest

from mdgs.data import engine
from mdgs.data.engine import load_scene, rng_for, scene_attrs, simulate, static_arrays
from mdgs.data.io import merge_files, open_dataset, write_file
from mdgs.data.record import FrameReducer
from mdgs.scenes import get_scene


@pytest.fixture(scope="module")
def strike():
    """A space robot whose arm strikes a free body now and then: few contacts, re-runs."""
    return load_scene(get_scene("space-strike"))


@pytest.fixture(scope="module")
def strike_frames(strike):
    return simulate(strike, "train", range(8), seed=0, n_frames=60)


def _assert_same(a: dict, b: dict) -> None:
    assert set(a) == set(b)
    for key in a:
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)


def test_lean_model_steps_bit_for_bit_like_the_model(strike):
    inst = strike.inst
    m, lean = inst.model, inst.lean_model
    assert lean is not None and lean.nsensordata < m.nsensordata
    red = FrameReducer(inst, strike.spec.substeps)
    a, b = mujoco.batch.Batch(m, 4, 1), mujoco.batch.Batch(lean, 4, 1)
    d = mujoco.MjData(m)
    for r in range(4):
        mujoco.mj_resetData(m, d)
        strike.spec.builder.initial_state(m, d, rng_for(0, "train", r))
        mujoco.mj_getState(m, d, a.state[r], mujoco.mjtState.mjSTATE_INTEGRATION)
    b.state[:] = a.state
    ra, rb = a.rollout(300, record=red.lean_fields), b.rollout(300, record=red.lean_fields)
    np.testing.assert_array_equal(a.state, b.state)
    for key in red.lean_fields:  # the lean sensordata is the model's up to the contact sensors
        x, y = ra[key], rb[key]
        np.testing.assert_array_equal(x[..., : y.shape[-1]] if key == "sensordata" else x, y)


def test_contact_frames_stepped_again_give_the_frames_of_the_full_model(
    strike, strike_frames, monkeypatch
):
    calls = []
    rollout = mujoco.batch.Batch.rollout

    def spy(self, nstep, *args, ids=None, **kw):
        calls.append((self.model is strike.inst.lean_model, ids is not None))
        return rollout(self, nstep, *args, ids=ids, **kw)

    monkeypatch.setattr(mujoco.batch.Batch, "rollout", spy)
    lean = simulate(strike, "train", range(8), seed=0, n_frames=60)
    assert (True, False) in calls and (False, True) in calls  # lean frames, contacts re-run
    _assert_same(strike_frames, lean)
    calls.clear()
    monkeypatch.setattr(engine, "_LEAN_ENTER", -1.0)  # never step with the lean model
    _assert_same(strike_frames, simulate(strike, "train", range(8), seed=0, n_frames=60))
    assert calls and not any(is_lean or rerun for is_lean, rerun in calls)


def test_blocks_and_batches_do_not_change_frames(strike, strike_frames):
    _assert_same(
        strike_frames, simulate(strike, "train", range(8), seed=0, n_frames=60, block_bytes=1)
    )
    alone = simulate(strike, "train", [5, 6], seed=0, n_frames=60)
    for key, v in alone.items():
        np.testing.assert_array_equal(v, strike_frames[key][5:7], err_msg=key)


def test_closed_loop_blocks_do_not_change_frames():
    sc = load_scene(get_scene("cubli-double"))
    a = simulate(sc, "valid", range(3), seed=2, n_frames=30)
    _assert_same(a, simulate(sc, "valid", range(3), seed=2, n_frames=30, block_bytes=1))


def _part(sc, frames, path, start):
    attrs = scene_attrs(sc)
    n = len(frames["qpos"])
    attrs.update(
        split="train",
        n_traj=n,
        n_frames=frames["qpos"].shape[1],
        traj_start=start,
        seed=0,
        preset="test",
        config_sha256="test",
        mdgs_version="test",
        complete=False,
    )
    write_file(path, attrs, sc.mjcf, static_arrays(sc), frames)


def test_all_zero_chunks_are_not_stored_and_read_back_as_zeros(strike, strike_frames, tmp_path):
    _part(strike, strike_frames, tmp_path / "p.h5", 0)
    with h5py.File(tmp_path / "p.h5") as f:
        d = f["frames/node_contact_force"]
        touched = np.flatnonzero(strike_frames["node_contact_force"].reshape(8, -1).any(1))
        assert 0 < len(touched) < 8 and d.id.get_num_chunks() == len(touched)
        assert d.fletcher32 and d.fillvalue == 0
    with open_dataset(tmp_path / "p.h5", verify=True, allow_incomplete=True) as ds:
        for key, v in strike_frames.items():
            np.testing.assert_array_equal(ds.frames(key), v, err_msg=key)


def test_merge_copies_stored_chunks_and_recodes_parts_with_other_filters(
    strike, strike_frames, tmp_path
):
    _part(strike, {k: v[:5] for k, v in strike_frames.items()}, tmp_path / "a.h5", 0)
    _part(strike, {k: v[5:] for k, v in strike_frames.items()}, tmp_path / "b.h5", 5)
    # a part written with other filters (an older writer): decoded, not copied verbatim
    with h5py.File(tmp_path / "b.h5", "r+") as f:
        old = f["frames/node_joint_force"][()]
        del f["frames/node_joint_force"]
        f["frames"].create_dataset(
            "node_joint_force",
            data=old,
            chunks=(1,) + old.shape[1:],
            compression="lzf",
            shuffle=True,
            fletcher32=True,
        )
    merge_files([tmp_path / "a.h5", tmp_path / "b.h5"], tmp_path / "m.h5", {"complete": True})
    with open_dataset(tmp_path / "m.h5", verify=True) as ds:
        for key, v in strike_frames.items():
            np.testing.assert_array_equal(ds.frames(key), v, err_msg=key)


def test_nearest_node_lookup_equals_brute_force_search(strike):
    """The compiled lookup (grid where a voxel has one answer, exact search elsewhere) returns
    a node at the smallest distance, for points inside, on the edge of and outside the grid."""
    from mdgs.data import _kernels

    red = FrameReducer(strike.inst, strike.spec.substeps)
    cent, nodes, lo, h, res, table, toff, noff = red.loc
    rng = np.random.default_rng(0)
    for c in range(red.C):
        mine = cent[noff[c] : noff[c + 1]]
        span = lo[c] + h[c] * res[c] - lo[c]
        pts = lo[c] - 0.2 * span + rng.random((400, 3)) * 1.4 * span
        for p in pts:
            n = _kernels._nearest(*p, cent, lo[c], h[c], res[c], table, toff[c], noff[c], noff[c + 1])  # fmt: skip
            assert noff[c] <= n < noff[c + 1]
            d = np.sum((mine - p) ** 2, axis=1)
            assert np.sum((cent[n] - p) ** 2) <= d.min() * (1 + 1e-12) + 1e-300


def test_contacts_beyond_the_reported_slots_still_sum_to_the_body_force():
    """With one contact slot per body, the force of the other contacts is put on a node too:
    node contact forces sum to each body's contact force (cfrc_ext), and overflow is counted."""
    from mdgs.data.engine import LoadedScene
    from mdgs.data.record import instrument

    sc = load_scene(get_scene("cubli-triple"))
    one = LoadedScene(spec=sc.spec, mjcf=sc.mjcf, inst=instrument(sc.mjcf, contact_slots=1))
    fr = simulate(one, "train", range(3), seed=0, n_frames=40)
    st = static_arrays(one)
    assert fr["contact_overflow"].sum() > 0  # a cube on the floor touches at several points
    for bi, b in enumerate(st["body_id"]):
        sel = st["node_body"] == b
        np.testing.assert_allclose(
            fr["node_contact_force"][:, :, sel].sum(2),
            fr["body_contact_force"][:, :, bi],
            rtol=0,
            atol=1e-10 * max(1.0, np.abs(fr["body_contact_force"]).max()),
        )


_SLIDE_CART = """
<mujoco>
  <option timestep="0.002"/>
  <worldbody>
    <geom type="plane" size="3 3 0.1"/>
    <body name="cart" pos="0 0 0.3">
      <joint name="rail" type="slide" axis="1 0 0"/>
      <geom type="box" size="0.2 0.1 0.05" mass="2"/>
      <body name="pole" pos="0.1 0 0.05">
        <joint name="hinge" type="hinge" axis="0 1 0"/>
        <geom type="capsule" fromto="0 0 0 0 0 0.4" size="0.03"/>
      </body>
    </body>
    <body name="box" pos="0.3 0 1">
      <freejoint/>
      <geom type="box" size="0.08 0.08 0.08"/>
    </body>
  </worldbody>
  <actuator>
    <motor joint="rail" gear="10"/>
    <motor joint="hinge" gear="1"/>
  </actuator>
</mujoco>
"""


def test_slide_actuator_loads_balance_mujocos_accelerations(tmp_path):
    """A user MJCF with a slide-driven cart carrying a hinged pole, hit by a falling box:
    per body, m g + contact + actuator + joint forces = m a (MuJoCo's), to round-off, and
    the slide actuator's force acts on the cart and, opposite, on the world."""
    from mdgs.scenes import user_scene

    path = tmp_path / "cart.xml"
    path.write_text(_SLIDE_CART)
    sc = load_scene(user_scene(str(path)))
    fr, st = simulate(sc, "train", range(3), seed=0, n_frames=60), static_arrays(sc)
    m, g = st["body_mass"][None, None, :, None], sc.inst.model.opt.gravity
    loads = m * g + fr["body_contact_force"] + fr["body_actuator_force"] + fr["body_joint_force"]
    ma = m * fr["body_acc"]
    assert np.abs(loads - ma).max() < 1e-9 * np.abs(ma).max()
    cart = list(st["body_names"]).index("cart")
    # the rail's motor pushes the cart along x with gear x control (10 u, held over a frame)
    push = fr["body_actuator_force"][:, :, cart]
    assert np.abs(push[..., 0]).max() > 1.0
    np.testing.assert_allclose(push[..., 0], 10 * fr["ctrl"][..., 0], rtol=1e-12, atol=1e-12)
    assert np.abs(push[..., 1:]).max() < 1e-12
