"""The Simulator contract every model meets, learned or not, so trainer, evaluator and study never ask which.

A model simulates the scenes of one dataset. It is built from the training split
(:meth:`Simulator.from_data`, which fits its normalisation there and nowhere else), bound to
the scene it simulates (:meth:`Simulator.bind`: the static graph and control map of a split,
so a model can be evaluated on a test variant of its scene), and then

- :meth:`Simulator.initial_state` reads the state it starts from out of recorded frames,
- :meth:`Simulator.step` advances a batch of states by one frame under the recorded controls,
- :meth:`Simulator.losses` gives its named training losses on a :class:`Batch`,
  summed by the trainer with :meth:`Simulator.loss_weights`,
- :meth:`Simulator.perturb` applies its own training-noise recipe to a batch.

Shapes: ``B`` scenes in a batch, ``N`` nodes, ``H`` past frames (``history``), ``nu`` actuators.
Every tensor of a :class:`State` is batch-first, so rows of two states can be spliced.
"""

from __future__ import annotations

import contextlib
import logging
import re
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import torch
from torch import nn

from mdgs.data.split import SplitData
from mdgs.models.layers import folded_weights
from mdgs.structure import rotation_fit

__all__ = ["State", "Batch", "Simulator", "ModelError", "batch_of", "compile_step", "COMPILE_MODES", "one_step_error"]


class ModelError(Exception):
    """A model that cannot simulate a scene or setting; the message names the input and the fix."""


@dataclass
class State:
    """The state a model steps: node positions and velocities plus what else it carries.

    x, v : [B, N, 3] node positions (m) and velocities (m/s).
    extra : model-specific batch-first tensors (a velocity history, MuJoCo's qpos/qvel, ...).
    """

    x: torch.Tensor
    v: torch.Tensor
    extra: dict[str, torch.Tensor] = field(default_factory=dict)

    def where(self, rows: torch.Tensor, other: State) -> State:
        """Rows ``rows`` ([B] bool) taken from ``other``, the rest from ``self``."""
        def pick(a, b):
            m = rows.to(a.device).view(-1, *([1] * (a.dim() - 1)))
            return torch.where(m, b.to(a.dtype), a)
        return State(pick(self.x, other.x), pick(self.v, other.v),
                     {k: pick(a, other.extra[k]) for k, a in self.extra.items()})


@dataclass
class Batch:
    """Training pairs: frame ``t`` (with ``H`` past frames) and its true successor ``t + 1``.

    x, v : [B, N, 3] at t.  ctrl : [B, nu] controls held over t -> t+1.
    x_next, v_next : [B, N, 3] at t+1.
    x_past, v_past : [B, H, N, 3] frames t-H .. t-1 (oldest first), or None when H = 0.
    x_future, v_future : [B, K, N, 3] frames t+2 .. t+1+K, and ctrl_future [B, K, nu] the controls
        held over t+1 -> t+2 .. t+K -> t+K+1, for models trained over several steps; None when K = 0.
    """

    x: torch.Tensor
    v: torch.Tensor
    ctrl: torch.Tensor
    x_next: torch.Tensor
    v_next: torch.Tensor
    x_past: torch.Tensor | None = None
    v_past: torch.Tensor | None = None
    x_future: torch.Tensor | None = None
    v_future: torch.Tensor | None = None
    ctrl_future: torch.Tensor | None = None

    def __len__(self) -> int:
        return self.x.shape[0]

    def rows(self, sel: slice) -> Batch:
        """The pairs ``sel`` of this batch (every tensor sliced along its first axis)."""
        return Batch(*(None if a is None else a[sel] for a in (getattr(self, f.name) for f in fields(self))))


