"""What each piece of physics the rigid tree once left out carries of a scene's motion: every test trajectory
replayed in MuJoCo (the recorded initial state and controls, the data's own timestep) as recorded, then with
the world's obstacles (its colliding geoms other than planes) switched off, with the joints' range limits
switched off, and with both; position MSE against the recorded nodes at t = 40 and t = 110 (10^-3 m^2, mean
over the test trajectories, moving nodes) (docs/mdgs-experiments.md, "Limits and obstacles").

    python benchmarks/mdgs_probes/unseen_physics.py DATA_FOLDER SCENE [SCENE ...]

DATA_FOLDER is a study's ``data/``. Also prints, per trajectory, the first frame at which MuJoCo touches an
obstacle and the first at which a range limit acts (None: never).
"""
import sys

import mujoco
import numpy as np

from mdgs.data.split import load_split


def replay(d, i, model, watch=False):
    """Node positions [T, N, 3] of trajectory ``i`` replayed in ``model``; with ``watch``, also the first
    frames of obstacle contact and of an active range limit."""
    data = mujoco.MjData(model)
    k = int(d.attrs["substeps"])
    nb, nc = d.static["node_body"], d.static["node_centroid"]
    obstacles = {g for g in range(model.ngeom) if model.geom_bodyid[g] == 0
                 and model.geom_type[g] != mujoco.mjtGeom.mjGEOM_PLANE}
    data.qpos[:], data.qvel[:] = d.qpos[i, 0], d.qvel[i, 0]
    T = d.qpos.shape[1]
    out, touch, limit = np.zeros((T, len(nb), 3)), None, None
    for t in range(T):
        mujoco.mj_kinematics(model, data)
        out[t] = data.xpos[nb] + np.einsum("nij,nj->ni", data.xmat[nb].reshape(-1, 3, 3), nc)
        data.ctrl[:] = d.ctrl[i, t]
        for _ in range(k):
            mujoco.mj_step(model, data)
            if watch and touch is None and any(int(data.contact[c].geom1) in obstacles
                                               or int(data.contact[c].geom2) in obstacles
                                               for c in range(data.ncon)):
                touch = t
            if watch and limit is None and np.any(data.efc_type[:data.nefc] == mujoco.mjtConstraint.mjCNSTR_LIMIT_JOINT):
                limit = t
    return out, touch, limit


def mse(d, model):
    moving = np.asarray(d.moving, bool) if d.moving is not None else slice(None)
    e = np.array([((replay(d, i, model)[0] - d.x[i]) ** 2).sum(-1)[:, moving].mean(-1) for i in range(len(d.qpos))])
    return e[:, 39].mean() * 1e3, e[:, -1].mean() * 1e3


for scene in sys.argv[2:]:
    d = load_split(f"{sys.argv[1]}/{scene}/test.h5")
    print(scene, flush=True)
    for i in range(len(d.qpos)):
        _, touch, limit = replay(d, i, d.mj_model(), watch=True)
        print(f"  trajectory {i}: first obstacle contact at frame {touch}, first active limit at frame {limit}")
    variants = {"as recorded": d.mj_model()}
    m = d.mj_model()
    obstacles = [g for g in range(m.ngeom) if m.geom_bodyid[g] == 0 and m.geom_type[g] != mujoco.mjtGeom.mjGEOM_PLANE]
    m.geom_contype[obstacles], m.geom_conaffinity[obstacles] = 0, 0
    variants["no obstacles"] = m
    m = d.mj_model()
    m.jnt_limited[:] = 0
    variants["no range limits"] = m
    m = d.mj_model()
    m.geom_contype[obstacles], m.geom_conaffinity[obstacles], m.jnt_limited[:] = 0, 0, 0
    variants["neither"] = m
    for name, model in variants.items():
        t40, t110 = mse(d, model)
        print(f"  {name:16s} t=40 {t40:9.3g}  t=110 {t110:9.3g}", flush=True)
