"""How the control kernels run: numba's JIT, or the module compiled ahead of time from them.

Every kernel of this package is a Python function decorated with `njit` (and `prange`,
`vectorize`) from here, so the math is written once.  Two ways to run it, chosen once per
process by the environment variable SWARM_KERNELS before the first control module is imported:

    jit   (default) numba compiles the kernels on first use and caches them on disk; the batch
          simulator and the world take this way (`prange` over large batches, and the world's
          own numba kernels call the control kernels).
    aot   a robot process: the kernels come from an extension module that
          `robot_firmware.control.aot` compiled ahead of time (numba.pycc) from the same
          functions, so the process never imports numba or llvmlite (about 150 MiB less).
          A function the module does not export runs as plain Python (numpy), correct but slow:
          only the functions a robot calls in its tick are exported.

The module is named after a hash of this package's sources (every .py file here) and the
versions of Python, NumPy and numba (`source_hash`), so an edited kernel is never run from an
old build: with no module for the current hash, `aot` falls back to the JIT with a one-line
note on stderr (rebuild with `python -m robot_firmware.control.aot`; scripts/ensure-env.sh and
the Dockerfile do).  The compiled functions check no types themselves (a wrong dtype would read
past an array), so every call goes through `AotKernel`, which compares each argument with the
signature the module was built for and runs the Python function when one differs.

The JIT's disk cache is named the same way (`use_jit_cache`): one directory per state of the
sources of every compiled kernel (this package, world/, services/sim/, swarm_config/), since
numba would otherwise load a cached kernel of world/ or services/sim/ with the control kernels
it calls as they were when it was compiled.  The world package imports this module first, so
its kernels are cached there too.
"""

from __future__ import annotations

import hashlib
import importlib.machinery
import importlib.metadata
import importlib.util
import json
import os
import platform
import shutil
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

KERNELS_ENV = "SWARM_KERNELS"
AOT_DIR_ENV = "SWARM_AOT_DIR"
"""Where the ahead-of-time module lives (default: this package's __pycache__)."""
MODES = ("jit", "aot")
PACKAGE_DIR = Path(__file__).resolve().parent
MODULE_PREFIX = "control_kernels_"
JIT_CACHE_PREFIX = "numba-"
COMPILED_SOURCE_DIRS = (
    PACKAGE_DIR,
    PACKAGE_DIR.parents[1] / "world",
    PACKAGE_DIR.parents[1] / "services" / "sim",
    PACKAGE_DIR.parents[1] / "swarm_config",
)
"""Where the JIT's kernels and the compiled code that calls them are written: these kernels,
the world's and the batch simulator's (which call them), and the configuration they read."""

ArgSpec = Any
"""What `AotKernel` checks an argument against (JSON): ["a", dtype, ndim] for a C-contiguous
array, ["t", [specs]] for a tuple, ["f"], ["i"], ["b"] for a float, int or bool."""


def source_hash(directories: Sequence[Path] | None = None) -> str:
    """Hash of the sources (every .py file of `directories`, this package by default) and the
    tool versions."""
    digest = hashlib.sha256()
    for directory in (PACKAGE_DIR,) if directories is None else directories:
        for path in sorted(directory.glob("*.py")):
            digest.update(f"{directory.name}/{path.name}".encode())
            digest.update(path.read_bytes())
    for name in ("numpy", "numba", "llvmlite"):
        digest.update(f"{name}={_version(name)}".encode())
    digest.update(f"{sys.version}|{platform.machine()}".encode())
    return digest.hexdigest()[:20]


def _version(distribution: str) -> str:
    try:
        return importlib.metadata.version(distribution)
    except importlib.metadata.PackageNotFoundError:
        return "none"


def aot_dir() -> Path:
    return Path(os.environ.get(AOT_DIR_ENV) or PACKAGE_DIR / "__pycache__")


def module_name(hash_: str) -> str:
    return MODULE_PREFIX + hash_


def module_paths(hash_: str, directory: Path | None = None) -> tuple[Path, Path]:
    """(extension module, JSON of its exports) for a source hash."""
    directory = aot_dir() if directory is None else directory
    suffix = importlib.machinery.EXTENSION_SUFFIXES[0]
    name = module_name(hash_)
    return directory / f"{name}{suffix}", directory / f"{name}.json"


