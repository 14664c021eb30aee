"""Pictures of a scene at one state, for the docs: a MuJoCo render next to the element graph.

:func:`draw_frame` draws one recorded frame in two panels: MuJoCo's own render
(offscreen OpenGL, see :func:`gl_backend`; the panel is left out if no backend works)
and the element partition as the model sees it: nodes at element centroids (area ~
mass, grey for static geometry), edges between elements that share a face, one colour
per body. Which frame to draw is the caller's choice: ``python -m mdgs.data.draw``
simulates one per scene (see :mod:`mdgs.data.draw`).
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np

from mdgs.scenes._spec import SceneSpec

__all__ = ["draw_frame", "gl_backend"]


_PROBE = (
    "import mujoco; m = mujoco.MjModel.from_xml_string(\"<mujoco><worldbody><geom size='.1'/></worldbody></mujoco>\");"
    " r = mujoco.Renderer(m, 8, 8); d = mujoco.MjData(m); r.update_scene(d); r.render()"
)


def gl_backend() -> str | None:
    """An offscreen OpenGL backend that works here (``egl``, then ``osmesa``), or None.

    MuJoCo picks its backend from MUJOCO_GL when it is first imported, so the probe runs
    in fresh interpreters and a caller re-executes itself with the winner.
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


def draw_frame(
    spec: SceneSpec,
    mjcf: str,
    partition,
    state: dict[str, np.ndarray],
    frame: int,
    out: Path,
    gl: str | None = None,
) -> Path:
    """Write ``out/<spec.name>.png`` of one frame and return its path.

    Parameters
    ----------
    spec, mjcf
        The scene and its MJCF text (as simulated).
    partition
        Its :class:`mdgs.partition.Partition` (``static``, ``body``, ``mass``,
        ``adjacency``, ``n_nodes``).
    state
        The frame's recorded arrays (names of :mod:`mdgs.data.schema`): ``node_pos``
        ``[N, 3]``, ``qpos`` ``[nq]``, ``qvel`` ``[nv]`` and ``time`` (s).
    frame
        Its index, for the title.
    gl
        The OpenGL backend MuJoCo was imported with, or None to draw the graph only.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import mujoco

    part = partition
    x = state["node_pos"]
    moving = ~part.static
    centre = x[moving].mean(0)
    extent = float(np.ptp(x[moving], axis=0).max()) + 0.15
    panels = 2 if gl else 1
    fig = plt.figure(figsize=(5.2 * panels, 4.6), dpi=100)
    if gl:
        m = mujoco.MjModel.from_xml_string(mjcf)
        d = mujoco.MjData(m)
        d.qpos[:], d.qvel[:] = state["qpos"], state["qvel"]
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
    fig.suptitle(f"{spec.name} (frame {frame}, t = {state['time']:.2f} s)", fontsize=11)
    fig.tight_layout()
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"{spec.name}.png"
    fig.savefig(path)
    plt.close(fig)
    return path
