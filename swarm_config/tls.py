"""A swarm's TLS files: a certificate authority of its own and the router's certificate.

DESIGN.md §7.1: on one host the processes reach the router over loopback TCP; between hosts
the links can be TLS (`tls/HOST:PORT` endpoints), so that no one on the network reads the
traffic or impersonates the router.  `generate_tls_files` writes, into `<credentials>/tls/`
(mode 0700, every file 0600 from creation, like the credentials):

    ca.pem           the swarm's CA certificate (EC P-256, self-signed, CA:TRUE, pathlen 0):
                     every client is given it (`transport/link/tls/root_ca_certificate`) and
                     accepts only a router whose certificate it signed
    router.pem       the router's certificate, signed by the CA: subjectAltName = the host
                     names and IP addresses the clients connect to (`--tls-host`; default
                     127.0.0.1 and localhost), extendedKeyUsage serverAuth
    router-key.pem   the router's private key (PKCS#8)

The CA's private key is discarded once the router certificate is signed: no one, not even
whoever holds the directory, can issue another certificate the clients would trust.  A new
router certificate (another host, expiry, a leaked key) means a new CA, and every client
gets the new `ca.pem`.

The files are made by the `openssl` command line (OpenSSL >= 1.1.1; Debian and the project's
image have it) rather than by a Python package: it adds no dependency to the project, and
what it writes is what any TLS tool reads.  A missing `openssl`, a failed step or a host
name that is neither an IP address nor a DNS name is a `TlsError` that says what to do, and
leaves the directory as it was: the files are made in a private temporary directory and
moved in only when all of them exist and `openssl verify` accepts the chain.
"""

from __future__ import annotations

import ipaddress
import os
import re
import secrets
import shutil
import stat
import subprocess
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Final

from swarm_config.credentials import (
    make_private_dir,
    write_private_file,
)
from swarm_config.settings import SettingsError

TLS_DIR_NAME: Final = "tls"
"""The TLS directory inside a credentials directory: `<credentials>/tls/`."""
CA_CERTIFICATE_FILE: Final = "ca.pem"
ROUTER_CERTIFICATE_FILE: Final = "router.pem"
ROUTER_PRIVATE_KEY_FILE: Final = "router-key.pem"

TLS_ROOT_CA_ENV: Final = "SWARM_TLS_ROOT_CA"
"""Environment variable naming the CA certificate a client trusts (a path; not a secret)."""

DEFAULT_TLS_HOSTS: Final = ("127.0.0.1", "localhost")
DEFAULT_VALID_DAYS: Final = 365
OPENSSL_TIMEOUT_S: Final = 60.0

_DNS_LABEL = r"[A-Za-z0-9](?:[A-Za-z0-9-]{0,61}[A-Za-z0-9])?"
_DNS_NAME = re.compile(rf"^{_DNS_LABEL}(?:\.{_DNS_LABEL})*$")
_MAX_DNS_NAME_CHARS = 253


class TlsError(SettingsError):
    """TLS files that cannot be made or used: no openssl, a bad host name, missing files."""


@dataclass(frozen=True)
class TlsFiles:
    """The paths of a swarm's TLS files in one directory (they may not exist yet)."""

    directory: Path

    @property
    def ca_certificate(self) -> Path:
        return self.directory / CA_CERTIFICATE_FILE

    @property
    def router_certificate(self) -> Path:
        return self.directory / ROUTER_CERTIFICATE_FILE

    @property
    def router_private_key(self) -> Path:
        return self.directory / ROUTER_PRIVATE_KEY_FILE

    @property
    def all(self) -> tuple[Path, Path, Path]:
        return (self.ca_certificate, self.router_certificate, self.router_private_key)

    def complete(self) -> bool:
        """Whether all three files are there."""
        return all(path.is_file() for path in self.all)


def tls_dir(credentials_dir: Path) -> Path:
    return credentials_dir / TLS_DIR_NAME


def is_dns_name(host: str) -> bool:
    """Whether `host` is a DNS name: dot-separated labels of letters, digits and inner hyphens
    (RFC 1123), 253 characters at most."""
    return len(host) <= _MAX_DNS_NAME_CHARS and _DNS_NAME.match(host) is not None


def subject_alt_name(hosts: Sequence[str]) -> str:
    """The subjectAltName value for `hosts` ('IP:127.0.0.1, DNS:localhost'); TlsError for a
    host that is neither an IP address nor a DNS name, or for no host at all."""
    if not hosts:
        raise TlsError("the router certificate needs at least one host name or IP address")
    entries: list[str] = []
    for host in hosts:
        try:
            entries.append(f"IP:{ipaddress.ip_address(host)}")
            continue
        except ValueError:
            pass
        if not is_dns_name(host):
            raise TlsError(
                f"--tls-host {host!r} is neither an IP address nor a DNS name "
                "(e.g. 192.168.1.20 or router.lab)"
            )
        entries.append(f"DNS:{host.lower()}")
    return ", ".join(dict.fromkeys(entries))


def find_openssl() -> str:
    """The `openssl` executable; TlsError saying how to get one."""
    found = shutil.which("openssl")
    if found is None:
        raise TlsError(
            "TLS certificates are made with the `openssl` command, which is not on PATH; "
            "install it (Debian/Ubuntu: `apt-get install openssl`) and try again"
        )
    return found


