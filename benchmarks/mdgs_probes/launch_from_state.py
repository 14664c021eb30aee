"""From a trained MDGS's own state partway along a test trajectory, what do MuJoCo and the rigid tree do?
Rolls the run out on the test split, takes its state (node positions and velocities) of trajectory TRAJ at
each FRAME, turns it into MuJoCo's qpos and qvel (each object's pose fitted to its nodes, the twist from
their velocities, hinge and slide coordinates as `mdgs.actuation` reads them; checked by mapping the
recorded state and replaying it), and steps from there to the end of the trajectory with the recorded
controls: MuJoCo at the data's own timestep, the rigid tree (the run with its state network zeroed) and
the run itself. Prints the lowest moving node's height every 4 frames, and the highest it reaches, for
each (docs/mdgs-experiments.md, "What the learned correction adds to the rigid tree").

    python benchmarks/mdgs_probes/launch_from_state.py RUN DATA_FOLDER TRAJ FRAME [FRAME ...]

RUN is a run trained with ``actuation = "dynamics"`` on a scene whose moving objects hang on one free
joint, hinges and slides (rotational-center, the Cubli, the user scene).
"""
import copy
import sys

import mujoco
import numpy as np
import torch

from mdgs.actuation import _joint_angles
from mdgs.data.split import load_split
from mdgs.evaluate.rollout import rollout
from mdgs.models.base import State
from mdgs.rigid import twist
from mdgs.runs import load_run
from mdgs.structure import kabsch

torch.set_num_threads(1)
run, data, traj, frames = sys.argv[1], sys.argv[2], int(sys.argv[3]), [int(f) for f in sys.argv[4:]]
d = load_split(f"{data}/test.h5")
mj = d.mj_model()
model, _ = load_run(run, "cpu")
model.eval()
model.bind(d)
start = copy.deepcopy(model)
start.state.zero_output()
sc, links = model.scene_on("cpu"), model._drives.links
nb, nc = d.static["node_body"], d.static["node_centroid"]
obj, S, mv = sc.obj.numpy(), sc.n_obj, d.moving
body_of = {o: int(np.unique(nb[obj == o])[0]) for o in range(S) if (obj == o).any()}


def to_mujoco(x: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """qpos, qvel of node positions and velocities [N, 3]."""
    x, v = (torch.tensor(a[None], dtype=torch.float64) for a in (x, v))
    R, t = kabsch(sc.ref_shape.double(), x, sc.obj, S)
    tw = twist(x, v, sc.obj, S, sc.mass)
    qpos, qvel = np.array(mj.qpos0, float), np.zeros(mj.nv)
    for lk in links:
        o = lk.child
        (j,) = [j for j in range(mj.njnt) if mj.jnt_bodyid[j] == body_of[o]]
        qa, va = mj.jnt_qposadr[j], mj.jnt_dofadr[j]
        w = tw.omega[0, o].numpy()
        if lk.kind == "free":
            pos, quat = t[0, o].numpy(), np.zeros(4)
            mujoco.mju_mat2Quat(quat, R[0, o].numpy().reshape(-1))
            qpos[qa:qa + 3], qpos[qa + 3:qa + 7] = pos, quat
            qvel[va:va + 3] = tw.vc[0, o].numpy() + np.cross(w, pos - tw.c[0, o].numpy())
            qvel[va + 3:va + 6] = R[0, o].numpy().T @ w
        elif lk.kind in ("hinge", "slide"):
            qpos[qa] = float(_joint_angles(R, t, lk, model._drives)[0])
            Rp = R[0, lk.parent].numpy() if lk.parent >= 0 else np.eye(3)
            wp = tw.omega[0, lk.parent].numpy() if lk.parent >= 0 else np.zeros(3)
            if lk.kind == "hinge":
                qvel[va] = (Rp @ lk.axis) @ (w - wp)
            else:
                raise SystemExit("slides are not mapped by this probe")
        else:
            raise SystemExit(f"a {lk.kind} joint is not mapped by this probe")
    return qpos, qvel


def mujoco_nodes(qpos, qvel, f0: int) -> np.ndarray:
    """Node positions [T, N, 3] from frame f0 to the end, MuJoCo at the data's timestep."""
    dat = mujoco.MjData(mj)
    dat.qpos[:], dat.qvel[:] = qpos, qvel
    out = []
    for f in range(f0, d.x.shape[1]):
        mujoco.mj_kinematics(mj, dat)
        out.append(dat.xpos[nb] + np.einsum("nij,nj->ni", dat.xmat[nb].reshape(-1, 3, 3), nc))
        dat.ctrl[:] = d.ctrl[traj, f]
        for _ in range(int(d.attrs["substeps"])):
            mujoco.mj_step(mj, dat)
    return np.array(out)


def model_nodes(sim, x, v, f0: int) -> np.ndarray:
    st, out = State(torch.tensor(x[None]).float(), torch.tensor(v[None]).float()), [x]
    with torch.no_grad():
        for f in range(f0, d.x.shape[1] - 1):
            st = sim.step(st, torch.tensor(d.ctrl[traj:traj + 1, f], dtype=torch.float32))
            out.append(st.x[0].numpy())
    return np.array(out)


q, qd = to_mujoco(d.x[traj, 0], d.v[traj, 0])
check = np.abs(mujoco_nodes(q, qd, 0) - d.x[traj]).max()
print(f"recorded state mapped and replayed in MuJoCo: {check:.2g} m from the data at most", flush=True)
r = rollout(model, d, "cpu")
print(f"data: lowest moving node's height at most {d.x[traj][:, mv, 2].min(-1).max():.3f} m over the trajectory")
for f0 in frames:
    x, v = r.x[traj, f0].astype(np.float64), r.v[traj, f0].astype(np.float64)
    for name, xs in (("mujoco", mujoco_nodes(*to_mujoco(x, v), f0)), ("rigid tree", model_nodes(start, x, v, f0)),
                     ("the run", model_nodes(model, x, v, f0))):
        low = xs[:, mv, 2].min(-1)
        print(f"from the run's frame {f0:3d}, {name:10s}: lowest node every 4 frames "
              + " ".join(f"{z:.3f}" for z in low[::4]) + f"; highest it gets {low.max():.3f} m", flush=True)
