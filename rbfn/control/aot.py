"""The closed loop's chunk compiled ahead of time (AOTInductor) and cached on disk.

`torch.compile` pays its tracing and compilation in every process (about 10 s at best for one
SCARA period, minutes for a chunk of 25). An AOTInductor package is a shared library with the
chunk's graph: built once per configuration (minutes), then loaded in milliseconds, so a small
batch, whose eager step is per-operation overhead, runs at compiled speed from the second run on.

The cache key is a fingerprint of everything the chunk's code closes over, so a changed gain,
plant parameter, robot, integrator, chunk length, input shape, dtype, device, torch version or
source file of `rbfn.control` / `rbfn.robots` gives a new package, never a stale one. Packages are
written atomically; the directory is $ACO_RBFN_CACHE/aot, default ~/.cache/aco-rbfn/aot.
"""

from __future__ import annotations

import collections
import contextlib
import dataclasses
import enum
import functools
import hashlib
import logging
import os
import shutil
import tempfile
import warnings
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import torch

# torch (2.13) has no public pytree module: torch.export.pytree is this same module under another
# name, not a documented API. The package's call spec is serialised in this module's format.
import torch.utils._pytree as pytree

__all__ = [
    "ahead_of_time",
    "cache_dir",
    "fingerprint",
    "chunk_key",
    "aot_chunk",
    "Package",
    "serializable",
    "map_tensors",
    "rebuilder",
]

_SOURCES = ("control", "robots")  # packages whose code the chunk runs


ENV = "ACO_RBFN_AOT"  # what `auto` means: 1 compiled ahead of time, 0 eager; unset: by device

# A package of one environment keeps its temporaries in arrays on the C++ stack, not on the heap:
# at B = 1 the UR5's period made 394 heap allocations, which took most of its time (4.3x faster
# so; bench.realistic_loop, docs/benchmarks.md). AOTInductor does so only where every temporary
# has a static shape, their total is under its cap (100 kB: the UR5's period holds 65 kB at
# B = 1) and the graph calls no op outside the generated code (the chain's running sums are
# written as additions when compiled for this: rbfn.robots.arm_terms). With more environments the
# option is off: over the cap it would fall back to the heap, and such a package (UR5, B = 64)
# crashed at its first call in torch 2.13.
STACK_ENVS = 1


def _wrappers() -> tuple[Any, type] | None:
    """Inductor's table of code generators by device and its stack-allocating CPU wrapper
    generator, or None where this torch lacks them."""
    try:
        from torch._inductor.codegen import common
        from torch._inductor.codegen.cpp_wrapper_cpu_array_ref import CppWrapperCpuArrayRef
    except ImportError:
        return None
    if not hasattr(common, "device_codegens") or not hasattr(common, "init_backend_registration"):
        return None
    return common, CppWrapperCpuArrayRef


@contextlib.contextmanager
def _cpu_wrapper(stack: bool) -> Iterator[dict]:
    """Inductor's options for a build, temporaries on the stack or not, with the CPU wrapper
    generator they need registered for its duration. Inductor registers that generator once per
    process, by the stack option's value at the first build (torch 2.13): unchosen, a package of
    many environments built after one of one environment took the stack's generator, and crashed.
    Registered first here, outside any build's options, the generator otherwise is the heap's.
    Where this torch lacks these internals, the option stays off."""
    found = _wrappers() if stack else None
    if found is None:
        yield {}
        return
    common, on_stack = found
    common.init_backend_registration()
    before = common.device_codegens["cpu"]
    common.device_codegens["cpu"] = dataclasses.replace(before, cpp_wrapper_codegen=on_stack)
    try:
        yield {"aot_inductor.allow_stack_allocation": True}
    finally:
        common.device_codegens["cpu"] = before


def ahead_of_time(setting: Any, device: torch.device | str, compile: bool = False) -> bool:
    """Whether a loop configured with `control.aot` / `online.aot` = `setting` (auto, true or false;
    a bool reads as true or false) runs compiled ahead of time on `device`; `compile`: the loop is
    torch.compile'd instead (`control.compile`), which auto leaves alone.

    auto: compiled on a CPU, where a small batch's eager step is mostly per-operation overhead
    that the package removes, if the C++ compiler AOTInductor calls (g++) is on the PATH; eager
    on CUDA, whose kernels cost more than the Python around them and whose packages this project
    does not test. $ACO_RBFN_AOT (0 or 1) overrides auto: the test suite sets 0, so that only the
    tests of compilation build packages."""
    s = str(setting).lower()
    if s != "auto":
        return s == "true"
    if compile:
        return False
    env = os.environ.get(ENV, "").strip().lower()
    if env:
        if env not in ("0", "1", "false", "true"):
            raise ValueError(f"${ENV} is {env!r}: choose 0 or 1 (unset: compiled on a CPU, eager on CUDA)")
        return env in ("1", "true")
    return torch.device(device).type == "cpu" and shutil.which("g++") is not None


