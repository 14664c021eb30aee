"""``mdgs evaluate``: roll out whole test trajectories with trained runs and non-learned references."""

from __future__ import annotations

from pathlib import Path

import typer

from mdgs.cli import app, fail


def _parse_reference(text: str) -> tuple[str, dict]:
    """``mujoco:20`` -> ("mujoco", {"dt_factor": 20}); ``constant-twist`` -> ("constant-twist", {})."""
    name, _, arg = text.partition(":")
    if name == "mujoco":
        try:
            k = int(arg or "1")
        except ValueError:
            fail(f"--reference {text}: write mujoco:K with K an integer timestep factor (e.g. mujoco:20)")
        if k < 1:
            fail(f"--reference {text}: the timestep factor must be at least 1")
        return name, {"dt_factor": k}
    if name == "constant-twist" and arg:
        parts = arg.split("+")
        sub = [p for p in parts if p.startswith("substeps=")]
        parts = [p for p in parts if not p.startswith("substeps=")]
        n = 1
        if sub:
            if len(sub) > 1 or not sub[0][9:].isdigit() or int(sub[0][9:]) < 1 or "dynamics" not in parts:
                fail(f"--reference {text}: write substeps=N once, N a positive integer, with dynamics "
                     f"(e.g. constant-twist:dynamics+joints+trapezoidal+substeps=4)")
            n = int(sub[0][9:])
        gyro = [p[: -len("-gyroscopic")] for p in parts if p.endswith("-gyroscopic")]
        parts = [p for p in parts if not p.endswith("-gyroscopic")]
        if len(gyro) > 1 or (gyro and gyro[0] not in ("implicit", "midpoint")):
            fail(f"--reference {text}: write one of implicit-gyroscopic or midpoint-gyroscopic")
        if gyro and "dynamics" not in parts:
            fail(f"--reference {text}: {gyro[0]}-gyroscopic sets how the rigid tree steps; write dynamics+{gyro[0]}-gyroscopic")
        soft = "soft-contact" in parts
        parts = [p for p in parts if p != "soft-contact"]
        if soft and "dynamics" not in parts:
            fail(f"--reference {text}: soft-contact gives the rigid tree MuJoCo's soft contact; write dynamics+soft-contact")
        if soft and "push-out" in parts:
            fail(f"--reference {text}: push-out would undo the soft contact's depth; write one of push-out or soft-contact")
        rules = [p for p in parts if p in ("momentum", "coordinates")]
        parts = [p for p in parts if p not in ("momentum", "coordinates")]
        if len(rules) > 1:
            fail(f"--reference {text}: write one of momentum or coordinates (two ways to keep the joints)")
        if rules and not {"dynamics", "joints"} <= set(parts):
            fail(f"--reference {text}: {rules[0]} sets how the rigid tree keeps its joints; "
                 f"write dynamics+joints+{rules[0]}")
        if not set(parts) <= {"motors", "joints", "coupled", "dynamics", "trapezoidal", "push-out"} or len(set(parts)) != len(parts):
            fail(f"--reference {text}: constant-twist takes motors, joints or motors+joints, coupled "
                 f"with motors, or dynamics (e.g. constant-twist:motors+joints, constant-twist:motors+coupled+joints, "
                 f"constant-twist:dynamics+joints, +trapezoidal to move with the mean of the old and new twist, "
                 f"+push-out with dynamics to move the tree out of the world's surfaces after every step, "
                 f"+implicit-gyroscopic or +midpoint-gyroscopic with dynamics for gyroscopic terms at each step's end "
                 f"or halfway, +momentum with dynamics+joints to project the twists onto the joints by impulses, "
                 f"+coordinates with dynamics+joints to step in the joints' coordinates, +soft-contact with dynamics "
                 f"for MuJoCo's soft contact)")
        if "coupled" in parts and "motors" not in parts:
            fail(f"--reference {text}: coupled is a form of the motors' response; write motors+coupled")
        if "dynamics" in parts and {"motors", "coupled"} & set(parts):
            fail(f"--reference {text}: dynamics already holds the motors; write dynamics or dynamics+joints")
        if "push-out" in parts and "dynamics" not in parts:
            fail(f"--reference {text}: push-out moves the rigid tree out of the surfaces; write dynamics+push-out")
        return name, ({k.replace("-", "_"): True for k in parts} | ({"substeps": n} if n > 1 else {})
                      | ({"gyroscopic": gyro[0]} if gyro else {}) | ({"joint_velocities": rules[0]} if rules else {})
                      | ({"contact": "soft"} if soft else {}))
    if arg:
        fail(f"--reference {text}: {name} takes no setting")
    return name, {}


