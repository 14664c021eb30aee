"""Non-learned peers that sit beside every learned model: constant twist, and MuJoCo at a coarser timestep.

Both meet the :class:`~mdgs.models.base.Simulator` contract and have nothing to train:

- :class:`ConstantTwist` (``constant-twist``): every moving body keeps its velocity and
  angular velocity (no forces, no contact) and moves rigidly over the frame. A learned
  simulator that does not beat it has learned no dynamics (gravity, contact, actuation).
  With ``motors=True`` ("constant twist + motors") the bodies that motors drive also take the
  velocity change of each motor's joint with its parent held (:func:`mdgs.actuation.motor_accelerations`):
  the physics of the controls a learned model is handed. With ``joints=True`` ("constant twist +
  joints") every step is projected onto the scene's MJCF joints (:func:`mdgs.joints.project_joints`,
  the same projection MDGS applies to its simulated steps), so hinged bodies stay hinged: it is
  what an MDGS whose network outputs zero simulates, and the reference that shows what training
  adds to MDGS. With ``dynamics=True`` ("rigid tree") the bodies take the whole tree's forward
  dynamics instead (motors, gravity, velocity terms, range limits, contact with the world's surfaces
  with friction at box corners and cylinder rims; :func:`mdgs.actuation.coupled_motor_accelerations`
  given the velocities): a
  hand-written simulator of the scene's MJCF at one semi-implicit Euler step per frame, and what an
  MDGS with ``actuation="dynamics"`` simulates untrained.
- :class:`MuJoCoReference` (``mujoco``): the physics engine that made the data, replaying
  each test trajectory from its recorded initial state under the recorded controls, with the
  timestep ``dt_factor`` times the dataset's (``substeps / dt_factor`` steps per frame). At
  ``dt_factor = 1`` it reproduces the data (up to the solver's warm start, which is not
  recorded); coarser, it is the cheap, strong, non-learned peer of a learned simulator.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np
import torch

from mdgs.actuation import (
    DriveSet,
    check_contact,
    coupled_motor_accelerations,
    drives_of,
    gyroscopic_weight,
    motor_accelerations,
    warn_unseen,
)
from mdgs.data.split import SplitData
from mdgs.graphs import SceneGraph
from mdgs.joints import JointSet, joints_of, project_joints
from mdgs.models.base import ModelError, Simulator, State
from mdgs.rigid import advance, project, twist
from mdgs.tree import check_joint_velocities, tree_step, warn_unprojected

__all__ = ["ConstantTwist", "ConstantTwistConfig", "MuJoCoReference", "MuJoCoConfig"]


@dataclass(frozen=True)
class ConstantTwistConfig:
    """Settings of the constant-twist reference.

    motors : add each motor's joint response with its parent held
        (:func:`mdgs.actuation.motor_accelerations`); the label gains "+ motors".
    coupled : with ``motors``, the motors' response with every joint coupled instead, the parents
        recoiling (:func:`mdgs.actuation.coupled_motor_accelerations`, MuJoCo's ``M^-1 qfrc_actuator``);
        the label gains "+ coupled motors".
    joints : project every step onto the scene's joints (:func:`mdgs.joints.project_joints`, as
        MDGS's ``joints``); the label gains "+ joints". With ``dynamics`` the tree needs it wherever a rotor
        spins fast: the forward dynamics holds the joints through their accelerations only, so their
        positions drift, and a hinge whose child spins at hundreds of rad/s leaves it within frames (the tiny
        Cubli's test trajectory, 4 or 16 substeps alike); every study row of the tree projects.
    dynamics : the whole tree's forward dynamics instead of the motors' response alone: motors,
        gravity, the velocity terms, range limits and contact with the world's surfaces with friction at
        box corners and cylinder rims (:func:`mdgs.actuation.coupled_motor_accelerations` given the velocities), integrated by
        semi-implicit Euler over the frame; the label is "rigid tree" (a hand-written, one-step-per-frame
        simulator of the scene's MJCF, without MuJoCo's contact model).
    trapezoidal : move each body over the frame with the mean of its old and new twist (exact for a
        constant acceleration) instead of the new one; the label gains ", trapezoidal".
    push_out : with ``dynamics``, move the tree out of the world's surfaces after every step, its twists
        kept (:func:`mdgs.actuation.push_out`); the label gains ", push-out".
    substeps : with ``dynamics``, integrate the frame in this many equal substeps (:func:`mdgs.tree.tree_step`;
        the controls held); above 1 the label gains ", N substeps".
    gyroscopic : with ``dynamics``, "explicit" (the gyroscopic terms at each step's start), "implicit" (at its
        end) or "midpoint" (halfway), linearised: each body's gyroscopic torque and a hinge's cross-axis velocity
        terms (:data:`mdgs.actuation.GYROSCOPIC`); the label gains ", implicit gyroscopic" or ", midpoint gyroscopic".
    joint_velocities : with ``dynamics`` and ``joints``, "parent" (each child takes its parent's twist across the
        joint) or "momentum" (the least kinetic-energy change, equal and opposite impulses at the joints:
        :func:`mdgs.actuation.project_velocities`); the label gains ", momentum projection". Or "coordinates":
        the tree stepped in its joint coordinates, nothing projected (:func:`mdgs.tree.tree_step`; with
        ``trapezoidal`` velocity Verlet, else semi-implicit Euler); the label gains ", joint coordinates".
    contact : with ``dynamics``, "rigid" (a held corner stops within the step) or "soft" (MuJoCo's soft contact,
        :data:`mdgs.actuation.CONTACT_MODELS`; without ``push_out``, which would undo its depth); the label gains
        ", soft contact".
    """

    motors: bool = False
    joints: bool = False
    coupled: bool = False
    dynamics: bool = False
    trapezoidal: bool = False
    push_out: bool = False
    substeps: int = 1
    gyroscopic: str = "explicit"
    joint_velocities: str = "parent"
    contact: str = "rigid"

    def __post_init__(self):
        for k in ("motors", "joints", "coupled", "dynamics", "trapezoidal", "push_out"):
            if not isinstance(getattr(self, k), bool):
                raise ValueError(f"{k} must be true or false, got {getattr(self, k)!r}")
        if self.coupled and not self.motors:
            raise ValueError("coupled is a form of the motors' response; set motors = true with it")
        if self.dynamics and (self.motors or self.coupled):
            raise ValueError("dynamics already holds the motors (the whole tree's response); "
                             "set motors = false and coupled = false with it")
        if self.push_out and not self.dynamics:
            raise ValueError("push_out moves the rigid tree out of the world's surfaces; set dynamics = true with it")
        if isinstance(self.substeps, bool) or not isinstance(self.substeps, int) or self.substeps < 1:
            raise ValueError(f"substeps must be a positive integer, got {self.substeps!r}")
        if self.substeps > 1 and not self.dynamics:
            raise ValueError("substeps integrate the rigid tree's forward dynamics; set dynamics = true with them")
        gyroscopic_weight(self.gyroscopic)  # a rule it does not know raises, naming the rules
        if self.gyroscopic != "explicit" and not self.dynamics:
            raise ValueError("gyroscopic sets how the rigid tree's forward dynamics steps; set dynamics = true with it")
        check_joint_velocities(self.joint_velocities)
        if self.joint_velocities != "parent" and not (self.dynamics and self.joints):
            raise ValueError("joint_velocities sets how the rigid tree keeps its joints; "
                             "set dynamics = true and joints = true with it")
        check_contact(self.contact, self.push_out)
        if self.contact != "rigid" and not self.dynamics:
            raise ValueError("contact sets the rigid tree's contact model; set dynamics = true with it")


class ConstantTwist(Simulator):
    """Every moving body keeps its twist (least-squares fit of its nodes, :func:`mdgs.rigid.twist`) and
    moves rigidly over ``frame_dt`` (:func:`mdgs.rigid.advance`); static nodes stay."""

    name = "constant-twist"
    Config = ConstantTwistConfig
    learned = False
    summary = "reference: every body keeps its velocity and angular velocity (no forces)"

    @property
    def scalar_loops(self) -> bool:
        """Always: with ``dynamics`` the step is the rigid tree's forward dynamics (:attr:`Simulator.scalar_loops`),
        and without it each body's twist, motors and joints, loops over a few bodies' 3-vectors as well; scalar loops
        took the step ahead of time from 0.014 to 0.013 ms a frame (plain), 0.032 to 0.028 (+ joints) and 0.067 to
        0.060 (+ motors + joints) on the tiny Cubli, rollouts unchanged
        (``docs/results/benchmarks/compiled_dynamics-twist-loops.txt``)."""
        return True

    def bind(self, split: SplitData) -> None:
        super().bind(split)
        self._scene = SceneGraph.from_static(split.static, has_contact=split.has_contact)
        self._dt = float(split.frame_dt)
        self._drives = (drives_of(split.mj_model(), split.static["node_body"], split.static["node_centroid"])
                        if self.config.motors or self.config.dynamics else DriveSet())
        if self.config.dynamics:
            warn_unseen(self._drives, "the rigid tree reference")
        self._joints = (joints_of(split.mj_model(), split.static["node_body"], split.static["node_centroid"])
                        if self.config.joints else JointSet())
        if self.config.dynamics:
            warn_unprojected(self._drives, self.config.joints, "the rigid tree reference")

    def step(self, state: State, ctrl: torch.Tensor) -> State:
        x, v = state.x, state.v
        sc = self._scene
        seg, mass, ref = sc.obj.to(x.device), sc.mass.to(x.device), sc.ref_shape.to(x.device)
        m = (~sc.static).to(x.device).view(1, -1, 1)
        if self.config.dynamics:  # the whole tree's forward dynamics, in substeps (mdgs.tree)
            xn, vn = tree_step(x, v, ctrl, self._drives, ref, seg, sc.n_obj, mass, self._dt, self.config.substeps,
                               self.config.trapezoidal, self.config.push_out, self._joints,
                               self.config.gyroscopic, self.config.joint_velocities, self.config.contact)
            return State(torch.where(m, xn, x), torch.where(m, vn, torch.zeros_like(vn)))
        tw = twist(x, v, seg, sc.n_obj, mass)
        vc, w = tw.vc, tw.omega
        if self._drives:  # + the motors' velocity change over the frame (parents held, or the whole tree's)
            response = coupled_motor_accelerations if self.config.coupled else motor_accelerations
            acc = response(x, ctrl, self._drives, ref, seg, sc.n_obj)
            dvc, dw = project(acc * self._dt, x, tw, seg, sc.n_obj, mass)
            vc, w = vc + dvc, w + dw
        xn, vn = advance(x, tw, vc, w, self._dt, seg, trapezoidal=self.config.trapezoidal)
        if self._joints:  # hinged bodies stay hinged (the projection of MDGS's simulated steps)
            xn, vn = project_joints(xn, vn, self._joints, ref, seg, sc.n_obj, mass)
        return State(torch.where(m, xn, x), torch.where(m, vn, torch.zeros_like(vn)))


@dataclass(frozen=True)
class MuJoCoConfig:
    """Settings of :class:`MuJoCoReference`.

    dt_factor : timestep as a multiple of the dataset's ``dt`` (1: the data's own timestep;
        it must divide the dataset's substeps per frame, e.g. 20 = one step per frame for
        20-substep data).
    """

    dt_factor: int = 1
    velocity_noise: float = 0.0
    """Relative perturbation of the initial velocities: ``qvel * (1 + velocity_noise * N(0, 1))``
    per coordinate at the rollout's first frame (the sensitivity floor of a study; 0: none)."""
    noise_seed: int = 0
    """Seed of that perturbation (with the trajectory index)."""

    def __post_init__(self):
        if int(self.dt_factor) < 1:
            raise ValueError(f"dt_factor must be a positive integer, got {self.dt_factor!r}")
        if self.velocity_noise < 0:
            raise ValueError(f"velocity_noise must be >= 0, got {self.velocity_noise!r}")


class MuJoCoReference(Simulator):
    """MuJoCo replaying recorded trajectories at ``dt_factor`` times the dataset timestep.

    State ``extra``: ``qpos`` [B, nq], ``qvel`` [B, nv], ``act`` [B, na] (float64). Node positions
    and velocities are the element centroids moved with their bodies (``node_centroid`` in the
    body frame). A step in which MuJoCo warns of a bad acceleration (and resets) yields NaN, so
    the evaluator counts the trajectory as diverged instead of silently restarting it.
    """

    name = "mujoco"
    Config = MuJoCoConfig
    learned = False
    compilable = False
    summary = "reference: MuJoCo from the recorded initial state at dt_factor x the data's timestep"

    def bind(self, split: SplitData) -> None:
        super().bind(split)
        k = int(self.config.dt_factor)
        sub = int(split.attrs["substeps"])
        if sub % k:
            raise ModelError(f"dt_factor {k} does not divide the {sub} integrator steps per frame of {split.path}; "
                             f"choose a divisor of {sub}")
        try:
            self._model = split.mj_model()  # the stored MJCF with the files it reads
            self._model.opt.integrator = getattr(mujoco.mjtIntegrator, "mjINT_" + str(split.attrs["integrator"]))
        except Exception as e:  # noqa: BLE001 - MuJoCo reports parse/compile problems as several types
            raise ModelError(f"MuJoCo cannot rebuild the scene of {split.path} ({e}); regenerate the dataset") from None
        self._model.opt.timestep = float(split.attrs["dt"]) * k
        self._steps = sub // k
        self._data = mujoco.MjData(self._model)
        self._rows: list = []
        self._packed: tuple = (None,)  # (state key, packed full-physics states, rollout output) of cost_step
        st = split.static
        self._body = np.asarray(st["node_body"], int)
        self._local = np.asarray(st["node_centroid"], float)
        self._moving = ~np.asarray(st["node_static"], bool)

    def initial_state(self, split: SplitData, traj: np.ndarray, frame: int) -> State:
        base = super().initial_state(split, traj, frame)
        dev = self.device
        ex = {k: np.array(getattr(split, k)[traj, frame], np.float64) for k in ("qpos", "qvel", "act")}
        if self.config.velocity_noise > 0 and frame == 0:
            for row, i in enumerate(np.asarray(traj)):
                rng = np.random.default_rng([self.config.noise_seed, int(i)])
                ex["qvel"][row] *= 1.0 + self.config.velocity_noise * rng.standard_normal(ex["qvel"].shape[1])
            d = self._data
            xs, vs = [], []
            for row in range(len(ex["qpos"])):
                d.qpos[:], d.qvel[:] = ex["qpos"][row], ex["qvel"][row]
                x, v = self._nodes(d)
                xs.append(x)
                vs.append(v)
            base = State(torch.from_numpy(np.stack(xs)).to(dev, base.x.dtype),
                         torch.from_numpy(np.stack(vs)).to(dev, base.v.dtype))
        return State(base.x, base.v, {k: torch.from_numpy(a).to(dev) for k, a in ex.items()})

    def _nodes(self, d: mujoco.MjData) -> tuple[np.ndarray, np.ndarray]:
        """Node positions and velocities [N, 3] of the state in ``d`` (runs MuJoCo's kinematics)."""
        m = self._model
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        mujoco.mj_comVel(m, d)
        b = self._body
        x = d.xpos[b] + np.einsum("nij,nj->ni", d.xmat[b].reshape(-1, 3, 3), self._local)
        # cvel: [angular; linear] velocity about the subtree centre of mass of the body's root
        w, lin = d.cvel[b, :3], d.cvel[b, 3:]
        v = lin + np.cross(w, x - d.subtree_com[m.body_rootid[b]])
        v[~self._moving] = 0.0
        return x, v

    def step(self, state: State, ctrl: torch.Tensor) -> State:
        m = self._model
        B = state.x.shape[0]
        qpos, qvel, act = (state.extra[k].cpu().numpy() for k in ("qpos", "qvel", "act"))
        ctrl = ctrl.detach().cpu().numpy().astype(np.float64)
        out = {k: np.empty_like(a) for k, a in (("qpos", qpos), ("qvel", qvel), ("act", act))}
        xs = np.empty((B, len(self._body), 3))
        vs = np.empty_like(xs)
        bad = int(mujoco.mjtWarning.mjWARN_BADQACC)
        if len(self._rows) != B:  # one MjData per trajectory, so each keeps its solver warm start
            self._rows = [mujoco.MjData(m) for _ in range(B)]
        for i, d in enumerate(self._rows):
            d.warning[bad].number = 0
            d.qpos[:], d.qvel[:] = qpos[i], qvel[i]
            if m.na:
                d.act[:] = act[i]
            if m.nu:
                d.ctrl[:] = ctrl[i]
            for _ in range(self._steps):
                mujoco.mj_step(m, d)
            out["qpos"][i], out["qvel"][i] = d.qpos, d.qvel
            out["act"][i] = d.act if m.na else act[i]
            xs[i], vs[i] = self._nodes(d)
            if d.warning[bad].number or not np.isfinite(d.qacc).all():
                xs[i] = vs[i] = np.nan
        dev, dt = state.x.device, state.x.dtype
        return State(torch.from_numpy(xs).to(dev, dt), torch.from_numpy(vs).to(dev, dt),
                     {k: torch.from_numpy(a).to(dev) for k, a in out.items()})

    def cost_step(self, state: State, ctrl: torch.Tensor) -> State:
        """What a frame costs MuJoCo: its integrator steps for every row, from the state in ``state``.

        The mapping of MuJoCo's state to element nodes (:meth:`step`) serves only the comparison
        with the data, so the cost axis (:func:`mdgs.evaluate.cost.step_cost`) times this instead:
        one trajectory with ``mj_step`` on one MjData, a batch with ``mujoco.rollout`` (MuJoCo's
        own batched stepping in C, one thread; the rows' full physics states are packed once per
        state, outside the timed steps). Returns ``state`` unchanged.
        """
        m = self._model
        qpos, qvel = state.extra["qpos"].cpu().numpy(), state.extra["qvel"].cpu().numpy()
        c = ctrl.detach().cpu().numpy().astype(np.float64)
        B = len(qpos)
        if B == 1:
            d = self._data
            d.qpos[:], d.qvel[:] = qpos[0], qvel[0]
            if m.nu:
                d.ctrl[:] = c[0]
            for _ in range(self._steps):
                mujoco.mj_step(m, d)
            return state
        from mujoco import rollout as mj_rollout

        spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
        key = (state.extra["qpos"].data_ptr(), B)
        if self._packed[0] != key:
            d = self._data
            init = np.empty((B, mujoco.mj_stateSize(m, spec)))
            act = state.extra["act"].cpu().numpy()
            for i in range(B):
                d.qpos[:], d.qvel[:] = qpos[i], qvel[i]
                if m.na:
                    d.act[:] = act[i]
                mujoco.mj_getState(m, d, init[i], spec)
            self._packed = (key, init, np.empty((B, self._steps, init.shape[1])))
        _, init, out = self._packed
        control = c[:, None, :] if m.nu else None
        mj_rollout.rollout(m, self._data, init, control, nstep=self._steps, state=out, skip_checks=False)
        return state