def batch_of(d: SplitData, idx: np.ndarray, dev, history: int = 0, future: int = 0) -> Batch:
    """The :class:`Batch` of pairs ``idx`` [B, 2] (trajectory, frame t) of a split, on ``dev``
    (``future`` frames after t + 1 too: ``idx`` from ``d.pairs(history, future)``)."""
    t, f = idx[:, 0], idx[:, 1]
    g = lambda a, k: torch.from_numpy(a[t, f + k]).to(dev)  # noqa: E731
    span = lambda a, ks: torch.from_numpy(a[t[:, None], f[:, None] + ks]).to(dev)  # noqa: E731
    past = (span(d.x, np.arange(-history, 0)), span(d.v, np.arange(-history, 0))) if history else (None, None)
    ahead = ((span(d.x, np.arange(2, future + 2)), span(d.v, np.arange(2, future + 2)),
              span(d.ctrl, np.arange(1, future + 1))) if future else (None, None, None))
    return Batch(g(d.x, 0), g(d.v, 0), g(d.ctrl, 0), g(d.x, 1), g(d.v, 1), *past, *ahead)


class Simulator(nn.Module):
    """Base class of every model in :data:`mdgs.models.MODELS` (see the module docstring).

    Class attributes a model sets: ``name`` (its registry key), ``Config`` (a dataclass with
    every default documented), ``learned`` (False for references that have nothing to train),
    ``summary`` (one line for ``--help`` and tables), ``default_lr`` (the learning rate its authors
    train with; ``mdgs train`` uses it when ``--lr`` is not given). Instance attribute ``history``:
    past frames the model needs besides the current one (0 for one-frame models).
    """

    name: ClassVar[str] = ""
    Config: ClassVar[type] = object
    learned: ClassVar[bool] = True
    summary: ClassVar[str] = ""
    default_lr: ClassVar[float] = 1e-3
    #: Whether the step is torch code that :func:`compile_step` can compile (false: MuJoCo, whose step
    #: is its C engine).
    compilable: ClassVar[bool] = True
    #: Registry name of a model that trains to the very same weights as this one (the two differ only
    #: at rollout, e.g. ``sgnn-snap`` -> ``sgnn``): a study trains that run once and evaluates both
    #: (:meth:`from_trained`). ``None``: this model trains its own run.
    trains_as: ClassVar[str | None] = None
    #: Bumped when a change of this model's defaults or code changes its results: study cells are
    #: keyed by it (:meth:`mdgs.study.runner.Cell.spec`), so a study reruns the cells the change
    #: makes stale instead of mixing results of two versions of the model.
    revision: ClassVar[int] = 0

    @property
    def scalar_loops(self) -> bool:
        """Whether :func:`compile_step` writes this model's compiled step with scalar loops for the CPU (``LOOPS``).
        True where the step runs the rigid tree's forward dynamics (:func:`mdgs.tree.tree_step`,
        :func:`mdgs.actuation.coupled_motor_accelerations`): thousands of operations on 3-vectors, rotations and
        systems of the tree's size, loops shorter than one vector of 16 lanes, each of which pays for its masked
        remainder when vectorised; and for constant twist's step, the same kind of loops over a few bodies. A
        network's loops span its hidden width and keep their vectors
        (``benchmarks/compiled_dynamics.py --loops vector scalar`` measures both). False unless a model says
        otherwise."""
        return False

    def __init__(self, config: Any):
        super().__init__()
        self.config = config
        self.history = 0
        self.future = 0  # frames after t + 1 a training pass needs (multi-step training)
        self._split: SplitData | None = None
        self._binds = 0
        # follows .to(device) so that models without parameters know their device too
        self.register_buffer("_device_probe", torch.zeros(0), persistent=False)

    # --- construction -------------------------------------------------------------------
    @classmethod
    def resolve_config(cls, config: Any, train: SplitData) -> Any:
        """Fill the settings a model takes from the training data (scales, sizes); default: unchanged."""
        return config

    @classmethod
    def from_data(cls, train: SplitData, config: Any | None = None) -> Simulator:
        """Build the model for the scene of ``train`` and fit its normalisation on that split only."""
        cfg = cls.resolve_config(config if config is not None else cls.Config(), train)
        model = cls(cfg)
        model.bind(train)
        model.fit(train)
        return model

    @classmethod
    def from_trained(cls, twin: Simulator) -> Simulator:
        """This model with the weights and settings of a trained ``trains_as`` model ``twin`` (same device,
        eval mode); only the settings in which this model's ``Config`` defaults differ from the twin's
        (its rollout settings) take this model's defaults."""
        if cls.trains_as is None or twin.name != cls.trains_as:
            raise ModelError(f"model {cls.name!r} does not share the training of {twin.name!r}")
        mine, theirs = cls.Config(), type(twin.config)()
        own = {f.name: getattr(mine, f.name) for f in fields(mine)
               if getattr(mine, f.name) != getattr(theirs, f.name, None)}
        cfg = cls.Config(**{**asdict(twin.config), **own})
        model = cls(cfg).to(twin.device)
        model.load_state_dict(twin.state_dict())
        if twin._split is not None:
            model.bind(twin._split)
        return model.eval()

    def fit(self, train: SplitData) -> None:
        """Fit normalisation statistics on the training split (default: nothing)."""

    def bind(self, split: SplitData) -> None:
        """Simulate the scene of ``split`` (its static graph and control map) from now on."""
        self._split = split
        self._binds += 1  # compile_step warms a compiled step once per binding

    def config_dict(self) -> dict:
        """The resolved configuration, JSON-ready."""
        return asdict(self.config)

    def with_config(self, **changes) -> Any:
        return replace(self.config, **changes)

    # --- simulation ---------------------------------------------------------------------
    def initial_state(self, split: SplitData, traj: np.ndarray, frame: int) -> State:
        """The state of trajectories ``traj`` [B] at ``frame`` (frames ``frame - history .. frame`` are read)."""
        dev = self.device
        return State(torch.from_numpy(split.x[traj, frame]).to(dev), torch.from_numpy(split.v[traj, frame]).to(dev))

    def step(self, state: State, ctrl: torch.Tensor) -> State:
        """One frame forward: ``state`` at t and controls ``ctrl`` [B, nu] held over t -> t+1 -> state at t+1."""
        raise NotImplementedError

    # --- training -----------------------------------------------------------------------
    def losses(self, batch: Batch) -> dict[str, torch.Tensor]:
        """Named loss terms of one batch (scalars)."""
        raise NotImplementedError(f"model {self.name!r} has nothing to train")

    def loss_weights(self) -> dict[str, float]:
        """Weight of each named loss in the total the trainer minimises."""
        return {"mse": 1.0}

    def validation_error(self, batch: Batch) -> torch.Tensor:
        """One-step error on a clean batch, for model selection and the LR schedule (default: ``losses()['mse']``)."""
        return self.losses(batch)["mse"]

    def perturb(self, batch: Batch, gen: torch.Generator) -> Batch:
        """The model's training-noise recipe applied to a batch (default: none)."""
        return batch

    def optimizer(self, lr: float):
        """``(optimizer, scheduler, when)``: Adam (lr, betas 0.9/0.999) and ReduceLROnPlateau (patience 3,
        factor 0.8) stepped on the validation error once per epoch (``when = "epoch"``)."""
        opt = torch.optim.Adam(self.parameters(), lr=lr, betas=(0.9, 0.999))
        return opt, torch.optim.lr_scheduler.ReduceLROnPlateau(opt, patience=3, factor=0.8), "epoch"

    @property
    def device(self) -> torch.device:
        return self._device_probe.device

    def parameter_count(self) -> int:
        return sum(p.numel() for p in self.parameters())


