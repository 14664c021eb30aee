"""The non-learned references: constant twist and MuJoCo replaying the data at a coarser timestep."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest
import torch

from mdgs.data.generate import GenerateConfig, generate
from mdgs.data.split import load_split
from mdgs.evaluate.cost import step_cost
from mdgs.evaluate.rollout import rollout
from mdgs.models import MODELS, ModelError


@pytest.fixture(scope="module")
def test_split(tmp_path_factory):
    out = tmp_path_factory.mktemp("cubli")
    generate(GenerateConfig(scene="cubli-triple", out=str(out), preset="tiny"))
    return load_split(out / "test.h5")


def _mujoco(d, **kw):
    cls = MODELS["mujoco"]
    return cls.from_data(d, cls.Config(**kw))


def test_mujoco_at_the_data_timestep_replays_the_data(test_split):
    # same model, same initial state, same controls: only the solver's warm start of frame 0 is
    # not recorded, so contact forces differ at round-off; 1e-9 m^2 is far below any model error
    r = rollout(_mujoco(test_split, dt_factor=1), test_split)
    assert np.nanmax(r.pos_mse) < 1e-9 and (r.diverged_at < 0).all()


def test_coarser_mujoco_is_less_accurate_but_finite(test_split):
    fine = rollout(_mujoco(test_split, dt_factor=1), test_split).pos_mse[:, 39].mean()
    coarse = rollout(_mujoco(test_split, dt_factor=20), test_split).pos_mse[:, 39].mean()
    assert np.isfinite(coarse) and coarse > 100 * max(fine, 1e-16)


def test_dt_factor_must_divide_the_substeps(test_split):
    sub = int(test_split.attrs["substeps"])
    bad = next(k for k in range(2, 3 * sub) if sub % k)
    with pytest.raises(ModelError, match="does not divide"):
        _mujoco(test_split, dt_factor=bad)


def test_velocity_noise_moves_initial_velocities_only(test_split):
    idx = np.arange(test_split.x.shape[0])
    clean = _mujoco(test_split).initial_state(test_split, idx, 0)
    noisy = _mujoco(test_split, velocity_noise=1e-3, noise_seed=1).initial_state(test_split, idx, 0)
    dq = (noisy.extra["qvel"] - clean.extra["qvel"]).abs()
    rel = dq / clean.extra["qvel"].abs().clamp_min(1e-12)
    assert 0 < float(rel.max()) < 1e-2 and torch.equal(noisy.extra["qpos"], clean.extra["qpos"])
    assert torch.allclose(noisy.x, clean.x, atol=1e-6)  # positions are those of the same qpos


def test_mujoco_cost_counts_its_steps_not_the_node_mapping(test_split, monkeypatch):
    model = _mujoco(test_split, dt_factor=int(test_split.attrs["substeps"]))
    monkeypatch.setattr(type(model), "_nodes", lambda self, d: (_ for _ in ()).throw(AssertionError("mapped")))
    c = step_cost(model, test_split, batch=1, frames=5, repeats=1)
    assert c["ms_per_frame"] > 0


def test_batched_mujoco_cost_steps_the_same_physics_as_the_rollout(test_split):
    """The batched cost is mujoco.rollout: it must advance each row exactly as the accuracy rollout's
    mj_step loop does (same frame of the data after one frame; 1e-9 m^2 as in the replay test)."""
    import mujoco

    model = _mujoco(test_split)
    idx = np.arange(3) % test_split.x.shape[0]  # a batch of 3 rows (the batched path)
    state = model.initial_state(test_split, idx, 0)
    ctrl = torch.from_numpy(test_split.ctrl[idx, 0])
    model.cost_step(state, ctrl)
    packed = model._packed[2][:, -1]  # [B, nstate] full physics after one frame
    nq = model._model.nq
    qpos = packed[:, 1:1 + nq]  # mjSTATE_FULLPHYSICS starts with time, then qpos
    stepped = model.step(state, ctrl).extra["qpos"].numpy()
    np.testing.assert_allclose(qpos, stepped, rtol=0, atol=1e-9)
    assert np.abs(qpos - test_split.qpos[idx, 0]).max() > 1e-6  # it did move
    c = step_cost(model, test_split, batch=len(idx), frames=3, repeats=1)
    assert c["ms_per_trajectory_frame"] > 0 and mujoco.mj_stateSize(model._model, mujoco.mjtState.mjSTATE_FULLPHYSICS) == packed.shape[1]


def test_constant_twist_has_nothing_to_train(test_split):
    ref = MODELS["constant-twist"].from_data(test_split)
    assert not ref.learned and ref.parameter_count() == 0
    with pytest.raises(NotImplementedError):
        ref.losses(None)


@pytest.mark.skipif(not any(__import__("shutil").which(c) for c in ("cc", "gcc", "clang")),
                    reason="torch.compile on a CPU needs a C compiler")
def test_a_compiled_step_rolls_out_the_eager_trajectories(test_split):
    """compile_step swaps in a torch.compile'd step (a new function object) whose rollout is the
    eager one as one graph, and rolling out the same split again compiles nothing new; constant twist: the
    cheapest model to compile (seconds)."""
    from mdgs.models import compile_step

    ref = MODELS["constant-twist"].from_data(test_split)
    eager = rollout(ref, test_split, "cpu")
    assert "step" not in vars(ref)
    from torch._dynamo.utils import counters

    graphs = counters["stats"]["unique_graphs"]
    assert compile_step(ref) is ref and "step" in vars(ref)  # the instance's own (compiled) step
    compiled = rollout(ref, test_split, "cpu")
    np.testing.assert_allclose(compiled.x, eager.x, rtol=0, atol=1e-5)  # float32 fusion may reorder rounding
    assert counters["stats"]["unique_graphs"] == graphs + 1  # the whole step one graph: no graph breaks
    # a second rollout of the same split (rollout binds again) runs the graph already compiled
    graphs = counters["stats"]["unique_graphs"]
    again = rollout(ref, test_split, "cpu")
    assert counters["stats"]["unique_graphs"] == graphs
    np.testing.assert_array_equal(again.x, compiled.x)


def test_ahead_of_time_compiled_mdgs_rolls_out_as_the_eager_step_and_reuses_its_package(test_split):
    """``compile_step(model, "aot")``: an MDGS with random weights (so the state network acts) rolls out
    every test trajectory as the eager step does, binding the same scene again reuses its package, and
    an unknown mode is refused by name."""
    from mdgs.models import compile_step
    from mdgs.models.mdgs import ModelConfig

    torch.manual_seed(0)
    model = MODELS["mdgs"].from_data(test_split, ModelConfig(hidden=16, global_dim=16, zero_init=False))
    eager = rollout(model, test_split, "cpu")
    assert compile_step(model, "aot") is model
    aot = rollout(model, test_split, "cpu")
    np.testing.assert_allclose(aot.x, eager.x, rtol=0, atol=1e-5)  # float32 fusion may reorder rounding
    assert np.abs(eager.x[:, -1] - test_split.x[:, -1]).max() > 1e-3  # the untrained network does move things
    again = rollout(model, test_split, "cpu")  # bound again to the same scene: its package, the same numbers
    np.testing.assert_array_equal(again.x, aot.x)
    assert len(list(Path(model._aot_dir.name).iterdir())) == 1
    assert _heap_allocations(model) > 0  # a step with library calls keeps its buffers on the heap
    with pytest.raises(ValueError, match="'jit' is not one of inductor, aot"):
        compile_step(model, "jit")


def _heap_allocations(model) -> int:
    """How often the C++ wrappers of ``model``'s ahead-of-time packages allocate a tensor on the heap."""
    import zipfile

    count = 0
    for package in Path(model._aot_dir.name).iterdir():
        with zipfile.ZipFile(package) as z:
            count += sum(z.read(n).decode().count("aoti_torch_empty_strided(")
                         for n in z.namelist() if n.endswith(".wrapper.cpp"))
    return count


