"""Pictures of the scenes for the docs: a MuJoCo render next to the element graph.

    python -m mdgs.scenes.draw --out docs/img/scenes [SCENE ...]

For each scene, trajectory 0 of the training split (seed 0) is simulated to a frame
where things move, and two panels are drawn at that frame: MuJoCo's own render
(offscreen OpenGL: ``MUJOCO_GL=egl`` first, then ``osmesa``; the panel is left out if
neither works) and the element partition as the model sees it: nodes at element
centroids (area ~ mass, grey for static geometry), edges between elements that share
a face, one colour per body.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import numpy as np

__all__ = ["draw_scene", "main"]


_PROBE = (
    "import mujoco; m = mujoco.MjModel.from_xml_string(\"<mujoco><worldbody><geom size='.1'/></worldbody></mujoco>\");"
    " r = mujoco.Renderer(m, 8, 8); d = mujoco.MjData(m); r.update_scene(d); r.render()"
)


def _gl_backend() -> str | None:
    """An offscreen OpenGL backend that works here (probed in subprocesses), or None.

    MuJoCo picks its backend from MUJOCO_GL when it is first imported, so the probe
    runs in a fresh interpreter and :func:`main` re-executes itself with the winner.
    """
    import subprocess

    for backend in ("egl", "osmesa"):
        env = {**os.environ, "MUJOCO_GL": backend}
        try:
            ok = (
                subprocess.run(
                    [sys.executable, "-c", _PROBE], env=env, capture_output=True, timeout=60
                ).returncode
                == 0
            )
        except (OSError, subprocess.TimeoutExpired):
            ok = False
        if ok:
            return backend
    return None


def _render(model, data, lookat, distance, width=480, height=400):
    import mujoco

    cam = mujoco.MjvCamera()
    cam.lookat[:] = lookat
    cam.distance = distance
    cam.azimuth, cam.elevation = 135.0, -25.0
    opt = mujoco.MjvOption()
    opt.sitegroup[:] = 0
    with mujoco.Renderer(model, height, width) as r:
        r.update_scene(data, camera=cam, scene_option=opt)
        return r.render()


def draw_scene(name: str, out: Path, frame: int = 40, gl: str | None = None) -> Path:
    """Write ``out/<name>.png`` and return its path."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import mujoco

    from mdgs.data.engine import load_scene, simulate
    from mdgs.scenes import SCENES

    spec = SCENES[name]
    sc = load_scene(spec)
    fr = simulate(sc, "train", [0], seed=0, n_frames=frame + 1)
    part = sc.inst.partition
    x = fr["node_pos"][0, frame]
    moving = ~part.static
    centre = x[moving].mean(0)
    extent = float(np.ptp(x[moving], axis=0).max()) + 0.15
    panels = 2 if gl else 1
    fig = plt.figure(figsize=(5.2 * panels, 4.6), dpi=100)
    if gl:
        m = mujoco.MjModel.from_xml_string(sc.mjcf)
        d = mujoco.MjData(m)
        d.qpos[:], d.qvel[:] = fr["qpos"][0, frame], fr["qvel"][0, frame]
        mujoco.mj_forward(m, d)
        ax0 = fig.add_subplot(1, 2, 1)
        ax0.imshow(_render(m, d, centre, 1.6 * extent + 0.4))
        ax0.set_axis_off()
        ax0.set_title("MuJoCo", fontsize=10)
    ax = fig.add_subplot(1, panels, panels, projection="3d")
    cmap = plt.get_cmap("tab10")
    bodies = sorted(set(part.body.tolist()) - {0})
    colour = {b: cmap(i % 10) for i, b in enumerate(bodies)}
    for i, j in part.adjacency:
        c = (0.6, 0.6, 0.6, 0.6) if part.static[i] else colour[int(part.body[i])]
        ax.plot(*zip(x[i], x[j], strict=True), color=c, lw=1.0)
    size = 8 + 120 * (part.mass / max(part.mass.max(), 1e-12)) ** (2 / 3)
    cols = [
        (0.55, 0.55, 0.55, 1.0) if part.static[i] else colour[int(part.body[i])]
        for i in range(part.n_nodes)
    ]
    ax.scatter(
        x[:, 0],
        x[:, 1],
        x[:, 2],
        s=np.where(part.static, 10, size),
        c=cols,
        depthshade=False,
        edgecolors="k",
        linewidths=0.3,
    )
    half = 0.5 * max(extent, 0.3)
    ax.set_xlim(centre[0] - half, centre[0] + half)
    ax.set_ylim(centre[1] - half, centre[1] + half)
    ax.set_zlim(
        max(centre[2] - half, -0.05) if spec.family != "space" else centre[2] - half,
        (max(centre[2] - half, -0.05) if spec.family != "space" else centre[2] - half) + 2 * half,
    )
    ax.set_box_aspect((1, 1, 1))
    ax.view_init(elev=25, azim=-45)
    ax.set_xlabel("x (m)", fontsize=8)
    ax.set_ylabel("y (m)", fontsize=8)
    ax.set_zlabel("z (m)", fontsize=8)
    ax.tick_params(labelsize=7)
    ax.set_title(f"{part.n_nodes} elements, {len(part.adjacency)} face edges", fontsize=10)
    fig.suptitle(f"{name} (frame {frame}, t = {fr['time'][0, frame]:.2f} s)", fontsize=11)
    fig.tight_layout()
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"{name}.png"
    fig.savefig(path)
    plt.close(fig)
    return path


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description="Draw the scenes (MuJoCo render + element graph).")
    ap.add_argument("--out", type=Path, default=Path("docs/img/scenes"))
    ap.add_argument("--frame", type=int, default=40)
    ap.add_argument("scenes", nargs="*")
    a = ap.parse_args(argv)
    if "MUJOCO_GL" not in os.environ:
        backend = _gl_backend()
        env = {**os.environ, "MUJOCO_GL": backend or "disabled"}
        os.execve(
            sys.executable,
            [sys.executable, "-m", "mdgs.scenes.draw", *(sys.argv[1:] if argv is None else argv)],
            env,
        )
    gl = os.environ["MUJOCO_GL"] if os.environ["MUJOCO_GL"] in ("egl", "osmesa", "glfw") else None
    if gl is None:
        print("no OpenGL backend (tried egl, osmesa): drawing element graphs only", file=sys.stderr)
    from mdgs.scenes import SCENES

    for name in a.scenes or list(SCENES):
        print(draw_scene(name, a.out, a.frame, gl))


if __name__ == "__main__":
    main()
