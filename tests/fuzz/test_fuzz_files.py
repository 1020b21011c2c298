"""Fuzzing the files a user writes: scenarios, fuzzy parameter files, process settings files and
credentials files.  Each loader may only raise its own error (`ScenarioError`, `SettingsError`,
`CredentialsError`), whose first line-item names the failing field; that field (or the kind of
problem) is the refusal's reason in the summary table.

PyYAML's pure-Python loader takes about 1.5 ms over a scenario file, so the 10,000 inputs of a
file kind are validated from parsed mappings (mutants of the real file's mapping), and a
further 1,000 mutated texts per kind go through the loader itself from a file.  Inputs the
loader fails on with another exception are collected (type and input) and reported together
at the end of the test.
"""

from __future__ import annotations

import json
import os
import random
import re
from collections import Counter
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import pytest
import yaml
from pydantic import ValidationError

from robot_firmware.control.fuzzy_parameters import FuzzyParameters
from swarm_config.scenario import ScenarioError, load_rule_base, load_scenario, parse_scenario
from swarm_config.settings import SettingsError
from tests.fuzz.generate import mutate_json, mutate_text, random_bytes, random_text
from tests.fuzz.ledger import ACCEPTED, LEDGER
from tests.fuzz.processes import PAPER
from world.runtime import WorldConfig

MAPPINGS = 10_000
TEXTS = 1_000


_PROBLEM_LINE = re.compile(r"^  (?P<where>[^:]+?)(?: \(or \$\w+\))?: (?P<message>.*)$")
_FIRST_LINE_KINDS = (
    ("YAML mapping", "not a mapping"),
    ("YAML", "not YAML"),
    ("lets others read", "file mode"),
    ("cannot read", "unreadable"),
    ("not a regular file", "not a file"),
)


def reason_of(error: Exception) -> str:
    """The error type and the first field it names (`unknown field` for one the model does
    not have), or the kind of problem its first line states."""
    name = type(error).__name__
    if isinstance(error, ValidationError):
        first = error.errors(include_url=False)[0]
        where, message = ".".join(str(p) for p in first["loc"]), first["msg"]
    else:
        lines = str(error).splitlines()
        found = next(filter(None, (_PROBLEM_LINE.match(line) for line in lines[1:])), None)
        if found is None:
            head = lines[0] if lines else ""
            kind = next((k for words, k in _FIRST_LINE_KINDS if words in head), "other")
            return f"{name}: {kind}"
        where, message = found["where"], found["message"]
    if "Extra inputs are not permitted" in message:
        return f"{name}: unknown field"
    field = where.split(".")[0].strip()
    if not field:
        return f"{name}: (top level)"
    return f"{name}: {field if re.fullmatch(r'[a-z_][a-z0-9_]*', field) else 'garbled field'}"


def fuzz_loader(
    target: str,
    inputs: Iterable[Any],
    load: Callable[[Any], object],
    refusal: type[Exception] | tuple[type[Exception], ...],
) -> None:
    """Every input either loads or is refused with `refusal`; anything else is collected."""
    escaped: Counter[str] = Counter()
    examples: dict[str, Any] = {}
    for item in inputs:
        try:
            load(item)
        except refusal as exc:
            LEDGER.record(target, reason_of(exc))
        except Exception as exc:  # the defect this test looks for
            kind = f"ESCAPED {type(exc).__name__}"
            escaped[kind] += 1
            examples.setdefault(kind, item)
            LEDGER.record(target, kind)
        else:
            LEDGER.record(target, ACCEPTED)
    assert not escaped, f"{dict(escaped)}; e.g. {examples}"


def _written(directory: Path, texts: Iterable[str | bytes]) -> Iterable[Path]:
    path = directory / "input.yaml"
    for text in texts:
        path.write_bytes(text if isinstance(text, bytes) else text.encode("utf-8", "replace"))
        yield path


def _texts(seed: int, valid_text: str, count: int = TEXTS) -> Iterable[str | bytes]:
    rng = random.Random(seed)
    for _ in range(count):
        roll = rng.random()
        if roll < 0.05:
            yield random_bytes(rng, 200)
        elif roll < 0.15:
            yield random_text(rng)
        else:
            yield mutate_text(rng, valid_text)


def _mappings(seed: int, valid: dict[str, Any], count: int = MAPPINGS) -> Iterable[Any]:
    rng = random.Random(seed)
    for _ in range(count):
        yield mutate_json(rng, valid)


# -- scenarios -----------------------------------------------------------------------------------


