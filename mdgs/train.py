"""Training and evaluation of MDGS on the HDF5 datasets (Section 3.4, Appendix B.2).

Adam (lr 1e-3, betas (0.9, 0.999)), ReduceLROnPlateau (patience 3, factor 0.8) on the
validation loss, Gaussian input noise, one input frame. Every epoch writes
``<out>/checkpoint.pt`` (atomically) and ``--resume`` continues from it; the resolved
configuration is written to ``<out>/config.json``. :func:`register` adds the ``train``
and ``evaluate`` commands to a typer app.
"""

from __future__ import annotations

import json
import os
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

import numpy as np
import torch

from mdgs.graphs import SceneGraph
from mdgs.losses import constraint_loss, mse_loss, speeds_of
from mdgs.model import MDGS, ModelConfig

__all__ = ["TrainConfig", "SplitData", "load_split", "train", "evaluate", "register"]


@dataclass
class TrainConfig:
    """Training run settings; every default documented.

    data : folder with ``train.h5``, ``valid.h5``, ``test.h5`` (``mdgs generate`` output).
    out : run folder (checkpoint, config.json, metrics.jsonl).
    epochs : passes over the training pairs.  batch_size : graphs per step.
    lr : Adam learning rate (B.2: 1e-3).  noise : input noise std as a fraction of each
    feature's std (B.2: 0.06; Cubli 4e-4 absolute).  seed : RNG seed.
    device : "auto" (CUDA when present), "cpu" or "cuda".  max_steps : cap on steps per
    epoch (0: none).  model : the :class:`ModelConfig` (scales filled from data if 1.0).
    """

    data: str = "data"
    out: str = "runs/mdgs"
    epochs: int = 20
    batch_size: int = 32
    lr: float = 1e-3
    noise: float = 0.06
    seed: int = 0
    device: str = "auto"
    max_steps: int = 0
    model: ModelConfig = field(default_factory=ModelConfig)


@dataclass
class SplitData:
    """One split in memory: x, v [T, F, N, 3] float32; static arrays; frame_dt (s); has_contact."""

    x: np.ndarray
    v: np.ndarray
    static: dict
    frame_dt: float
    has_contact: bool

    def pairs(self) -> np.ndarray:
        """All (trajectory, frame) indices with a next frame -> [P, 2]."""
        T, F = self.x.shape[:2]
        return np.stack(np.meshgrid(np.arange(T), np.arange(F - 1), indexing="ij"), -1).reshape(-1, 2)


def load_split(path: str | os.PathLike) -> SplitData:
    """Read a dataset file through :func:`mdgs.data.io.open_dataset` (checked)."""
    from mdgs.data.io import open_dataset

    with open_dataset(path) as ds:
        return SplitData(
            x=ds.frames("node_pos").astype(np.float32),
            v=ds.frames("node_vel").astype(np.float32),
            static=dict(ds.static),
            frame_dt=float(ds.attrs["frame_dt"]),
            has_contact=bool(ds.attrs["has_contact"]),
        )


def _device(name: str) -> torch.device:
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(name)


def _resolve_model(cfg: ModelConfig, d: SplitData) -> ModelConfig:
    """Fill scales left at 1.0 from the training data (increment stds, element weight)."""
    moving = ~np.asarray(d.static["node_static"], bool)
    dx = (d.x[:, 1:] - d.x[:, :-1])[:, :, moving]
    dv = (d.v[:, 1:] - d.v[:, :-1])[:, :, moving]
    mass = np.asarray(d.static["node_mass"])[moving]
    kw = {}
    if cfg.dx_scale == 1.0:
        kw["dx_scale"] = float(max(dx.std(), 1e-12))
    if cfg.dv_scale == 1.0:
        kw["dv_scale"] = float(max(dv.std(), 1e-12))
    if cfg.force_scale == 1.0:  # typical |M dv / dt| of an element
        kw["force_scale"] = float(max(np.abs(mass[None, None, :, None] * dv / d.frame_dt).mean(), 1e-9))
    return ModelConfig(**{**asdict(cfg), **kw})


def _features_stats(model: MDGS, scene: SceneGraph, d: SplitData) -> tuple[torch.Tensor, torch.Tensor]:
    idx = np.random.default_rng(0).choice(d.x.shape[0] * d.x.shape[1], size=min(256, d.x.shape[0] * d.x.shape[1]), replace=False)
    x = torch.tensor(d.x.reshape(-1, *d.x.shape[2:])[idx])
    v = torch.tensor(d.v.reshape(-1, *d.v.shape[2:])[idx])
    z = model.node_features(scene, x, v).reshape(-1, model.d_z)
    return z.mean(0), z.std(0)