def test_an_ahead_of_time_step_of_fused_loops_alone_keeps_its_buffers_on_the_stack(test_split):
    """Constant twist compiled ahead of time (its step calls no library kernel: :func:`mdgs.models.base._stack_allocation`)
    rolls out every test trajectory as its eager step does, its package's C++ wrapper allocates nothing on the heap
    (every buffer on the stack), and inductor's CPU wrapper registered before compiling is registered again after
    it. MDGS's package, which calls matrix products, allocates on the heap (the test above)."""
    from torch._inductor.codegen import common

    from mdgs.models import compile_step

    cls = MODELS["constant-twist"]
    model = cls.from_data(test_split, cls.Config())
    eager = rollout(model, test_split, "cpu")
    common.init_backend_registration()
    registered = common.device_codegens["cpu"]
    compile_step(model, "aot")
    aot = rollout(model, test_split, "cpu")
    np.testing.assert_allclose(aot.x, eager.x, rtol=0, atol=1e-5)  # float32 fusion may reorder rounding
    assert _heap_allocations(model) == 0
    assert common.device_codegens["cpu"] is registered


def test_only_a_single_trajectorys_step_with_one_rotation_fit_is_exported_with_jacobi_rotations(test_split, monkeypatch):
    """Ahead of time, MDGS's step for one trajectory (one Kabsch fit) is exported with Jacobi rotations (no SVD
    left in the program); for two trajectories, and the rigid tree's step (two fits a frame, each of which would
    cost 25-40 s of compiling), with the SVD. Compiling itself is stood in for (it takes a minute)."""
    from mdgs.models import compile_step

    programs = []

    def stop(program, **kw):
        programs.append({str(n.target) for n in program.graph.nodes})
        raise RuntimeError("stood in for")

    monkeypatch.setattr(torch._inductor, "aoti_compile_and_package", stop)
    md, ct = MODELS["mdgs"], MODELS["constant-twist"]
    cases = [(md.from_data(test_split), 1, True), (md.from_data(test_split), 2, False),
             (ct.from_data(test_split, ct.Config(dynamics=True, joints=True)), 1, False)]
    for model, batch, jacobi in cases:
        compile_step(model, "aot")
        model.bind(test_split)
        traj = np.zeros(batch, dtype=int)
        st = model.initial_state(test_split, traj, model.history)
        ctrl = torch.from_numpy(test_split.ctrl[traj, model.history])
        model.step(st, ctrl)  # the first step of a binding runs eagerly
        with pytest.raises(ModelError, match="does not compile ahead of time"):
            model.step(st, ctrl)
        ops = programs[-1]
        assert (not any("svd" in op for op in ops)) == jacobi
        assert any("copysign" in op for op in ops) == jacobi


