"""A swarm across two hosts, each with its own Zenoh router (docs/multi-host.md), on one machine.

The test makes two network namespaces, "hosts" A and B, joined by a veth pair with the
addresses it gives (10.211.X.Y+1 and +2 on a /30 of its own, from the test's pid); each host has
only its loopback and its end of the pair, so the swarm's traffic goes only to those addresses.
Host A runs the world's side (`swarm up --listen tls/A:7448 --only robot1,robot2`: a router
that takes other hosts' routers on TLS, the world, robot1 and robot2), host B the rest
(`swarm up --connect tls/A:7448 --only robot3`: a router linked to A's, and robot3), both with
copies of one credentials set.  The namespaces are removed in a `finally`, whatever happens.

* In lockstep the paper scenario run across the hosts writes the same summary.json, byte for
  byte, as the same scenario run on host A alone (both runs shortened to
  `LOCKSTEP_DURATION_S`), and the test prints both side by side.
* In real time, once the formation flies, the veth link is cut for `CUT_S` and restored.  The
  world is the reference clock and goes on; to it robot3 is a robot with its power cut (DESIGN.md
  §7): its body is braked and stays where it stopped, its token goes with the link's lease, the
  others fly on without a collision and robot1 keeps leading; to robot3 the world is gone:
  its motors go off within `MOTORS_OFF_WITHIN_S` and it safe-stops.  After the restore robot3
  rejoins and the formation is back under 5 cm, to stay, within `FORMATION_BACK_WITHIN_S` of
  simulated time; the figures are printed.

What the test's own clients see they see from inside the hosts: an observer process per
namespace (this module run as `python -m tests.integration.test_multi_host observe`) logs in as
the operator and prints JSON lines with the monotonic time, which all namespaces share.

The network tests need root (`ip netns`, `ip link`); they skip, saying so, only when not root.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import queue
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager, suppress
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import pytest

from swarm_config.scenario import CircleSpec, load_scenario
from tests.support.waiting import wait_for

ROOT = Path(__file__).resolve().parents[2]
PAPER = ROOT / "configs" / "scenarios" / "paper.yaml"
SWARM = "lab"

LOCAL_PORT = 7447
"""Each host's router for the host's own processes, on the host's loopback."""
LINK_PORT = 7448
"""Where host A's router takes the other hosts' routers, on A's veth address (TLS)."""
LOCKSTEP_DURATION_S = 30.0
"""The paper scenario's length in both lockstep runs (the paper's is 60 s)."""
CUT_S = 2.0
FORMATION_BOUND_M = 0.05
FORMATION_BACK_WITHIN_S = 10.0
"""Simulated seconds from the restore of the link until the formation is under 5 cm and stays
there (for `STAYS_UNDER_S`, DESIGN.md §8's rejoin time)."""
STAYS_UNDER_S = 2.0
STEADY_FLIGHT_S = 15.0
MOTORS_OFF_WITHIN_S = 0.2
"""From the last sense message robot3 had before the cut until its act messages show its motors
off (its sense time-out, 100 ms, plus a control period and the time the message takes)."""
STANDS_STILL_M = 0.01
"""How far robot3's braked body may move from when the world counts it out (its token gone with
the link's lease, about a second after the cut) to the restore.  Before that the world held its
time for robot3 (the starvation guard, up to half a second), then braked it: a body at the
formation's speed coasts about 2 cm while its motors spin down."""
WORLD_GOES_ON_S = 0.5
"""Simulated time the world must run during the cut: the world may hold its time for a robot
that stops answering, but only until its token goes (about one lease)."""
LEASE_S = 1.0
"""The routers' lease on links between hosts (services/router/access.py)."""
ROBOTS = ("robot1", "robot2", "robot3")
FOLLOWERS = ("robot2", "robot3")
HOST_A_ROBOTS = ("robot1", "robot2")
HOST_B_ROBOTS = ("robot3",)


# -- the two hosts --------------------------------------------------------------------------


@dataclass(frozen=True)
class Host:
    """One network namespace: its name, its veth end and the address the test gave it."""

    namespace: str
    veth: str
    address: str

    def command(self, *argv: str) -> list[str]:
        """`argv` run inside this host."""
        return ["ip", "netns", "exec", self.namespace, *argv]

    def swarm(self, *args: str) -> list[str]:
        return self.command(sys.executable, "-m", "services.cli.main", *args)


@dataclass(frozen=True)
class TwoHosts:
    a: Host
    b: Host

    @property
    def link_endpoint(self) -> str:
        """Host A's router, as host B's router reaches it."""
        return f"tls/{self.a.address}:{LINK_PORT}"

    def set_link(self, up: bool) -> None:
        _ip("-n", self.a.namespace, "link", "set", self.a.veth, "up" if up else "down")


