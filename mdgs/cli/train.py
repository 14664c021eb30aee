"""``mdgs train``: train any learned model of the registry on a generated dataset (resumable)."""

from __future__ import annotations

import os
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
    structure: bool = typer.Option(None, "--structure/--no-structure", show_default=False,
                                   help="MDGS: structural constraint module (B.1.3); on by default."),
    bound: str = typer.Option(None, "--bound", help="MDGS: bound of L_cst, paper (Eq. 12, default) or corrected."),
    integrator: str = typer.Option(None, "--integrator",
                                   help="MDGS: rigid (default; per-object twist, exact rigid motion), twist (g read "
                                        "in twist space), euler or direct (Eq. 9 literally); see docs/ambiguities.md."),
    noise: str = typer.Option(None, "--noise", help="Training noise of the model, e.g. MDGS: auto (default), none, "
                                                   "abs:SIGMA or inc:FRACTION (see docs/training.md)."),
    settings: list[str] = typer.Option(None, "--set", metavar="KEY=VALUE",
                                       help="Any field of the model's config (e.g. hidden=100); repeatable."),
    epochs: int = typer.Option(20, "--epochs", help="Total epochs (a resumed run stops at this count)."),
    batch_size: int = typer.Option(32, "--batch-size", help="Graphs per step."),
    lr: float = typer.Option(None, "--lr", show_default=False,
                             help="Learning rate; default: the model's own (MDGS, B.2: Adam 1e-3; GNS, SGNN: 1e-4)."),
    seed: int = typer.Option(0, "--seed", help="Seed of initialisation, batch order and noise."),
    max_steps: int = typer.Option(0, "--max-steps", help="Cap on steps per epoch (0: full pass)."),
    valid_max_pairs: int = typer.Option(0, "--valid-max-pairs", help="Cap on validation pairs (0: all)."),
    select: str = typer.Option("last", "--select",
                               help="Which epoch's weights to keep for evaluation: last, valid (lowest one-step "
                                    "validation error), rollout (lowest validation rollout error, failures capped) "
                                    "or rollout-or-start (the same, the weights training started from included)."),
    select_data: Path = typer.Option(None, "--select-data", show_default=False,
                                     help="With --select rollout*: score the rollouts on this folder's valid.h5 "
                                          "instead (e.g. validation trajectories 10x as long, from `mdgs generate "
                                          "--split valid --frames N`), to keep the epoch that stays stable."),
    ema: float = typer.Option(0.0, "--ema", help="Decay of an exponential moving average of the weights, updated "
                                                 "every step; the average is validated, selected and evaluated "
                                                 "(e.g. 0.99: about the last 100 steps). 0: off."),
    device: str = typer.Option("auto", "--device", help="auto (CUDA when present), cpu or cuda."),
) -> None:
    """Train a model on a generated dataset (MDGS: Adam, plateau scheduler, training noise; Appendix B.2)."""
    from mdgs.data.schema import DatasetError
    from mdgs.models import ModelError, get_model
    from mdgs.runs import RunError
    from mdgs.train import TrainConfig

    try:
        cls = get_model(model)
        opts = {"structure": structure, "bound": bound, "integrator": integrator, "noise": noise}
        opts = {k: v for k, v in opts.items() if v is not None}
        opts.update(parse_settings(cls.Config, settings or []))
        known = set(cls.Config.__dataclass_fields__)
        unknown = sorted(set(opts) - known)
        if unknown:
            flag = unknown[0] if unknown[0] in ("structure", "bound", "integrator", "noise") else f"--set {unknown[0]}"
            fail(f"model {model!r} has no setting {flag.lstrip('-')}; its settings are {', '.join(sorted(known))}")
        mcfg = cls.Config(**opts)
        lr = cls.default_lr if lr is None else lr
        cfg = TrainConfig(data=str(data), out=str(out), model_name=model, epochs=epochs, batch_size=batch_size,
                          lr=lr, seed=seed, max_steps=max_steps, valid_max_pairs=valid_max_pairs, device=device,
                          select=select, select_data=str(select_data or ""), ema=ema, model=mcfg)
    except ValueError as e:
        fail(f"--model {model}: {e}")
    except (ModelError, RunError) as e:
        fail(str(e))
    try:
        last, done = _train_with_progress(cfg)
    except (DatasetError, RunError, ModelError) as e:
        fail(str(e))
    except KeyboardInterrupt:
        typer.echo(f"interrupted; rerun the same command to resume {out} from its last finished epoch", err=True)
        raise typer.Exit(130) from None
    if os.environ.get("RANK", "0") != "0":  # under torchrun: rank 0 speaks for the job
        return
    if last:
        losses = ", ".join(f"L_{k[6:]} {v:.4g}" for k, v in last.items() if k.startswith("train_") and k != "train_seconds")
        typer.echo(f"{out}: epoch {last['epoch'] + 1}/{epochs}, train {losses}, valid one-step MSE {last['valid_mse']:.4g}")
        if select != "last":
            import json

            from mdgs.runs import read_checkpoint
            from mdgs.train.loop import SELECT_KEY

            hist = json.loads((out / "metrics.json").read_text())
            key = SELECT_KEY[select]
            best = min(hist, key=lambda h: h[key])
            start = read_checkpoint(out / "checkpoint.pt", "cpu").get("selected_epoch") == -1
            if start:
                typer.echo(f"{out}: evaluates the weights training started from (--select {select}: they roll out "
                           f"better on valid than every epoch, best {key} {best[key]:.4g})")
            else:
                typer.echo(f"{out}: evaluates the weights of epoch {best['epoch'] + 1} (--select {select}: "
                           f"{key} {best[key]:.4g})" + (f", their moving average (--ema {ema})" if ema else ""))
        elif ema:
            typer.echo(f"{out}: evaluates the moving average of the weights (--ema {ema})")
    else:
        typer.echo(f"{out}: already holds {done.get('finished', '?')} finished epochs (--epochs {epochs}); "
                   "raise --epochs to continue it")