def _openssl_config(swarm: str, alt_names: str) -> str:
    return (
        "[req]\n"
        "distinguished_name = dn\n"
        "prompt = no\n"
        "[dn]\n"
        f"CN = swarm {swarm}\n"
        "[ca_ext]\n"
        "basicConstraints = critical, CA:TRUE, pathlen:0\n"
        "keyUsage = critical, keyCertSign, cRLSign\n"
        "subjectKeyIdentifier = hash\n"
        "[router_ext]\n"
        "basicConstraints = critical, CA:FALSE\n"
        "keyUsage = critical, digitalSignature\n"
        "extendedKeyUsage = serverAuth\n"
        f"subjectAltName = {alt_names}\n"
        "subjectKeyIdentifier = hash\n"
        "authorityKeyIdentifier = keyid\n"
    )


def _run(openssl: str, *args: str, cwd: Path) -> None:
    try:
        result = subprocess.run(
            [openssl, *args],
            cwd=cwd,
            capture_output=True,
            text=True,
            timeout=OPENSSL_TIMEOUT_S,
            check=False,
        )
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise TlsError(f"`openssl {args[0]}` could not run: {exc}") from None
    if result.returncode != 0:
        detail = (result.stderr.strip().splitlines() or ["no message"])[-1]
        raise TlsError(f"`openssl {args[0]}` failed (exit {result.returncode}): {detail}")


def generate_tls_files(
    directory: Path,
    swarm: str,
    hosts: Sequence[str] = DEFAULT_TLS_HOSTS,
    valid_days: int = DEFAULT_VALID_DAYS,
) -> TlsFiles:
    """Make a new CA and a router certificate for `hosts` in `directory` (0700; files 0600),
    replacing any there; TlsError, with `directory` unchanged, when anything fails."""
    alt_names = subject_alt_name(hosts)
    if valid_days < 1:
        raise TlsError(f"certificates must be valid for at least 1 day, not {valid_days}")
    openssl = find_openssl()
    make_private_dir(directory)
    days = str(valid_days)
    with tempfile.TemporaryDirectory(prefix=".tls-", dir=directory) as scratch_name:
        scratch = Path(scratch_name)  # mode 0700: the keys are private while they are made
        (scratch / "openssl.cnf").write_text(_openssl_config(swarm, alt_names), encoding="utf-8")
        config = ("-config", "openssl.cnf")
        p256 = ("-algorithm", "EC", "-pkeyopt", "ec_paramgen_curve:P-256")
        _run(openssl, "genpkey", *p256, "-out", "ca-key.pem", cwd=scratch)
        _run(openssl, "genpkey", *p256, "-out", "router-key.pem", cwd=scratch)
        _run(
            openssl, "req", "-new", "-x509", *config, "-extensions", "ca_ext",
            "-key", "ca-key.pem", "-subj", f"/CN=swarm {swarm} CA", "-days", days,
            "-sha256", "-set_serial", f"0x{secrets.token_hex(16)}", "-out", "ca.pem",
            cwd=scratch,
        )  # fmt: skip
        _run(
            openssl, "req", "-new", *config, "-key", "router-key.pem",
            "-subj", f"/CN=swarm {swarm} router", "-out", "router.csr",
            cwd=scratch,
        )  # fmt: skip
        _run(
            openssl, "x509", "-req", "-in", "router.csr", "-CA", "ca.pem",
            "-CAkey", "ca-key.pem", "-set_serial", f"0x{secrets.token_hex(16)}",
            "-days", days, "-sha256", "-extfile", "openssl.cnf", "-extensions", "router_ext",
            "-out", "router.pem",
            cwd=scratch,
        )  # fmt: skip
        _run(openssl, "verify", "-x509_strict", "-CAfile", "ca.pem", "router.pem", cwd=scratch)
        made = {
            name: (scratch / name).read_bytes()
            for name in (CA_CERTIFICATE_FILE, ROUTER_CERTIFICATE_FILE, ROUTER_PRIVATE_KEY_FILE)
        }
    # The CA key went with the scratch directory.
    files = TlsFiles(directory)
    for path in files.all:
        write_private_file(path, made[path.name])
    return files


def read_tls_files(directory: Path) -> TlsFiles:
    """The TLS files in `directory`, checked: all there, and the router's key private;
    TlsError saying how to make them."""
    files = TlsFiles(directory)
    missing = [path.name for path in files.all if not path.is_file()]
    if missing:
        raise TlsError(
            f"{directory}: no {', '.join(missing)}; make a CA and the router's certificate "
            f"with `swarm credentials DIR --tls` (it writes DIR/{TLS_DIR_NAME}/)"
        )
    key = files.router_private_key
    mode = key.stat().st_mode
    if mode & 0o077:
        raise TlsError(
            f"{key}: mode {stat.S_IMODE(mode):04o} lets others read the router's private key; "
            f"`chmod 600 {key}`"
        )
    return files


def root_ca_from_environment() -> Path | None:
    """The CA certificate named by $SWARM_TLS_ROOT_CA, None when it is unset; TlsError when it
    names no file."""
    value = os.environ.get(TLS_ROOT_CA_ENV)
    if not value:
        return None
    path = Path(value)
    if not path.is_file():
        raise TlsError(
            f"${TLS_ROOT_CA_ENV} names {path}, which is not a file; give the swarm's "
            f"CA certificate (<credentials>/{TLS_DIR_NAME}/{CA_CERTIFICATE_FILE})"
        )
    return path
