"""Raw MuJoCo stepping rate vs full dataset-generation rate, side by side, per scene.

    python benchmarks/bench_generate.py [SCENE ...] [--traj 25] [--frames 110]

For each scene, the same trajectories (initial states and controls) are run twice on
one core:

- **raw**: the scene's own MJCF (no sensors), one ``mujoco.rollout`` call over the whole
  trajectory batch, controls replayed from the generation (so closed-loop scenes
  follow the same path);
- **generation**: what ``mdgs generate`` does per batch: stepping the instrumented model
  in a ``mujoco.batch.Batch`` (per frame for closed-loop controllers), element
  extraction, force accounting and writing the part file; ``+merge`` adds the final
  copy of the part into the split file (done once per dataset).

Both count integrator steps; the ratio is generation / raw throughput (target >= 0.70).
Scene setup (MJCF compile, partition) is done once per dataset and not counted.

Timings are noisy on a shared machine, so the two are measured side by side: each
repeat runs the generation, the merge and then raw stepping of that repeat's
trajectories, after one uncounted warm-up repeat; ratios are the medians of the
repeats' paired ratios, rates the medians of the repeats' rates. ``write`` is the part
file's share, in units of raw stepping time.

Each repeat's files are deleted after it (``mdgs generate`` deletes its parts after the
merge too), so the next repeat writes into page-cache memory the system has used
before. ``--keep-files`` keeps them instead: every write then grows the page cache into
memory never touched since boot, which on some virtual machines costs far more than
the write itself (on the 2-core VM of docs/scenes.md, ~3 ms of kernel time per MB: a
73 MB part takes 0.2-0.28 s instead of 0.02-0.05 s).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import mujoco
import numpy as np
from mujoco import rollout

from mdgs.data.engine import load_scene, scene_attrs, simulate, static_arrays
from mdgs.data.io import merge_files, write_file
from mdgs.data.presets import PRESETS
from mdgs.scenes import SCENES


def bench(name: str, n_traj: int, n_frames: int, repeats: int, keep: bool = False) -> dict:
    t = time.perf_counter()
    sc = load_scene(SCENES[name])
    setup = time.perf_counter() - t
    k = sc.spec.substeps
    steps = n_traj * n_frames * k
    static, attrs = static_arrays(sc), scene_attrs(sc)
    attrs.update(
        split="train",
        n_traj=n_traj,
        n_frames=n_frames,
        traj_start=0,
        seed=0,
        preset="bench",
        config_sha256="bench",
        mdgs_version="bench",
        complete=False,
    )
    m = mujoco.MjModel.from_xml_string(sc.mjcf)
    d = mujoco.MjData(m)
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS

    def raw_inputs(fr):
        # raw: same initial states and controls, plain model, one rollout call
        init = np.zeros((n_traj, mujoco.mj_stateSize(m, spec)))
        for i in range(n_traj):
            mujoco.mj_resetData(m, d)
            d.qpos[:], d.qvel[:] = fr["qpos"][i, 0], fr["qvel"][i, 0]
            mujoco.mj_getState(m, d, init[i], spec)
        return init, np.ascontiguousarray(np.repeat(fr["ctrl"], k, axis=1))

    gen, write, merge, raw = [], [], [], []
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(repeats + 1):  # repeat 0: warm-up, not counted
            t = time.perf_counter()
            fr = simulate(sc, "train", range(n_traj), seed=r, n_frames=n_frames)
            t1 = time.perf_counter()
            part, final = Path(tmp) / f"part{r}.h5", Path(tmp) / f"train{r}.h5"
            write_file(part, attrs, sc.mjcf, static, fr)
            g, w = time.perf_counter() - t, time.perf_counter() - t1
            t = time.perf_counter()
            merge_files([part], final, {"complete": True})
            mg = time.perf_counter() - t
            init, ctrl = raw_inputs(fr)
            t = time.perf_counter()
            rollout.rollout(m, [d], init, ctrl if m.nu else None, nstep=n_frames * k)
            rw = time.perf_counter() - t
            if not keep:
                part.unlink()
                final.unlink()
            if r:
                gen.append(g)
                write.append(w)
                merge.append(mg)
                raw.append(rw)
    gen, write, merge, raw = np.array(gen), np.array(write), np.array(merge), np.array(raw)
    return {
        "scene": name,
        "nodes": sc.inst.partition.n_nodes,
        "bodies": m.nbody - 1,
        "steps": steps,
        "setup_s": setup,
        "raw": float(np.median(steps / raw)),
        "gen": float(np.median(steps / gen)),
        "ratio": float(np.median(raw / gen)),
        "ratio_merged": float(np.median(raw / (gen + merge))),
        "write": float(np.median(write / raw)),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenes", nargs="*", default=[n for n, s in SCENES.items() if not s.variant_of])
    ap.add_argument(
        "--traj",
        type=int,
        default=PRESETS["paper"].batch,
        help="trajectories per batch (the paper preset's batch)",
    )
    ap.add_argument("--frames", type=int, default=110)
    ap.add_argument(
        "--repeats", type=int, default=3, help="paired repeats (median), after a warm-up"
    )
    ap.add_argument(
        "--keep-files",
        action="store_true",
        help="keep every repeat's files (writes then grow the page cache; see above)",
    )
    a = ap.parse_args()
    print(
        f"{'scene':<26}{'nodes':>6}{'bodies':>7}{'steps':>9}  {'raw steps/s':>12}  {'generation steps/s':>19}  {'ratio':>6}  {'+merge':>7}  {'write':>6}"
    )
    ratios = []
    for name in a.scenes:
        r = bench(name, a.traj, a.frames, a.repeats, keep=a.keep_files)
        ratios.append(r["ratio"])
        print(
            f"{r['scene']:<26}{r['nodes']:>6}{r['bodies']:>7}{r['steps']:>9}  {r['raw']:>12,.0f}  {r['gen']:>19,.0f}  {r['ratio']:>6.2f}  {r['ratio_merged']:>7.2f}  {r['write']:>6.2f}",
            flush=True,
        )
    print(f"{'geometric mean ratio':<52}{np.exp(np.mean(np.log(ratios))):>32.2f}")


if __name__ == "__main__":
    main()
