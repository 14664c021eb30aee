"""The ``train`` and ``evaluate`` commands (typer), kept free of torch at import time.

``mdgs validate`` and ``mdgs generate`` must not pay torch's import; the command bodies
import :mod:`mdgs.train` and :mod:`mdgs.evaluate` when they run.
"""

from __future__ import annotations

from pathlib import Path

import typer

__all__ = ["register"]


def register(app) -> None:
    """Add ``train`` and ``evaluate`` to the typer ``app``."""
    _register_train(app)
    _register_evaluate(app)


def _register_train(app) -> None:

    @app.command("train")
    def train_cmd(
        data: Path = typer.Option(..., "--data", help="Folder with train.h5 and valid.h5 (`mdgs generate` output)."),
        out: Path = typer.Option(..., "--out", help="Run folder; rerunning the same command resumes it."),
        model: str = typer.Option("mdgs", "--model", help="mdgs, mdgs-nc (no L_cst) or mdgs-sc (single speed)."),
        structure: bool = typer.Option(True, "--structure/--no-structure", help="Structural constraint module (B.1.3)."),
        bound: str = typer.Option("paper", "--bound", help="Bound of L_cst: paper (Eq. 12) or corrected."),
        integrator: str = typer.Option("rigid", "--integrator",
                                       help="rigid (per-object twist, exact rigid motion), twist (g read in twist "
                                            "space), euler or direct (Eq. 9 literally); see docs/ambiguities.md."),
        epochs: int = typer.Option(20, "--epochs", help="Total epochs (a resumed run stops at this count)."),
        batch_size: int = typer.Option(32, "--batch-size", help="Graphs per step."),
        lr: float = typer.Option(1e-3, "--lr", help="Adam learning rate (B.2)."),
        noise: str = typer.Option("auto", "--noise", help="auto, none, abs:SIGMA or inc:FRACTION (see docs/training.md)."),
        seed: int = typer.Option(0, "--seed", help="Seed of initialisation, batch order and noise."),
        max_steps: int = typer.Option(0, "--max-steps", help="Cap on steps per epoch (0: full pass)."),
        valid_max_pairs: int = typer.Option(0, "--valid-max-pairs", help="Cap on validation pairs (0: all)."),
        device: str = typer.Option("auto", "--device", help="auto (CUDA when present), cpu or cuda."),
    ) -> None:
        """Train MDGS on a generated dataset (Adam, plateau scheduler, training noise; Appendix B.2)."""
        from mdgs.cli import _fail
        from mdgs.data.schema import DatasetError
        from mdgs.model import ModelConfig
        from mdgs.train import RunError, TrainConfig, _train_with_progress

        try:
            mcfg = ModelConfig(variant=model, structure=structure, bound=bound, integrator=integrator)
        except ValueError as e:
            _fail(f"--model/--bound/--integrator: {e}")
        for name, val in (("--epochs", epochs), ("--batch-size", batch_size)):
            if val < 1:
                _fail(f"{name} {val} must be at least 1")
        if not lr > 0:
            _fail(f"--lr {lr} must be positive")
        cfg = TrainConfig(data=str(data), out=str(out), epochs=epochs, batch_size=batch_size, lr=lr, noise=noise,
                          seed=seed, max_steps=max_steps, valid_max_pairs=valid_max_pairs, device=device, model=mcfg)
        try:
            last = _train_with_progress(cfg)
        except (DatasetError, RunError) as e:
            _fail(str(e))
        except KeyboardInterrupt:
            typer.echo(f"interrupted; rerun the same command to resume {out} from its last finished epoch", err=True)
            raise typer.Exit(130) from None
        if last:
            typer.echo(f"{out}: epoch {last['epoch'] + 1}/{epochs}, train L_mse {last['train_mse']:.4g}, "
                       f"L_cst {last['train_cst']:.4g}, valid one-step MSE {last['valid_mse']:.4g}")
        else:
            typer.echo(f"{out}: already trained for {epochs} epochs; raise --epochs to continue")


def _register_evaluate(app) -> None:

    @app.command("evaluate")
    def evaluate_cmd(
        runs: list[Path] = typer.Argument(..., help="Run folder(s) from `mdgs train`; several (seeds) give mean +- std."),
        data: Path = typer.Option(..., "--data", help="Dataset folder (`mdgs generate` output)."),
        split: str = typer.Option("test", "--split", help="test, valid or train."),
        json_path: Path = typer.Option(None, "--json", help="Report path (default RUN/evaluation-SPLIT.json)."),
        traj: int = typer.Option(0, "--traj", help="Test trajectory drawn in the trajectory plot."),
        device: str = typer.Option("auto", "--device", help="auto (CUDA when present), cpu or cuda."),
    ) -> None:
        """Roll out whole test trajectories; rollout MSE at t=40 and t=110 (m^2), curves and plots."""
        from mdgs.cli import _fail
        from mdgs.data.schema import DatasetError
        from mdgs.evaluate import evaluate
        from mdgs.train import RunError

        if split not in ("train", "valid", "test"):
            _fail(f"--split {split} is not one of train, valid, test")
        try:
            rep = evaluate([str(r) for r in runs], data, split, json_path, device, traj)
        except (DatasetError, RunError) as e:
            _fail(str(e))
        agg = rep["aggregate"]

        def fmt(key: str) -> str:
            m = agg[key]
            if m["mean"] is None:
                return "n/a (diverged)"
            return f"{m['mean']:.4g}" + (f" +- {m['std']:.2g}" if agg["runs"] > 1 else "")

        r0 = rep["runs"][0]

        def n_used(t: int) -> str:
            return f"{sum(r[f'mse_t{t}_trajectories'] for r in rep['runs'])}/{sum(r['trajectories'] for r in rep['runs'])}"

        typer.echo(f"{r0['scene']} {split}: position MSE t=40 {fmt('mse_t40')} m^2 ({n_used(40)} trajectories), "
                   f"t=110 {fmt('mse_t110')} m^2 ({n_used(110)}); {agg['runs']} run(s); report {rep['json']}")
        ref = rep["reference"]
        typer.echo(f"reference (every body keeps its twist, no forces): t=40 {ref['mse_t40']:.4g} m^2, "
                   f"t=110 {ref['mse_t110']:.4g} m^2")
        for r in rep["runs"]:
            for dv in r["diverged"]:
                typer.echo(f"warning: {r['run']}: test trajectory {dv['trajectory']} diverged at step {dv['step']} "
                           f"(t = {dv['time_s']:.3g} s) and is left out of the means from there on", err=True)