def _ip(*args: str) -> None:
    result = subprocess.run(["ip", *args], capture_output=True, text=True, timeout=30)
    assert result.returncode == 0, f"ip {' '.join(args)}: {result.stderr.strip()}"


def _subnet_of(pid: int) -> tuple[str, str]:
    """Two addresses of a /30 of 10.211.0.0/16 that only this pid uses."""
    slot = pid % (1 << 14)
    base = f"10.211.{slot >> 6}"
    low = (slot & 0x3F) * 4
    return f"{base}.{low + 1}", f"{base}.{low + 2}"


def _end_processes_in(namespace: str) -> None:
    """SIGKILL whatever still runs inside `namespace` (processes this test started there)."""
    listed = subprocess.run(
        ["ip", "netns", "pids", namespace], capture_output=True, text=True, timeout=30
    )
    for pid in listed.stdout.split():
        with suppress(ProcessLookupError, ValueError):
            os.kill(int(pid), signal.SIGKILL)


@contextmanager
def two_hosts() -> Iterator[TwoHosts]:
    """Namespaces A and B with a veth pair between them; both removed on the way out."""
    pid = os.getpid()
    address_a, address_b = _subnet_of(pid)
    a = Host(f"swarm-mh-{pid}-a", f"smh{pid}a", address_a)
    b = Host(f"swarm-mh-{pid}-b", f"smh{pid}b", address_b)
    made: list[str] = []
    try:
        for host in (a, b):
            _ip("netns", "add", host.namespace)
            made.append(host.namespace)
        _ip("link", "add", a.veth, "type", "veth", "peer", "name", b.veth)
        for host in (a, b):
            _ip("link", "set", host.veth, "netns", host.namespace)
            _ip("-n", host.namespace, "addr", "add", f"{host.address}/30", "dev", host.veth)
            _ip("-n", host.namespace, "link", "set", "lo", "up")
            _ip("-n", host.namespace, "link", "set", host.veth, "up")
        yield TwoHosts(a, b)
    finally:
        for namespace in made:
            _end_processes_in(namespace)
        for namespace in made:
            subprocess.run(["ip", "netns", "del", namespace], capture_output=True, timeout=30)
        # A veth pair goes with its namespace; one never moved into it is still here.
        subprocess.run(["ip", "link", "del", a.veth], capture_output=True, timeout=30)


@pytest.fixture
def hosts() -> Iterator[TwoHosts]:
    if os.geteuid() != 0:
        pytest.skip("needs root: makes two network namespaces and a veth pair (ip netns, ip link)")
    with two_hosts() as made:
        yield made


# -- processes inside the hosts -------------------------------------------------------------


def _pump(stream: IO[str], into: list[str], lock: threading.Lock) -> threading.Thread:
    """Keep every line of `stream` (on a thread of its own, so a pipe never fills)."""

    def pump() -> None:
        with suppress(ValueError):
            for line in stream:
                with lock:
                    into.append(line)

    thread = threading.Thread(target=pump, name="multi-host-output", daemon=True)
    thread.start()
    return thread


@dataclass
class Running:
    """A process inside a host and every line it printed."""

    process: subprocess.Popen[str]
    lines: list[str] = field(default_factory=list)
    lock: threading.Lock = field(default_factory=threading.Lock)
    reader: threading.Thread | None = None

    @classmethod
    def start(cls, argv: Sequence[str], env: dict[str, str] | None = None) -> Running:
        process = subprocess.Popen(
            list(argv),
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            cwd=ROOT,
            env={**os.environ, "PYTHONUNBUFFERED": "1", **(env or {})},
        )
        running = cls(process)
        assert process.stdout is not None
        running.reader = _pump(process.stdout, running.lines, running.lock)
        return running

    def output(self) -> str:
        with self.lock:
            return "".join(self.lines)

    def records(self) -> list[dict[str, Any]]:
        """The JSON lines printed so far (an observer's)."""
        with self.lock:
            lines = list(self.lines)
        return [json.loads(line) for line in lines if line.startswith("{")]

    def wait_ready(self, timeout_s: float = 90.0) -> None:
        """Until `swarm up` says it started its processes (its line `swarm NAME: ...`)."""
        wait_for(
            lambda: (
                any(line.startswith("swarm ") for line in list(self.lines))
                or self.process.poll() is not None
            ),
            timeout_s=timeout_s,
            describe="swarm up's start",
        )
        assert self.process.poll() is None, self.output()

    def stop(self, timeout_s: float = 60.0) -> int:
        """Ctrl-C, as a user would; SIGKILL if it does not end in `timeout_s`."""
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGINT)
        try:
            code = self.process.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            self.process.kill()
            code = self.process.wait()
        if self.reader is not None:
            self.reader.join(timeout=10.0)  # the rest of the output, up to the pipe's end
        assert self.process.stdout is not None
        self.process.stdout.close()
        return code


