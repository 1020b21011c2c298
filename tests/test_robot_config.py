import subprocess
import sys
from pathlib import Path

import pytest
from robot_firmware.runtime import RobotConfig
from swarm_config.settings import SettingsError

ROOT = Path(__file__).resolve().parents[1]
PAPER = str(ROOT / "configs" / "scenarios" / "paper.yaml")


def test_environment_fills_what_the_command_line_omits() -> None:
    env = {
        "ROBOT_ID": "robot2",
        "SWARM_NAME": "bench",
        "SWARM_SCENARIO": PAPER,
        "ZENOH_CONNECT": "tcp/10.0.0.1:7447, tcp/10.0.0.2:7447",
        "SWARM_KEY": "s3cret",
    }
    config = RobotConfig.from_sources({}, env)
    assert config.name == "robot2" and config.swarm == "bench"
    assert config.connect == ["tcp/10.0.0.1:7447", "tcp/10.0.0.2:7447"]
    assert config.secret == "s3cret"
    assert "s3cret" not in repr(config)
    wins = RobotConfig.from_sources({"name": "robot3", "connect": ["tcp/127.0.0.1:1"]}, env)
    assert wins.name == "robot3" and wins.connect == ["tcp/127.0.0.1:1"]


def test_yaml_file_is_the_lowest_layer(tmp_path: Path) -> None:
    file = tmp_path / "robot.yaml"
    file.write_text(f"name: robot1\nscenario: {PAPER}\ntelemetry_rate_hz: 5\nswarm: yard\n")
    config = RobotConfig.from_sources({}, {"SWARM_NAME": "lab"}, config_file=file)
    assert config.name == "robot1" and config.telemetry_rate_hz == 5.0
    assert config.swarm == "lab"
    file.write_text("- not\n- a mapping\n")
    with pytest.raises(ValueError, match="mapping"):
        RobotConfig.from_sources({}, {}, config_file=file)


def test_bad_value_names_the_field_and_its_variable() -> None:
    with pytest.raises(SettingsError) as info:
        RobotConfig.from_sources(
            {}, {"ROBOT_NAME": "Robot 1", "SWARM_SCENARIO": PAPER, "TELEMETRY_RATE_HZ": "-3"}
        )
    message = str(info.value)
    assert "name (or $ROBOT_NAME)" in message
    assert "telemetry_rate_hz (or $TELEMETRY_RATE_HZ)" in message


def test_robot_process_refuses_a_bad_setting_without_traceback() -> None:
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "services.cli.main",
            "robot",
            "--name",
            "Robot 1",
            "--scenario",
            PAPER,
        ],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=60,
    )
    assert result.returncode == 2
    assert "name (or $ROBOT_NAME)" in result.stderr
    assert "Traceback" not in result.stderr
    unknown = subprocess.run(
        [
            sys.executable,
            "-m",
            "services.cli.main",
            "robot",
            "--name",
            "robot9",
            "--scenario",
            PAPER,
        ],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=60,
    )
    assert unknown.returncode == 2 and "no robot named 'robot9'" in unknown.stderr
