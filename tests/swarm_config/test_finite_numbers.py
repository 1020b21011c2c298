"""No NaN or infinity gets into a run through a file or a setting: each is refused, naming the
field.  Before, a scenario with `x_m: .nan` ran the whole simulation on NaN without a word, and
`swarm up --duration inf` started every process and crashed the world at its first tick."""

from __future__ import annotations

import copy
import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any, get_args

import pytest

from robot_firmware.net.messages import TelemetryMessage, parse_message
from robot_firmware.runtime import RobotConfig
from services.dashboard.live import DashboardConfig
from swarm_config.scenario import ScenarioError, load_scenario, parse_scenario
from swarm_config.settings import LayeredSettings, SettingsError
from world.runtime import WorldConfig

ROOT = Path(__file__).resolve().parents[2]
SCENARIOS = sorted((ROOT / "configs" / "scenarios").glob("*.yaml"))
NON_FINITE = (math.nan, math.inf, -math.inf)


def _float_leaves(value: Any, path: tuple[str | int, ...] = ()) -> Iterator[tuple[str | int, ...]]:
    if isinstance(value, dict):
        for key, child in value.items():
            yield from _float_leaves(child, (*path, key))
    elif isinstance(value, list):
        for index, child in enumerate(value):
            yield from _float_leaves(child, (*path, index))
    elif isinstance(value, float):
        yield path


@pytest.mark.parametrize("path", SCENARIOS, ids=lambda p: p.stem)
def test_every_number_of_a_scenario_refuses_nan_and_infinity(path: Path) -> None:
    # Every field, defaults included: the scenario as the simulator sees it.
    full = load_scenario(path).model_dump(mode="json")
    leaves = list(_float_leaves(full))
    assert len(leaves) > 90
    for leaf in leaves:
        for bad in NON_FINITE:
            data = copy.deepcopy(full)
            parent = data
            for key in leaf[:-1]:
                parent = parent[key]
            parent[leaf[-1]] = bad
            with pytest.raises(ScenarioError) as refused:
                parse_scenario(data, path.name)
            lines = str(refused.value).splitlines()
            assert len(lines) == 2, lines  # one problem, on its own line
            where, message = lines[1].strip().split(": ", 1)
            assert message == "Input should be a finite number", (leaf, lines)
            # The path of the field, with a trajectory's kind where it is one of several.
            named = where.split(".")
            assert named[0] == str(leaf[0]) and named[-1] == str(leaf[-1]), (leaf, where)
            assert [t for t in named if t in map(str, leaf)] == [str(k) for k in leaf], where


def _float_fields(model: type[LayeredSettings]) -> list[str]:
    return [
        name
        for name, field in model.model_fields.items()
        if field.annotation is float or float in get_args(field.annotation)
    ]


@pytest.mark.parametrize("model", [WorldConfig, RobotConfig, DashboardConfig])
def test_process_settings_refuse_nan_and_infinity(model: type[LayeredSettings]) -> None:
    fields = _float_fields(model)
    assert fields
    for name in fields:
        for bad in (*NON_FINITE, "inf", "nan", "1e400"):  # as a flag, a variable or YAML gives it
            with pytest.raises(SettingsError) as refused:
                model.from_sources({name: bad}, environ={})
            assert any(
                line.startswith(f"  {name}") and line.endswith(": Input should be a finite number")
                for line in str(refused.value).splitlines()
            ), (name, bad, str(refused.value))


def test_a_telemetry_message_with_a_stamp_no_run_reaches_is_refused() -> None:
    ok = parse_message(TelemetryMessage, b'{"robot": "robot1", "t_s": 12.5}')
    assert ok is not None and ok.t_s == 12.5
    for stamp in (b"NaN", b"Infinity", b"-Infinity", b"1e300", b"1e10"):
        refused = parse_message(TelemetryMessage, b'{"robot": "robot1", "t_s": ' + stamp + b"}")
        assert refused is None, stamp