def _credentials_for_both(tmp_path: Path, hosts: TwoHosts) -> tuple[Path, Path]:
    """One run's credentials, with a router certificate for host A's address, and host B's
    copy of them (as one would copy the directory to another machine)."""
    on_a = tmp_path / "credentials-a"
    made = subprocess.run(
        [sys.executable, "-m", "services.cli.main", "credentials", str(on_a), "--scenario"]
        + [str(PAPER), "--tls", "--tls-host", hosts.a.address],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=60,
    )
    assert made.returncode == 0, made.stderr
    on_b = tmp_path / "credentials-b"
    shutil.copytree(on_a, on_b)
    return on_a, on_b


def _start_host_b(hosts: TwoHosts, credentials: Path, out: Path) -> Running:
    return Running.start(
        hosts.b.swarm(
            "up", "--out", str(out), "--credentials", str(credentials), "--port", str(LOCAL_PORT),
            "--connect", hosts.link_endpoint, "--only", ",".join(HOST_B_ROBOTS),
        )
    )  # fmt: skip


def _host_a_args(hosts: TwoHosts, credentials: Path, out: Path) -> list[str]:
    return [
        "up", "--out", str(out), "--credentials", str(credentials), "--port", str(LOCAL_PORT),
        "--listen", hosts.link_endpoint, "--only", ",".join(HOST_A_ROBOTS), "--no-dashboard",
    ]  # fmt: skip


def _observer(host: Host, credentials: Path, *what: str) -> Running:
    return Running.start(
        host.command(
            sys.executable, "-m", "tests.integration.test_multi_host", "observe",
            "--connect", f"tcp/127.0.0.1:{LOCAL_PORT}", *what,
        ),
        env={"SWARM_CREDENTIALS_FILE": str(credentials / "operator.json")},
    )  # fmt: skip


# -- lockstep: the same run on one host and on two ------------------------------------------


def _scalars(value: object, prefix: str = "") -> dict[str, object]:
    """Every number, string, boolean and null of a JSON document, by its dotted path."""
    if isinstance(value, dict):
        return {
            path: leaf
            for key, item in value.items()
            for path, leaf in _scalars(item, f"{prefix}{key}.").items()
        }
    if isinstance(value, list):
        return {
            path: leaf
            for i, item in enumerate(value)
            for path, leaf in _scalars(item, f"{prefix}{i}.").items()
        }
    return {prefix.rstrip("."): value}


def _side_by_side(one: dict[str, Any], two: dict[str, Any]) -> str:
    """Every value of both summaries, one row each, the rows that differ marked with `!`;
    counters that are 0 (or null) in both are counted, not listed."""
    left, right = _scalars(one), _scalars(two)
    paths = sorted(set(left) | set(right))
    empty = [p for p in paths if left.get(p) in (0, None) and right.get(p) in (0, None)]
    shown = [p for p in paths if p not in empty]
    width = max(map(len, shown))
    rows = [f"  {'summary.json':<{width}}  {'one host (A)':>20}  {'two hosts (A + B)':>20}"]
    for path in shown:
        a, b = json.dumps(left.get(path)), json.dumps(right.get(path))
        rows.append(f"{'  ' if a == b else '! '}{path:<{width}}  {a:>20}  {b:>20}")
    rows.append(f"  and {len(empty)} counters and fields that are 0 or null in both")
    return "\n".join(rows)


