"""Credentials of a run: generation, files of mode 0600 in a 0700 directory, clear refusals."""

from __future__ import annotations

import json
import os
import stat
from pathlib import Path

import pytest

from swarm_config.credentials import (
    ROUTER_USERS_FILE,
    SERVICE_IDENTITIES,
    CredentialsError,
    ProcessCredentials,
    credentials_path,
    generate_credential_set,
    read_credential_set,
    read_credentials,
    write_credential_set,
)

ROBOTS = ("robot1", "robot2", "robot3")


def _mode(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


def test_a_generated_set_has_one_identity_per_process_and_fresh_secrets() -> None:
    first = generate_credential_set("lab", ROBOTS)
    second = generate_credential_set("lab", ROBOTS)
    assert first.identities == (*SERVICE_IDENTITIES, *ROBOTS)
    assert first.swarm_key != second.swarm_key and first.run_id != second.run_id
    passwords = [first.passwords[name].get_secret_value() for name in first.identities]
    assert len(set(passwords)) == len(passwords)
    assert all(len(p) == 64 for p in passwords)
    assert first.for_identity("robot2").swarm_key == first.swarm_key
    assert first.for_identity("world").swarm_key is None
    assert first.with_new_run_id().run_id != first.run_id
    with pytest.raises(CredentialsError, match="nobody"):
        first.for_identity("nobody")
    with pytest.raises(CredentialsError):
        generate_credential_set("lab", ("robot1", "operator"))


def test_files_are_private_from_creation_and_read_back(tmp_path: Path) -> None:
    credentials = generate_credential_set("lab", ROBOTS)
    directory = tmp_path / "run" / "credentials"
    old_umask = os.umask(0)  # the most permissive umask: the modes must not depend on it
    try:
        paths = write_credential_set(directory, credentials)
    finally:
        os.umask(old_umask)
    assert _mode(directory) == 0o700
    assert set(paths) == set(credentials.identities)
    for identity, path in paths.items():
        assert _mode(path) == 0o600, path
        loaded = read_credentials(path)
        assert loaded == credentials.for_identity(identity)
    users = (directory / ROUTER_USERS_FILE).read_text().splitlines()
    assert _mode(directory / ROUTER_USERS_FILE) == 0o600
    assert [line.split(":")[0] for line in users] == list(credentials.identities)
    assert not [p for p in directory.iterdir() if p.name.endswith(".tmp")]
    again = read_credential_set(directory, ROBOTS)
    assert again.swarm_key == credentials.swarm_key and again.passwords == credentials.passwords


def test_secrets_never_show_in_repr_or_errors(tmp_path: Path) -> None:
    credentials = generate_credential_set("lab", ROBOTS)
    robot = credentials.for_identity("robot1")
    for text in (repr(credentials), str(credentials), repr(robot), str(robot)):
        assert robot.password.get_secret_value() not in text
        assert credentials.swarm_key.get_secret_value() not in text
    path = tmp_path / "bad.json"
    data = json.loads(robot.to_json_bytes())
    data["run_id"] = "not hex"
    path.write_text(json.dumps(data))
    path.chmod(0o600)
    with pytest.raises(CredentialsError) as info:
        read_credentials(path)
    assert "run_id" in str(info.value)
    assert robot.password.get_secret_value() not in str(info.value)


def test_missing_unreadable_malformed_or_shared_files_are_refused(tmp_path: Path) -> None:
    robot = generate_credential_set("lab", ROBOTS).for_identity("robot1")
    with pytest.raises(CredentialsError, match="SWARM_CREDENTIALS_FILE"):
        read_credentials(tmp_path / "missing.json")
    path = tmp_path / "robot1.json"
    path.write_bytes(robot.to_json_bytes())
    path.chmod(0o644)
    with pytest.raises(CredentialsError, match="chmod 600"):
        read_credentials(path)
    path.chmod(0o600)
    assert read_credentials(path) == robot
    path.write_text("{not json")
    with pytest.raises(CredentialsError, match="not a credentials file"):
        read_credentials(path)
    path.write_text(json.dumps({"identity": "robot1"}))
    with pytest.raises(CredentialsError, match="password"):
        read_credentials(path)
    with pytest.raises(CredentialsError, match="not a regular file"):
        read_credentials(tmp_path)
    if os.geteuid() != 0:  # root reads any file
        path.write_bytes(robot.to_json_bytes())
        path.chmod(0)
        with pytest.raises(CredentialsError, match="cannot read"):
            read_credentials(path)


def test_only_robots_hold_the_swarm_key() -> None:
    credentials = generate_credential_set("lab", ROBOTS)
    assert len(credentials.for_identity("robot3").swarm_key_bytes()) == 32
    with pytest.raises(CredentialsError, match="only robots"):
        credentials.for_identity("dashboard").swarm_key_bytes()
    assert credentials_path(Path("x"), "world") == Path("x/world.json")
    assert isinstance(credentials.for_identity("operator"), ProcessCredentials)
