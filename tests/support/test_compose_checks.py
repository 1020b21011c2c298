"""The compose smoke test's checks over scripted world status replies, on a fake clock."""

from __future__ import annotations

import http.server
import json
import socket
import subprocess
import sys
import threading
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path

import pytest

from robot_firmware.net.messages import WorldStatusReply
from tests.integration.conftest import free_port
from tests.support.compose_checks import (
    CheckFailedError,
    FormationHold,
    Probe,
    RunSummary,
    after_kill_problems,
    check_final,
    check_gone,
    check_grpc,
    check_live,
    check_rejoin,
    check_viewer,
    format_figure_m,
    hold_formation,
    http2_answer_problem,
    main,
    position_error_m,
    read_world_status,
)
from tests.support.fake_clock import FakeClock

ROOT = Path(__file__).resolve().parents[2]

ROBOTS = ("robot1", "robot2", "robot3")


def reply(
    t_s: float = 10.0,
    live: Iterable[str] = ROBOTS,
    errors_m: Mapping[str, float] | None = None,
    collisions: int = 0,
) -> dict[str, object]:
    """A status reply with the keys world/runtime.py answers with."""
    return {
        "ok": True,
        "t_s": t_s,
        "tick": int(t_s * 100),
        "clock_mode": "real_time",
        "live": sorted(live),
        "robots": list(ROBOTS),
        "metrics": {
            "leader": "robot1",
            "collisions": collisions,
            "formation_rms_m": {"robot2": 0.012, "robot3": None},
            "leader_tracking_rms_m": 0.004,
        },
        "position_errors_m": dict(errors_m or dict.fromkeys(ROBOTS, 0.01)),
        "radio": {"delivered": 10, "frames": 10},
        "lockstep_owed": {},
    }


def status(**kwargs: object) -> WorldStatusReply:
    return WorldStatusReply.model_validate(reply(**kwargs))  # type: ignore[arg-type]


class ScriptedWorld:
    """Answers from a script, one status per query; the last answer repeats."""

    def __init__(self, answers: Iterable[WorldStatusReply | None]) -> None:
        self._answers: Iterator[WorldStatusReply | None] = iter(answers)
        self._last: WorldStatusReply | None = None
        self.queries = 0

    def __call__(self) -> WorldStatusReply | None:
        self.queries += 1
        self._last = next(self._answers, self._last)
        return self._last


def probe_of(answers: Iterable[WorldStatusReply | None]) -> tuple[Probe, FakeClock]:
    clock = FakeClock()
    return Probe(ScriptedWorld(answers), clock=clock, sleep=clock.sleep), clock


# -- the world's reply --------------------------------------------------------------------------


def test_reply_is_read_as_the_world_status_model() -> None:
    st = read_world_status(json.dumps(reply(t_s=12.5, live=["robot3", "robot1"])).encode())
    assert isinstance(st, WorldStatusReply)
    assert st.t_s == 12.5
    assert st.live == ("robot1", "robot3")
    assert position_error_m(st, "robot2") == 0.01
    assert position_error_m(st, "robot9") == float("inf")


def test_a_refusal_is_no_status() -> None:
    assert read_world_status(b'{"ok": false, "error": "unknown admin verb"}') is None


@pytest.mark.parametrize(
    ("key", "value"), [("t_s", "soon"), ("live", None), ("position_errors_m", [0.1])]
)
def test_a_reply_that_does_not_fit_is_a_failed_check(key: str, value: object) -> None:
    bad = reply()
    bad[key] = value
    with pytest.raises(CheckFailedError, match="the world's status reply does not fit"):
        read_world_status(json.dumps(bad).encode())


@pytest.mark.parametrize("payload", [b"{}", b"not json", b"[1, 2]"])
def test_a_reply_that_is_no_status_at_all_is_a_failed_check(payload: bytes) -> None:
    with pytest.raises(CheckFailedError, match="the world's status reply does not fit: b'"):
        read_world_status(payload)


# -- formation hold -----------------------------------------------------------------------------


def test_formation_holds_after_hold_s_in_a_row() -> None:
    hold = FormationHold(ROBOTS, max_error_m=0.05, hold_s=3.0)
    good = status()
    assert [hold.update(t_s, good) for t_s in (0.0, 1.0, 2.0, 2.9)] == [False] * 4
    assert hold.update(3.0, good)


@pytest.mark.parametrize(
    "interruption",
    [
        None,  # no answer
        status(errors_m={"robot1": 0.01, "robot2": 0.05, "robot3": 0.01}),  # at the bound
        status(live=["robot1", "robot3"]),  # robot2 not live
        status(errors_m={"robot1": 0.01, "robot3": 0.01}),  # no error reported for robot2
    ],
)
def test_an_interruption_starts_the_hold_again(interruption: WorldStatusReply | None) -> None:
    hold = FormationHold(ROBOTS, max_error_m=0.05, hold_s=3.0)
    good = status()
    assert not hold.update(0.0, good)
    assert not hold.update(2.5, good)
    assert not hold.update(3.0, interruption)
    assert not hold.update(3.5, good)
    assert not hold.update(6.0, good)
    assert hold.update(6.5, good)


