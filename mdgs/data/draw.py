"""``python -m mdgs.data.draw``: the pictures of the scenes in docs/scenes.md, at a simulated frame.

    python -m mdgs.data.draw --out docs/img/scenes [SCENE ...]

For each scene, trajectory 0 of the training split (seed 0) is simulated to a frame
where things move (40 by default) and drawn by :func:`mdgs.scenes.draw.draw_frame`:
MuJoCo's render (offscreen OpenGL: ``MUJOCO_GL=egl`` first, then ``osmesa``; the panel
is left out if neither works) next to the element graph.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from mdgs.data.engine import load_scene, simulate
from mdgs.scenes import SCENES
from mdgs.scenes.draw import draw_frame, gl_backend

__all__ = ["draw_scene", "main"]


def draw_scene(name: str, out: Path, frame: int = 40, gl: str | None = None) -> Path:
    """Write ``out/<name>.png`` of frame ``frame`` of training trajectory 0 (seed 0)."""
    spec = SCENES[name]
    sc = load_scene(spec)
    fr = simulate(sc, "train", [0], seed=0, n_frames=frame + 1)
    state = {key: fr[key][0, frame] for key in ("node_pos", "qpos", "qvel", "time")}
    return draw_frame(spec, sc.mjcf, sc.inst.partition, state, frame, out, gl)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description="Draw the scenes (MuJoCo render + element graph).")
    ap.add_argument("--out", type=Path, default=Path("docs/img/scenes"))
    ap.add_argument("--frame", type=int, default=40)
    ap.add_argument("scenes", nargs="*")
    a = ap.parse_args(argv)
    if "MUJOCO_GL" not in os.environ:
        backend = gl_backend()
        env = {**os.environ, "MUJOCO_GL": backend or "disabled"}
        os.execve(
            sys.executable,
            [sys.executable, "-m", "mdgs.data.draw", *(sys.argv[1:] if argv is None else argv)],
            env,
        )
    gl = os.environ["MUJOCO_GL"] if os.environ["MUJOCO_GL"] in ("egl", "osmesa", "glfw") else None
    if gl is None:
        print("no OpenGL backend (tried egl, osmesa): drawing element graphs only", file=sys.stderr)
    for name in a.scenes or list(SCENES):
        print(draw_scene(name, a.out, a.frame, gl))


if __name__ == "__main__":
    main()
