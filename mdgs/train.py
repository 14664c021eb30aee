"""Training of MDGS on the HDF5 datasets (Section 3.4, Appendix B.2).

Settings of Appendix B.2: Adam (lr 1e-3, betas (0.9, 0.999)); ReduceLROnPlateau on the
validation loss (patience 3, factor 0.8); training noise (4e-4 for Cubli scenes, 0.06 x
std for the others; see :func:`noise_sigmas` for exactly what is perturbed); one input
frame ``t`` predicts frame ``t + 1``. A batch holds ``batch_size`` graphs of the scene
(block-diagonal batching, :mod:`mdgs.graphs`).

A run folder ``OUT`` holds:

- ``config.json``   the resolved configuration (model scales, noise sigmas, data identity, device);
- ``checkpoint.pt`` model, optimiser, scheduler, history; written atomically after every epoch;
- ``metrics.json``  one record per epoch (train L_mse, L_cst, valid one-step MSE, lr, seconds);
- ``steps.json``    the training loss every ``log_every`` steps (the live loss of the progress bar).

Running the same ``mdgs train`` command again resumes from the last finished epoch; the
random stream of epoch ``e`` is seeded by ``(seed, e)``, so a resumed run continues exactly
as an uninterrupted one would (up to floating-point nondeterminism of the device).

Actuated scenes: each actuator's control ``ctrl_k`` (actuator units) enters the node
features of the body it drives (+ctrl_k) and of that body's parent (-ctrl_k, the reaction),
one channel per actuator; see :func:`control_map` and docs/ambiguities.md.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path

import numpy as np
import torch

from mdgs.data.schema import DatasetError
from mdgs.graphs import SceneGraph
from mdgs.losses import constraint_loss, mse_loss, speeds_of
from mdgs.model import MDGS, ModelConfig
from mdgs.rigid import advance, perturb, twist

__all__ = [
    "TrainConfig",
    "SplitData",
    "RunError",
    "load_split",
    "control_map",
    "noise_sigmas",
    "train",
    "load_run",
]

#: Training noise of Appendix B.2: absolute sigma (m, m/s) for Cubli scenes.
CUBLI_NOISE = 4e-4
#: Training noise of Appendix B.2 for the other scenes, as a fraction of the per-step increment std.
INCREMENT_NOISE = 0.06


class RunError(Exception):
    """A run folder or checkpoint that cannot be used; the message names it and the fix."""


@dataclass
class TrainConfig:
    """Training run settings; every default documented here.

    Attributes
    ----------
    data : folder with ``train.h5`` and ``valid.h5`` (``mdgs generate`` output).
    out : run folder (see the module docstring).
    epochs : passes over all (trajectory, frame) training pairs.
    batch_size : graphs per optimisation step.
    lr : Adam learning rate (B.2: 1e-3); betas (0.9, 0.999) and the plateau scheduler
        (patience 3, factor 0.8) are fixed to the paper's values.
    noise : "auto" (B.2: ``abs:4e-4`` for Cubli scenes, ``inc:0.06`` otherwise),
        ``abs:S`` (sigma S in m and m/s) or ``inc:F`` (F x std of the per-step increments),
        or ``none``. See :func:`noise_sigmas`.
    seed : seeds parameter initialisation, batch order and noise.
    device : "auto" (CUDA when present), "cpu" or "cuda".
    max_steps : cap on optimisation steps per epoch (0: no cap, a full pass).
    valid_max_pairs : cap on validation pairs per epoch (0: all; an even subsample otherwise).
    log_every : steps between entries of ``steps.json``.
    model : the :class:`ModelConfig`; scales left at 1.0 and ``control_dim`` are filled from data.
    """

    data: str = "data"
    out: str = "runs/mdgs"
    epochs: int = 20
    batch_size: int = 32
    lr: float = 1e-3
    noise: str = "auto"
    seed: int = 0
    device: str = "auto"
    max_steps: int = 0
    valid_max_pairs: int = 0
    log_every: int = 10
    model: ModelConfig = field(default_factory=ModelConfig)


@dataclass
class SplitData:
    """One split in memory.

    x, v : [T, F, N, 3] float32 node positions (m) and velocities (m/s).
    control : [T, F, N, C] float32 per-node control features (C = number of actuators, may be 0).
    static : the file's ``/static`` arrays.  attrs : root attributes.  frame_dt : s.
    """

    x: np.ndarray
    v: np.ndarray
    control: np.ndarray
    static: dict
    attrs: dict
    frame_dt: float
    has_contact: bool
    path: str = ""

    def pairs(self) -> np.ndarray:
        """All (trajectory, frame) indices with a next frame -> [P, 2]."""
        T, F = self.x.shape[:2]
        return np.stack(np.meshgrid(np.arange(T), np.arange(F - 1), indexing="ij"), -1).reshape(-1, 2)

    @property
    def moving(self) -> np.ndarray:
        return ~np.asarray(self.static["node_static"], bool)

    def identity(self) -> dict:
        """What a checkpoint must agree with: scene, MJCF hash, node and actuator counts."""
        return {"scene": str(self.attrs["scene"]), "family": str(self.attrs.get("family", "")),
                "mjcf_sha256": str(self.attrs["mjcf_sha256"]), "n_nodes": int(self.x.shape[2]),
                "n_actuators": int(self.control.shape[-1])}


def control_map(mjcf: str, node_body: np.ndarray) -> np.ndarray:
    """Signs ``[nu, N]``: +1 on nodes of the body actuator k drives, -1 on its parent's, 0 elsewhere.

    The driven body is read from the MJCF compiled by MuJoCo: the body of the actuator's
    joint (transmission ``joint``/``jointinparent``) or of its site (``site``). Tendon and
    other transmissions drive no single body and get no nodes. Nodes of the world (body 0)
    get no reaction. The feature of node i is then ``control[i, k] = sign[k, i] * ctrl_k``.
    """
    import mujoco

    m = mujoco.MjModel.from_xml_string(mjcf)
    node_body = np.asarray(node_body)
    sign = np.zeros((m.nu, len(node_body)), np.float32)
    for k in range(m.nu):
        typ, tid = int(m.actuator_trntype[k]), int(m.actuator_trnid[k, 0])
        if typ in (int(mujoco.mjtTrn.mjTRN_JOINT), int(mujoco.mjtTrn.mjTRN_JOINTINPARENT)):
            body = int(m.jnt_bodyid[tid])
        elif typ == int(mujoco.mjtTrn.mjTRN_SITE):
            body = int(m.site_bodyid[tid])
        else:
            continue
        parent = int(m.body_parentid[body])
        sign[k, node_body == body] = 1.0
        if parent != 0:
            sign[k, node_body == parent] = -1.0
    return sign


def load_split(path: str | os.PathLike) -> SplitData:
    """Read one dataset file (checked by :func:`mdgs.data.io.open_dataset`); reject non-finite states.

    Raises :class:`~mdgs.data.schema.DatasetError` naming the file and the fix.
    """
    from mdgs.data.io import open_dataset

    with open_dataset(path) as ds:
        x = ds.frames("node_pos").astype(np.float32)
        v = ds.frames("node_vel").astype(np.float32)
        ctrl = ds.frames("ctrl").astype(np.float32)  # [T, F, nu]
        static = dict(ds.static)
        attrs = dict(ds.attrs)
        mjcf = ds.mjcf
    for name, a in (("node_pos", x), ("node_vel", v), ("ctrl", ctrl)):
        if not np.isfinite(a).all():
            t = int(np.argwhere(~np.isfinite(a))[0][0])
            raise DatasetError(f"{path}: /frames/{name} holds NaN or infinite values (first in trajectory {t}); "
                               "regenerate the dataset with `mdgs generate` or remove that trajectory")
    if x.shape[1] < 2:
        raise DatasetError(f"{path} has fewer than 2 frames per trajectory; generate a dataset with more frames")
    sign = control_map(mjcf, static["node_body"]) if ctrl.shape[-1] else np.zeros((0, x.shape[2]), np.float32)
    control = np.einsum("tfk,kn->tfnk", ctrl, sign).astype(np.float32)
    return SplitData(x=x, v=v, control=control, static=static, attrs=attrs, frame_dt=float(attrs["frame_dt"]),
                     has_contact=bool(attrs["has_contact"]), path=str(path))


def _device(name: str) -> torch.device:
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cuda" and not torch.cuda.is_available():
        raise RunError("--device cuda was asked for but no CUDA device is present; use --device auto or cpu")
    if name not in ("cpu", "cuda"):
        raise RunError(f"--device {name!r} is not known; use auto, cpu or cuda")
    return torch.device(name)


def _increments(d: SplitData) -> tuple[np.ndarray, np.ndarray]:
    mv = d.moving
    return (d.x[:, 1:] - d.x[:, :-1])[:, :, mv], (d.v[:, 1:] - d.v[:, :-1])[:, :, mv]


def noise_sigmas(spec: str, d: SplitData) -> tuple[float, float]:
    """Noise std ``(sigma_x [m], sigma_v [m/s])`` of the spec ``auto``, ``abs:S``, ``inc:F`` or ``none``.

    What is perturbed: the *input* frame only, ``x_t + sigma_x * eps``, ``v_t + sigma_v * eps'``
    with independent standard normal ``eps`` per moving node and coordinate (static nodes are
    never perturbed); the targets ``x_{t+1}, v_{t+1}`` stay clean, so the model learns to pull a
    perturbed state back onto the true trajectory (the noise-corrected target of
    Sanchez-Gonzalez et al. 2020 for a one-frame input). ``inc:F`` sets each sigma to F times
    the std of the per-step increments ``x_{t+1} - x_t`` (resp. ``v_{t+1} - v_t``) of the
    training set: the scale the model predicts, so the noise never swamps one step. The
    paper's "0.06 times the standard deviation" names no quantity; a fraction of the states'
    own spread (metres for positions) is larger than a whole step and was found to make the
    one-step target unlearnable. Cubli scenes use the paper's absolute 4e-4 (m and m/s).
    """
    s = spec.strip().lower()
    if s == "auto":
        s = f"abs:{CUBLI_NOISE}" if str(d.attrs.get("family", "")) == "cubli" else f"inc:{INCREMENT_NOISE}"
    if s == "none":
        return 0.0, 0.0
    kind, _, val = s.partition(":")
    try:
        f = float(val)
    except ValueError:
        f = -1.0
    if kind not in ("abs", "inc") or not np.isfinite(f) or f < 0:
        raise RunError(f"--noise {spec!r} is not understood; use auto, none, abs:SIGMA (m, m/s) or inc:FRACTION")
    if kind == "abs":
        return f, f
    dx, dv = _increments(d)
    return f * float(dx.std()), f * float(dv.std())


def _rigid_increments(d: SplitData, scene: SceneGraph, dt: float, trapezoidal: bool = False,
                      max_pairs: int = 4096) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """What the rigid integrators' g predicts, on (up to ``max_pairs``) training pairs.

    Returns the node velocity increments of the rigid twist change ``(v_c' - v_c) + (w' - w) x r_i``
    and the position residual ``x' - advance(x, twist', dt)``, both [P, N_moving, 3], and the
    moving objects' increments ``v_c' - v_c`` and ``w' - w`` [P, S_moving, 3].
    """
    pairs = d.pairs()
    if len(pairs) > max_pairs:
        pairs = pairs[np.linspace(0, len(pairs) - 1, max_pairs).astype(int)]
    t, f = pairs[:, 0], pairs[:, 1]
    x0, v0 = torch.from_numpy(d.x[t, f]).double(), torch.from_numpy(d.v[t, f]).double()
    x1, v1 = torch.from_numpy(d.x[t, f + 1]).double(), torch.from_numpy(d.v[t, f + 1]).double()
    seg, n, mass = scene.obj, scene.n_obj, scene.mass
    a, b = twist(x0, v0, seg, n, mass), twist(x1, v1, seg, n, mass)
    r = x0 - a.c[:, seg]
    dv = (b.vc - a.vc)[:, seg] + torch.linalg.cross((b.omega - a.omega)[:, seg], r, dim=-1)
    xr, _ = advance(x0, a, b.vc, b.omega, dt, seg, trapezoidal=trapezoidal)
    mv = d.moving
    objs = np.unique(np.asarray(seg)[mv])
    return (dv[:, mv].numpy(), (x1 - xr)[:, mv].numpy(), (b.vc - a.vc)[:, objs].numpy(),
            (b.omega - a.omega)[:, objs].numpy())


def _resolve_model(cfg: ModelConfig, d: SplitData, scene: SceneGraph | None = None) -> ModelConfig:
    """Fill scales left at 1.0 from the training data and set ``control_dim`` and ``dt``.

    ``dx_scale``, ``dv_scale``: std of what g predicts under the chosen integrator (position
    residual and velocity increment); ``force_scale``: mean ``|M dv / dt|`` of an element.
    """
    dx, dv = _increments(d)
    mass = np.asarray(d.static["node_mass"])[d.moving]
    kw = {"control_dim": int(d.control.shape[-1])}
    if cfg.dt <= 0.0:
        kw["dt"] = float(d.frame_dt)
    dt = kw.get("dt", cfg.dt)
    f_scale = float(max(np.abs(mass[None, None, :, None] * dv / d.frame_dt).mean(), 1e-9))
    if cfg.integrator == "euler":  # the learned position term is the residual x' - x - dt v'
        xs, vs = d.x[..., d.moving, :], d.v[..., d.moving, :]
        dx = (xs[:, 1:] - xs[:, :-1] - dt * vs[:, 1:]).reshape(-1, 3)
    elif cfg.integrator in ("rigid", "twist"):
        if scene is None:
            raise ValueError("the rigid integrators' scales need the scene graph")
        dv, dx, dvc, dw = _rigid_increments(d, scene, dt, trapezoidal=cfg.integrator == "twist")
        if cfg.integrator == "twist":
            if cfg.dvc_scale == 1.0:
                kw["dvc_scale"] = float(max(dvc.std(), 1e-12))
            if cfg.dw_scale == 1.0:
                kw["dw_scale"] = float(max(dw.std(), 1e-12))
    # twist: g has no position output; a velocity error weighs like the position error it makes
    # over half a frame. Otherwise: the spread of g's position target.
    dx_auto = dt / 2 * float(dv.std()) if cfg.integrator == "twist" else float(dx.std())
    if cfg.dx_scale == 1.0:
        kw["dx_scale"] = max(dx_auto, 1e-12)
    if cfg.dv_scale == 1.0:
        kw["dv_scale"] = float(max(dv.std(), 1e-12))
    if cfg.force_scale == 1.0:  # typical |M dv / dt| of an element, N
        kw["force_scale"] = f_scale
    return replace(cfg, **kw)


def _feature_stats(model: MDGS, scene: SceneGraph, d: SplitData) -> tuple[torch.Tensor, torch.Tensor]:
    """Mean and std of the raw node features z over 256 random training frames -> [d_z] each."""
    n = d.x.shape[0] * d.x.shape[1]
    idx = np.random.default_rng(0).choice(n, size=min(256, n), replace=False)
    x = torch.tensor(d.x.reshape(-1, *d.x.shape[2:])[idx])
    v = torch.tensor(d.v.reshape(-1, *d.v.shape[2:])[idx])
    c = torch.tensor(d.control.reshape(-1, *d.control.shape[2:])[idx])
    z = model.node_features(scene, x, v, c).reshape(-1, model.d_z)
    return z.mean(0), z.std(0)


def step_losses(model: MDGS, scene: SceneGraph, cfg: ModelConfig, x, v, c, xt, vt, dt: float, moving):
    """``(L_mse, L_cst)`` of one batch: Eq. (10) on scaled ``[x || v]`` and Eqs. (13)-(15)."""
    p = model(scene, x, v, c)
    l_mse = mse_loss(p.x, p.v, xt, vt, moving, cfg.dx_scale, cfg.dv_scale)  # Eq. (10)
    l_cst = constraint_loss(p.force, x, v, p.x, p.v, scene.mass, scene.tau, scene.obj, scene.n_obj, dt,
                            moving=moving, bound=cfg.bound, speeds=speeds_of(cfg.variant),
                            scale=cfg.force_scale * int(moving.sum()))  # Eqs. (13)-(15)
    return l_mse, l_cst


def batch_of(d: SplitData, idx: np.ndarray, dev) -> tuple[torch.Tensor, ...]:
    """Frames ``(x_t, v_t, control_t, x_{t+1}, v_{t+1})`` [B, N, .] for pairs ``idx`` [B, 2]."""
    t, f = idx[:, 0], idx[:, 1]
    g = lambda a, k: torch.from_numpy(a[t, f + k]).to(dev)  # noqa: E731
    return g(d.x, 0), g(d.v, 0), g(d.control, 0), g(d.x, 1), g(d.v, 1)


@torch.no_grad()
def one_step_mse(model: MDGS, scene: SceneGraph, d: SplitData, dev, batch_size: int = 64,
                 max_pairs: int = 0) -> float:
    """One-step L_mse (Eq. 10, scaled by the model's dx/dv scales, moving nodes) over a split."""
    model.eval()
    moving = ~scene.static
    pairs = d.pairs()
    if max_pairs and len(pairs) > max_pairs:
        pairs = pairs[np.linspace(0, len(pairs) - 1, max_pairs).astype(int)]
    err = 0.0
    for s in range(0, len(pairs), batch_size):
        x, v, c, xt, vt = batch_of(d, pairs[s:s + batch_size], dev)
        p = model(scene, x, v, c)
        err += mse_loss(p.x, p.v, xt, vt, moving, model.config.dx_scale, model.config.dv_scale).item() * len(x)
    return err / len(pairs)


def _atomic_write(path: Path, write: Callable[[Path], None]) -> None:
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    try:
        write(tmp)
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def atomic_json(obj, path: Path) -> None:
    """Write ``obj`` as JSON to ``path`` atomically (temporary sibling, then rename)."""
    _atomic_write(Path(path), lambda p: p.write_text(json.dumps(obj, indent=2) + "\n"))


def _train_fingerprint(cfg: TrainConfig) -> dict:
    """The settings that must agree for a resume (not epochs, step caps or device: a run may be extended)."""
    d = asdict(cfg)
    for k in ("data", "out", "epochs", "device", "log_every", "max_steps", "valid_max_pairs"):
        d.pop(k)
    return d


def _load_checkpoint(path: Path, dev) -> dict:
    try:
        state = torch.load(path, map_location=dev, weights_only=False)
    except Exception as e:  # noqa: BLE001 - any unreadable file is the same user error
        raise RunError(f"{path} cannot be read ({type(e).__name__}); delete it to start the run afresh, "
                       "or point to another run folder") from None
    need = ("model", "opt", "sched", "epoch", "config", "train_fingerprint", "data_identity", "history", "steps")
    if not isinstance(state, dict) or any(k not in state for k in need):
        raise RunError(f"{path} is not a checkpoint of this version of `mdgs train`; delete it to start the run "
                       "afresh, or point to another run folder")
    return state


def train(cfg: TrainConfig, progress: Callable[[dict], None] | None = None,
          splits: dict | None = None) -> dict:
    """Train (or resume) the run ``cfg.out``; returns the last epoch's metrics.

    ``progress(event)`` is called with ``{"kind": "start"|"step"|"epoch", ...}``.
    ``splits`` (``{"train": SplitData, "valid": SplitData}``) bypasses the files.
    Raises :class:`RunError` or :class:`~mdgs.data.schema.DatasetError` for user errors.
    """
    progress = progress or (lambda e: None)
    out = Path(cfg.out)
    if splits is None:
        data = Path(cfg.data)
        if not data.is_dir():
            raise DatasetError(f"data folder {data} does not exist; create it with `mdgs generate SCENE --out {data}`")
        splits = {s: load_split(data / f"{s}.h5") for s in ("train", "valid")}
    tr, va = splits["train"], splits["valid"]
    if tr.identity()["mjcf_sha256"] != va.identity()["mjcf_sha256"]:
        raise DatasetError(f"{va.path} is of another scene than {tr.path}; use the three files of one `mdgs generate` run")
    dev = _device(cfg.device)
    scene_cpu = SceneGraph.from_static(tr.static, has_contact=tr.has_contact)
    mcfg = _resolve_model(cfg.model, tr, scene_cpu)
    sig_x, sig_v = noise_sigmas(cfg.noise, tr)
    resolved = {**asdict(cfg), "model": mcfg.to_dict(), "device": str(dev),
                "noise_sigma_x_m": sig_x, "noise_sigma_v_m_per_s": sig_v, "data_identity": tr.identity(),
                "frame_dt_s": tr.frame_dt, "train_pairs": int(len(tr.pairs()))}
    ckpt_path = out / "checkpoint.pt"
    state = _load_checkpoint(ckpt_path, dev) if ckpt_path.exists() else None
    if state is not None:
        if state["data_identity"]["mjcf_sha256"] != tr.identity()["mjcf_sha256"]:
            raise RunError(f"{out} holds a run trained on scene {state['data_identity']['scene']!r}, not on "
                           f"{tr.identity()['scene']!r} from {cfg.data}; choose another --out or delete {ckpt_path}")
        if state["train_fingerprint"] != _train_fingerprint(cfg):
            diff = sorted(k for k, v in _train_fingerprint(cfg).items() if state["train_fingerprint"].get(k) != v)
            raise RunError(f"{out} holds a run with other settings ({', '.join(diff)} differ); rerun with the "
                           f"settings in {out / 'config.json'}, choose another --out, or delete {ckpt_path}")
    out.mkdir(parents=True, exist_ok=True)
    torch.manual_seed(cfg.seed)
    scene = scene_cpu.to(dev)
    model = MDGS(mcfg, contact=tr.has_contact).to(dev)
    model.set_normalization(*_feature_stats(model, scene_cpu, tr))
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr, betas=(0.9, 0.999))
    sched = torch.optim.lr_scheduler.ReduceLROnPlateau(opt, patience=3, factor=0.8)
    history, steps_log, start = [], [], 0
    if state is not None:
        model.load_state_dict(state["model"])
        opt.load_state_dict(state["opt"])
        sched.load_state_dict(state["sched"])
        history, steps_log, start = state["history"], state["steps"], state["epoch"] + 1
    atomic_json(resolved, out / "config.json")
    moving = ~scene.static
    mv = moving.view(1, -1, 1).to(torch.float32)
    pairs_all = tr.pairs()
    n_steps = max(1, len(pairs_all) // cfg.batch_size)
    if cfg.max_steps:
        n_steps = min(n_steps, cfg.max_steps)
    progress({"kind": "start", "epoch": start, "epochs": cfg.epochs, "steps": n_steps, "device": str(dev)})
    for epoch in range(start, cfg.epochs):
        t0 = time.perf_counter()
        rng = np.random.default_rng([cfg.seed, epoch])  # same stream whether resumed or not
        gen = torch.Generator(device=dev).manual_seed(int(rng.integers(2**62)))
        pairs = rng.permutation(pairs_all)
        model.train()
        tot = np.zeros(2)
        for s in range(n_steps):
            x, v, c, xt, vt = batch_of(tr, pairs[s * cfg.batch_size:(s + 1) * cfg.batch_size], dev)
            # training noise (B.2) on the input frame's moving nodes; targets stay clean (noise_sigmas)
            nx = sig_x * mv * torch.randn(x.shape, generator=gen, device=dev)
            nv = sig_v * mv * torch.randn(v.shape, generator=gen, device=dev)
            if mcfg.integrator in ("rigid", "twist"):  # rigid rollouts see rigid errors: perturb each object rigidly
                xn, vn = perturb(x, v, nx, nv, scene.obj, scene.n_obj, scene.mass)
                x, v = torch.where(mv > 0, xn, x), torch.where(mv > 0, vn, v)
            else:
                x, v = x + nx, v + nv
            l_mse, l_cst = step_losses(model, scene, mcfg, x, v, c, xt, vt, tr.frame_dt, moving)
            loss = l_mse + mcfg.cst_weight * l_cst  # Section 3.4: summed
            if not torch.isfinite(loss):
                raise RunError(f"training diverged at epoch {epoch}, step {s} (loss {loss.item()}); "
                               f"lower --lr or the noise, or delete {ckpt_path} to restart from scratch")
            opt.zero_grad()
            loss.backward()
            opt.step()
            tot += [l_mse.item(), l_cst.item()]
            if s % cfg.log_every == 0 or s == n_steps - 1:
                steps_log.append({"epoch": epoch, "step": s, "loss": loss.item(), "l_mse": l_mse.item(),
                                  "l_cst": l_cst.item()})
            progress({"kind": "step", "epoch": epoch, "step": s + 1, "steps": n_steps, "loss": loss.item(),
                      "l_mse": l_mse.item(), "l_cst": l_cst.item()})
        train_s = time.perf_counter() - t0
        val = one_step_mse(model, scene, va, dev, max(cfg.batch_size, 64), cfg.valid_max_pairs)
        sched.step(val)
        rec = {"epoch": epoch, "train_mse": float(tot[0] / n_steps), "train_cst": float(tot[1] / n_steps),
               "valid_mse": val, "lr": opt.param_groups[0]["lr"], "steps": n_steps,
               "train_seconds": train_s, "seconds": time.perf_counter() - t0}
        history.append(rec)
        ckpt = {"model": model.state_dict(), "opt": opt.state_dict(), "sched": sched.state_dict(), "epoch": epoch,
                "config": resolved, "train_fingerprint": _train_fingerprint(cfg), "data_identity": tr.identity(),
                "has_contact": tr.has_contact, "history": history, "steps": steps_log}
        _atomic_write(ckpt_path, lambda p, ckpt=ckpt: torch.save(ckpt, p))
        atomic_json(history, out / "metrics.json")
        atomic_json(steps_log, out / "steps.json")
        progress({"kind": "epoch", **rec})
    return history[-1] if history else {}


def load_run(run: str | os.PathLike, dev) -> tuple[MDGS, dict]:
    """Load ``<run>/checkpoint.pt`` -> (model on ``dev`` in eval mode, checkpoint dict)."""
    path = Path(run) / "checkpoint.pt"
    if not Path(run).is_dir():
        raise RunError(f"run folder {run} does not exist; train one with `mdgs train --data DIR --out {run}`")
    if not path.exists():
        raise RunError(f"{run} has no checkpoint.pt (no epoch finished yet); run `mdgs train` with --out {run} first")
    state = _load_checkpoint(path, dev)
    mc = state["config"]["model"]
    mcfg = ModelConfig(**{f.name: mc[f.name] for f in fields(ModelConfig) if f.name in mc})
    model = MDGS(mcfg, contact=state["has_contact"]).to(dev)
    try:
        model.load_state_dict(state["model"])
    except RuntimeError:
        raise RunError(f"{path} does not match the model configuration in it (edited or from another mdgs "
                       "version); retrain the run with `mdgs train`") from None
    model.eval()
    return model, state


def _train_with_progress(cfg: TrainConfig) -> dict:
    from rich.progress import TextColumn

    from mdgs.cli import progress_bar

    progress, console = progress_bar(TextColumn("{task.fields[loss]}"))
    with progress as bar:
        task = None

        def on(e: dict) -> None:
            nonlocal task
            if e["kind"] == "start":
                if e["epoch"]:
                    console.print(f"resuming {cfg.out} at epoch {e['epoch'] + 1} of {e['epochs']} on {e['device']}")
                else:
                    console.print(f"training {cfg.out}: {e['epochs']} epochs x {e['steps']} steps on {e['device']}")
            elif e["kind"] == "step":
                desc = f"epoch {e['epoch'] + 1}"
                if task is None:
                    task = bar.add_task(desc, total=e["steps"], loss="")
                elif e["step"] == 1:
                    bar.reset(task)
                bar.update(task, description=desc, completed=e["step"], total=e["steps"],
                           loss=f"loss {e['loss']:.4g} (mse {e['l_mse']:.3g}, cst {e['l_cst']:.3g})")
            elif e["kind"] == "epoch":
                console.print(f"epoch {e['epoch'] + 1}: train L_mse {e['train_mse']:.4g}, L_cst {e['train_cst']:.4g}, "
                              f"valid MSE {e['valid_mse']:.4g}, lr {e['lr']:.3g}, {e['seconds']:.1f} s")

        return train(cfg, progress=on)
