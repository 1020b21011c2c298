"""A swarm run's credentials: one file per process identity, the file format and its I/O.

DESIGN.md §7.1 "Identities": every process authenticates to the router with its own user and
password, and the robots share the secret their radio frames are signed with.  Secrets come
from files, never from the repository, a command line or a child's environment: a process is
given the *path* of its credentials file (`--credentials FILE` or `$SWARM_CREDENTIALS_FILE`).

`swarm up` makes a fresh set for every run (`generate_credential_set`) and writes it with
`write_credential_set` into `<out>/credentials/`, a directory of mode 0700:

    <identity>.json      ProcessCredentials of router, world, launcher, dashboard, operator
                         and every robot; mode 0600 from creation (written to a temporary
                         file in the same directory, fsynced, renamed)
    router-users.txt     the router's `transport/auth/usrpwd/dictionary_file`: one
                         `user:password` line per identity; mode 0600

A credentials file holds (JSON, `ProcessCredentials`):

    format       1
    identity     the Zenoh user name (router, world, launcher, dashboard, operator, robotN)
    password     the identity's router password, 32 random bytes as 64 hex digits
    swarm        the swarm name the credentials belong to
    run_id       16 hex digits, new for every run; bound into every radio frame
    swarm_key    robots only: the radio frames' 32-byte secret as 64 hex digits

`read_credentials` refuses, with a `CredentialsError` that says what to do, a file that is
missing, unreadable, not this format, or readable by anyone but its owner.  The secrets are
`SecretStr`: their repr and str are '**********', so a log line or an error message that shows
the model shows no secret.
"""

from __future__ import annotations

import json
import os
import secrets
import stat
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Annotated, Any, Final, Literal

from pydantic import (
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    SecretStr,
    ValidationError,
    field_validator,
)

from swarm_config.atomic_files import PRIVATE_FILE_MODE, write_file_atomically
from swarm_config.settings import SettingsError, describe_validation_error

CREDENTIALS_FILE_ENV: Final = "SWARM_CREDENTIALS_FILE"
"""Environment variable naming a process's credentials file (a path, never a secret)."""

CREDENTIALS_DIR_NAME: Final = "credentials"
"""The credentials directory inside a run directory: `<out>/credentials/`."""
ROUTER_USERS_FILE: Final = "router-users.txt"

ROUTER: Final = "router"
WORLD: Final = "world"
LAUNCHER: Final = "launcher"
DASHBOARD: Final = "dashboard"
OPERATOR: Final = "operator"
SERVICE_IDENTITIES: Final = (ROUTER, WORLD, LAUNCHER, DASHBOARD, OPERATOR)
"""Every identity of a run but the robots, whose names come from the scenario."""

RUN_ID_BYTES: Final = 8
SWARM_KEY_BYTES: Final = 32
PASSWORD_BYTES: Final = 32
PRIVATE_DIR_MODE: Final = 0o700

_HEX_DIGITS = frozenset("0123456789abcdef")

HOW_TO_GET_CREDENTIALS: Final = (
    f"give the path of this process's credentials file with --credentials FILE or "
    f"${CREDENTIALS_FILE_ENV}; `swarm up` writes one per process to "
    f"<out>/{CREDENTIALS_DIR_NAME}/<name>.json (e.g. runs/swarm/{CREDENTIALS_DIR_NAME}/"
    f"{OPERATOR}.json for the swarm command line)"
)


class CredentialsError(SettingsError):
    """Credentials that cannot be used: missing, unreadable, malformed or too permissive."""


def _check_hex(value: str, n_bytes: int, what: str) -> str:
    if len(value) != 2 * n_bytes or not set(value) <= _HEX_DIGITS:
        raise ValueError(f"{what} must be {2 * n_bytes} lowercase hex digits")
    return value