def test_lockstep_across_two_hosts_writes_the_one_host_summary_byte_for_byte(
    hosts: TwoHosts, tmp_path: Path
) -> None:
    duration = str(LOCKSTEP_DURATION_S)
    lockstep = ("--lockstep", "--duration", duration)
    one_host = tmp_path / "one-host"
    started_s = time.monotonic()
    alone = subprocess.run(
        hosts.a.swarm("up", "--out", str(one_host), "--no-dashboard", *lockstep),
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=600,
    )
    one_host_wall_s = time.monotonic() - started_s
    assert alone.returncode == 0, alone.stdout + alone.stderr

    credentials_a, credentials_b = _credentials_for_both(tmp_path, hosts)
    out_a, out_b = tmp_path / "host-a", tmp_path / "host-b"
    host_b = _start_host_b(hosts, credentials_b, out_b)
    try:
        host_b.wait_ready()
        started_s = time.monotonic()
        host_a = subprocess.run(
            hosts.a.swarm(*_host_a_args(hosts, credentials_a, out_a), *lockstep),
            capture_output=True,
            text=True,
            cwd=ROOT,
            timeout=600,
        )
        two_hosts_wall_s = time.monotonic() - started_s
    finally:
        host_b_code = host_b.stop()
    assert host_a.returncode == 0, host_a.stdout + host_a.stderr
    assert host_b_code == 0, host_b.output()

    one = (one_host / "summary.json").read_bytes()
    two = (out_a / "summary.json").read_bytes()
    print(
        f"\nlockstep, paper scenario, {duration} s: one host {one_host_wall_s:.1f} s of wall "
        f"time, two hosts {two_hosts_wall_s:.1f} s (robot3 on host B, over TLS)\n"
        + _side_by_side(json.loads(one), json.loads(two))
        + f"\nsha256 one host  {hashlib.sha256(one).hexdigest()}"
        f"\nsha256 two hosts {hashlib.sha256(two).hexdigest()}"
    )
    # The run was split as asked: robot3 ran on host B only, the world on host A only.
    assert (out_b / "logs" / "robot3.log").exists() and not (out_a / "logs" / "robot3.log").exists()
    assert not (out_b / "logs" / "world.log").exists() and not (out_b / "summary.json").exists()
    assert "robot robot3 up" in (out_b / "logs" / "robot3.log").read_text()
    assert one == two


# -- real time: the link between the hosts cut for 2 s --------------------------------------


def _at(records: Sequence[dict[str, Any]], kind: str) -> list[dict[str, Any]]:
    return [r for r in records if r["kind"] == kind]


def _latest_status(observer: Running) -> dict[str, Any] | None:
    statuses = _at(observer.records(), "status")
    return statuses[-1] if statuses else None


def _formation_error_m(status: dict[str, Any] | None) -> float | None:
    if status is None or set(status["live"]) != set(ROBOTS):
        return None
    return max(status["errors_m"][name] for name in FOLLOWERS)


def _displacement_m(poses: Sequence[Sequence[float]]) -> float:
    x0, y0 = poses[0][0], poses[0][1]
    return max(((p[0] - x0) ** 2 + (p[1] - y0) ** 2) ** 0.5 for p in poses)


