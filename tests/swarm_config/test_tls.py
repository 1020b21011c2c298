"""The swarm's TLS files: what `generate_tls_files` writes, what it refuses, and where the
router and client configs name them."""

from __future__ import annotations

import os
import stat
import subprocess
from pathlib import Path

import pytest

from robot_firmware.net.session import client_config, open_client
from services.router.access import router_config_document
from swarm_config.credentials import ROUTER_USERS_FILE, generate_credential_set
from swarm_config.tls import (
    TLS_ROOT_CA_ENV,
    TlsError,
    TlsFiles,
    generate_tls_files,
    read_tls_files,
    root_ca_from_environment,
    subject_alt_name,
)


def _openssl(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(["openssl", *args], capture_output=True, text=True, check=False)


@pytest.fixture(scope="module")
def made(tmp_path_factory: pytest.TempPathFactory) -> TlsFiles:
    directory = tmp_path_factory.mktemp("credentials") / "tls"
    return generate_tls_files(directory, "lab", hosts=("127.0.0.1", "router.lab", "::1"))


def test_files_are_private_in_a_private_directory(made: TlsFiles) -> None:
    assert stat.S_IMODE(made.directory.stat().st_mode) == 0o700
    for path in made.all:
        assert stat.S_IMODE(path.stat().st_mode) == 0o600, path


def test_only_the_three_files_remain_and_no_ca_key(made: TlsFiles) -> None:
    assert sorted(p.name for p in made.directory.iterdir()) == sorted(p.name for p in made.all)
    holding_a_key = [path for path in made.all if b"PRIVATE KEY" in path.read_bytes()]
    assert holding_a_key == [made.router_private_key]


def test_router_certificate_names_the_hosts_and_is_no_ca(made: TlsFiles) -> None:
    text = _openssl("x509", "-in", str(made.router_certificate), "-noout", "-text").stdout
    assert "IP Address:127.0.0.1" in text
    assert "DNS:router.lab" in text
    assert "IP Address:0:0:0:0:0:0:0:1" in text
    assert "CA:FALSE" in text
    assert "TLS Web Server Authentication" in text


def test_ca_signed_the_router_certificate(made: TlsFiles) -> None:
    verified = _openssl("verify", "-CAfile", str(made.ca_certificate), str(made.router_certificate))
    assert verified.returncode == 0, verified.stderr
    ca_text = _openssl("x509", "-in", str(made.ca_certificate), "-noout", "-text").stdout
    assert "CA:TRUE" in ca_text


def test_router_key_matches_its_certificate(made: TlsFiles) -> None:
    from_cert = _openssl("x509", "-in", str(made.router_certificate), "-noout", "-pubkey").stdout
    from_key = _openssl("pkey", "-in", str(made.router_private_key), "-pubout").stdout
    assert from_cert and from_cert == from_key


def test_another_ca_does_not_verify_the_router(made: TlsFiles, tmp_path: Path) -> None:
    other = generate_tls_files(tmp_path / "tls", "lab")
    verified = _openssl(
        "verify", "-CAfile", str(other.ca_certificate), str(made.router_certificate)
    )
    assert verified.returncode != 0


def test_a_new_set_replaces_the_old(tmp_path: Path) -> None:
    first = generate_tls_files(tmp_path / "tls", "lab")
    ca_before = first.ca_certificate.read_bytes()
    second = generate_tls_files(tmp_path / "tls", "lab")
    assert second.ca_certificate.read_bytes() != ca_before


@pytest.mark.parametrize("host", ["bad,host", "a b", "-lead.example", "", "x" * 254, "*.lab"])
def test_bad_host_is_refused_and_nothing_is_written(tmp_path: Path, host: str) -> None:
    with pytest.raises(TlsError, match="neither an IP address nor a DNS name"):
        generate_tls_files(tmp_path / "tls", "lab", hosts=(host,))
    assert not (tmp_path / "tls").exists()


def test_no_host_is_refused() -> None:
    with pytest.raises(TlsError, match="at least one"):
        subject_alt_name(())


def test_zero_days_is_refused(tmp_path: Path) -> None:
    with pytest.raises(TlsError, match="at least 1 day"):
        generate_tls_files(tmp_path / "tls", "lab", valid_days=0)
    assert not (tmp_path / "tls").exists()


def test_missing_openssl_says_how_to_get_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("PATH", str(tmp_path / "empty"))
    with pytest.raises(TlsError, match="apt-get install openssl"):
        generate_tls_files(tmp_path / "tls", "lab")
    assert not (tmp_path / "tls").exists()


def test_failing_openssl_step_leaves_the_directory_as_it_was(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    kept = generate_tls_files(tmp_path / "tls", "lab")
    before = {path.name: path.read_bytes() for path in kept.all}
    fake = tmp_path / "bin" / "openssl"
    fake.parent.mkdir()
    fake.write_text("#!/bin/sh\necho 'simulated failure' >&2\nexit 3\n")
    fake.chmod(0o755)
    monkeypatch.setenv("PATH", str(fake.parent))
    with pytest.raises(TlsError, match=r"`openssl genpkey` failed \(exit 3\): simulated failure"):
        generate_tls_files(tmp_path / "tls", "lab")
    assert {path.name: path.read_bytes() for path in kept.all} == before
    assert sorted(p.name for p in kept.directory.iterdir()) == sorted(before)


def test_read_tls_files_names_what_is_missing(tmp_path: Path) -> None:
    with pytest.raises(TlsError, match=r"no ca.pem, router.pem, router-key.pem.*--tls"):
        read_tls_files(tmp_path)


def test_read_tls_files_refuses_a_readable_key(tmp_path: Path) -> None:
    files = generate_tls_files(tmp_path / "tls", "lab")
    os.chmod(files.router_private_key, 0o644)
    with pytest.raises(TlsError, match="chmod 600"):
        read_tls_files(files.directory)


def test_root_ca_from_environment(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(TLS_ROOT_CA_ENV, raising=False)
    assert root_ca_from_environment() is None
    monkeypatch.setenv(TLS_ROOT_CA_ENV, str(tmp_path / "nothing.pem"))
    with pytest.raises(TlsError, match="not a file"):
        root_ca_from_environment()
    ca = tmp_path / "ca.pem"
    ca.write_text("x")
    monkeypatch.setenv(TLS_ROOT_CA_ENV, str(ca))
    assert root_ca_from_environment() == ca


def test_router_config_names_the_certificate_and_keeps_login_and_acl(made: TlsFiles) -> None:
    credentials = generate_credential_set("lab", ["robot1"])
    document = router_config_document(
        credentials, Path(ROUTER_USERS_FILE), ["tls/127.0.0.1:7447"], made
    )
    assert document["transport"]["link"]["tls"] == {
        "listen_certificate": str(made.router_certificate.resolve()),
        "listen_private_key": str(made.router_private_key.resolve()),
        "root_ca_certificate": str(made.ca_certificate.resolve()),
    }
    assert document["transport"]["auth"]["usrpwd"]["dictionary_file"] == ROUTER_USERS_FILE
    assert document["access_control"]["default_permission"] == "deny"


def test_router_config_without_tls_has_no_tls_section() -> None:
    credentials = generate_credential_set("lab", ["robot1"])
    document = router_config_document(credentials, Path("u"), ["tcp/127.0.0.1:7447"])
    assert set(document["transport"]["link"]) == {"rx"}  # the message size limit only


def test_tls_endpoint_without_certificate_is_refused() -> None:
    credentials = generate_credential_set("lab", ["robot1"])
    with pytest.raises(TlsError, match="swarm credentials DIR --tls"):
        router_config_document(credentials, Path("u"), ["tls/0.0.0.0:7447"])


def test_client_config_trusts_the_given_ca(made: TlsFiles) -> None:
    config = client_config(["tls/127.0.0.1:7447"], None, None, made.ca_certificate)
    expected = f'"{made.ca_certificate.resolve()}"'
    assert config.get_json("transport/link/tls/root_ca_certificate") == expected
    plain = client_config(["tcp/127.0.0.1:7447"])
    assert plain.get_json("transport/link/tls/root_ca_certificate") == "null"


def test_open_client_refuses_a_tls_endpoint_without_a_ca(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(TLS_ROOT_CA_ENV, raising=False)
    monkeypatch.delenv("SWARM_CREDENTIALS_FILE", raising=False)
    with pytest.raises(
        TlsError, match=r"needs the swarm's CA certificate: set \$SWARM_TLS_ROOT_CA"
    ):
        open_client(["tls/127.0.0.1:9"])