def test_formation_check_passes_over_a_settling_sequence(
    capsys: pytest.CaptureFixture[str],
) -> None:
    far = status(errors_m={"robot1": 0.02, "robot2": 0.30, "robot3": 0.12})
    near = status(errors_m={"robot1": 0.01, "robot2": 0.04, "robot3": 0.03})
    probe, _ = probe_of([None, far, far, near, far] + [near] * 20)
    hold_formation(probe, ROBOTS, 0.05, 3.0, 60.0, "formation")
    # Polled every 0.5 s: settled from the sixth answer (2.5 s) on, held at 5.5 s.
    assert probe.elapsed_s() == 5.5
    out = capsys.readouterr().out
    assert "formation: every position error < 5 cm for 3 s, 5.5 s after the start" in out


def test_formation_check_fails_at_once_on_a_collision() -> None:
    probe, _ = probe_of([status(), status(collisions=1)])
    with pytest.raises(CheckFailedError, match="formation: the world reports 1 collisions"):
        hold_formation(probe, ROBOTS, 0.05, 3.0, 60.0, "formation")
    assert probe.elapsed_s() == 0.5


def test_formation_check_times_out_with_the_last_answer(
    capsys: pytest.CaptureFixture[str],
) -> None:
    unsettled = status(errors_m={"robot1": 0.01, "robot2": 0.2, "robot3": 0.01})
    probe, _ = probe_of([unsettled])
    with pytest.raises(CheckFailedError) as raised:
        hold_formation(probe, ROBOTS, 0.05, 3.0, 10.0, "formation")
    assert str(raised.value) == (
        "formation: the position errors of robot1, robot2, robot3 were not all under 5 cm "
        "for 3 s within 10 s"
    )
    assert probe.elapsed_s() == 10.0
    assert "robot2 20.0" in capsys.readouterr().out.splitlines()[-1]


# -- live, gone, rejoin, final ------------------------------------------------------------------


def test_live_waits_for_every_robot() -> None:
    probe, _ = probe_of([None, status(live=["robot1"]), status()])
    check_live(probe, ROBOTS, 60.0)
    assert probe.elapsed_s() == 1.0


def test_live_fails_when_the_world_never_answers(capsys: pytest.CaptureFixture[str]) -> None:
    probe, _ = probe_of([None])
    with pytest.raises(CheckFailedError, match="robot1, robot2, robot3 not all live within 5 s"):
        check_live(probe, ROBOTS, 5.0)
    assert "the world never answered" in capsys.readouterr().out


def test_gone_passes_when_the_others_keep_going() -> None:
    probe, clock = probe_of(
        [status(t_s=20.0), status(t_s=20.2, live=["robot1", "robot3"]), status(t_s=25.0)]
    )
    with pytest.raises(CheckFailedError, match="robot2 came back by itself"):
        check_gone(probe, ROBOTS, "robot2", 5.0, 0.05)
    probe, clock = probe_of(
        [
            status(t_s=20.0),
            status(t_s=20.2, live=["robot1", "robot3"]),
            status(t_s=25.1, live=["robot1", "robot3"]),
        ]
    )
    check_gone(probe, ROBOTS, "robot2", 5.0, 0.05)
    assert clock.sleeps_s == [0.2, 5.0]


def test_gone_fails_when_the_robot_stays_listed() -> None:
    probe, _ = probe_of([status()])
    with pytest.raises(CheckFailedError, match="still lists robot2 as live 10 s after the kill"):
        check_gone(probe, ROBOTS, "robot2", 5.0, 0.05)


def test_after_kill_problems_names_each_problem() -> None:
    before = status(t_s=20.0, live=["robot1", "robot3"])
    fine = status(t_s=24.0, live=["robot1", "robot3"])
    assert after_kill_problems(before, fine, "robot2", ROBOTS, 5.0) == []
    bad = status(
        t_s=22.0,
        live=["robot1", "robot2"],
        errors_m={"robot1": 0.07, "robot2": 0.0, "robot3": 0.0},
        collisions=2,
    )
    assert after_kill_problems(before, bad, "robot2", ROBOTS, 5.0) == [
        "robot1, robot3 did not all stay live",
        "robot2 came back by itself (its restart policy should be 'no')",
        "the world advanced only 2.0 s in 5 s",
        "the world reports 2 collisions",
    ]


OFF_TRACK = {"robot1": 0.9, "robot2": 0.3, "robot3": 0.01}


