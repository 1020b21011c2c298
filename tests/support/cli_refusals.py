"""A `swarm` command refused in-process before it opens any Zenoh session: its status and its
stderr lines (tests/services)."""

from __future__ import annotations

from collections.abc import Sequence

import pytest
import zenoh

from services.cli.main import main


def forbid_zenoh_sessions(monkeypatch: pytest.MonkeyPatch) -> None:
    """From now on in this test any `zenoh.open` fails it: a refusal must come before the
    command connects."""

    def refuse(*_args: object, **_kwargs: object) -> None:
        raise AssertionError("the command opened a Zenoh session before refusing")

    monkeypatch.setattr(zenoh, "open", refuse)


def refusal_lines(argv: Sequence[str], capsys: pytest.CaptureFixture[str]) -> list[str]:
    """Run `swarm argv` in this process; it must end with status 2 and no traceback.  Its
    stderr, line by line."""
    try:
        status = main(list(argv))
    except SystemExit as exc:  # argparse's own refusal
        status = int(exc.code or 0)
    err = capsys.readouterr().err
    assert status == 2, err
    assert "Traceback" not in err
    return err.strip().splitlines()
