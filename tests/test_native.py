"""The register model and drivers compiled by mypyc (robot_firmware/native.py, native_build.py).

A robot process (SWARM_NATIVE=mypyc) loads them from the build of the current sources and
runs the same closed loop, register word for register word, as the source; a build of other
sources is never loaded.  run-tests runs the register model's, the drivers' and the messages'
tests once more with SWARM_NATIVE=mypyc, where `test_this_process_runs_the_mode_it_asked_for`
makes sure that they ran compiled.
"""

from __future__ import annotations

import json
import os
import shutil
import sys
import time
from pathlib import Path

import pytest

from robot_firmware import native
from robot_firmware.fpga import bus
from robot_firmware.native_build import STALE_STAGING_S, sweep_stale_staging
from robot_firmware.net.admin import answer
from robot_firmware.net.messages import RobotStatusReply
from tests.fuzz.processes import make_robot, robot_credentials
from tests.support.python_child import run_python


@pytest.fixture(scope="module")
def native_built() -> Path:
    """The build for the current sources (built now, in the default place, if missing)."""
    if native.load_manifest(native.source_hash()) is None:
        built = run_python(
            "from robot_firmware.native_build import main; main([])", {native.NATIVE_ENV: "python"}
        )
        assert built.returncode == 0, built.stderr.decode()[-4000:]
    assert native.load_manifest(native.source_hash()) is not None
    return native.build_dir(native.source_hash())


def test_this_process_runs_the_mode_it_asked_for() -> None:
    """Under SWARM_NATIVE=mypyc (run-tests' second pass) every compiled module is the build's
    extension; otherwise every one runs from its source."""
    if os.environ.get(native.NATIVE_ENV) == "mypyc":
        assert native.MODE == "mypyc", "no build for these sources: run scripts/ensure-env.sh"
        build = native.build_dir(native.source_hash())
        for name in native.COMPILED_MODULES:
            module = sys.modules.get(name)
            assert module is None or Path(str(module.__file__)).is_relative_to(build), name
        assert Path(str(bus.__file__)).is_relative_to(build)
    else:
        assert native.MODE == "python"
        assert str(bus.__file__).endswith("bus.py")


def test_a_robots_status_says_how_it_runs_its_register_model(
    tmp_path_factory: pytest.TempPathFactory,
) -> None:
    robot_credentials(tmp_path_factory.mktemp("credentials"))
    robot = make_robot("robot2")
    status = answer(robot.process.admin_handlers(), "status", b"")
    assert isinstance(status, RobotStatusReply)
    expected = "mypyc" if os.environ.get(native.NATIVE_ENV) == "mypyc" else "python"
    assert status.register_model == expected


def test_a_robot_process_loads_the_build_of_its_sources(native_built: Path) -> None:
    code = (
        "import robot_firmware.runtime, robot_firmware.fpga.qep as qep, "
        "robot_firmware.drivers.motors as motors; from robot_firmware import native; "
        "print(native.MODE); print(qep.__file__); print(motors.__file__)"
    )
    ran = run_python(code, {native.NATIVE_ENV: "mypyc"})
    assert ran.returncode == 0, ran.stderr.decode()
    mode, qep_file, motors_file = ran.stdout.decode().split()
    assert mode == "mypyc"
    for file in (qep_file, motors_file):
        assert Path(file).is_relative_to(native_built) and Path(file).is_file()
    assert ran.stderr.decode() == ""


def test_a_build_of_other_sources_is_never_loaded(native_built: Path, tmp_path: Path) -> None:
    """An old build (another hash) in the directory: the process runs the source and says so."""
    other = native.build_dir("0" * 20, tmp_path)
    shutil.copytree(native_built, other)
    manifest = json.loads((other / native.MANIFEST).read_text())
    manifest["source_hash"] = "0" * 20
    (other / native.MANIFEST).write_text(json.dumps(manifest))
    code = (
        "import robot_firmware.fpga.bus as bus; from robot_firmware import native; "
        "print(native.MODE, bus.__file__)"
    )
    ran = run_python(code, {native.NATIVE_ENV: "mypyc", native.NATIVE_DIR_ENV: str(tmp_path)})
    assert ran.returncode == 0, ran.stderr.decode()
    mode, bus_file = ran.stdout.decode().split()
    assert (mode, Path(bus_file).name) == ("python", "bus.py")
    note = ran.stderr.decode().strip().splitlines()
    assert len(note) == 1 and "no mypyc build for these sources" in note[0]


def test_an_incomplete_build_is_not_loaded(native_built: Path, tmp_path: Path) -> None:
    """A build that lost one of its modules (an interrupted copy) is not taken either."""
    current = native.build_dir(native.source_hash(), tmp_path)
    shutil.copytree(native_built, current)
    manifest = json.loads((current / native.MANIFEST).read_text())
    (current / manifest["modules"]["robot_firmware.fpga.qep"]).unlink()
    assert native.load_manifest(native.source_hash(), tmp_path) is None


def test_a_build_sweeps_only_the_staging_folders_of_builds_long_gone(tmp_path: Path) -> None:
    left = tmp_path / f".{native.BUILD_PREFIX}killed"
    running = tmp_path / f".{native.BUILD_PREFIX}running"
    kept = native.build_dir("0" * 20, tmp_path)
    for folder in (left, running, kept):
        (folder / "robot_firmware").mkdir(parents=True)
    now_s = time.time()
    long_ago_s = now_s - STALE_STAGING_S - 60
    for folder in (left, kept):
        os.utime(folder, (long_ago_s, long_ago_s))
    assert sweep_stale_staging(tmp_path, now_s) == [left]
    assert not left.exists() and running.is_dir() and kept.is_dir()


def test_an_unknown_mode_is_named_and_the_source_runs() -> None:
    code = "from robot_firmware import native; print(native.MODE)"
    ran = run_python(code, {native.NATIVE_ENV: "fast"})
    assert ran.returncode == 0
    assert ran.stdout.decode().split() == ["python"]
    assert "SWARM_NATIVE='fast' is not one of" in ran.stderr.decode()


CLOSED_LOOP = """
import hashlib
from pathlib import Path

from robot_firmware import native
from robot_firmware.net.frames import key_from_secret
from services.sim.firmware_swarm import FirmwareSwarm
from swarm_config.scenario import load_scenario

swarm = FirmwareSwarm(load_scenario(Path("configs/scenarios/paper.yaml")), key_from_secret("x"))
digest = hashlib.sha256()
for _ in range(TICKS):
    swarm.step()
    digest.update(swarm.world.bodies.pose.tobytes())
    for robot in swarm.robots:
        digest.update(repr(sorted(robot.fabric.bus.snapshot().items())).encode())
        digest.update(repr(robot.fabric.bus.error_counts).encode())
print(native.MODE, digest.hexdigest())
"""


@pytest.mark.slow
def test_compiled_and_source_register_models_run_the_same_closed_loop(
    native_built: Path,
) -> None:
    """The paper scenario's robots as firmware on their fabric models, 8 s of control periods:
    every pose and every register word of every robot after every period is the same with
    the compiled register model and drivers as with their source."""
    code = CLOSED_LOOP.replace("TICKS", "800")
    digests = {}
    for mode in ("mypyc", "python"):
        ran = run_python(code, {native.NATIVE_ENV: mode})
        assert ran.returncode == 0, ran.stderr.decode()
        ran_mode, digests[mode] = ran.stdout.decode().split()
        assert ran_mode == mode
    assert digests["mypyc"] == digests["python"]