def cache_dir() -> Path:
    """Where compiled chunks are kept: $ACO_RBFN_CACHE/aot, default ~/.cache/aco-rbfn/aot."""
    root = os.environ.get("ACO_RBFN_CACHE") or Path.home() / ".cache" / "aco-rbfn"
    return Path(root) / "aot"


def fingerprint(*objs, skip: tuple[str, ...] = ()) -> str:
    """A hex digest of objects' values and this code: tensors by dtype, shape and bytes;
    dataclasses, plain objects (their public attributes but those named in `skip`), containers
    and scalars recursively; then the source files of rbfn.control and rbfn.robots and torch's
    version."""
    h = hashlib.sha256()
    seen: set[int] = set()

    def put(x) -> None:
        if isinstance(x, torch.Tensor):
            t = x.detach().cpu().contiguous()
            h.update(f"T{t.dtype}{tuple(t.shape)}{x.device.type}".encode())
            h.update(t.view(torch.uint8).numpy().tobytes() if t.numel() else b"")
        elif x is None or isinstance(
            x, (bool, int, float, str, bytes, slice, range, enum.Enum, torch.dtype, torch.device)
        ):
            h.update(f"{type(x).__name__}:{x!r};".encode())
        elif isinstance(x, (list, tuple)):
            h.update(f"{type(x).__name__}[{len(x)}".encode())
            for v in x:
                put(v)
            h.update(b"]")
        elif isinstance(x, dict):
            h.update(b"{")
            for k in sorted(x, key=repr):
                put(k)
                put(x[k])
            h.update(b"}")
        elif id(x) in seen:
            h.update(b"<seen>")
        else:
            seen.add(id(x))
            h.update(f"<{type(x).__module__}.{type(x).__qualname__}>".encode())
            if dataclasses.is_dataclass(x):
                fields = {f.name: getattr(x, f.name) for f in dataclasses.fields(x)}
            elif not hasattr(x, "__dict__"):
                raise TypeError(f"cannot fingerprint a {type(x).__qualname__} (no attributes to read)")
            else:
                # Private attributes are caches (keyed by id, say), not values.
                fields = {k: v for k, v in vars(x).items() if not k.startswith("_") and k not in skip}
            put(fields)

    for o in objs:
        put(o)
    h.update(_code_digest())
    return h.hexdigest()[:32]


@functools.cache
def _code_digest() -> bytes:
    """The digest of rbfn.control's and rbfn.robots's source files and torch's version, read once
    per process: a file edited while a run goes on keys neither its later packages nor a next run's
    wrongly (the next run reads the edit)."""
    h = hashlib.sha256()
    root = Path(__file__).resolve().parents[1]
    for pkg in _SOURCES:
        for f in sorted((root / pkg).glob("*.py")):
            h.update(f.name.encode() + f.read_bytes())
    h.update(torch.__version__.encode())
    return h.digest()


def serializable(*types: type) -> None:
    """Let a package's call spec hold these NamedTuples: pytree serialises a namedtuple's spec
    only under a registered name (here its module and qualified name)."""
    for cls in types:
        if cls not in pytree.SUPPORTED_NODES:
            pytree._register_namedtuple(cls, serialized_type_name=f"{cls.__module__}.{cls.__qualname__}")


def chunk_key(plant, controller, dt: float, integrator: str, chunk: int, example: tuple) -> str:
    """The cache key of a `make_chunk` function: its plant, controller (not its features or
    initial weights, which are inputs), time step, integrator, length, and the example
    arguments' (loop, periods) structure, shapes, dtypes and devices (not their values)."""
    leaves, spec = pytree.tree_flatten(example)
    shapes = [(tuple(t.shape), t.dtype, t.device) if isinstance(t, torch.Tensor) else t for t in leaves]
    return fingerprint(plant, controller, dt, integrator, chunk, shapes, str(spec), skip=("features", "w0"))


class _Chunk(torch.nn.Module):
    def __init__(self, run: Callable) -> None:
        super().__init__()
        self.run = run

    def forward(self, loop, periods):
        return self.run(loop, periods)


def aot_chunk(run: Callable, key: str, example: tuple, envs: int, log: Callable[[str], None] | None = None) -> Callable:
    """`run` (a `make_chunk` function) as the AOTInductor package cached under `key`, built from
    the `example` arguments (loop, periods) of `envs` environments on a miss (minutes); returns a
    function with run's signature."""
    path = cache_dir() / f"chunk-{key}.pt2"
    if not path.is_file():
        with warnings.catch_warnings():
            # torch's own deprecation notices, raised inside its export and lowering (its pytree's
            # when it pickles the program's input spec, and `torch._prims_common.check`'s).
            warnings.filterwarnings("ignore", message=r".*isinstance\(treespec, LeafSpec\).*", category=FutureWarning)
            warnings.filterwarnings("ignore", message=r".*_prims_common\.check.*deprecated", category=FutureWarning)
            _build(run, path, example, envs <= STACK_ENVS, log)
    return _load(path)