class AotKernel:
    """A function of the ahead-of-time module, called only with the types it was built for.

    Every call's arguments are checked against the built types (`type_check`): a wrong dtype
    would read past an array.  The firmware passes the same tuples of the same arrays every
    tick (robot_firmware/control/controller.py `OneRobotControl`), so a call whose tuples and
    arrays are the very objects of one already checked has only its scalars checked: those
    objects are kept (so their ids stay theirs), and nothing here changes an array's dtype,
    dimensions or strides in place.  At most `TRUSTED_CALLS` such sets are kept."""

    TRUSTED_CALLS = 4

    def __init__(
        self, compiled: Callable[..., Any], spec: list[ArgSpec], py_func: Callable[..., Any]
    ) -> None:
        self.compiled = compiled
        self.spec = spec
        self.py_func = py_func
        self.matches = type_check(spec)
        self._objects = [i for i, item in enumerate(spec) if item[0] in ("a", "t")]
        scalars = [i for i, item in enumerate(spec) if item[0] not in ("a", "t")]
        self._scalars_match = type_check([spec[i] for i in scalars])
        self._scalar_positions = scalars
        self._trusted: dict[tuple[int, ...], tuple[Any, ...]] = {}
        self.__doc__ = py_func.__doc__
        self.__name__ = py_func.__name__
        self.mismatches = 0
        """Calls that ran the Python function because an argument's type differed."""

    def __call__(self, *args: Any) -> Any:
        if len(args) == len(self.spec):
            key = tuple([id(args[i]) for i in self._objects])
            if key in self._trusted and self._scalars_match(
                *[args[i] for i in self._scalar_positions]
            ):
                return self.compiled(*args)
            if self.matches(*args):
                if len(self._trusted) >= self.TRUSTED_CALLS:
                    self._trusted.pop(next(iter(self._trusted)))
                self._trusted[key] = tuple(args[i] for i in self._objects)
                return self.compiled(*args)
        self.mismatches += 1
        return self.py_func(*args)


def type_check(spec: list[ArgSpec]) -> Callable[..., bool]:
    """A function of the arguments that is True when they have exactly the types of `spec`.

    Written out as one expression (no loop, no recursion: it runs on every tick); an array is
    checked for its dtype, its dimensions and C order, a tuple for its length and items."""
    dtypes: dict[str, np.dtype[Any]] = {}
    terms: list[str] = []

    def check(value: str, item: ArgSpec) -> None:
        kind = item[0]
        if kind == "a":
            dtypes.setdefault(item[1], np.dtype(item[1]))
            name = f"_d{list(dtypes).index(item[1])}"
            terms.append(
                f"type({value}) is _ndarray and {value}.dtype == {name} and "
                f"{value}.ndim == {item[2]} and {value}.flags.c_contiguous"
            )
        elif kind == "t":
            terms.append(f"isinstance({value}, tuple) and len({value}) == {len(item[1])}")
            for index, inner in enumerate(item[1]):
                check(f"{value}[{index}]", inner)
        elif kind == "b":
            terms.append(f"isinstance({value}, _bools)")
        elif kind == "i":
            terms.append(f"isinstance({value}, _ints) and not isinstance({value}, bool)")
        else:
            terms.append(f"isinstance({value}, _numbers)")

    names = [f"a{i}" for i in range(len(spec))]
    for name, item in zip(names, spec, strict=True):
        check(name, item)
    body = " and ".join(f"({t})" for t in terms) or "True"
    source = f"def matches(*args):\n    if len(args) != {len(spec)}:\n        return False\n"
    if names:
        source += f"    {', '.join(names)}, = args\n"
    source += f"    return bool({body})\n"
    scope: dict[str, Any] = {
        "_ndarray": np.ndarray,
        "_bools": (bool, np.bool_),
        "_ints": (int, np.integer),
        "_numbers": (float, int, np.floating, np.integer),
        **{f"_d{i}": dtype for i, dtype in enumerate(dtypes.values())},
    }
    exec(source, scope)  # the source is made here, from the build's own type list
    matches: Callable[..., bool] = scope["matches"]
    return matches


def _load_aot(hash_: str) -> tuple[Any, dict[str, Any]] | None:
    """The ahead-of-time module for `hash_` and its exports, or None when it is not there."""
    module_path, exports_path = module_paths(hash_)
    if not module_path.is_file() or not exports_path.is_file():
        return None
    exports = json.loads(exports_path.read_text())
    if exports.get("source_hash") != hash_:
        return None
    spec = importlib.util.spec_from_file_location(module_name(hash_), module_path)
    if spec is None or spec.loader is None:
        return None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module, exports["functions"]


