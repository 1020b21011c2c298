"""Build the register model and drivers with mypyc for robot processes (robot_firmware/native.py).

    .venv/bin/python -m robot_firmware.native_build [--dir DIR] [--check]

Compiles the modules of `native.COMPILED_MODULES` from their sources into one directory named
after `native.source_hash()`, with a manifest of the extension files; builds of other hashes
there are removed, and so are the staging folders (`.native-*`) that builds killed half-way
left more than `STALE_STAGING_S` ago.  --check only says whether the build for the current
sources is there (exit 0) or not (1).  The build needs mypy (with its mypyc) and a C compiler,
and about 35 s of CPU.
"""

from __future__ import annotations

import argparse
import importlib.machinery
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

from robot_firmware.native import (
    BUILD_PREFIX,
    COMPILED_MODULES,
    GROUP_NAME,
    MANIFEST,
    NATIVE_ENV,
    build_dir,
    load_manifest,
    native_dir,
    source_hash,
    source_path,
)

STALE_STAGING_S = 600.0
"""A staging folder untouched this long belongs to no build that is still running."""


def sweep_stale_staging(parent: Path, now_s: float | None = None) -> list[Path]:
    """Remove the staging folders in `parent` that builds killed half-way left (untouched for
    `STALE_STAGING_S`); a running build's own is younger.  Returns those removed."""
    now_s = time.time() if now_s is None else now_s
    removed = []
    for staging in parent.glob(f".{BUILD_PREFIX}*"):
        try:
            stale = staging.is_dir() and now_s - staging.stat().st_mtime > STALE_STAGING_S
        except FileNotFoundError:  # another build renamed or removed it meanwhile
            continue
        if stale:
            shutil.rmtree(staging, ignore_errors=True)
            removed.append(staging)
    return removed


def build(directory: Path | None = None) -> Path:
    """Compile `COMPILED_MODULES` with mypyc into the build directory of the current sources;
    builds of other hashes there are removed.  Returns the build's directory."""
    from mypyc.build import mypycify
    from setuptools import Distribution

    hash_ = source_hash()
    target = build_dir(hash_, directory)
    parent = target.parent
    parent.mkdir(parents=True, exist_ok=True)
    sweep_stale_staging(parent)
    with tempfile.TemporaryDirectory(prefix="native-build-") as scratch_name:
        scratch = Path(scratch_name)
        extensions = mypycify(
            [str(source_path(module)) for module in COMPILED_MODULES],
            opt_level="3",
            target_dir=str(scratch / "c"),
            group_name=GROUP_NAME,
        )
        distribution = Distribution({"name": GROUP_NAME, "ext_modules": extensions})
        command = distribution.get_command_obj("build_ext")
        command.build_lib = str(scratch / "lib")
        command.build_temp = str(scratch / "tmp")
        distribution.run_command("build_ext")
        staging = Path(tempfile.mkdtemp(prefix=f".{BUILD_PREFIX}", dir=parent))
        modules: dict[str, str] = {}
        suffix = importlib.machinery.EXTENSION_SUFFIXES[0]
        for built in (scratch / "lib").rglob(f"*{suffix}"):
            relative = built.relative_to(scratch / "lib")
            name = ".".join(relative.with_name(relative.name[: -len(suffix)]).parts)
            (staging / relative).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(built, staging / relative)  # in the package layout mypyc expects
            modules[name] = relative.as_posix()
        (staging / MANIFEST).write_text(
            json.dumps({"source_hash": hash_, "modules": modules}, indent=1, sort_keys=True)
        )
        shutil.rmtree(target, ignore_errors=True)
        staging.rename(target)
    for old in parent.glob(f"{BUILD_PREFIX}*"):
        if old != target and old.is_dir():
            shutil.rmtree(old, ignore_errors=True)
    return target


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m robot_firmware.native_build",
        description="Compile the register model and drivers with mypyc for robot processes "
        f"({NATIVE_ENV}=mypyc).",
    )
    parser.add_argument("--dir", type=Path, help=f"where builds live (default {native_dir()})")
    parser.add_argument(
        "--check", action="store_true", help="exit 0 if the build for these sources is there"
    )
    args = parser.parse_args(argv)
    hash_ = source_hash()
    if args.check:
        found = load_manifest(hash_, args.dir) is not None
        print(f"{'found' if found else 'no'} build for {hash_} in {build_dir(hash_, args.dir)}")
        return 0 if found else 1
    where = build(args.dir)
    print(f"built {len(COMPILED_MODULES)} modules into {where}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