def test_steps_that_run_the_rigid_tree_compile_with_scalar_loops_unless_told_otherwise(test_split, monkeypatch):
    """Ahead of time, a step that runs the rigid tree's forward dynamics (MDGS's "dynamics" prior, constant twist
    with ``dynamics``) or constant twist's few bodies' 3-vectors is compiled with a vector width of one bit (scalar
    loops), a network's step (MDGS without the prior) with inductor's vectors; ``loops`` overrides the model's choice
    and an unknown way is refused by name. Compiling itself is stood in for."""
    from mdgs.models import compile_step

    options = []

    def stop(program, inductor_configs=None, **kw):
        options.append(dict(inductor_configs or {}))
        raise RuntimeError("stood in for")

    monkeypatch.setattr(torch._inductor, "aoti_compile_and_package", stop)
    md, ct = MODELS["mdgs"], MODELS["constant-twist"]
    cases = [(md.from_data(test_split), None, False), (md.from_data(test_split, md.Config(actuation="dynamics")), None, True),
             (ct.from_data(test_split), None, True), (ct.from_data(test_split, ct.Config(dynamics=True)), None, True),
             (md.from_data(test_split, md.Config(actuation="dynamics")), "vector", False),
             (md.from_data(test_split), "scalar", True)]
    for model, loops, scalar in cases:
        if loops is None:  # the model's own choice
            assert model.scalar_loops == scalar
        compile_step(model, "aot", loops)
        model.bind(test_split)
        st = model.initial_state(test_split, np.zeros(1, dtype=int), model.history)
        ctrl = torch.from_numpy(test_split.ctrl[:1, model.history])
        model.step(st, ctrl)  # the first step of a binding runs eagerly
        with pytest.raises(ModelError, match="does not compile ahead of time"):
            model.step(st, ctrl)
        assert (options[-1].get("cpp.simdlen") == 1) == scalar
        assert options[-1]["max_fusion_size"] == 4096  # the other options kept
    with pytest.raises(ValueError, match="loops 'wide' is not one of vector, scalar"):
        compile_step(md.from_data(test_split), "aot", "wide")


@pytest.mark.skipif(not any(__import__("shutil").which(c) for c in ("cc", "gcc", "clang")),
                    reason="torch.compile on a CPU needs a C compiler")
