"""Router ACL grants (services/router/access.py): what a robot may do with liveliness tokens."""

from __future__ import annotations

from robot_firmware.net.keys import SwarmKeys
from services.router.access import identity_grants

ROBOTS = ("robot1", "robot2", "robot3")
KEYS = SwarmKeys("lab")


def test_every_robot_may_watch_the_robots_tokens() -> None:
    grants = identity_grants("lab", ROBOTS)
    for name in ROBOTS:
        allowed = grants[name].allowed
        assert KEYS.alive_all("robot") in allowed[("liveliness_token", "egress")]
        assert KEYS.alive_all("robot") in allowed[("declare_liveliness_subscriber", "ingress")]
        assert KEYS.alive_all("robot") in allowed[("liveliness_query", "ingress")]


def test_a_robot_declares_only_its_own_token() -> None:
    grants = identity_grants("lab", ROBOTS)
    for name in ROBOTS:
        declared = grants[name].allowed[("liveliness_token", "ingress")]
        assert declared == [KEYS.alive("robot", name)]


def test_a_robot_watches_no_token_but_the_robots() -> None:
    allowed = identity_grants("lab", ROBOTS)["robot2"].allowed
    assert allowed[("liveliness_token", "egress")] == [KEYS.alive_all("robot")]