class ProcessCredentials(BaseModel):
    """What one process needs to join its swarm's run: who it is and its secrets."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    format: Literal[1] = 1
    identity: str = Field(pattern=r"^[a-z][a-z0-9_-]{0,31}$")
    password: SecretStr
    swarm: str = Field(pattern=r"^[a-z][a-z0-9_-]{0,31}$")
    run_id: str
    swarm_key: SecretStr | None = None

    @field_validator("password", "swarm_key")
    @classmethod
    def _secret_hex(cls, value: SecretStr | None) -> SecretStr | None:
        if value is not None:
            _check_hex(value.get_secret_value(), SWARM_KEY_BYTES, "a secret")
        return value

    @field_validator("run_id")
    @classmethod
    def _run_id_hex(cls, value: str) -> str:
        return _check_hex(value, RUN_ID_BYTES, "run_id")

    @property
    def run_id_bytes(self) -> bytes:
        """The run id as the frames carry it."""
        return bytes.fromhex(self.run_id)

    def swarm_key_bytes(self) -> bytes:
        """The radio frames' secret; CredentialsError for an identity that has none."""
        if self.swarm_key is None:
            raise CredentialsError(
                f"the credentials of {self.identity!r} hold no swarm key: only robots sign "
                "radio frames"
            )
        return bytes.fromhex(self.swarm_key.get_secret_value())

    def to_json_bytes(self) -> bytes:
        """The file's content, secrets in clear: written only by `write_private_file`."""
        data: dict[str, Any] = {
            "format": self.format,
            "identity": self.identity,
            "password": self.password.get_secret_value(),
            "swarm": self.swarm,
            "run_id": self.run_id,
        }
        if self.swarm_key is not None:
            data["swarm_key"] = self.swarm_key.get_secret_value()
        return (json.dumps(data, indent=2) + "\n").encode("utf-8")


class CredentialSet(BaseModel):
    """Every identity's credentials of one run (what `swarm up` or the compose init makes)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    swarm: str
    run_id: str
    swarm_key: SecretStr
    robots: tuple[str, ...]
    passwords: Mapping[str, SecretStr]

    @property
    def identities(self) -> tuple[str, ...]:
        return (*SERVICE_IDENTITIES, *self.robots)

    def for_identity(self, identity: str) -> ProcessCredentials:
        if identity not in self.passwords:
            raise CredentialsError(
                f"no credentials for {identity!r}; identities: {', '.join(self.identities)}"
            )
        return ProcessCredentials(
            identity=identity,
            password=self.passwords[identity],
            swarm=self.swarm,
            run_id=self.run_id,
            swarm_key=self.swarm_key if identity in self.robots else None,
        )

    def router_users(self) -> bytes:
        """The router's dictionary file: one `user:password` line per identity."""
        lines = (f"{name}:{self.passwords[name].get_secret_value()}\n" for name in self.identities)
        return "".join(lines).encode("utf-8")

    def with_new_run_id(self) -> CredentialSet:
        """The same secrets for a new run: only the run id changes."""
        return self.model_copy(update={"run_id": new_run_id()})


def new_run_id() -> str:
    return secrets.token_hex(RUN_ID_BYTES)


def generate_credential_set(swarm: str, robots: Sequence[str]) -> CredentialSet:
    """Fresh random credentials for a run of `robots` on `swarm`."""
    names = tuple(robots)
    clash = set(names) & set(SERVICE_IDENTITIES)
    if clash or len(set(names)) != len(names):
        raise CredentialsError(f"robot names must be unique and not one of {SERVICE_IDENTITIES}")
    return CredentialSet(
        swarm=swarm,
        run_id=new_run_id(),
        swarm_key=SecretStr(secrets.token_hex(SWARM_KEY_BYTES)),
        robots=names,
        passwords={
            name: SecretStr(secrets.token_hex(PASSWORD_BYTES))
            for name in (*SERVICE_IDENTITIES, *names)
        },
    )


def credentials_path(directory: Path, identity: str) -> Path:
    return directory / f"{identity}.json"


def write_private_file(path: Path, data: bytes) -> None:
    """Write `data` to `path` atomically, readable and writable by the owner only from the
    moment the file exists (swarm_config/atomic_files.py); FileWriteError when it cannot."""
    write_file_atomically(path, data, mode=PRIVATE_FILE_MODE)


def make_private_dir(directory: Path) -> None:
    """Create `directory` (and parents) and make it 0700."""
    directory.mkdir(parents=True, exist_ok=True, mode=PRIVATE_DIR_MODE)
    os.chmod(directory, PRIVATE_DIR_MODE)