def _build(run: Callable, path: Path, example: tuple, stack: bool, log: Callable[[str], None] | None) -> None:
    """Export `run` at `example` and write its AOTInductor package to `path` atomically, its
    temporaries on the stack with `stack` (`_cpu_wrapper`)."""
    if log:
        log(f"compiling the closed-loop step ahead of time into {path} (a minute or two, once per configuration)")
    path.parent.mkdir(parents=True, exist_ok=True)
    # One eager call first: the caches the step fills on first use (the dynamics' constants per
    # dtype and device) then hold real tensors, not the export trace's fake ones, which would
    # slow every later eager call or fail it.
    with torch.inference_mode():
        run(*pytree.tree_map_only(torch.Tensor, torch.clone, example))
    program = torch.export.export(_Chunk(run), example, strict=False)
    fd, tmp = tempfile.mkstemp(suffix=".pt2", dir=path.parent)
    os.close(fd)
    # The lowering warns once per call of an op without a C shim (torch.linalg.solve, the perfect-
    # knowledge controller's and phase 1's), which it then calls through its proxy executor: a
    # note for torch's developers, not for whoever runs evaluate.py.
    lowering = logging.getLogger("torch._inductor.ir")
    level = lowering.level
    lowering.setLevel(logging.ERROR)
    try:
        with _cpu_wrapper(stack) as configs:
            torch._inductor.aoti_compile_and_package(program, package_path=tmp, inductor_configs=configs)
        os.replace(tmp, path)
    finally:
        lowering.setLevel(level)
        if os.path.exists(tmp):
            os.unlink(tmp)


class Package:
    """A loaded package: called with the chunk's arguments it returns the chunk's output tree;
    `flat` takes and returns the tensors alone, in pytree's leaf order, for a caller that keeps
    them flat between chunks (`rbfn.control.simulator.run_chunks`), and `out_spec` is the
    output's structure."""

    def __init__(self, loader: Any, out_spec: pytree.TreeSpec) -> None:
        self.flat: Callable[[list[torch.Tensor]], list[torch.Tensor]] = loader.boxed_run
        self.out_spec = out_spec
        self._rebuild = rebuilder(out_spec)

    def __call__(self, *args: Any) -> Any:
        flat: list[torch.Tensor] = []
        map_tensors(flat.append, args)  # in pytree's leaf order
        return self._rebuild(iter(self.flat(flat)))


def _load(path: Path) -> Callable:
    """The package at `path` as a function of the chunk's arguments (a `Package`).

    Through torch's package loader directly where this torch has it: torch's own
    `aoti_load_package` first imports the compiler and probes the CPU's vector extensions in
    subprocesses (about 2 s) only to warn about a device mismatch, which cannot happen with a
    package built here for this device."""
    try:
        loader = torch._C._aoti.AOTIModelPackageLoader(str(path), "model", False, 1, -1)
        out_spec = pytree.treespec_loads(loader.get_call_spec()[1])
    except (AttributeError, TypeError, RuntimeError):
        return torch._inductor.aoti_load_package(str(path))
    return Package(loader, out_spec)


# A package of one short chunk runs in a few hundred microseconds: pytree's generic flatten and
# unflatten of the loop's named state cost about as much again, so the shapes the chunks use
# (tuples, NamedTuples, lists, None, tensors) are walked directly; anything else goes to pytree.


def same_kind(like: tuple, parts: Any) -> tuple:
    """`parts` as a tuple of `like`'s kind: its NamedTuple class (a payload's `load`, the loop's
    state), or a plain tuple."""
    return type(like)(*parts) if hasattr(like, "_fields") else tuple(parts)


def map_tensors(fn: Callable[..., Any], tree: Any, *others: Any) -> Any:
    """`tree` with each tensor x replaced by fn(x, *the same places of `others`), other leaves kept:
    pytree.tree_map_only(torch.Tensor, ...) without its cost on the loop's named state."""
    if isinstance(tree, torch.Tensor):
        return fn(tree, *others)
    if tree is None or isinstance(tree, (bool, int, float)):
        return tree
    if isinstance(tree, (tuple, list)):
        parts = [map_tensors(fn, v, *(o[i] for o in others)) for i, v in enumerate(tree)]
        return parts if isinstance(tree, list) else same_kind(tree, parts)
    return pytree.tree_map(lambda x, *o: fn(x, *o) if isinstance(x, torch.Tensor) else x, tree, *others)


def rebuilder(spec: pytree.TreeSpec) -> Callable[[Iterator[Any]], Any]:
    """A function of an iterator over leaves that builds `spec`'s tree from them."""
    if spec.is_leaf():
        return next
    kids = [rebuilder(c) for c in spec.children()]
    kind = spec.type
    if kind is tuple:
        return lambda it: tuple([k(it) for k in kids])
    if kind is list:
        return lambda it: [k(it) for k in kids]
    if kind is type(None):
        return lambda it: None
    if kind is collections.namedtuple:  # pytree's node of every NamedTuple: its class is the context
        cls = spec.context
        return lambda it: cls(*[k(it) for k in kids])
    n = spec.num_leaves
    return lambda it: spec.unflatten([next(it) for _ in range(n)])