#: What :func:`compile_step` can compile a step with ("cudagraphs": CUDA devices only).
COMPILE_MODES = ("inductor", "aot", "cudagraphs")

#: Kabsch fits a single trajectory's ahead-of-time step may make by Jacobi rotations (each lengthens the compile
#: by tens of seconds for a few percent of a step, :func:`_aot_step`); a step with more keeps the SVD.
JACOBI_MAX_FITS = 1

#: How :func:`compile_step` writes a compiled step's loops for the CPU: "vector" (inductor's default: the
#: instruction set's widest vectors, 16 float lanes with AVX-512) or "scalar" (a vector width, ``cpp.simdlen``,
#: of one bit, which no instruction set has, so inductor writes scalar loops).
LOOPS = ("vector", "scalar")

#: Whether an ahead-of-time step of fused loops alone (no library call) is compiled again with its intermediate
#: buffers on the stack (:func:`_stack_allocation`); False keeps every package's buffers on the heap, for a
#: side-by-side measurement (benchmarks/compiled_dynamics.py ``--stack``).
AOT_STACK_ALLOCATION = True


@torch.no_grad()
def compile_step(model: Simulator, mode: str = "inductor", loops: str | None = None) -> Simulator:
    """Give ``model`` a compiled rollout step (in place; returns the model).

    ``mode="inductor"`` (``torch.compile``): ``model.step`` becomes one compiled graph per batch
    shape (``dynamic=False``): the first step of each new batch size compiles (seconds to tens of
    seconds on a CPU), later steps run the fused kernels. The results are the eager step's up to float
    round-off (bit-identical for MDGS and constant twist, 1e-6 m apart for GNS over a rollout:
    benchmarks/bench_models.py ``--compile`` compares the two rollouts; a step of LGNS or HGNS, which differentiate
    inside the step with ``torch.func``, measured to 3e-9 of the largest state, tests/test_model_lgns.py). Where
    dynamo cannot trace (a graph break: MuJoCo's C code, the energy peers' contact edges in a scene too large for
    their masked candidate pairs) the code runs eagerly. Binding the model again (as :func:`~mdgs.evaluate.rollout.rollout` and
    :func:`~mdgs.evaluate.cost.step_cost` do) reuses the compiled graphs (tests/test_references.py).

    ``mode="aot"`` (AOTInductor): the step of each scene and batch shape is exported
    (``torch.export``), compiled ahead of time into a package in a temporary folder and called
    directly, with no dynamo guard check per step: the fastest single-trajectory step (MDGS on the
    Cubli, width 50: 0.24 against 0.41 ms per frame for ``inductor``, benchmarks/bench_models.py
    ``--compile aot``). Inference only (no gradient); the weights and the bound scene are compiled
    in: a package is reused for the same scene (by its static arrays) and batch shape, a new scene
    compiles its own, and weights changed after compiling are not seen (compile after training). A step that does not export
    raises :class:`ModelError` naming ``inductor``. The package computes what the eager step computes, in
    another order: products of weights alone are folded into constants when it loads
    (:func:`~mdgs.models.layers.folded_weights`), and a single trajectory's step with one Kabsch fit
    (:data:`JACOBI_MAX_FITS`) uses Jacobi rotations instead of the SVD (:func:`mdgs.structure.rotation_fit`),
    so rollouts differ from the eager
    ones by float32 round-off and what a rollout makes of it (MDGS on the tiny Cubli, every test
    trajectory: 0-4.3e-6 m in three runs, benchmarks/bench_models.py ``--compile aot``). A step whose package calls
    no library kernel (constant twist's) is compiled a second time with its intermediate buffers on the stack
    (:func:`_stack_allocation`): its step for one trajectory then costs half as much.

    ``mode="cudagraphs"`` (CUDA only; ``torch.compile`` with ``mode="reduce-overhead"``): inductor's
    kernels recorded once per batch shape into a CUDA graph and replayed, so a step costs one graph
    launch instead of one launch per kernel, which is what a small scene's step costs on a GPU. The
    replay writes into the same output buffers every step, so the step returns copies. A model on
    the CPU raises :class:`ModelError`, and so does the first step of a model whose step cannot be
    captured (one that copies between host and device inside). The step is traced inside
    :func:`mdgs.structure.rotation_fit` ("horn"), so its Kabsch fits use Horn's quaternion method instead of
    the SVD, whose error check reads a result on the host: with the SVD the MDGS step failed to
    capture on an H100 (``docs/results.md``, "On a GPU"); with Horn's method it captures as one graph
    (0.47 ms a single-trajectory step on an H100, one replay, tests/test_cuda.py). A graph break inside
    the step leaves the code after it eager (one of them cost 4x on the H100: tests/test_references.py
    checks that MDGS's step traces as one graph). ``"aot"`` is refused on
    CUDA: loading the package crashed the process there (torch 2.11, CUDA 13)."""
    if not isinstance(model, Simulator):
        raise TypeError(f"compile_step takes a Simulator, not {type(model).__name__}")
    if mode not in COMPILE_MODES:
        raise ValueError(f"compile mode {mode!r} is not one of {', '.join(COMPILE_MODES)}")
    if loops not in (None, *LOOPS):
        raise ValueError(f"loops {loops!r} is not one of {', '.join(LOOPS)} (or None: the model's choice)")
    scalar = model.scalar_loops if loops is None else loops == "scalar"
    loop_options = {"cpp.simdlen": 1} if scalar and model.device.type == "cpu" else {}
    # dynamo keeps the compiled variants of a step on the code object of the model class's step, shared by
    # every instance: each compiled model adds one per batch shape, and past the limit (8 by default)
    # dynamo would silently run the step eagerly
    torch._dynamo.config.recompile_limit = max(torch._dynamo.config.recompile_limit, 64)
    if mode == "aot" and model.device.type == "cuda":
        raise ModelError(f"compile mode 'aot' is refused on {model.device}: loading an AOTInductor package of the MDGS "
                         "step crashed the process on an H100 (torch 2.11, CUDA 13; docs/results.md, "
                         "'On a GPU'); use 'inductor' there")
    if mode == "cudagraphs" and model.device.type != "cuda":
        raise ModelError(f"compile mode 'cudagraphs' replays CUDA graphs, and {model.name!r} is on {model.device}: "
                         "move it to a CUDA device (--device cuda) or use 'inductor' or 'aot'")
    eager = type(model).step.__get__(model)
    # cpp_wrapper: the compiled graph's kernels are launched from generated C++ rather than Python,
    # which is most of the per-step overhead left on a CPU (0.57 -> 0.43 ms per frame for MDGS at
    # hidden width 100, one trajectory, benchmarks/bench_models.py)
    compiled = None
    if mode == "inductor":
        compiled = torch.compile(eager, dynamic=False, options={"cpp_wrapper": True, **loop_options})
    elif mode == "cudagraphs":
        graphed = torch.compile(eager, dynamic=False, mode="reduce-overhead")

        def compiled(state: State, ctrl: torch.Tensor) -> State:
            torch.compiler.cudagraph_mark_step_begin()  # each call is a new replay: earlier outputs may be reused
            try:
                with rotation_fit("horn"):  # Kabsch without the SVD's host-side error check
                    out = graphed(state, ctrl)
            except RuntimeError as e:
                if "graph capture" not in str(e):
                    raise
                raise ModelError(f"the step of {model.name!r} cannot be captured as a CUDA graph ({str(e).splitlines()[0][:90]}: "
                                 "it synchronises with the host inside the step, e.g. torch.linalg's error checks); "
                                 "use compile mode 'inductor'") from e
            return State(out.x.clone(), out.v.clone(), {k: t.clone() for k, t in out.extra.items()})
    warm: set = set()
    packages: dict = {}
    scenes: dict = {}
    ready: dict = {}  # key -> the package an ahead-of-time step calls: one lookup a step once compiled

    def step(state: State, ctrl: torch.Tensor) -> State:
        # the first step of each binding and batch shape runs eagerly: it fills the scene's caches
        # (graph propagators, joint groups), which compiled steps then read as constants of one graph
        # instead of building them in graph breaks
        key = (model._binds, state.x.shape, state.x.dtype, state.x.device,
               tuple(sorted(state.extra)) if state.extra else ())
        run = ready.get(key)
        if run is None:
            if key not in warm:
                warm.add(key)
                return eager(state, ctrl)
            if compiled is not None:
                return compiled(state, ctrl)
            if model._binds not in scenes:  # rebinding the same scene (every rollout does) reuses its packages
                scenes[model._binds] = _scene_fingerprint(model._split)
            pkey = (scenes[model._binds], *key[1:])
            if pkey not in packages:
                packages[pkey] = _aot_step(model, eager, state, ctrl, loop_options)
            run = ready[key] = packages[pkey]
        names = key[-1]
        if not names:
            x, v = run([state.x, state.v, ctrl])
            return State(x, v)
        out = run([state.x, state.v, ctrl, *(state.extra[k] for k in names)])
        return State(out[0], out[1], dict(zip(names, out[2:], strict=True)))

    model.step = step
    return model


