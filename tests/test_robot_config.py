import subprocess
import sys
from pathlib import Path

import pytest

from robot_firmware.runtime import RobotConfig
from swarm_config.credentials import generate_credential_set, write_credential_set
from swarm_config.settings import SettingsError

ROOT = Path(__file__).resolve().parents[1]
PAPER = str(ROOT / "configs" / "scenarios" / "paper.yaml")


def _credentials(tmp_path: Path, swarm: str) -> dict[str, Path]:
    return write_credential_set(
        tmp_path / "credentials", generate_credential_set(swarm, ("robot1", "robot2", "robot3"))
    )


def test_environment_fills_what_the_command_line_omits(tmp_path: Path) -> None:
    files = _credentials(tmp_path, "bench")
    env = {
        "ROBOT_ID": "robot2",
        "SWARM_NAME": "bench",
        "SWARM_SCENARIO": PAPER,
        "ZENOH_CONNECT": "tcp/10.0.0.1:7447, tcp/10.0.0.2:7447",
        "SWARM_CREDENTIALS_FILE": str(files["robot2"]),
    }
    config = RobotConfig.from_sources({}, env)
    assert config.name == "robot2" and config.swarm == "bench"
    assert config.connect == ["tcp/10.0.0.1:7447", "tcp/10.0.0.2:7447"]
    assert config.credentials.identity == "robot2"
    secret = config.credentials.swarm_key
    assert secret is not None and secret.get_secret_value() not in repr(config)
    wins = RobotConfig.from_sources(
        {"name": "robot3", "connect": ["tcp/127.0.0.1:1"], "credentials": files["robot3"]}, env
    )
    assert wins.name == "robot3" and wins.connect == ["tcp/127.0.0.1:1"]
    with pytest.raises(SettingsError, match="'robot2' of swarm 'bench', not 'robot3'"):
        RobotConfig.from_sources({"name": "robot3"}, env)


def test_robot_without_credentials_is_told_how_to_give_them() -> None:
    with pytest.raises(SettingsError) as info:
        RobotConfig.from_sources({}, {"ROBOT_NAME": "robot1", "SWARM_SCENARIO": PAPER})
    assert "credentials (or $SWARM_CREDENTIALS_FILE)" in str(info.value)
    assert "swarm up" in str(info.value)


def test_yaml_file_is_the_lowest_layer(tmp_path: Path) -> None:
    files = _credentials(tmp_path, "lab")
    file = tmp_path / "robot.yaml"
    file.write_text(
        f"name: robot1\nscenario: {PAPER}\ntelemetry_rate_hz: 5\nswarm: yard\n"
        f"credentials: {files['robot1']}\n"
    )
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


@pytest.mark.parametrize(
    "connect", ["garbage", "tcp/10.0.0.1", "tcp/10.0.0.1:0", "http/10.0.0.1:80", "tcp/:7447"]
)
def test_an_endpoint_that_cannot_be_one_names_the_field_and_its_variable(
    tmp_path: Path, connect: str
) -> None:
    files = _credentials(tmp_path, "lab")
    env = {
        "ROBOT_NAME": "robot1",
        "SWARM_SCENARIO": PAPER,
        "ZENOH_CONNECT": f"tcp/127.0.0.1:7447, {connect}",
        "SWARM_CREDENTIALS_FILE": str(files["robot1"]),
    }
    with pytest.raises(SettingsError, match=r"connect \(or \$ZENOH_CONNECT\): '"):
        RobotConfig.from_sources({}, env)
    ipv6 = RobotConfig.from_sources({}, {**env, "ZENOH_CONNECT": "tcp/[::1]:7447"})
    assert ipv6.connect == ["tcp/[::1]:7447"]


def test_robot_process_refuses_a_bad_setting_without_traceback(tmp_path: Path) -> None:
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
    assert unknown.returncode == 2 and "credentials" in unknown.stderr
    assert "SWARM_CREDENTIALS_FILE" in unknown.stderr and "Traceback" not in unknown.stderr
    files = write_credential_set(tmp_path, generate_credential_set("lab", ("robot9",)))
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
            "--credentials",
            str(files["robot9"]),
        ],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=60,
    )
    assert unknown.returncode == 2 and "no robot named 'robot9'" in unknown.stderr