def _step_loss(model, scene, cfg: ModelConfig, x, v, xt, vt, dt, moving):
    p = model(scene, x, v)
    l_mse = mse_loss(p.x, p.v, xt, vt, moving, cfg.dx_scale, cfg.dv_scale)  # Eq. (10)
    speeds = speeds_of(cfg.variant)
    l_cst = constraint_loss(p.force, x, v, p.x, p.v, scene.mass, scene.tau, scene.obj, scene.n_obj, dt,
                            moving=moving, bound=cfg.bound, speeds=speeds,
                            scale=cfg.force_scale * int(moving.sum()))  # Eqs. (13)-(15)
    return l_mse, l_cst


def _batch(d: SplitData, idx: np.ndarray, dev):
    t, f = idx[:, 0], idx[:, 1]
    g = lambda a, k: torch.tensor(a[t, f + k], device=dev)  # noqa: E731
    return g(d.x, 0), g(d.v, 0), g(d.x, 1), g(d.v, 1)


def _atomic_save(obj, path: Path) -> None:
    tmp = path.with_name(path.name + ".tmp")
    torch.save(obj, tmp)
    os.replace(tmp, path)


def train(cfg: TrainConfig, resume: bool = False, splits: dict | None = None) -> dict:
    """Train; returns the last epoch's metrics. ``splits`` (name -> SplitData) bypasses the files."""
    out = Path(cfg.out)
    out.mkdir(parents=True, exist_ok=True)
    splits = splits or {s: load_split(Path(cfg.data) / f"{s}.h5") for s in ("train", "valid")}
    tr, va = splits["train"], splits["valid"]
    dev = _device(cfg.device)
    torch.manual_seed(cfg.seed)
    rng = np.random.default_rng(cfg.seed)
    mcfg = _resolve_model(cfg.model, tr)
    scene = SceneGraph.from_static(tr.static, has_contact=tr.has_contact).to(dev)
    model = MDGS(mcfg, contact=tr.has_contact).to(dev)
    model.set_normalization(*_features_stats(model, scene.to("cpu"), tr))
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr, betas=(0.9, 0.999))
    sched = torch.optim.lr_scheduler.ReduceLROnPlateau(opt, patience=3, factor=0.8)
    start = 0
    ckpt = out / "checkpoint.pt"
    if resume and ckpt.exists():
        state = torch.load(ckpt, map_location=dev, weights_only=False)
        model.load_state_dict(state["model"])
        opt.load_state_dict(state["opt"])
        sched.load_state_dict(state["sched"])
        start = state["epoch"] + 1
        rng = np.random.default_rng([cfg.seed, start])
    resolved = {**asdict(cfg), "model": mcfg.to_dict(), "device": str(dev)}
    (out / "config.json").write_text(json.dumps(resolved, indent=2))
    moving = ~scene.static
    sx = torch.tensor(tr.x.std(axis=(0, 1, 2)), device=dev)
    sv = torch.tensor(tr.v.std(axis=(0, 1, 2)), device=dev)
    metrics = {}
    for epoch in range(start, cfg.epochs):
        model.train()
        pairs = rng.permutation(tr.pairs())
        n_steps = len(pairs) // cfg.batch_size or 1
        if cfg.max_steps:
            n_steps = min(n_steps, cfg.max_steps)
        tot = np.zeros(2)
        for s in range(n_steps):
            x, v, xt, vt = _batch(tr, pairs[s * cfg.batch_size:(s + 1) * cfg.batch_size], dev)
            # training noise (B.2) on the input frame only; targets stay clean
            x = x + cfg.noise * sx * torch.randn_like(x) * moving.view(1, -1, 1)
            v = v + cfg.noise * sv * torch.randn_like(v) * moving.view(1, -1, 1)
            l_mse, l_cst = _step_loss(model, scene, mcfg, x, v, xt, vt, tr.frame_dt, moving)
            loss = l_mse + mcfg.cst_weight * l_cst
            opt.zero_grad()
            loss.backward()
            opt.step()
            tot += [l_mse.item(), l_cst.item()]
        val = evaluate_split(model, scene, va, dev, cfg.batch_size)
        sched.step(val["mse"])
        metrics = {"epoch": epoch, "train_mse": float(tot[0] / n_steps), "train_cst": float(tot[1] / n_steps),
                   "valid_mse": val["mse"], "lr": opt.param_groups[0]["lr"]}
        with open(out / "metrics.jsonl", "a") as f:
            f.write(json.dumps(metrics) + "\n")
        _atomic_save({"model": model.state_dict(), "opt": opt.state_dict(), "sched": sched.state_dict(),
                      "epoch": epoch, "config": resolved, "has_contact": tr.has_contact}, ckpt)
    return metrics