def test_gone_waits_for_a_leader_on_a_detour_to_be_back_on_its_trajectory() -> None:
    down = ["robot1", "robot3"]
    probe, clock = probe_of(
        [
            status(t_s=20.0),
            status(t_s=20.2, live=down),
            status(t_s=25.1, live=down, errors_m=OFF_TRACK),
            status(t_s=25.3, live=down, errors_m=OFF_TRACK),
            status(t_s=25.5, live=down),
        ]
    )
    check_gone(probe, ROBOTS, "robot2", 5.0, 0.05)
    assert clock.sleeps_s == [0.2, 5.0, 0.2]


def test_gone_fails_when_the_leader_stays_off_its_trajectory() -> None:
    down = ["robot1", "robot3"]
    probe, _ = probe_of(
        [status(t_s=20.0), status(t_s=20.2, live=down)]
        + [status(t_s=25.1, live=down, errors_m=OFF_TRACK)]
    )
    with pytest.raises(CheckFailedError, match="the leader robot1 left its trajectory"):
        check_gone(probe, ROBOTS, "robot2", 5.0, 0.05)


def test_gone_fails_on_a_collision_while_the_leader_comes_back() -> None:
    down = ["robot1", "robot3"]
    probe, _ = probe_of(
        [
            status(t_s=20.0),
            status(t_s=20.2, live=down),
            status(t_s=25.1, live=down, errors_m=OFF_TRACK),
            status(t_s=26.0, live=down, collisions=1),
        ]
    )
    with pytest.raises(CheckFailedError, match="the world reports 1 collisions"):
        check_gone(probe, ROBOTS, "robot2", 5.0, 0.05)


def test_rejoin_counts_its_time_out_from_the_restart() -> None:
    down = status(live=["robot1", "robot3"])
    back_far = status(errors_m={"robot1": 0.01, "robot2": 0.4, "robot3": 0.01})
    probe, _ = probe_of([down] * 10 + [back_far] * 100)
    with pytest.raises(CheckFailedError, match=r"robot2 rejoined: .* within 20 s"):
        check_rejoin(probe, ROBOTS, "robot2", 0.05, 2.0, 20.0)
    assert probe.elapsed_s() == 20.0


def test_rejoin_passes_when_the_robot_settles() -> None:
    down = status(live=["robot1", "robot3"])
    probe, _ = probe_of([down] * 5 + [status()] * 10)
    check_rejoin(probe, ROBOTS, "robot2", 0.05, 2.0, 45.0)
    assert probe.elapsed_s() == pytest.approx(1.0 + 2.0)


def test_final_fails_on_collisions(capsys: pytest.CaptureFixture[str]) -> None:
    probe, _ = probe_of([None, status(collisions=3)])
    with pytest.raises(CheckFailedError, match="the world reports 3 collisions"):
        check_final(probe, 10.0)
    assert "formation RMS robot2 0.012 m, robot3 n/a" in capsys.readouterr().out
    probe, _ = probe_of([status()])
    check_final(probe, 10.0)


# -- viewer, summary, command line --------------------------------------------------------------


def test_viewer_waits_for_http_200() -> None:
    clock = FakeClock()
    answers = iter([None, 503, 200])
    check_viewer("http://127.0.0.1:1/", 10.0, lambda url, t: next(answers), clock, clock.sleep)
    with pytest.raises(CheckFailedError, match=r"no web viewer at .* \(HTTP status: 404\)"):
        check_viewer("http://127.0.0.1:1/", 2.0, lambda url, t: 404, clock, clock.sleep)


def test_a_rerun_grpc_server_answers_the_http2_preface() -> None:
    """The check against the real thing: Rerun's gRPC server, as the dashboard serves it."""
    port = free_port()
    with subprocess.Popen(
        [sys.executable, "-c", RERUN_GRPC_SERVER, str(port)],
        stdout=subprocess.PIPE,
        text=True,
        cwd=ROOT,
    ) as server:
        try:
            assert server.stdout is not None
            assert server.stdout.readline().startswith("rerun+http://")
            check_grpc(("127.0.0.1", port), 30.0)
        finally:
            server.kill()


RERUN_GRPC_SERVER = """
import sys, time
import rerun as rr
recording = rr.RecordingStream("compose-check")
print(recording.serve_grpc(grpc_port=int(sys.argv[1]), server_memory_limit="10MB"), flush=True)
time.sleep(60)
"""


class _Http1Handler(http.server.BaseHTTPRequestHandler):
    def log_message(self, format: str, *args: object) -> None:
        pass


