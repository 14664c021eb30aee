"""Time to derive Kane's equations of MJCF trees (10+ DOF), and their residuals against MuJoCo and Pinocchio.

    python benchmarks/bench_mjcf.py [--kanes-method] [--states 20]

Models (built here, or taken from the repository):

- ``humanoid-24``: free trunk, two legs (ball hip, hinge knee, hinge ankle), two arms
  (ball shoulder, hinge elbow): 24 speeds, 4 joints deep;
- ``chain-12``: 12 hinges in a chain, axes alternating y, x: 12 speeds, 12 deep;
- ``space-single``: the paper's scene, a 6-joint arm on a free base: 12 speeds, 7 deep;
- ``arm``, ``floating_base``: ``examples/mjcf``.

Printed per model: speeds, joints on the deepest path, seconds to read the compiled model,
to derive by the body-frame route (``kane.systems.bodyframe``), by sympy's KanesMethod
(where :data:`kane.mjcf.KANES_METHOD_MAX_DEPTH` lets it run, or everywhere with
``--kanes-method``), and the largest relative residuals on random states. Target (issue
16): a 10+ DOF tree derives in under a minute.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from kane.mjcf import crosscheck_mjcf, from_mjcf

ROOT = Path(__file__).resolve().parents[1]


def _capsule(name, pos, joint, length, axis="0 1 0", inner=""):
    j = f'<joint name="{name}" type="{joint}"' + (f' axis="{axis}"' if joint == "hinge" else "") + "/>"
    return (f'<body name="{name}" pos="{pos}">{j}<geom type="capsule" fromto="0 0 0 0 0 -{length}" size="0.03"/>'
            f"{inner}</body>")


def humanoid() -> str:
    leg = lambda s: _capsule(f"{s}hip", f"0 {0.1 if s == 'l' else -0.1} -0.2", "ball", 0.4,  # noqa: E731
                             inner=_capsule(f"{s}knee", "0 0 -0.4", "hinge", 0.4,
                                            inner=_capsule(f"{s}ankle", "0 0 -0.4", "hinge", 0.1, axis="1 0 0")))
    arm = lambda s: _capsule(f"{s}shoulder", f"0 {0.25 if s == 'l' else -0.25} 0.3", "ball", 0.3,  # noqa: E731
                             inner=_capsule(f"{s}elbow", "0 0 -0.3", "hinge", 0.3))
    body = "".join([leg("l"), leg("r"), arm("l"), arm("r")])
    return (f'<mujoco model="humanoid"><worldbody><body name="trunk" pos="0 0 1.2"><freejoint name="root"/>'
            f'<geom type="box" size="0.1 0.2 0.3"/>{body}</body></worldbody></mujoco>')


def chain(n: int) -> str:
    inner = ""
    for k in reversed(range(n)):
        inner = _capsule(f"l{k}", "0 0 -0.3" if k else "0 0 0", "hinge", 0.3, axis="0 1 0" if k % 2 == 0 else "1 0 0",
                         inner=inner)
    return f'<mujoco model="chain"><worldbody>{inner}</worldbody></mujoco>'


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--kanes-method", action="store_true", help="run sympy's KanesMethod on every model")
    ap.add_argument("--states", type=int, default=20)
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp())
    models = {"humanoid-24": humanoid(), "chain-12": chain(12)}
    try:
        from mdgs.scenes import get_scene

        models["space-single"] = get_scene("space-single").mjcf()
    except ImportError:  # kane alone installed
        pass
    paths = {k: tmp / f"{k}.xml" for k in models}
    for k, xml in models.items():
        paths[k].write_text(xml)
    paths["arm"] = ROOT / "examples" / "mjcf" / "arm.xml"
    paths["floating_base"] = ROOT / "examples" / "mjcf" / "floating_base.xml"
    print(f"{'model':<14} {'speeds':>6} {'depth':>5} {'load s':>7} {'body-frame s':>12} {'KanesMethod s':>13}  "
          f"{'MuJoCo':>8} {'Pinocchio':>9} {'Kane-vs-KM':>10}")
    for name, path in paths.items():
        mm = from_mjcf(path)
        t = time.perf_counter()
        sm = mm.explicit
        t_bf = time.perf_counter() - t
        run_km = args.kanes_method or mm.kanes_method_applies
        t_km = float("nan")
        if run_km:
            t = time.perf_counter()
            mm.kanes_method  # noqa: B018 (derive)
            t_km = time.perf_counter() - t
        r = crosscheck_mjcf(mm, n_states=args.states, model=None if run_km else sm)
        mj = max(r[k] for k in r if k.startswith("mujoco_"))
        pin_ = max(r.get("pinocchio_crba", float("nan")), r.get("pinocchio_rnea", float("nan")))
        km = r.get("kanes_method", float("nan"))
        print(f"{name:<14} {len(sm.u):>6} {mm.joint_depth:>5} {mm.seconds_load:>7.2f} {t_bf:>12.2f} {t_km:>13.2f}  "
              f"{mj:>8.1e} {pin_:>9.1e} {km:>10.1e}", flush=True)


if __name__ == "__main__":
    main()
