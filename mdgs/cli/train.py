"""``mdgs train``: train any learned model of the registry on a generated dataset (resumable)."""

from __future__ import annotations

from pathlib import Path

import typer

from mdgs.cli import app, fail, progress_bar

_MODEL_HELP = ("Model of the registry: mdgs, mdgs-nc (no L_cst), mdgs-sc (single speed); "
               "`mdgs evaluate --list-models` lists every model.")


@app.command("train")
def train_cmd(
    data: Path = typer.Option(..., "--data", help="Folder with train.h5 and valid.h5 (`mdgs generate` output)."),
    out: Path = typer.Option(..., "--out", help="Run folder; rerunning the same command resumes it."),
    model: str = typer.Option("mdgs", "--model", help=_MODEL_HELP),
    structure: bool = typer.Option(True, "--structure/--no-structure", help="MDGS: structural constraint module (B.1.3)."),
    bound: str = typer.Option("paper", "--bound", help="MDGS: bound of L_cst, paper (Eq. 12) or corrected."),
    integrator: str = typer.Option("rigid", "--integrator",
                                   help="MDGS: rigid (per-object twist, exact rigid motion), twist (g read in twist "
                                        "space), euler or direct (Eq. 9 literally); see docs/ambiguities.md."),
    noise: str = typer.Option("auto", "--noise", help="MDGS: auto, none, abs:SIGMA or inc:FRACTION (see docs/training.md)."),
    epochs: int = typer.Option(20, "--epochs", help="Total epochs (a resumed run stops at this count)."),
    batch_size: int = typer.Option(32, "--batch-size", help="Graphs per step."),
    lr: float = typer.Option(1e-3, "--lr", help="Learning rate (MDGS, B.2: Adam 1e-3)."),
    seed: int = typer.Option(0, "--seed", help="Seed of initialisation, batch order and noise."),
    max_steps: int = typer.Option(0, "--max-steps", help="Cap on steps per epoch (0: full pass)."),
    valid_max_pairs: int = typer.Option(0, "--valid-max-pairs", help="Cap on validation pairs (0: all)."),
    device: str = typer.Option("auto", "--device", help="auto (CUDA when present), cpu or cuda."),
) -> None:
    """Train a model on a generated dataset (MDGS: Adam, plateau scheduler, training noise; Appendix B.2)."""
    from mdgs.data.schema import DatasetError
    from mdgs.models import MODELS, ModelError, get_model
    from mdgs.runs import RunError
    from mdgs.train import TrainConfig

    try:
        cls = get_model(model)
        opts = {"structure": structure, "bound": bound, "integrator": integrator, "noise": noise}
        known = set(cls.Config.__dataclass_fields__)
        mcfg = cls.Config(**{k: v for k, v in opts.items() if k in known})
        cfg = TrainConfig(data=str(data), out=str(out), model_name=model, epochs=epochs, batch_size=batch_size,
                          lr=lr, seed=seed, max_steps=max_steps, valid_max_pairs=valid_max_pairs, device=device,
                          model=mcfg)
    except ValueError as e:
        fail(f"--model {model}: {e}")
    except (ModelError, RunError) as e:
        fail(str(e) + ("" if model in MODELS else ""))
    try:
        last = _train_with_progress(cfg)
    except (DatasetError, RunError, ModelError) as e:
        fail(str(e))
    except KeyboardInterrupt:
        typer.echo(f"interrupted; rerun the same command to resume {out} from its last finished epoch", err=True)
        raise typer.Exit(130) from None
    if last:
        losses = ", ".join(f"L_{k[6:]} {v:.4g}" for k, v in last.items() if k.startswith("train_") and k != "train_seconds")
        typer.echo(f"{out}: epoch {last['epoch'] + 1}/{epochs}, train {losses}, valid one-step MSE {last['valid_mse']:.4g}")
    else:
        typer.echo(f"{out}: already trained for {epochs} epochs; raise --epochs to continue")


def _train_with_progress(cfg) -> dict:
    from rich.progress import TextColumn

    from mdgs.train import train

    progress, console = progress_bar(TextColumn("{task.fields[loss]}"))
    with progress as bar:
        task = None

        def on(e: dict) -> None:
            nonlocal task
            if e["kind"] == "start":
                if e["epoch"]:
                    console.print(f"resuming {cfg.out} ({e['model']}) at epoch {e['epoch'] + 1} of {e['epochs']} "
                                  f"on {e['device']}")
                else:
                    console.print(f"training {cfg.out} ({e['model']}): {e['epochs']} epochs x {e['steps']} steps "
                                  f"on {e['device']}")
            elif e["kind"] == "step":
                desc = f"epoch {e['epoch'] + 1}"
                if task is None:
                    task = bar.add_task(desc, total=e["steps"], loss="")
                elif e["step"] == 1:
                    bar.reset(task)
                parts = ", ".join(f"{k} {v:.3g}" for k, v in e["losses"].items())
                bar.update(task, description=desc, completed=e["step"], total=e["steps"],
                           loss=f"loss {e['loss']:.4g} ({parts})")
            elif e["kind"] == "epoch":
                losses = ", ".join(f"L_{k[6:]} {v:.4g}" for k, v in e.items()
                                   if k.startswith("train_") and k != "train_seconds")
                console.print(f"epoch {e['epoch'] + 1}: train {losses}, valid MSE {e['valid_mse']:.4g}, "
                              f"lr {e['lr']:.3g}, {e['seconds']:.1f} s")

        return train(cfg, progress=on)