def parse_settings(config_cls, items: list[str]) -> dict:
    """``["hidden=100", "structure=false", "dv_scales=1,0.04"]`` -> ``{"hidden": 100, "structure": False,
    "dv_scales": (1.0, 0.04)}`` typed by the config's fields (a tuple of floats: comma-separated, each positive)."""
    import dataclasses
    import math

    types = {f.name: f.type for f in dataclasses.fields(config_cls)}
    out = {}
    for item in items:
        key, eq, text = item.partition("=")
        key = key.strip().replace("-", "_")
        if not eq or not key:
            fail(f"--set {item!r} is not of the form KEY=VALUE (for example hidden=100)")
        if key not in types:
            fail(f"--set {key}: the model has no such setting; its settings are {', '.join(types)}")
        t = str(types[key])
        try:
            if t.startswith("bool"):
                if text.lower() not in ("true", "false", "1", "0", "yes", "no"):
                    raise ValueError(text)
                val = text.lower() in ("true", "1", "yes")
            elif t.startswith("int"):
                val = int(text)
            elif t.startswith("float"):
                val = None if (text.lower() == "none" and "None" in t) else float(text)
            elif t.startswith("tuple[float"):  # per-object values, comma-separated
                val = tuple(float(v) for v in text.split(",")) if text.strip() else ()
                if any(not math.isfinite(v) or v <= 0 for v in val):
                    raise ValueError(text)
            else:
                val = text
        except ValueError:
            fail(f"--set {item!r}: {text!r} is not a valid {t} value for {key}")
        out[key] = val
    return out


def _train_with_progress(cfg) -> tuple[dict, dict]:
    """Train with a progress bar -> (last epoch's metrics, ``{"finished": N}`` when nothing was left to do)."""
    from rich.progress import TextColumn

    from mdgs.evaluate.rollout import rollout_score
    from mdgs.train import train

    progress, console = progress_bar(TextColumn("{task.fields[loss]}"))
    done: dict = {}
    with progress as bar:
        task = None

        def on(e: dict) -> None:
            nonlocal task
            if e["kind"] == "done":
                done["finished"] = e["epoch"] + 1
            elif e["kind"] == "start":
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

        return train(cfg, progress=on, score=rollout_score), done
