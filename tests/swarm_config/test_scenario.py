import re
from collections.abc import Callable
from pathlib import Path

import pytest
import yaml

from swarm_config.scenario import (
    RUN_SCENARIO_FILE,
    ScenarioError,
    load_rule_base,
    load_scenario,
    parse_scenario,
    snapshot_scenario,
)
from swarm_config.settings import INPUT_FILE_BYTES_MAX, parse_yaml
from tests.fuzz.generate import alias_bomb

ROOT = Path(__file__).resolve().parents[2]
PAPER = ROOT / "configs" / "scenarios" / "paper.yaml"


def _paper_data() -> dict:
    return yaml.safe_load(PAPER.read_text())


def test_paper_scenario_is_the_papers_experiment() -> None:
    scenario = load_scenario(PAPER)
    assert scenario.robot_names == ("robot1", "robot2", "robot3")
    assert scenario.leader_index == 0
    traj = scenario.trajectory
    assert traj.kind == "circle" and traj.radius_m == 1.5 and traj.angular_rate_radps == 0.35
    assert scenario.robot_body.wheel_base_m == 0.25
    assert scenario.robot_body.wheel_radius_m == 0.0508
    assert len(scenario.obstacles) == 1
    params = scenario.controller_params()
    assert params.wheel_radius_m == scenario.robot_body.wheel_radius_m


@pytest.mark.parametrize(
    ("path", "value", "expected"),
    [
        (("robots", 1, "slot", "distance_m"), -1.0, "robots.1.slot.distance_m"),
        (("trajectory", "kind"), "spiral", "trajectory"),
        (("controller", "kp"), [1.0, 2.0], "controller.kp"),
        (("radio", "profile"), "moon", "unknown radio profile"),
        (("sensors", "sonar", "noise_std_m"), "loud", "sensors.sonar.noise_std_m"),
        (("duration_s",), 0, "duration_s"),
        (("robot_body", "wheel_radius"), 0.05, "robot_body.wheel_radius"),
        (("radio", "broadcast_rate_hz"), 1e300, "radio.broadcast_rate_hz (1e+300) is above"),
        (("radio", "broadcast_rate_hz"), 100.5, "above the control rate (100 Hz)"),
        (("duration_s",), 0.005, "duration_s (0.005 s) is shorter than one control period"),
    ],
)
def test_bad_field_is_named_in_the_error(path: tuple, value: object, expected: str) -> None:
    data = _paper_data()
    node = data
    for key in path[:-1]:
        node = node[key] if isinstance(node, list) else node.setdefault(key, {})
    node[path[-1]] = value
    with pytest.raises(ScenarioError) as info:
        parse_scenario(data, "bad.yaml")
    assert expected in str(info.value)
    assert str(info.value).startswith("bad.yaml")


def test_structural_problems_are_explained() -> None:
    data = _paper_data()
    data["robots"][1]["role"] = "leader"
    data["robots"][1].pop("slot")
    with pytest.raises(ScenarioError, match="exactly one robot must be the leader"):
        parse_scenario(data)
    data = _paper_data()
    data["robots"][2]["initial_pose"] = data["robots"][1]["initial_pose"]
    with pytest.raises(ScenarioError, match="start overlapping"):
        parse_scenario(data)
    with pytest.raises(ScenarioError, match="mapping"):
        parse_scenario(["not", "a", "mapping"])


@pytest.mark.parametrize(
    ("change", "named"),
    [
        (lambda d: d["robots"][0]["initial_pose"].update(x_m=1e300), "robot robot1 starts at"),
        (lambda d: d["obstacles"][0].update(position_m=[2147.4, 0.0]), "obstacle 0 reaches"),
        (lambda d: d["trajectory"].update(radius_m=1e6), "the trajectory, with the farthest"),
        (lambda d: d["trajectory"].update(centre_m=[2146.0, 0.0]), "the trajectory, with the"),
        (lambda d: d["robots"][1]["slot"].update(distance_m=3000.0), "the trajectory, with the"),
    ],
)
def test_a_scenario_beyond_the_positioning_receivers_range_is_refused(
    change: Callable[[dict], None], named: str
) -> None:
    # Before, it ran: the batch simulator on the far coordinates, every robot's firmware on a
    # fix saturated at 2147 m.
    data = _paper_data()
    change(data)
    with pytest.raises(ScenarioError, match="beyond the positioning receiver's range") as refused:
        parse_scenario(data)
    assert named in str(refused.value), refused.value