def write_credential_set(directory: Path, credentials: CredentialSet) -> dict[str, Path]:
    """Write every identity's file and the router's user file; returns identity -> path."""
    make_private_dir(directory)
    paths: dict[str, Path] = {}
    for identity in credentials.identities:
        path = credentials_path(directory, identity)
        write_private_file(path, credentials.for_identity(identity).to_json_bytes())
        paths[identity] = path
    write_private_file(directory / ROUTER_USERS_FILE, credentials.router_users())
    return paths


def _check_private(path: Path) -> None:
    try:
        mode = path.stat().st_mode
    except FileNotFoundError:
        raise CredentialsError(f"no credentials file {path}; {HOW_TO_GET_CREDENTIALS}") from None
    except OSError as exc:
        raise CredentialsError(f"{path}: cannot read ({exc.strerror})") from None
    if not stat.S_ISREG(mode):
        raise CredentialsError(f"{path}: not a regular file")
    if mode & 0o077:
        raise CredentialsError(
            f"{path}: mode {stat.S_IMODE(mode):04o} lets others read the secrets; "
            f"`chmod 600 {path}` (only its owner may read it)"
        )


def read_credentials(path: Path) -> ProcessCredentials:
    """One process's credentials; CredentialsError saying what is wrong and what to do."""
    _check_private(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise CredentialsError(f"{path}: cannot read ({exc.strerror})") from None
    try:
        return ProcessCredentials.model_validate_json(raw)
    except ValidationError as exc:
        # Never echo the input: it holds secrets.
        problems = describe_validation_error(f"{path}: not a credentials file", exc)
        raise CredentialsError(problems) from None


def read_credential_set(directory: Path, robots: Iterable[str]) -> CredentialSet:
    """The set written by `write_credential_set` (every identity must be there and agree)."""
    names = tuple(robots)
    files = {
        name: read_credentials(credentials_path(directory, name))
        for name in (*SERVICE_IDENTITIES, *names)
    }
    robot_keys = {files[name].swarm_key for name in names}
    first = files[ROUTER]
    if len(robot_keys) > 1 or None in robot_keys:
        raise CredentialsError(f"{directory}: the robots' swarm keys are missing or differ")
    for name, creds in files.items():
        if creds.identity != name or creds.swarm != first.swarm:
            raise CredentialsError(f"{credentials_path(directory, name)}: identity or swarm differ")
    key = next(iter(robot_keys)) if names else SecretStr(secrets.token_hex(SWARM_KEY_BYTES))
    assert key is not None
    return CredentialSet(
        swarm=first.swarm,
        run_id=first.run_id,
        swarm_key=key,
        robots=names,
        passwords={name: creds.password for name, creds in files.items()},
    )


def credentials_from_source(value: object) -> ProcessCredentials:
    """A settings field's value (a path, as text or Path, or loaded credentials) as loaded
    credentials; a missing one is an error that says how to give one."""
    if isinstance(value, ProcessCredentials):
        return value
    if value is None or value == "":
        raise ValueError(f"no credentials: {HOW_TO_GET_CREDENTIALS}")
    if isinstance(value, str | os.PathLike):
        try:
            return read_credentials(Path(value))
        except CredentialsError as exc:
            raise ValueError(str(exc)) from None
    raise ValueError("must be the path of a credentials file")


CredentialsFile = Annotated[ProcessCredentials, BeforeValidator(credentials_from_source)]
"""A settings field holding a process's credentials, given as the path of their file."""


def optional_credentials_from_source(value: object) -> ProcessCredentials | None:
    """Like `credentials_from_source`, but nothing given is None (the process decides)."""
    return None if value is None or value == "" else credentials_from_source(value)


OptionalCredentialsFile = Annotated[
    ProcessCredentials | None, BeforeValidator(optional_credentials_from_source)
]
"""A settings field that may hold a process's credentials, given as the path of their file."""


def check_identity(credentials: ProcessCredentials, identity: str, swarm: str) -> None:
    """ValueError unless `credentials` are `identity`'s on `swarm`."""
    if credentials.identity != identity or credentials.swarm != swarm:
        raise ValueError(
            f"the credentials file is {credentials.identity!r} of swarm {credentials.swarm!r}, "
            f"not {identity!r} of swarm {swarm!r}"
        )