def _scene_fingerprint(split: SplitData | None) -> str:
    """A hash of what a bound scene compiles into a step: the split's identity and static arrays."""
    import hashlib
    import json

    if split is None:
        return ""
    h = hashlib.sha256(json.dumps(split.identity(), sort_keys=True).encode())
    for k in sorted(split.static):
        a = np.ascontiguousarray(split.static[k])
        h.update(k.encode() + str(a.dtype).encode() + str(a.shape).encode() + a.tobytes())
    return h.hexdigest()


@contextlib.contextmanager
def _scalar_isa_accepted():
    """Within this block, loading a package compiled with scalar loops (:data:`LOOPS`) does not warn that its
    instruction set (none: ``INVALID_VEC_ISA``) differs from the machine's: scalar code runs on any of them."""
    log = logging.getLogger("torch.export.pt2_archive._package")

    def keep(record: logging.LogRecord) -> bool:
        return not (isinstance(record.args, tuple) and record.args[:1] == ("AOTI_CPU_ISA",)
                    and record.args[-1:] == ("INVALID_VEC_ISA",))

    log.addFilter(keep)
    try:
        yield
    finally:
        log.removeFilter(keep)


_LIBRARY_CALL = re.compile(r"\baoti_torch_(cpu_\w+|proxy_executor_call_function|call_dispatcher)\(")