def test_what_is_not_a_grpc_server_is_named() -> None:
    """Nothing listening; a listener that takes the connection and drops it (Docker's
    published port in front of a server that listens on the container's loopback only); an
    HTTP/1 server."""
    port = free_port()
    assert http2_answer_problem(("127.0.0.1", port), 2.0) == "Connection refused"
    with socket.create_server(("127.0.0.1", 0)) as dropper:
        address = dropper.getsockname()[:2]

        def drop() -> None:
            connection, _ = dropper.accept()
            connection.close()

        threading.Thread(target=drop, daemon=True).start()
        assert http2_answer_problem(address, 5.0) in (  # reset: the preface was never read
            "the connection closed after 0 bytes",
            "Connection reset by peer",
        )
    with http.server.HTTPServer(("127.0.0.1", 0), _Http1Handler) as http1:
        threading.Thread(target=http1.handle_request, daemon=True).start()
        problem = http2_answer_problem(http1.server_address[:2], 5.0)  # type: ignore[arg-type]
        assert problem is not None
        assert problem.endswith("not with an HTTP/2 SETTINGS frame")
    clock = FakeClock()
    answers = iter(["Connection refused", None])
    check_grpc(("h", 1), 10.0, lambda address, t: next(answers), clock, clock.sleep)
    with pytest.raises(CheckFailedError, match=r"no gRPC server at h:1 \(Connection refused\)"):
        check_grpc(("h", 1), 2.0, lambda address, t: "Connection refused", clock, clock.sleep)


def write_summary(path: Path, **overrides: object) -> Path:
    summary: dict[str, object] = {
        "duration_s": 48.25,
        "collisions": 0,
        "clock_mode": "real_time",
        "formation_rms_m": {"robot2": 0.0123, "robot3": 0.0101},
        "leader_tracking_rms_m": 0.0042,
        "min_robot_separation_m": 0.31,
        "min_obstacle_clearance_m": None,
        "control_timing": {
            "robot1": {"ticks": 4800, "deadline_misses": 3, "period_jitter_p99_ms": 1.25},
            "robot2": None,
        },
    }
    path.write_text(json.dumps({**summary, **overrides}))
    return path


def test_summary_report_lines(tmp_path: Path) -> None:
    lines = RunSummary.read(write_summary(tmp_path / "summary.json")).report_lines()
    assert lines == [
        "world summary: 48.2 s simulated (real_time), collisions 0, formation RMS robot2 "
        "0.012 m, robot3 0.010 m, leader RMS 0.004 m, min robot separation 0.310 m, "
        "min obstacle clearance n/a",
        "robot1: 3 of 4800 control deadlines missed, period jitter p99 1.2 ms",
        "robot2: no control timing",
    ]


@pytest.mark.parametrize(
    ("overrides", "problem"),
    [
        ({"duration_s": 12.0}, "the world ran 12.0 s, not more than 20 s"),
        ({"collisions": 2}, "2 collisions"),
    ],
)
def test_summary_judged(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    overrides: dict[str, object],
    problem: str,
) -> None:
    good = write_summary(tmp_path / "good.json")
    assert main(["summary", str(good), "--min-duration", "20"]) == 0
    bad = write_summary(tmp_path / "summary.json", **overrides)
    assert main(["summary", str(bad)]) == 0  # a report only
    assert main(["summary", str(bad), "--min-duration", "20"]) == 1
    assert capsys.readouterr().out.splitlines()[-1] == f"CHECK FAILED: summary.json: {problem}"


@pytest.mark.parametrize("content", ["", "[1, 2]", '{"duration_s": 3.0}'])
def test_an_unreadable_summary_fails_without_a_traceback(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], content: str
) -> None:
    path = tmp_path / "summary.json"
    path.write_text(content)
    assert main(["summary", str(path)]) == 1
    assert capsys.readouterr().out.startswith(f"CHECK FAILED: cannot read {path}")
    assert main(["summary", str(tmp_path / "missing.json")]) == 1


@pytest.mark.parametrize(
    "argv",
    [
        ["gone", "--connect", "tcp/127.0.0.1:1", "--robot", "robot9"],
        ["formation", "--connect", "tcp/127.0.0.1:1", "--max-error-m", "-0.1"],
        ["live", "--connect", "tcp/127.0.0.1:1", "--robots", "robot1,robot1"],
        ["live"],
        ["teleport", "--connect", "tcp/127.0.0.1:1"],
        ["grpc", "127.0.0.1"],
        ["grpc", "127.0.0.1:0"],
    ],
)
def test_usage_errors_exit_2(argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as raised:
        main(argv)
    assert raised.value.code == 2
    assert "error:" in capsys.readouterr().err


def test_figures_in_metres() -> None:
    assert format_figure_m(0.01234) == "0.012 m"
    assert format_figure_m(None) == "n/a"
    assert format_figure_m({}) == "n/a"
    assert format_figure_m({"robot2": 0.5, "robot3": None}) == "robot2 0.500 m, robot3 n/a"