def test_unreadable_and_malformed_files(tmp_path: Path) -> None:
    with pytest.raises(ScenarioError, match="cannot read"):
        load_scenario(tmp_path / "missing.yaml")
    broken = tmp_path / "broken.yaml"
    broken.write_text("name: [unclosed\n")
    with pytest.raises(ScenarioError, match="not valid YAML"):
        load_scenario(broken)


def test_a_key_written_twice_is_refused_naming_it_and_both_lines(tmp_path: Path) -> None:
    """PyYAML keeps the last of two equal keys; a scenario with `duration_s` twice ran the
    second one.  Both the loader and the run's copy refuse it."""
    text = PAPER.read_text(encoding="utf-8")
    first_line = text.splitlines().index("duration_s: 60.0") + 1
    twice = tmp_path / "twice.yaml"
    twice.write_text(text.replace("duration_s: 60.0\n", "duration_s: 60.0\nduration_s: 0.5\n"))
    expected = f"found the key 'duration_s' twice \\(first on line {first_line}\\)"
    with pytest.raises(ScenarioError, match="not valid YAML") as refused:
        load_scenario(twice)
    assert re.search(expected, str(refused.value)), refused.value
    assert f"line {first_line + 1}," in str(refused.value)
    with pytest.raises(ScenarioError, match=expected):
        snapshot_scenario(twice, tmp_path)
    assert not (tmp_path / RUN_SCENARIO_FILE).exists()
    nested = tmp_path / "nested.yaml"
    nested.write_text(text.replace("  radius_m: 1.5\n", "  radius_m: 1.5\n  radius_m: 2.5\n"))
    with pytest.raises(ScenarioError, match="found the key 'radius_m' twice"):
        load_scenario(nested)


def test_aliases_that_expand_beyond_a_million_values_are_refused(tmp_path: Path) -> None:
    """484 bytes of nested aliases as the trajectory's `kind` stand for 10**8 values.  The
    validation error quoted the tag it found: for 10**7 values refusing the file took 13 s and
    wrote 358 MB of error text.  The loader refuses such a file before anything walks it."""
    text = PAPER.read_text(encoding="utf-8")
    bomb = tmp_path / "bomb.yaml"
    bomb.write_text(text.replace("  kind: circle\n", f"  kind: {alias_bomb(8)}\n"), "utf-8")
    with pytest.raises(ScenarioError, match="aliases expand to more than 1,000,000 values") as e:
        load_scenario(bomb)
    assert len(str(e.value)) < 300
    with pytest.raises(yaml.YAMLError, match="alias inside the node it refers to"):
        parse_yaml("a: &a [1, *a]")
    with pytest.raises(yaml.YAMLError, match="alias inside the node it refers to"):
        parse_yaml("a: &a {b: [*a]}")
    # Aliases within the bound still load, shared or merged.
    assert parse_yaml(f"a: {alias_bomb(4)}")["a"][-1] == [[[[[1] * 10] * 10] * 10] * 10] * 10
    assert parse_yaml("x: &x [1]\ny: [*x, *x]") == {"x": [1], "y": [[1], [1]]}


def test_a_refusal_quotes_a_long_value_shortened_and_lists_fifty_problems_at_most() -> None:
    """A 100 kB trajectory `kind` came back as 100 kB of error (pydantic quotes a tag it
    does not know); each problem is now cut in its middle, keeping what names it."""
    data = _paper_data()
    data["trajectory"]["kind"] = "x" * 100_000
    with pytest.raises(ScenarioError) as refused:
        parse_scenario(data)
    line = str(refused.value).splitlines()[-1]
    assert len(line) < 400
    assert line.startswith("  trajectory: Input tag 'xxx")
    assert "[... 99," in line
    assert line.endswith(
        "does not match any of the expected tags: 'circle', 'lemniscate', 'polyline'"
    )
    data = _paper_data()
    for robot in data["robots"]:
        robot["extra"] = 1
    data["robots"] = data["robots"] * 40
    with pytest.raises(ScenarioError, match=r"invalid scenario \(120 problems\)") as refused:
        parse_scenario(data)
    lines = str(refused.value).splitlines()
    assert len(lines) == 1 + 50 + 1
    assert lines[-1] == "  ... and 70 more"