def _calls_library(package: str) -> bool:
    """Whether the C++ wrapper of the AOTInductor ``package`` calls a library kernel (a matrix product, a solve, an
    op inductor does not generate): its ``aoti_torch_cpu_*`` shims, the proxy executor or the dispatcher. True where the
    package holds no wrapper source to read."""
    import zipfile

    with zipfile.ZipFile(package) as z:
        sources = [z.read(n).decode(errors="replace") for n in z.namelist() if n.endswith(".wrapper.cpp")]
    return not sources or any(_LIBRARY_CALL.search(src) for src in sources)


@contextlib.contextmanager
def _stack_allocation():
    """Within this block, AOTInductor keeps a CPU step's intermediate buffers on the stack where it can; yields the
    inductor options that say so (:func:`_aot_step` enters it only with :data:`AOT_STACK_ALLOCATION` true).

    Inductor's option ``aot_inductor.allow_stack_allocation`` takes effect only through the wrapper class that
    inductor registers for the CPU once per process, chosen by the option's value at that moment; the block
    registers the stack-allocating wrapper for its duration and restores the registered one after it. Inductor
    keeps every buffer on the heap where a graph calls a library kernel (:func:`_calls_library`) or its buffers
    exceed 100 kB in all, so :func:`_aot_step` compiles again in this block only a package of fused loops alone:
    the constant-twist reference's (twenty allocations of a few bytes each, half of its step's cost before;
    benchmarks/compiled_dynamics.py ``--stack``). Its constants are then folded when it compiles, not when it
    loads: the stack-allocating wrapper crashed a package that folds, at load, products of weights through a
    library call (MDGS's, a segmentation fault at its first call, torch 2.13). Where this torch lays its registry
    out otherwise, the block yields no options."""
    try:
        from torch._inductor.codegen import common
        from torch._inductor.codegen.cpp_wrapper_cpu_array_ref import CppWrapperCpuArrayRef

        common.init_backend_registration()
        registered = common.device_codegens["cpu"]
        common.device_codegens["cpu"] = replace(registered, cpp_wrapper_codegen=CppWrapperCpuArrayRef)
    except (ImportError, AttributeError, KeyError, TypeError):
        yield {}
        return
    try:
        yield {"aot_inductor.allow_stack_allocation": True, "aot_inductor.use_runtime_constant_folding": False}
    finally:
        common.device_codegens["cpu"] = registered


