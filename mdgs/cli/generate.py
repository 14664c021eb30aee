"""``mdgs generate``: trajectories of a built-in scene or a user MJCF as HDF5 datasets (train/valid/test)."""

from __future__ import annotations

from pathlib import Path

import typer

from mdgs.cli import app, fail, parse_share, progress_bar

_SCENE_HELP = "Scene name (see --list), or 'all' for every scene into OUT/<scene>/; required unless --mjcf or --list."


def _list_scenes() -> None:
    from mdgs.scenes import SCENES

    w = max(len(n) for n in SCENES)
    for name, s in SCENES.items():
        tag = f" [test set, variant of {s.variant_of}]" if s.variant_of else ""
        typer.echo(f"{name:<{w}}  {s.summary}{tag}")


def _human(nbytes: float) -> str:
    for unit in ("B", "KB", "MB", "GB"):
        if nbytes < 1024 or unit == "GB":
            return f"{nbytes:.1f} {unit}" if unit != "B" else f"{int(nbytes)} B"
        nbytes /= 1024
    return f"{nbytes:.1f} GB"


@app.command()
def generate(
    scene: str = typer.Argument(None, help=_SCENE_HELP, show_default=False),
    out: Path = typer.Option(None, "--out", help="Output directory (one HDF5 file per split)."),
    preset: str = typer.Option(
        "tiny", "--preset", help="tiny (CI), small (40/10/10) or paper (2000/100/100)."
    ),
    n_traj: int = typer.Option(
        None, "--n-traj", help="Total trajectories instead of the preset's (paper proportions)."
    ),
    workers: int = typer.Option(1, "--workers", help="Worker processes."),
    shard: str = typer.Option(
        "0/1", "--shard", help="Run only shard I of N (I/N); shards merge into one dataset."
    ),
    seed: int = typer.Option(
        0, "--seed", help="Base seed; output is bit-identical for a given seed."
    ),
    mjcf: Path = typer.Option(
        None, "--mjcf", help="Generate from your own MJCF file instead of a built-in scene."
    ),
    substeps: int = typer.Option(
        10, "--substeps", help="Integrator steps per frame for --mjcf scenes."
    ),
    refine: int = typer.Option(
        1, "--refine", help="Multiply the default partition resolution."
    ),
    frames: int = typer.Option(
        None, "--frames", show_default=False,
        help="Frames per trajectory instead of the preset's (e.g. 1100 for a stability test set).",
    ),
    split: list[str] = typer.Option(
        None, "--split", show_default=False,
        help="Only this split (train, valid or test; repeatable); with --n-traj N alone it gets all N, e.g. "
             "--split valid --frames 1100 --n-traj 10 for `mdgs train --select-data`.",
    ),
    list_scenes: bool = typer.Option(False, "--list", help="List the scenes and exit."),
) -> None:
    """Generate trajectories of a scene as HDF5 datasets (train/valid/test)."""
    if list_scenes:
        _list_scenes()
        return
    from mdgs.data.generate import GenerateConfig
    from mdgs.data.generate import generate as run
    from mdgs.data.presets import PRESETS
    from mdgs.data.record import SceneError
    from mdgs.data.schema import DatasetError
    from mdgs.partition import PartitionError, PartitionParams
    from mdgs.scenes import SCENES

    if out is None:
        fail("--out DIR is required (the directory that receives train.h5, valid.h5, test.h5)")
    if preset not in PRESETS:
        fail(f"unknown preset '{preset}'; choose one of {', '.join(PRESETS)}")
    if workers < 1:
        fail(f"--workers {workers} must be at least 1")
    if refine < 1:
        fail(f"--refine {refine} must be at least 1")
    if n_traj is not None and n_traj < 1:
        fail(f"--n-traj {n_traj} must be at least 1")
    if mjcf is not None and scene:
        fail("give either a SCENE or --mjcf FILE, not both")
    if mjcf is None and not scene:
        fail("name a SCENE (see `mdgs generate --list`) or give --mjcf FILE")
    if mjcf is not None and not mjcf.is_file():
        fail(f"--mjcf {mjcf} " + ("is a folder, not an MJCF file" if mjcf.is_dir() else "does not exist")
             + "; pass the path of an MJCF (.xml) file")
    names = list(SCENES) if scene == "all" else [scene] if scene else [""]
    for name in names:
        if name and name not in SCENES:
            fail(f"unknown scene '{name}'; run `mdgs generate --list` to see the scenes")
    shard_t = parse_share(shard, "--shard")
    cfgs = []
    for name in names:  # every setting is checked (GenerateConfig) before anything is written
        target = out / name if scene == "all" else out
        try:
            cfgs.append(GenerateConfig(
                scene=name,
                out=str(target),
                preset=preset,
                n_traj=n_traj,
                seed=seed,
                workers=workers,
                shard=shard_t,
                mjcf=str(mjcf) if mjcf else None,
                substeps=substeps,
                partition=PartitionParams(refine=refine),
                n_frames=frames,
                splits=tuple(dict.fromkeys(split)) if split else None,
            ))
        except DatasetError as e:
            fail(str(e))
    for cfg in cfgs:
        try:
            res = _run_with_progress(run, cfg, cfg.scene or mjcf.stem)
        except (DatasetError, SceneError, PartitionError, ValueError, FileNotFoundError) as e:
            fail(str(e))
        except KeyError as e:
            fail(str(e.args[0]) if e.args else str(e))
        except KeyboardInterrupt:
            typer.echo(f"interrupted; rerun the same command to resume {cfg.out} (finished parts are kept)", err=True)
            raise typer.Exit(130) from None
        _summary(res)


def _run_with_progress(run, cfg, label: str):
    progress, console = progress_bar()
    with progress as bar:
        task = bar.add_task(f"{label} trajectories", total=None)

        def progress(done: int, total: int) -> None:
            bar.update(task, completed=done, total=total)

        return run(cfg, progress=progress)


def _summary(res) -> None:
    if not res.merged:
        typer.echo(
            f"{res.scene}: this shard is done ({res.trajectories} trajectories); the dataset is merged by the run that finishes last."
        )
        return
    sizes = ", ".join(f"{split} {_human(p.stat().st_size)}" for split, p in res.files.items())
    rate = (
        f", {res.steps / res.seconds / 1e3:.0f}k steps/s"
        if res.trajectories
        else " (already complete)"
    )
    typer.echo(
        f"{res.scene}: {res.n_nodes} nodes; {sizes}; {res.trajectories} trajectories in {res.seconds:.1f} s{rate} -> {res.out}"
    )