def test_a_campaign_partition_of_every_robot_or_of_one_twice_is_refused() -> None:
    data = _paper_data()
    data["faults"] = [{"at_s": 1.0, "fault": {"fault": "partition", "robots": ["robot1"] * 2}}]
    with pytest.raises(ScenarioError, match="'robot1' is named twice"):
        parse_scenario(data)
    every = ["robot1", "robot2", "robot3"]
    data["faults"] = [{"at_s": 1.0, "fault": {"fault": "partition", "robots": every}}]
    with pytest.raises(ScenarioError, match=r"faults\[0\]: a partition of every robot"):
        parse_scenario(data)
    data["faults"] = [{"at_s": 1.0, "fault": {"fault": "partition", "robots": every[:2]}}]
    assert len(parse_scenario(data).faults) == 1


def test_keys_a_merge_brings_in_are_overridden_not_repeated() -> None:
    data = parse_yaml("base: &b {x: 1, y: 2}\nover:\n  <<: *b\n  x: 5\n")
    assert data == {"base": {"x": 1, "y": 2}, "over": {"x": 5, "y": 2}}
    with pytest.raises(yaml.YAMLError, match="found the key 'a' twice"):
        parse_yaml('{"a": 1, "a": 2}')  # JSON too


def test_a_file_too_large_or_endless_is_refused_before_it_is_read_whole(tmp_path: Path) -> None:
    too_large = tmp_path / "large.yaml"
    with too_large.open("wb") as handle:  # valid YAML: a comment, then one key
        handle.write(b"#" + b" " * INPUT_FILE_BYTES_MAX + b"\nname: x\n")
    with pytest.raises(ScenarioError, match=f"larger than {INPUT_FILE_BYTES_MAX:,} bytes"):
        load_scenario(too_large)
    if Path("/dev/zero").exists():
        with pytest.raises(ScenarioError, match="/dev/zero: scenario file is larger than"):
            load_scenario(Path("/dev/zero"))


def test_fuzzy_parameter_file_resolves_next_to_the_scenario(tmp_path: Path) -> None:
    data = _paper_data()
    data["fuzzy_parameter_file"] = "fuzzy.yaml"
    (tmp_path / "fuzzy.yaml").write_text(
        "error_centres: [-1.0, 0.0, 1.0]\nrate_centres: [-1.0, -0.2, 0.2, 1.0]\n"
    )
    scenario_file = tmp_path / "s.yaml"
    scenario_file.write_text(yaml.safe_dump(data))
    rule_base = load_rule_base(load_scenario(scenario_file))
    assert int(rule_base.rule_count) == 12
    (tmp_path / "fuzzy.yaml").write_text("error_centres: [1.0, 0.0]\nrate_centres: [-1, 1]\n")
    with pytest.raises(ScenarioError, match="error_centres"):
        load_rule_base(load_scenario(scenario_file))


@pytest.mark.parametrize("path", sorted((ROOT / "configs" / "scenarios").glob("*.yaml")))
def test_every_shipped_scenario_loads(path: Path) -> None:
    scenario = load_scenario(path)
    assert scenario.name == path.stem
    assert len(scenario.robot_names) >= 1


def test_a_run_copies_its_scenario_byte_for_byte(tmp_path: Path) -> None:
    copy = snapshot_scenario(PAPER, tmp_path / "run")
    assert copy == tmp_path / "run" / "scenario.yaml"
    assert copy.read_bytes() == PAPER.read_bytes()  # comments and all
    assert load_scenario(copy) == load_scenario(PAPER)


def test_a_run_copies_the_fuzzy_parameter_file_its_scenario_names(tmp_path: Path) -> None:
    data = _paper_data()
    data["fuzzy_parameter_file"] = "../fuzzy/mine.yaml"
    (tmp_path / "fuzzy").mkdir()
    fuzzy = tmp_path / "fuzzy" / "mine.yaml"
    fuzzy.write_text("error_centres: [-1.0, 0.0, 1.0]\nrate_centres: [-1.0, -0.2, 0.2, 1.0]\n")
    (tmp_path / "scenarios").mkdir()
    source = tmp_path / "scenarios" / "s.yaml"
    source.write_text(yaml.safe_dump(data))
    copy = snapshot_scenario(source, tmp_path / "run")
    fuzzy.write_text("error_centres: [1.0, 0.0]\nrate_centres: [-1, 1]\n")  # edited afterwards
    source.unlink()
    run = load_scenario(copy)
    assert run.fuzzy_parameter_file == tmp_path / "run" / "fuzzy_parameters.yaml"
    assert int(load_rule_base(run).rule_count) == 12  # the file as it was at the start
    assert run.model_copy(update={"fuzzy_parameter_file": None}) == parse_scenario(
        {**data, "fuzzy_parameter_file": None}
    )


