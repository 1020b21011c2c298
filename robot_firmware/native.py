"""The register model and the drivers compiled by mypyc from their own sources, for robots.

A robot's control period is some thousand small Python calls, most of them in the FPGA's
register model and the drivers that reach it over the bus (docs/scale.md, "Warm and cold").
mypyc, the compiler that comes with mypy (the project's type checker), turns those modules,
as they are written and type-annotated, into C extensions: no second copy of the register
model to keep in step.  Two ways to run them, chosen once per process by the environment
variable SWARM_NATIVE before the first module of `robot_firmware` is imported:

    python  (default) every module runs from its source; the tests, the world and the batch
            simulator take this way.
    mypyc   a robot process (`swarm up` sets it for the robots it starts): the modules of
            `COMPILED_MODULES` come from the extensions that
            `python -m robot_firmware.native_build` built: a fifth less of a robot's time per
            warm control period, a ninth per cold one (docs/scale.md).

The build is named after a hash of those modules' sources and of the versions of Python and
mypy (`source_hash`), so an edited module never runs from an old build: with no build for the
current hash, `mypyc` falls back to the source with a one-line note on stderr (rebuild with
`python -m robot_firmware.native_build`; scripts/ensure-env.sh does).  A compiled module checks
the annotated types of its arguments; the bus therefore takes `object` where a user's access
may be anything, and refuses it as a bus error in either way.
"""

from __future__ import annotations

import hashlib
import importlib.abc
import importlib.machinery
import importlib.metadata
import importlib.util
import json
import os
import platform
import sys
from collections.abc import Sequence
from importlib.machinery import ModuleSpec
from pathlib import Path
from types import ModuleType

NATIVE_ENV = "SWARM_NATIVE"
NATIVE_DIR_ENV = "SWARM_NATIVE_DIR"
"""Where the builds live (default: this package's __pycache__)."""
MODES = ("python", "mypyc")
PACKAGE_DIR = Path(__file__).resolve().parent
BUILD_PREFIX = "native-"
GROUP_NAME = "robot_firmware_native"
"""mypyc's shared library of the build: `<GROUP_NAME>__mypyc`, beside the modules."""
MANIFEST = "manifest.json"

COMPILED_MODULES = (
    "robot_firmware.fpga.address_map",
    "robot_firmware.fpga.registers",
    "robot_firmware.fpga.bus",
    "robot_firmware.fpga.clock",
    "robot_firmware.fpga.digital_filter",
    "robot_firmware.fpga.positioning",
    "robot_firmware.fpga.pwm",
    "robot_firmware.fpga.qep",
    "robot_firmware.fpga.sonar",
    "robot_firmware.fpga.sysid",
    "robot_firmware.fpga.watchdog",
    "robot_firmware.drivers.register_port",
    "robot_firmware.drivers.encoders",
    "robot_firmware.drivers.motors",
    "robot_firmware.drivers.positioning",
    "robot_firmware.drivers.sonar",
    "robot_firmware.drivers.watchdog",
)
"""The IP models and drivers a control period runs.  Not here: `fpga.fabric` (it defines a
pydantic model, which mypyc cannot build), `fpga.faults` and `drivers.system` (once per run or
per fault), and `fpga.regdoc`."""


def source_path(module: str) -> Path:
    """The source file of one of `COMPILED_MODULES`."""
    return PACKAGE_DIR.parent.joinpath(*module.split(".")).with_suffix(".py")


def source_hash() -> str:
    """Hash of the compiled modules' sources and of the Python and mypy versions."""
    digest = hashlib.sha256()
    for module in COMPILED_MODULES:
        digest.update(module.encode())
        digest.update(source_path(module).read_bytes())
    digest.update(f"mypy={_version('mypy')}|{sys.version}|{platform.machine()}".encode())
    return digest.hexdigest()[:20]


def _version(distribution: str) -> str:
    try:
        return importlib.metadata.version(distribution)
    except importlib.metadata.PackageNotFoundError:
        return "none"


def native_dir() -> Path:
    return Path(os.environ.get(NATIVE_DIR_ENV) or PACKAGE_DIR / "__pycache__")


def build_dir(hash_: str, directory: Path | None = None) -> Path:
    return (native_dir() if directory is None else directory) / f"{BUILD_PREFIX}{hash_}"


def load_manifest(hash_: str, directory: Path | None = None) -> dict[str, str] | None:
    """Module name -> extension file of the build for `hash_`, or None when it is not there
    (or incomplete)."""
    where = build_dir(hash_, directory)
    try:
        manifest = json.loads((where / MANIFEST).read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(manifest, dict) or manifest.get("source_hash") != hash_:
        return None
    files = manifest.get("modules")
    if not isinstance(files, dict) or not set(COMPILED_MODULES) <= set(files):
        return None
    paths = {str(name): str(where / str(file)) for name, file in files.items()}
    if not all(Path(path).is_file() for path in paths.values()):
        return None
    return paths


class CompiledModuleFinder(importlib.abc.MetaPathFinder):
    """Finds the modules of one build (and its shared library) before the source finder."""

    def __init__(self, paths: dict[str, str]) -> None:
        self.paths = paths

    def find_spec(
        self,
        fullname: str,
        path: Sequence[str] | None = None,
        target: ModuleType | None = None,
    ) -> ModuleSpec | None:
        del path, target
        file = self.paths.get(fullname)
        if file is None:
            return None
        loader = importlib.machinery.ExtensionFileLoader(fullname, file)
        return importlib.util.spec_from_file_location(fullname, file, loader=loader)


def _choose_mode() -> str:
    wanted = os.environ.get(NATIVE_ENV, "python") or "python"
    if wanted not in MODES:
        sys.stderr.write(f"{NATIVE_ENV}={wanted!r} is not one of {MODES}; using python\n")
        return "python"
    if wanted == "python":
        return "python"
    hash_ = source_hash()
    paths = load_manifest(hash_)
    if paths is None:
        sys.stderr.write(
            f"register model: no mypyc build for these sources ({hash_}) in {native_dir()}; "
            "running them from source (build: python -m robot_firmware.native_build)\n"
        )
        return "python"
    early = [name for name in COMPILED_MODULES if name in sys.modules]
    if early:
        sys.stderr.write(f"register model: {early[0]} was imported first; running from source\n")
        return "python"
    sys.meta_path.insert(0, CompiledModuleFinder(paths))
    return "mypyc"


MODE = _choose_mode()
"""The way this process runs the register model and drivers ("mypyc" only when the build for
these sources was found)."""