def test_a_link_cut_between_hosts_brakes_the_far_robot_and_the_formation_recovers(
    hosts: TwoHosts, tmp_path: Path
) -> None:
    credentials_a, credentials_b = _credentials_for_both(tmp_path, hosts)
    out_a, out_b = tmp_path / "host-a", tmp_path / "host-b"
    host_b = _start_host_b(hosts, credentials_b, out_b)
    host_a = Running.start(hosts.a.swarm(*_host_a_args(hosts, credentials_a, out_a)))
    watch_a = _observer(hosts.a, credentials_a, "--status", "--truth")
    watch_b = _observer(hosts.b, credentials_b, "--robot", "robot3")
    try:
        host_b.wait_ready()
        host_a.wait_ready()
        flying = wait_for(
            lambda: (
                (s := _latest_status(watch_a)) is not None
                and s["t_s"] >= STEADY_FLIGHT_S
                and (e := _formation_error_m(s)) is not None
                and e < FORMATION_BOUND_M
                and s
            ),
            timeout_s=180.0,
            every_s=0.2,
            describe="the formation under 5 cm across both hosts",
        )
        cut_at_s = time.monotonic()
        hosts.set_link(up=False)
        time.sleep(CUT_S)
        hosts.set_link(up=True)
        restored_at_s = time.monotonic()
        back: dict[str, Any] = {}

        def formation_back() -> bool:
            """Whether the formation has stayed under 5 cm for `STAYS_UNDER_S` since a status
            after the restore (every status seen, not only the newest, counts)."""
            after = [s for s in _at(watch_a.records(), "status") if s["wall_s"] > restored_at_s]
            under: list[dict[str, Any]] = []
            for status in after:
                error = _formation_error_m(status)
                under = under + [status] if error is not None and error < FORMATION_BOUND_M else []
            if not under or under[-1]["t_s"] - under[0]["t_s"] < STAYS_UNDER_S:
                return False
            back.update(under[0])
            return True

        wait_for(
            formation_back,
            timeout_s=120.0,
            every_s=0.2,
            describe="the formation under 5 cm (and staying there) after the link came back",
        )
        stopped_at_s = time.monotonic()
    finally:
        codes = {"host A": host_a.stop(), "host B": host_b.stop()}
        watch_a.stop(timeout_s=10.0)
        watch_b.stop(timeout_s=10.0)
    assert codes == {"host A": 0, "host B": 0}, host_a.output()[-3000:] + host_b.output()[-3000:]

    seen_a, seen_b = watch_a.records(), watch_b.records()
    statuses = _at(seen_a, "status")
    during = [s for s in statuses if cut_at_s < s["wall_s"] < restored_at_s]
    before = [s for s in statuses if s["wall_s"] <= cut_at_s]
    left_s = next((s["wall_s"] - cut_at_s for s in during if "robot3" not in s["live"]), None)
    out_at_s = cut_at_s + (left_s if left_s is not None else CUT_S)
    truths = [t for t in _at(seen_a, "truth") if out_at_s < t["wall_s"] < restored_at_s]
    own_acts = [a for a in _at(seen_b, "act") if cut_at_s < a["wall_s"] < restored_at_s]
    own_telemetry = [t for t in _at(seen_b, "telemetry") if cut_at_s < t["wall_s"] < restored_at_s]
    last_sense_s = max(
        (t["wall_s"] for t in _at(seen_b, "sense") if t["wall_s"] < restored_at_s), default=None
    )
    first_off_at_s = next((a["wall_s"] for a in own_acts if a["off"]), None)
    first_off_s = (
        None if first_off_at_s is None or last_sense_s is None else first_off_at_s - last_sense_s
    )
    rejoined = next(
        (s for s in statuses if s["wall_s"] > restored_at_s and set(s["live"]) == set(ROBOTS)),
        None,
    )
    cut_sim_s = (during[-1]["t_s"] - before[-1]["t_s"]) if during and before else 0.0
    robot3_moved_m = _displacement_m([t["poses"]["robot3"] for t in truths]) if truths else None
    robot1_moved_m = _displacement_m([t["poses"]["robot1"] for t in truths]) if truths else None
    truth_span_s = truths[-1]["t_s"] - truths[0]["t_s"] if truths else 0.0
    restored_sim_s = next(s["t_s"] for s in statuses if s["wall_s"] > restored_at_s)
    # How far the cut threw robot3 from its slot (the world's own metric, DESIGN.md §8).
    peak_error_m = max(
        s["errors_m"]["robot3"] for s in statuses if cut_at_s < s["wall_s"] <= back["wall_s"]
    )
    summary = json.loads((out_a / "summary.json").read_text())
    # Ctrl-C stops host A's robots before its world: what the world records after that is the
    # shutdown's, not the cut's.
    last_sim_s = max(s["t_s"] for s in statuses if s["wall_s"] < stopped_at_s)
    leader_changes = [e for e in summary["events"] if e["t_s"] <= last_sim_s]

    def ms(seconds: float | None) -> str:
        return "never" if seconds is None else f"{seconds * 1000:.0f} ms"

    figures = {
        "formation before the cut": f"{(_formation_error_m(flying) or 0) * 100:.1f} cm at "
        f"t = {flying['t_s']:.1f} s",
        "simulated time during the cut": f"{cut_sim_s:.2f} s (the world's clock went on)",
        "robot3's motors off after": f"{ms(first_off_s)} from its last sense message "
        f"({ms(None if first_off_at_s is None else first_off_at_s - cut_at_s)} from the cut; its "
        "own act messages on host B)",
        "robot3 safe-stopped": str(any(t["safe_stopped"] for t in own_telemetry)),
        "robot3 out of the live set after": ms(left_s),
        "braked robot3 moved": f"{(robot3_moved_m or 0) * 100:.2f} cm; robot1 "
        f"{robot1_moved_m or 0:.2f} m in the {truth_span_s:.2f} s simulated from when the "
        "world counted robot3 out to the restore",
        "robot3 live again after the restore": ms(
            None if rejoined is None else rejoined["wall_s"] - restored_at_s
        ),
        "robot3 farthest from its slot": f"{peak_error_m * 100:.1f} cm",
        "formation under 5 cm after the restore": f"{back['t_s'] - restored_sim_s:.2f} s "
        f"simulated, and stayed under for {STAYS_UNDER_S:.0f} s (max follower error then "
        f"{(_formation_error_m(back) or 0) * 100:.1f} cm)",
        "collisions; leader changes": f"{summary['collisions']}; {leader_changes}",
    }
    print(
        f"\nreal time across two hosts, link cut for {CUT_S:.0f} s:\n"
        + "\n".join(f"  {what:<40} {value}" for what, value in figures.items())
    )
    # The world is the clock: it went on while robot3 was cut off.
    assert cut_sim_s >= WORLD_GOES_ON_S
    # To the world, robot3 is a robot with its power cut: braked where it stopped (checked
    # last, below), and gone with its token after the link's lease; the others fly on.
    assert robot3_moved_m is not None
    trajectory = load_scenario(PAPER).trajectory
    assert isinstance(trajectory, CircleSpec)  # the paper's circle
    reference_speed_mps = trajectory.radius_m * abs(trajectory.angular_rate_radps)
    assert robot1_moved_m is not None and truth_span_s > 0.0
    assert robot1_moved_m > 0.5 * reference_speed_mps * truth_span_s  # the leader flies on
    assert left_s is not None and left_s <= LEASE_S + 1.0
    # To robot3 the world is gone: motors off, a safe stop.
    assert first_off_s is not None and first_off_s <= MOTORS_OFF_WITHIN_S
    assert first_off_at_s is not None
    assert all(a["off"] for a in own_acts if a["wall_s"] >= first_off_at_s)
    assert any(t["safe_stopped"] for t in own_telemetry)
    # After the restore it rejoins and the formation recovers; robot1 led all along.
    assert rejoined is not None
    assert peak_error_m > FORMATION_BOUND_M  # the cut did throw the formation out
    assert back["t_s"] - restored_sim_s <= FORMATION_BACK_WITHIN_S
    assert summary["collisions"] == 0
    assert leader_changes == []
    assert robot3_moved_m < STANDS_STILL_M