@torch.no_grad()
def evaluate_split(model: MDGS, scene: SceneGraph, d: SplitData, dev, batch_size: int = 64,
                   rollout_steps: int = 0) -> dict:
    """One-step MSE of ``[x || v]`` (unscaled, moving nodes) and, if asked, rollout MSE of positions."""
    model.eval()
    moving = ~scene.static
    pairs = d.pairs()
    err, n = 0.0, 0
    for s in range(0, len(pairs), batch_size):
        x, v, xt, vt = _batch(d, pairs[s:s + batch_size], dev)
        p = model(scene, x, v)
        err += mse_loss(p.x, p.v, xt, vt, moving).item() * len(x)
        n += len(x)
    res = {"mse": err / max(n, 1)}
    if rollout_steps:
        T = d.x.shape[0]
        steps = min(rollout_steps, d.x.shape[1] - 1)
        x0 = torch.tensor(d.x[:, 0], device=dev)
        v0 = torch.tensor(d.v[:, 0], device=dev)
        xs, _ = model.rollout(scene, x0, v0, steps)
        truth = torch.tensor(d.x[:, 1:steps + 1], device=dev)
        res["rollout_mse"] = ((xs - truth)[:, :, moving] ** 2).mean(dim=(0, 2, 3)).tolist()
        res["rollout_trajectories"] = T
    return res


def evaluate(run: str | os.PathLike, data: str | os.PathLike, split: str = "test", rollout_steps: int = 50,
             device: str = "auto") -> dict:
    """Load ``<run>/checkpoint.pt`` and evaluate it on ``<data>/<split>.h5``."""
    dev = _device(device)
    state = torch.load(Path(run) / "checkpoint.pt", map_location=dev, weights_only=False)
    mc = state["config"]["model"]
    mcfg = ModelConfig(**{f.name: mc[f.name] for f in fields(ModelConfig) if f.name in mc})
    d = load_split(Path(data) / f"{split}.h5")
    scene = SceneGraph.from_static(d.static, has_contact=d.has_contact).to(dev)
    model = MDGS(mcfg, contact=state["has_contact"]).to(dev)
    model.load_state_dict(state["model"])
    return evaluate_split(model, scene, d, dev, rollout_steps=rollout_steps)


def register(app) -> None:
    """Add ``train`` and ``evaluate`` commands to the typer ``app``."""
    import typer

    @app.command("train")
    def train_cmd(
        data: str = typer.Option(..., help="folder with train.h5 and valid.h5"),
        out: str = typer.Option("runs/mdgs", help="run folder"),
        variant: str = typer.Option("mdgs", help="mdgs, mdgs-nc or mdgs-sc"),
        structure: bool = typer.Option(True, help="structural constraint module (B.1.3)"),
        bound: str = typer.Option("paper", help="paper or corrected"),
        epochs: int = typer.Option(20),
        batch_size: int = typer.Option(32),
        noise: float = typer.Option(0.06),
        max_steps: int = typer.Option(0, help="cap on steps per epoch (0: none)"),
        device: str = typer.Option("auto"),
        resume: bool = typer.Option(False, help="continue from <out>/checkpoint.pt"),
    ):
        """Train MDGS on a generated dataset."""
        from mdgs.data.schema import DatasetError

        try:
            mcfg = ModelConfig(variant=variant, structure=structure, bound=bound)
        except ValueError as e:
            raise typer.BadParameter(str(e)) from None
        cfg = TrainConfig(data=data, out=out, epochs=epochs, batch_size=batch_size, noise=noise,
                          max_steps=max_steps, device=device, model=mcfg)
        try:
            m = train(cfg, resume=resume)
        except DatasetError as e:
            typer.echo(str(e), err=True)
            raise typer.Exit(2) from None
        typer.echo(json.dumps(m))

    @app.command("evaluate")
    def evaluate_cmd(
        run: str = typer.Option(..., help="run folder with checkpoint.pt"),
        data: str = typer.Option(..., help="dataset folder"),
        split: str = typer.Option("test"),
        rollout_steps: int = typer.Option(50),
        device: str = typer.Option("auto"),
    ):
        """One-step and rollout MSE of a trained run."""
        from mdgs.data.schema import DatasetError

        try:
            typer.echo(json.dumps(evaluate(run, data, split, rollout_steps, device)))
        except DatasetError as e:
            typer.echo(str(e), err=True)
            raise typer.Exit(2) from None