def test_scenario_mappings() -> None:
    valid = yaml.safe_load(PAPER.read_text())
    fuzz_loader("file scenario (mapping)", _mappings(10, valid), parse_scenario, ScenarioError)


def test_scenario_files(tmp_path: Path) -> None:
    texts = _texts(11, PAPER.read_text())
    fuzz_loader("file scenario (text)", _written(tmp_path, texts), load_scenario, ScenarioError)


# -- fuzzy parameter files -------------------------------------------------------------------------


def _parameters() -> dict[str, Any]:
    return FuzzyParameters.table2_defaults().model_dump(exclude_none=True)


def test_fuzzy_parameter_mappings() -> None:
    fuzz_loader(
        "file fuzzy parameters (mapping)",
        _mappings(12, _parameters()),
        FuzzyParameters.model_validate,
        ValidationError,
    )


def test_fuzzy_parameter_files(tmp_path: Path) -> None:
    scenario = load_scenario(PAPER)
    path = tmp_path / "input.yaml"

    def load(written: Path) -> object:
        return load_rule_base(scenario.model_copy(update={"fuzzy_parameter_file": written}))

    texts = _texts(13, yaml.safe_dump(_parameters(), sort_keys=False))
    fuzz_loader("file fuzzy parameters (text)", _written(path.parent, texts), load, ScenarioError)


# -- process settings ---------------------------------------------------------------------------

_WORLD_SETTINGS = {
    "swarm": "lab",
    "scenario": str(PAPER),
    "connect": ["tcp/127.0.0.1:7447"],
    "lockstep": True,
    "duration_s": 30.0,
    "act_timeout_ms": 100.0,
    "radio_profile": "lab",
    "max_speed": 2.0,
}


def test_settings_mappings() -> None:
    fuzz_loader(
        "file world settings (mapping)",
        _mappings(14, _WORLD_SETTINGS),
        lambda given: WorldConfig.from_sources(
            given if isinstance(given, dict) else {"swarm": given}, {}
        ),
        SettingsError,
    )


def test_settings_files(tmp_path: Path) -> None:
    texts = _texts(15, yaml.safe_dump(_WORLD_SETTINGS, sort_keys=False))
    fuzz_loader(
        "file world settings (text)",
        _written(tmp_path, texts),
        lambda path: WorldConfig.from_sources({}, {}, config_file=path),
        SettingsError,
    )


# -- credentials ----------------------------------------------------------------------------------


def test_credentials_files(tmp_path: Path) -> None:
    credentials = pytest.importorskip("swarm_config.credentials")
    files = credentials.write_credential_set(
        tmp_path / "valid", credentials.generate_credential_set("lab", ("robot1", "robot2"))
    )
    valid_json = files["robot1"].read_text()
    valid = yaml.safe_load(valid_json)
    rng = random.Random(16)
    path = tmp_path / "input.json"

    def inputs() -> Iterable[Path]:
        for _ in range(MAPPINGS):
            roll = rng.random()
            if roll < 0.1:
                data = random_bytes(rng, 200)
            elif roll < 0.6:
                data = json.dumps(mutate_json(rng, valid)).encode()
            elif roll < 0.95:
                data = mutate_text(rng, valid_json).encode("utf-8", "replace")
            else:
                data = valid_json.encode()
            path.unlink(missing_ok=True)
            path.write_bytes(data)
            os.chmod(path, 0o600 if rng.random() < 0.97 else rng.choice((0o644, 0o640, 0o604)))
            yield path

    fuzz_loader(
        "file credentials",
        inputs(),
        credentials.read_credentials,
        credentials.CredentialsError,
    )
    assert LEDGER.outcomes["file credentials"][ACCEPTED] > 0


def test_reasons_name_the_first_failing_field() -> None:
    with pytest.raises(ScenarioError) as scenario:
        parse_scenario({"name": "x"})
    assert reason_of(scenario.value).startswith("ScenarioError: ")
    with pytest.raises(ValidationError) as order:
        FuzzyParameters.model_validate({"error_centres": [1, 0], "rate_centres": [0, 1]})
    assert reason_of(order.value) == "ValidationError: error_centres"
    with pytest.raises(ValidationError) as extra:
        FuzzyParameters.model_validate({"error_centres": [0, 1], "rate_centres": [0, 1], "k": 1})
    assert reason_of(extra.value) == "ValidationError: unknown field"
    with pytest.raises(SettingsError) as settings:
        WorldConfig.from_sources({"swarm": "Not A Name"}, {})
    assert reason_of(settings.value) == "SettingsError: swarm"
