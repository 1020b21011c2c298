"""The viewer's host and the server's memory limit: what a browser and Rerun can use passes,
as it goes into the URL; anything else is refused with the reason."""

from __future__ import annotations

import pytest

from services.dashboard.viewer_options import (
    browser_host,
    default_listen_address,
    listen_address,
    server_memory_limit,
)


@pytest.mark.parametrize(
    ("given", "in_url"),
    [
        ("127.0.0.1", "127.0.0.1"),
        ("localhost", "localhost"),
        ("robots-lab.example.org", "robots-lab.example.org"),
        ("::1", "[::1]"),
        ("[::1]", "[::1]"),
        ("fe80:0:0::1", "[fe80::1]"),
        (" 10.0.0.7 ", "10.0.0.7"),
    ],
)
def test_a_host_a_browser_can_reach_is_written_as_a_url_needs_it(given: str, in_url: str) -> None:
    assert browser_host(given) == in_url


@pytest.mark.parametrize(
    "given",
    [
        "*",
        "",
        "lab host",
        "http://lab",
        "lab:9090",
        "lab/path",
        "-lab",
        "lab-.org",
        "a..b",
        "[lab]",
    ],
)
def test_a_host_no_url_can_hold_is_refused(given: str) -> None:
    with pytest.raises(ValueError, match="is not a host name or address"):
        browser_host(given)


@pytest.mark.parametrize("given", ["0.0.0.0", "::", "[::]"])
def test_the_any_address_is_refused_as_such(given: str) -> None:
    with pytest.raises(ValueError, match="the any-address"):
        browser_host(given)


@pytest.mark.parametrize("given", ["256MiB", "1.5GB", "2 GB", "0B", "3kB", "1TiB", "25%", "100%"])
def test_sizes_rerun_takes_pass_unchanged(given: str) -> None:
    assert server_memory_limit(given) == given


@pytest.mark.parametrize("given", ["-5", "-5GB", "10", "256mib", "2KB", "lots", "", "1e3MB"])
def test_other_sizes_are_refused(given: str) -> None:
    with pytest.raises(ValueError, match="is not a memory size"):
        server_memory_limit(given)


def test_a_share_above_the_whole_memory_is_refused() -> None:
    with pytest.raises(ValueError, match="at most 100%"):
        server_memory_limit("150%")


@pytest.mark.parametrize(
    ("host", "address"),
    [("127.0.0.1", "127.0.0.1"), ("localhost", "127.0.0.1"), ("[::1]", "::1"),
     ("robots.lab", "0.0.0.0"), ("192.168.1.20", "0.0.0.0")],
)  # fmt: skip
def test_the_data_server_listens_where_the_browser_can_reach_it_and_no_wider(
    host: str, address: str
) -> None:
    assert default_listen_address(host) == address


@pytest.mark.parametrize("given", ["nope", "http://1.2.3.4", "1.2.3", "*", ""])
def test_a_listen_address_that_is_no_ip_address_is_refused(given: str) -> None:
    with pytest.raises(ValueError, match="is not an IP address to listen on"):
        listen_address(given)
    assert listen_address("[::]") == "::" and listen_address(" 0.0.0.0 ") == "0.0.0.0"