def test_a_step_compiled_with_scalar_loops_rolls_out_the_eager_trajectories(test_split, caplog):
    """``loops="scalar"`` changes how inductor writes the loops, not what they compute: constant twist compiled so,
    by torch.compile and ahead of time, rolls out as its eager step (the same float32 tolerance as the vector loops'
    tests above), and loading the package does not warn that it was built for no instruction set."""
    from mdgs.models import compile_step

    eager = rollout(MODELS["constant-twist"].from_data(test_split), test_split, "cpu")
    for mode in ("inductor", "aot"):
        ref = compile_step(MODELS["constant-twist"].from_data(test_split), mode, "scalar")
        with caplog.at_level(logging.WARNING):
            np.testing.assert_allclose(rollout(ref, test_split, "cpu").x, eager.x, rtol=0, atol=1e-5)
    assert not [r for r in caplog.records if "INVALID_VEC_ISA" in r.getMessage()]


def test_cuda_graphs_are_refused_on_the_cpu_and_the_cost_falls_back_to_inductor(test_split):
    """``compile_step(model, "cudagraphs")`` needs a CUDA device: on the CPU one ModelError naming the
    device and the other modes; ``compiled_cost`` then times the next mode that works and says why."""
    from mdgs.evaluate.cost import compiled_cost
    from mdgs.models import compile_step

    ref = MODELS["constant-twist"].from_data(test_split)
    with pytest.raises(ModelError, match="replays CUDA graphs.*is on cpu.*'inductor' or 'aot'"):
        compile_step(ref, "cudagraphs")
    assert "step" not in vars(ref)  # refused before anything was swapped in
    out = compiled_cost(ref, test_split, "cudagraphs", batched=2)
    assert (out["requested"], out["compiled"]) == ("cudagraphs", "inductor")
    assert out["note"].startswith("cudagraphs: ModelError") and out["single"]["ms_per_frame"] > 0


@pytest.mark.parametrize("capture", ["works", "fails"])
def test_the_cuda_graph_step_is_traced_with_horns_rotation_returns_copies_and_turns_a_capture_failure_into_a_model_error(
        capture, test_split, monkeypatch):
    """The ``cudagraphs`` wrapper of :func:`compile_step`, on the CPU with ``torch.compile`` stood in for
    (no GPU here): it compiles with ``mode="reduce-overhead"``, calls the compiled step inside
    ``rotation_fit("horn")`` (no SVD, whose error check syncs with the host), hands back copies of the
    replay's outputs (the next replay overwrites them), and a capture failure becomes one ModelError."""
    import mdgs.structure
    from mdgs.models import State, compile_step

    ref = MODELS["constant-twist"].from_data(test_split)
    seen = {}

    def fake_compile(fn, **kw):
        seen.update(kw)

        def replay(state, ctrl):
            seen["horn"] = mdgs.structure._FIT.name == "horn"
            if capture == "fails":
                raise RuntimeError("Cannot copy between CPU and CUDA tensors during CUDA graph capture unless ...")
            seen["out"] = fn(state, ctrl)
            return seen["out"]
        return replay

    monkeypatch.setattr(type(ref), "device", property(lambda self: torch.device("cuda")))
    monkeypatch.setattr(torch, "compile", fake_compile)
    compile_step(ref, "cudagraphs")
    assert seen["mode"] == "reduce-overhead" and "horn" not in seen
    ref.bind(test_split)
    st = State(torch.from_numpy(test_split.x[:, 0]), torch.from_numpy(test_split.v[:, 0]))
    ctrl = torch.from_numpy(test_split.ctrl[:, 0])
    first = ref.step(st, ctrl)  # the first step of a binding runs eagerly (fills the scene's caches)
    assert "horn" not in seen
    if capture == "fails":
        with pytest.raises(ModelError, match="cannot be captured as a CUDA graph.*use compile mode 'inductor'"):
            ref.step(st, ctrl)
    else:
        out = ref.step(st, ctrl)
        assert out.x is not seen["out"].x and out.v is not seen["out"].v  # copies, not the replay's buffers
        torch.testing.assert_close(out.x, first.x, rtol=0, atol=0)
    assert seen["horn"] is True and mdgs.structure._FIT.name == "svd"  # Horn inside the call only