# -- the router configs of a swarm over hosts, without a network ----------------------------


@pytest.fixture(scope="module")
def run_credentials(tmp_path_factory: pytest.TempPathFactory) -> tuple[Any, Any]:
    """A credentials set of the paper's robots and TLS files for host address 10.211.0.1."""
    from swarm_config.credentials import generate_credential_set
    from swarm_config.tls import generate_tls_files

    directory = tmp_path_factory.mktemp("run-credentials")
    tls = generate_tls_files(directory / "tls", SWARM, ["10.211.0.1"])
    return generate_credential_set(SWARM, ROBOTS), tls


def _configs(run_credentials: tuple[Any, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
    """The router configs `swarm up` writes for the world's host and for another host."""
    from services.router.access import router_config_document

    credentials, tls = run_credentials
    users = Path("router-users.txt")
    local = f"tcp/127.0.0.1:{LOCAL_PORT}"
    link = f"tls/10.211.0.1:{LINK_PORT}"
    world_host = router_config_document(credentials, users, [local, link], tls, accept_routers=True)
    other_host = router_config_document(credentials, users, [local], tls, connect=[link])
    return world_host, other_host


def _policy_rules(document: dict[str, Any], subject: str) -> list[dict[str, Any]]:
    control = document["access_control"]
    rule_ids = {
        rule_id
        for policy in control["policies"]
        if subject in policy["subjects"]
        for rule_id in policy["rules"]
    }
    return [rule for rule in control["rules"] if rule["id"] in rule_ids]


def _allowed(rules: list[dict[str, Any]]) -> set[tuple[str, str, str]]:
    return {
        (message, flow, key)
        for rule in rules
        for message in rule["messages"]
        for flow in rule["flows"]
        for key in rule["key_exprs"]
    }


def test_the_world_host_lets_a_linked_router_do_what_the_robots_may_and_no_more(
    run_credentials: tuple[Any, Any],
) -> None:
    from robot_firmware.net.keys import SwarmKeys
    from services.router.access import access_control

    world_host, _ = _configs(run_credentials)
    linked = _allowed(_policy_rules(world_host, "router"))
    robots = set().union(*(_allowed(_policy_rules(world_host, name)) for name in ROBOTS))
    assert linked == robots
    keys = SwarmKeys(SWARM)
    for theirs in (keys.sense("robot3"), keys.clock, keys.truth, keys.radio_rx("robot1")):
        assert ("put", "ingress", theirs) not in linked  # the world's, never a robot's
    assert not any(key.startswith(keys.alive("launcher", "")) for _, _, key in linked)
    assert ("query", "ingress", keys.everything_under("admin")) not in linked
    # On one host the router identity may do nothing.
    alone = access_control(SWARM, ROBOTS)
    assert not [p for p in alone["policies"] if "router" in p["subjects"]]


def test_another_host_knows_the_world_hosts_router_by_its_certificate(
    run_credentials: tuple[Any, Any],
) -> None:
    world_host, other_host = _configs(run_credentials)
    hub = [s for s in other_host["access_control"]["subjects"] if s["id"] == "hub"]
    assert hub == [{"id": "hub", "cert_common_names": [f"swarm {SWARM} router"]}]
    assert _policy_rules(other_host, "hub")
    assert not [s for s in world_host["access_control"]["subjects"] if s["id"] == "hub"]
    assert other_host["connect"]["endpoints"] == [f"tls/10.211.0.1:{LINK_PORT}"]
    assert "connect" not in world_host
    # The clients' identities and rules are the same on every host.
    for name in (*ROBOTS, "world", "operator"):
        assert _policy_rules(world_host, name) == _policy_rules(other_host, name)


@pytest.mark.parametrize(
    ("shipped", "role"),
    [("router-world-host.json5", "world host"), ("router-other-host.json5", "other host")],
)
def test_the_shipped_multi_host_router_configs_match_what_swarm_up_writes(
    run_credentials: tuple[Any, Any], shipped: str, role: str
) -> None:
    import zenoh

    world_host, other_host = _configs(run_credentials)
    written = zenoh.Config.from_json5(
        json.dumps(world_host if role == "world host" else other_host)
    )
    example = zenoh.Config.from_file(str(ROOT / "configs" / "zenoh" / shipped))
    for key in (
        "mode",
        "connect/timeout_ms",
        "connect/exit_on_failure",
        "connect/retry",
        "scouting/multicast/enabled",
        "scouting/gossip/enabled",
        "transport/link/tx/lease",
        "transport/auth/usrpwd/user",
    ):
        assert example.get_json(key) == written.get_json(key), key
    protocols = [
        [endpoint.split("/", 1)[0] for endpoint in json.loads(config.get_json(key))]
        for config in (example, written)
        for key in ("listen/endpoints", "connect/endpoints")
    ]
    assert protocols[:2] == protocols[2:]


def test_each_host_starts_only_its_part_and_leaves_the_shared_credentials_as_they_are(
    tmp_path: Path,
) -> None:
    from services.launcher.launcher import Launcher, LaunchPlan
    from swarm_config.credentials import read_credential_set
    from tests.support.stand_in_processes import StandInFactory

    credentials = tmp_path / "credentials"
    made = subprocess.run(
        [sys.executable, "-m", "services.cli.main", "credentials", str(credentials)]
        + ["--tls", "--tls-host", "10.211.0.1"],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=60,
    )
    assert made.returncode == 0, made.stderr
    before = {path.name: path.read_bytes() for path in credentials.rglob("*") if path.is_file()}
    run_id = read_credential_set(credentials, ROBOTS).run_id
    link = f"tls/10.211.0.1:{LINK_PORT}"
    parts = {
        "world host": LaunchPlan(
            PAPER, ROBOTS, tmp_path / "a", dashboard=True, credentials_dir=credentials,
            only=HOST_A_ROBOTS, link_listen=[link],
        ),
        "other host": LaunchPlan(
            PAPER, ROBOTS, tmp_path / "b", dashboard=True, credentials_dir=credentials,
            only=HOST_B_ROBOTS, link_connect=[link],
        ),
    }  # fmt: skip
    launchers = {role: Launcher(plan, factory=StandInFactory()) for role, plan in parts.items()}  # type: ignore[arg-type]
    assert set(launchers["world host"].children) == {"router", "world", "dashboard", *HOST_A_ROBOTS}
    assert set(launchers["other host"].children) == {"router", *HOST_B_ROBOTS}
    for role, launcher in launchers.items():
        router = launcher.children["router"].argv
        config = launcher.plan.out_dir / "router.json5"
        assert router[router.index("--config") + 1] == str(config), role
        assert config.stat().st_mode & 0o077 == 0, role  # it holds the router's password
        for name in launcher.plan.started_robots:
            assert launcher._env(name)["SWARM_CREDENTIALS_FILE"] == str(
                credentials / f"{name}.json"
            )
    # With no world here, nothing ends the run but Ctrl-C.
    assert launchers["other host"].supervise_world() is None
    # The set every host has a copy of is the run's: same run id, not a byte changed.
    after = {path.name: path.read_bytes() for path in credentials.rglob("*") if path.is_file()}
    assert after == before
    assert read_credential_set(credentials, ROBOTS).run_id == run_id


# -- refusals, without a network ------------------------------------------------------------


def _swarm_up(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "services.cli.main", "up", *args],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=60,
    )


def test_only_with_a_robot_the_scenario_lacks_is_refused_naming_it(tmp_path: Path) -> None:
    out = tmp_path / "out"
    refused = _swarm_up("--out", str(out), "--only", "robot3,robot9")
    assert refused.returncode == 2
    assert "robot9" in refused.stderr and "robot1, robot2, robot3" in refused.stderr
    assert "Traceback" not in refused.stderr
    assert not out.exists()
    # A robot named twice (before: started once, without a word; a typo for another robot).
    twice = _swarm_up("--out", str(out), "--only", "robot3,robot3")
    assert twice.returncode == 2 and "--only names 'robot3' twice" in twice.stderr, twice.stderr
    assert not out.exists()


def test_joining_a_world_elsewhere_takes_no_world_setting_and_only_a_tls_link(
    tmp_path: Path,
) -> None:
    credentials = tmp_path / "credentials"
    made = subprocess.run(
        [sys.executable, "-m", "services.cli.main", "credentials", str(credentials)]
        + ["--tls", "--tls-host", "10.211.0.1"],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=60,
    )
    assert made.returncode == 0, made.stderr
    out = tmp_path / "out"
    given = ("--out", str(out), "--credentials", str(credentials))
    cases = {
        "--lockstep": ("--connect", "tls/10.211.0.1:7448", "--only", "robot3", "--lockstep"),
        "--only": ("--connect", "tls/10.211.0.1:7448"),
        "over TLS": ("--connect", "tcp/10.211.0.1:7448", "--only", "robot3"),
        "does not name 10.211.0.9": ("--connect", "tls/10.211.0.9:7448", "--only", "robot3"),
    }
    for expected, args in cases.items():
        refused = _swarm_up(*given, *args)
        assert refused.returncode == 2, (args, refused.stderr)
        assert expected in refused.stderr and "Traceback" not in refused.stderr, refused.stderr
    assert not out.exists()


# -- the observer, run inside a host --------------------------------------------------------


def observe(connect: str, status: bool, truth: bool, robots: Sequence[str]) -> None:
    """Print JSON lines until SIGINT or SIGTERM: the world's status every 0.1 s (`status`), its
    truth poses (`truth`), and each sense, act and telemetry message of `robots`; each line with
    the monotonic time it was seen (`wall_s`)."""
    import zenoh

    from robot_firmware.net.keys import SwarmKeys
    from robot_firmware.net.messages import TelemetryMessage, TruthMessage, parse_message
    from robot_firmware.net.session import open_client
    from robot_firmware.net.wire import decode_act

    keys = SwarmKeys(SWARM)
    lines: queue.SimpleQueue[dict[str, Any]] = queue.SimpleQueue()
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())

    def on_truth(sample: zenoh.Sample) -> None:  # zenoh callbacks: queue and return
        message = parse_message(TruthMessage, sample.payload.to_bytes())
        if message is not None:
            poses = {name: list(r.pose) for name, r in message.robots.items()}
            lines.put({"kind": "truth", "wall_s": time.monotonic(), "t_s": message.t_s,
                       "poses": poses})  # fmt: skip

    def on_act(sample: zenoh.Sample) -> None:
        act = decode_act(sample.payload.to_bytes())
        if act is not None:
            off = all(d == 0.0 for d in act.duty) or not any(act.enabled)
            robot = SwarmKeys.chunk(str(sample.key_expr), 3)
            lines.put({"kind": "act", "wall_s": time.monotonic(), "robot": robot, "off": off})

    def on_sense(sample: zenoh.Sample) -> None:
        robot = SwarmKeys.chunk(str(sample.key_expr), 3)
        lines.put({"kind": "sense", "wall_s": time.monotonic(), "robot": robot})

    def on_telemetry(sample: zenoh.Sample) -> None:
        message = parse_message(TelemetryMessage, sample.payload.to_bytes())
        if message is not None:
            lines.put({"kind": "telemetry", "wall_s": time.monotonic(), "robot": message.robot,
                       "safe_stopped": message.safe_stopped, "role": message.role})  # fmt: skip

    with open_client([connect]) as session:
        if truth:
            session.declare_subscriber(keys.truth, on_truth)
        for name in robots:
            session.declare_subscriber(keys.act(name), on_act)
            session.declare_subscriber(keys.sense(name), on_sense)
            session.declare_subscriber(keys.telemetry(name), on_telemetry)
        while not stop.is_set():
            if status:
                for reply in session.get(keys.admin("world", "status"), timeout=1.0):
                    if reply.ok is not None:
                        data = json.loads(reply.ok.payload.to_bytes())
                        lines.put({"kind": "status", "wall_s": time.monotonic(),
                                   "t_s": data["t_s"], "live": data["live"],
                                   "errors_m": data["position_errors_m"],
                                   "collisions": data["metrics"]["collisions"]})  # fmt: skip
            while not lines.empty():
                print(json.dumps(lines.get()), flush=True)
            stop.wait(0.1)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tests.integration.test_multi_host")
    sub = parser.add_subparsers(dest="command", required=True)
    watch = sub.add_parser("observe", help="print what the swarm shows, as JSON lines")
    watch.add_argument("--connect", required=True, metavar="ENDPOINT")
    watch.add_argument("--status", action="store_true", help="poll the world's status")
    watch.add_argument("--truth", action="store_true", help="the world's truth poses")
    watch.add_argument("--robot", action="append", default=[], help="a robot's messages")
    args = parser.parse_args(argv)
    observe(args.connect, args.status, args.truth, args.robot)
    return 0


if __name__ == "__main__":
    sys.exit(main())