def _list_models() -> None:
    from mdgs.models import MODELS

    w = max(len(n) for n in MODELS)
    for name, cls in MODELS.items():
        typer.echo(f"{name:<{w}}  {'learned  ' if cls.learned else 'reference'}  {cls.summary}")


@app.command("evaluate")
def evaluate_cmd(
    runs: list[Path] = typer.Argument(None, help="Run folder(s) from `mdgs train`; several (seeds) give mean +- std. Required unless --list-models."),
    data: Path = typer.Option(None, "--data", help="Dataset folder (`mdgs generate` output); required with RUNS."),
    split: str = typer.Option("test", "--split", help="test, valid or train."),
    json_path: Path = typer.Option(None, "--json", help="Report path (default RUN/evaluation-SPLIT.json)."),
    traj: int = typer.Option(0, "--traj", help="Test trajectory drawn in the trajectory plot."),
    reference: list[str] = typer.Option(None, "--reference", metavar="NAME[:K]",
                                        help="Also roll out a non-learned reference, e.g. mujoco:20 (MuJoCo at 20x "
                                             "the data's timestep), constant-twist:motors (constant twist plus the "
                                             "motors' known loads on the bodies they drive), constant-twist:joints "
                                             "(projected onto the joints, as MDGS), constant-twist:motors+joints, or with "
                                             "+coupled the motors' response of the whole tree (parents recoiling), "
                                             "constant-twist:dynamics+joints (the rigid tree: the MJCF's forward dynamics "
                                             "with contact and limits, one step per frame; append "
                                             "+trapezoidal, +push-out, +substeps=N, +implicit-gyroscopic or +midpoint-gyroscopic, e.g. "
                                             "constant-twist:dynamics+joints+trapezoidal+push-out+substeps=4); "
                                             "repeatable. constant-twist "
                                             "is always included."),
    device: str = typer.Option("auto", "--device", help="auto (CUDA when present), cpu or cuda."),
    compile_mode: str = typer.Option("none", "--compile", help="The runs' step: none (eager), inductor (torch.compile), "
                                "aot (compiled ahead of time; fastest for one trajectory on a CPU, about a minute "
                                "to compile) or cudagraphs (CUDA only: inductor's kernels replayed as one CUDA "
                                "graph); ms_per_frame then times the compiled step."),
    list_models: bool = typer.Option(False, "--list-models", help="List the models of the registry and exit."),
) -> None:
    """Roll out whole test trajectories; rollout MSE at t=40 and t=110 (m^2), curves and plots."""
    if list_models:
        _list_models()
        return
    from mdgs.data.schema import DatasetError
    from mdgs.evaluate import evaluate
    from mdgs.models import ModelError
    from mdgs.runs import RunError

    if not runs:
        fail("name at least one run folder (from `mdgs train`)")
    if data is None:
        fail("--data DIR is required (the dataset folder of `mdgs generate`)")
    if split not in ("train", "valid", "test"):
        fail(f"--split {split} is not one of train, valid, test")
    refs = [_parse_reference(r) for r in reference or []]
    try:
        rep = evaluate([str(r) for r in runs], data, split, json_path, device, traj, refs, compile_mode)
    except (DatasetError, RunError, ModelError) as e:
        fail(str(e))
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
    for ref in rep["references"]:
        def f(x):
            return "n/a (diverged)" if x is None else f"{x:.4g}"
        typer.echo(f"reference {ref['label']}: t=40 {f(ref['mse_t40'])} m^2, "
                   f"t=110 {f(ref['mse_t110'])} m^2")
    for r in rep["runs"]:
        for dv in r["diverged"]:
            typer.echo(f"warning: {r['run']}: test trajectory {dv['trajectory']} diverged at step {dv['step']} "
                       f"(t = {dv['time_s']:.3g} s) and is left out of the means from there on", err=True)