def test_compiled_cost_falls_back_mode_by_mode_and_says_why(test_split, monkeypatch):
    """``compiled_cost``: a step that compiles neither ahead of time nor by torch.compile is timed eagerly and
    the result names both refusals; MuJoCo (C code) is timed as it is; and the ahead-of-time step it
    times is the eager rollout's (constant twist: the cheapest model to compile)."""
    import mdgs.evaluate.cost as cost
    from mdgs.models import compile_step

    real = compile_step

    def refuse(model, mode, loops=None):
        raise ModelError(f"no {mode} today")

    monkeypatch.setattr(cost, "compile_step", refuse)
    ref = MODELS["constant-twist"].from_data(test_split)
    c = cost.compiled_cost(ref, test_split, "aot")
    assert (c["requested"], c["compiled"]) == ("aot", "none")
    assert ref.step.__func__ is type(ref).step  # the eager step, timed
    assert "aot: ModelError: no aot today" in c["note"] and "inductor: ModelError: no inductor today" in c["note"]
    assert c["single"]["batch"] == 1 and c["batched"]["batch"] == test_split.x.shape[0]
    c = cost.compiled_cost(_mujoco(test_split), test_split, "aot")
    assert c["compiled"] == "none" and "not torch code" in c["note"] and c["single"]["ms_per_frame"] > 0
    monkeypatch.setattr(cost, "compile_step", real)
    eager = rollout(ref, test_split, "cpu")
    c = cost.compiled_cost(ref, test_split, "aot")
    assert (c["compiled"], c["note"]) == ("aot", "") and c["compile_seconds"] > 0
    np.testing.assert_allclose(rollout(ref, test_split, "cpu").x, eager.x, rtol=0, atol=1e-5)
    with pytest.raises(ValueError, match="'jit' is not one of aot, inductor, none"):
        cost.compiled_cost(ref, test_split, "jit")


def test_a_compiled_step_that_compiles_again_is_timed_eagerly_and_says_why(test_split, monkeypatch):
    """A step whose graph follows the state (SGNN's contact edges) would compile anew at every timed step:
    the moment a compiled step adds a graph after its warm-up, ``compiled_cost`` stops and times the
    eager step, naming the reason. Here a new graph is simulated by raising dynamo's own graph count."""
    from torch._dynamo.utils import counters

    import mdgs.evaluate.cost as cost

    real = cost._refuse_recompiles

    def then_one_more_graph(model):
        real(model)
        counters["stats"]["unique_graphs"] += 1

    monkeypatch.setattr(cost, "_refuse_recompiles", then_one_more_graph)
    ref = MODELS["constant-twist"].from_data(test_split)
    c = cost.compiled_cost(ref, test_split, "inductor")
    assert c["compiled"] == "none" and "inductor: ModelError: the compiled step compiles again" in c["note"]
    assert ref.step.__func__ is type(ref).step and c["single"]["ms_per_frame"] > 0


@pytest.mark.parametrize("settings", [{}, {"actuation": "dynamics", "trapezoidal": True, "prior_input": True}],
                         ids=["paper", "dynamics-prior"])
def test_the_mdgs_step_traces_as_one_graph_without_breaks(test_split, settings):
    """What ``compile_step(model, "cudagraphs")`` captures must be one graph: on one H100 (torch 2.11) a
    single graph break (``bool`` of a Python list in ``JointSet.__bool__``) left the rest of MDGS's step
    eager, 55 kernel launches and 7 graph replays a step, 1.93 ms instead of 0.47
    (docs/results/benchmarks/profile_step-cuda-h100-cudagraphs.txt). Traced here by dynamo alone (no
    inductor, seconds), on the CPU, inside Horn's rotation fit as the captured step is."""
    from mdgs.structure import rotation_fit

    cls = MODELS["mdgs"]
    net = cls.from_data(test_split, cls.Config(**settings)).eval()
    net.bind(test_split)
    traj = np.arange(test_split.x.shape[0])
    st = net.initial_state(test_split, traj, net.history)
    ctrl = torch.from_numpy(test_split.ctrl[traj, net.history])
    eager = type(net).step.__get__(net)
    with torch.no_grad():
        eager(st, ctrl)  # the first step fills the scene's caches, as compile_step's first (eager) step does
        with rotation_fit("horn"):
            ex = torch._dynamo.explain(eager)(st, ctrl)
    assert ex.graph_break_count == 0, [b.reason.splitlines()[0] for b in ex.break_reasons]
    assert ex.graph_count == 1