def _aot_step(model: Simulator, eager, state: State, ctrl: torch.Tensor, loop_options: dict):
    """The eager step for ``state``'s batch shape exported and compiled by AOTInductor, loaded: a
    callable ``[x, v, ctrl, *extra] -> [x', v', *extra']`` (one list in, one out). The package lives in a temporary
    folder removed with the model."""
    import tempfile

    names = sorted(state.extra)

    class Step(nn.Module):
        def forward(self, x, v, c, *extra):
            s = eager(State(x, v, dict(zip(names, extra, strict=True))), c)
            return (s.x, s.v, *(s.extra[k] for k in names))

    if getattr(model, "_aot_dir", None) is None:
        model._aot_dir = tempfile.TemporaryDirectory(prefix="mdgs-aot-")
    folder = Path(model._aot_dir.name)
    path = str(folder / f"step-{len(list(folder.iterdir()))}.pt2")  # one package per scene and batch shape
    args = (state.x, state.v, ctrl, *(state.extra[k] for k in names))
    # folded_weights + use_runtime_constant_folding: products of weights alone (MDGS's Eqs. (5)-(6)) are
    # computed once when the package loads. A single trajectory's step with one Kabsch fit (MDGS's) fits it
    # by Jacobi (mdgs.structure.rotation_jacobi): one fused loop instead of the SVD's library call and the
    # copies around it (docs/results.md, "Speed, side by side"), at a longer compile; each further fit would
    # lengthen it as much (the rigid tree fits several times a frame), and a batch shares the SVD's call, so
    # those packages keep the SVD. max_fusion_size lets the fit's ~300 elementwise
    # operations fuse into one loop instead of several that pass ~280 buffers between them.
    options = {"aot_inductor.use_runtime_constant_folding": True, "max_fusion_size": 4096, **loop_options}
    try:
        with torch.no_grad(), folded_weights():
            program = None
            if state.x.shape[0] == 1:
                with rotation_fit("jacobi") as fits:
                    program = torch.export.export(Step(), args, strict=False)
                program = program if fits.calls <= JACOBI_MAX_FITS else None
            if program is None:
                program = torch.export.export(Step(), args, strict=False)
            torch._inductor.aoti_compile_and_package(program, package_path=path, inductor_configs=options)
            if AOT_STACK_ALLOCATION and not _calls_library(path):  # fused loops alone: again, buffers on the stack
                with _stack_allocation() as stack:
                    if stack:
                        torch._inductor.aoti_compile_and_package(program, package_path=path,
                                                                 inductor_configs={**options, **stack})
    except Exception as e:  # noqa: BLE001 - torch.export's and inductor's many failure types
        raise ModelError(f"the step of {model.name!r} does not compile ahead of time ({type(e).__name__}: "
                         f"{str(e).splitlines()[0][:120]}); use compile mode 'inductor'") from e
    with _scalar_isa_accepted():
        package = torch._inductor.aoti_load_package(path)
    # the package's own __call__ parses its input and output specs at every call (most of what a call
    # costs); the step's inputs and outputs are flat tuples of tensors, so the loader is called
    # with the flat list directly and its flat list of outputs is the step's tuple
    run = package.loader.boxed_run
    first, direct = package(*args), run(list(args))
    if not (isinstance(first, tuple) and len(first) == len(direct)
            and all(torch.equal(a, b) for a, b in zip(first, direct, strict=True))):
        return lambda a: list(package(*a))
    return run


def one_step_error(model: Simulator, d: SplitData, dev, batch_size: int = 64, max_pairs: int = 0) -> float:
    """Mean :meth:`~mdgs.models.base.Simulator.validation_error` over the pairs of a split (clean inputs)."""
    model.eval()
    model.bind(d)
    pairs = d.pairs(model.history)
    if max_pairs and len(pairs) > max_pairs:
        pairs = pairs[np.linspace(0, len(pairs) - 1, max_pairs).astype(int)]
    err = 0.0
    for s in range(0, len(pairs), batch_size):
        b = batch_of(d, pairs[s:s + batch_size], dev, model.history)
        err += model.validation_error(b).item() * len(b)
    return err / len(pairs)