def _choose_mode() -> tuple[str, Any, dict[str, Any]]:
    wanted = os.environ.get(KERNELS_ENV, "jit") or "jit"
    if wanted not in MODES:
        sys.stderr.write(f"{KERNELS_ENV}={wanted!r} is not one of {MODES}; using jit\n")
        return "jit", None, {}
    if wanted == "jit":
        return "jit", None, {}
    hash_ = source_hash()
    loaded = _load_aot(hash_)
    if loaded is None:
        sys.stderr.write(
            f"control kernels: no ahead-of-time module for these sources ({hash_}) in "
            f"{aot_dir()}; using numba's JIT (build: python -m robot_firmware.control.aot)\n"
        )
        return "jit", None, {}
    module, functions = loaded
    return "aot", module, functions


MODE, _AOT_MODULE, _AOT_FUNCTIONS = _choose_mode()
"""The way this process runs the kernels ("aot" only when the module was found)."""

JIT_KERNELS: list[tuple[str, bool, Any]] = []
"""(module.qualname, parallel, dispatcher) of every kernel decorated here in jit mode."""


def kernel_key(function: Callable[..., Any]) -> str:
    return f"{function.__module__}.{function.__qualname__}"


def use_jit_cache(
    source_dirs: Sequence[Path] = COMPILED_SOURCE_DIRS, root: Path | None = None
) -> Path | None:
    """Have numba cache the kernels decorated from now on in a directory of their own for
    this state of `source_dirs` (`root`/numba-<source_hash>; `root` is $NUMBA_CACHE_DIR, else
    this package's __pycache__), and remove the directories of other states.  Returns the
    directory, or None (numba's own places are left in use) where it cannot be made.

    numba keys a cached function by its own source file only: a kernel whose callee in another
    file changed would load its old machine code, callee and all.  With a directory per state
    of every file that holds kernels, an edit anywhere compiles them all again (once)."""
    import numba

    if root is None:
        root = Path(os.environ.get("NUMBA_CACHE_DIR") or PACKAGE_DIR / "__pycache__")
    directory = root / f"{JIT_CACHE_PREFIX}{source_hash(source_dirs)}"
    try:
        directory.mkdir(parents=True, exist_ok=True)
    except OSError:
        return None
    for other in root.glob(JIT_CACHE_PREFIX + "*"):
        if other != directory and other.is_dir():
            # A process still running on those sources finds its files gone and compiles.
            shutil.rmtree(other, ignore_errors=True)
    numba.config.CACHE_DIR = str(directory)  # type: ignore[attr-defined]
    return directory


if MODE == "jit":
    import numba

    JIT_CACHE_DIR = use_jit_cache()
    """Where numba caches the compiled kernels of this process (None: numba's own places)."""

    prange: Any = numba.prange
    vectorize: Any = numba.vectorize

    from numba.core.options import DefaultOptions

    NO_RUNTIME_OPTION: str | None = "_nrt" if hasattr(DefaultOptions, "_nrt") else None
    """numba's own target option that turns its memory runtime (NRT) off for one function
    (checked with numba 0.68.1); None in a numba without it."""

    def njit(*args: Any, allocates: bool = True, **options: Any) -> Any:
        """numba.njit, recording the kernel for the ahead-of-time build.

        `allocates=False` says the kernel makes no array of its own (no `np.empty`, no copy,
        no slice assigned from another array); numba then compiles it without its memory
        runtime (NRT), so every row view it takes (`pose[i]`, `counts[i]`) costs no atomic
        reference count.  A kernel so marked that does allocate fails to compile ("NRT
        required but not enabled").  Where numba has no such option, the kernel compiles
        as any other."""
        if not allocates and NO_RUNTIME_OPTION is not None:
            options = {**options, NO_RUNTIME_OPTION: False}

        def decorate(function: Callable[..., Any]) -> Any:
            dispatcher = numba.njit(**options)(function)
            JIT_KERNELS.append((kernel_key(function), bool(options.get("parallel")), dispatcher))
            return dispatcher

        if args and callable(args[0]):
            return decorate(args[0])
        return decorate

else:
    prange = range

    def njit(*args: Any, allocates: bool = True, **options: Any) -> Any:
        """The function from the ahead-of-time module (as `AotKernel`), else plain Python
        (the module is built with numba's memory runtime for every kernel: `allocates` and
        the options do not apply)."""

        def decorate(function: Callable[..., Any]) -> Any:
            export = _AOT_FUNCTIONS.get(kernel_key(function))
            if export is None:
                return function
            return AotKernel(getattr(_AOT_MODULE, export["symbol"]), export["spec"], function)

        if args and callable(args[0]):
            return decorate(args[0])
        return decorate

    def vectorize(*args: Any, **options: Any) -> Any:
        """An element-wise numpy form of a scalar function (float64 in and out)."""
        del args, options

        def decorate(function: Callable[..., Any]) -> Any:
            return np.vectorize(function, otypes=[np.float64])

        return decorate