def test_a_scenario_whose_fuzzy_parameter_file_is_missing_is_not_copied(tmp_path: Path) -> None:
    data = _paper_data()
    data["fuzzy_parameter_file"] = "nowhere.yaml"
    source = tmp_path / "s.yaml"
    source.write_text(yaml.safe_dump(data))
    with pytest.raises(ScenarioError, match="fuzzy_parameter_file"):
        snapshot_scenario(source, tmp_path / "run")
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize(
    "path",
    [
        ("radio", "broadcast_rate_hz"),
        ("sensors", "sonar", "rate_hz"),
        ("sensors", "positioning", "rate_hz"),
    ],
)
@pytest.mark.parametrize("rate_hz", [1e-17, 1e-300, 0.0099])
def test_a_rate_below_one_per_100_s_is_refused_naming_the_field(
    path: tuple[str, ...], rate_hz: float
) -> None:
    # Before, it passed (> 0), and `swarm sim` / `swarm tune` crashed with an OverflowError
    # on its period in ticks.
    data = _paper_data()
    node = data
    for key in path[:-1]:
        node = node.setdefault(key, {})
    node[path[-1]] = rate_hz
    with pytest.raises(ScenarioError) as refused:
        parse_scenario(data, "slow.yaml")
    assert f"{'.'.join(path)}: Input should be greater than or equal to 0.01" in str(refused.value)
    node[path[-1]] = 0.01  # the slowest allowed
    assert parse_scenario(data, "slow.yaml")


@pytest.mark.parametrize(
    ("change", "named"),
    [
        (lambda d: d.update(seed=True), "seed: a number, not true"),
        (lambda d: d.update(duration_s=True), "duration_s: a number, not true"),
        (lambda d: d["trajectory"].update(centre_m=[False, 0.0]), "trajectory.centre_m.0: "),
        (lambda d: d["robots"][1]["slot"].update(angle_deg=True), "robots.1.slot.angle_deg: "),
        (lambda d: d.update(controller={"kp": [4.0, True, 4.0]}), "controller.kp.1: a number"),
        (lambda d: d.update(sensors={"sonar": {"rate_hz": True}}), "sensors.sonar.rate_hz: "),
        (
            lambda d: d.update(faults=[{"at_s": True, "fault": {"fault": "heal"}}]),
            "faults.0.at_s: a number, not true",
        ),
    ],
)
def test_a_boolean_given_for_a_number_is_refused_naming_the_field(
    change: Callable[[dict], None], named: str
) -> None:
    # Before, pydantic took true for 1 and false for 0: `seed: true` ran seed 1 and
    # `duration_s: true` a 1 s run, without a word.
    data = _paper_data()
    change(data)
    with pytest.raises(ScenarioError) as refused:
        parse_scenario(data, "bool.yaml")
    assert str(refused.value).startswith("bool.yaml: invalid scenario (1 problem):")
    assert named in str(refused.value), refused.value


def test_a_boolean_field_still_takes_a_boolean_and_a_fuzzy_file_refuses_one_for_a_centre(
    tmp_path: Path,
) -> None:
    data = _paper_data()
    data["trajectory"] = {"kind": "polyline", "waypoints_m": [[0, 0], [1, 0]], "closed": False}
    assert parse_scenario(data).trajectory.closed is False  # type: ignore[union-attr]
    fuzzy = tmp_path / "fuzzy.yaml"
    fuzzy.write_text("error_centres: [false, true]\nrate_centres: [-1.0, 1.0]\n")
    scenario = tmp_path / "scenario.yaml"
    scenario.write_text(PAPER.read_text() + "\nfuzzy_parameter_file: fuzzy.yaml\n")
    with pytest.raises(ScenarioError, match=r"error_centres\.0: a number, not false"):
        load_rule_base(load_scenario(scenario))


@pytest.mark.parametrize("name", ["world", "router", "launcher", "dashboard", "operator"])
def test_a_robot_named_as_a_service_of_the_run_is_refused_naming_the_field(name: str) -> None:
    # Before, `swarm sim` ran it and `swarm credentials` refused it naming neither the robot
    # nor the field.
    data = _paper_data()
    data["robots"][1]["name"] = name
    with pytest.raises(ScenarioError) as info:
        parse_scenario(data, "bad.yaml")
    assert f"  robots.1.name: {name!r} is reserved for a service of the run" in str(info.value)
    data["robots"][1]["name"] = f"{name}2"  # only the name itself is taken
    assert parse_scenario(data, "good.yaml").robot_names[1] == f"{name}2"
