"""Code shared by the test harnesses: the integration tests and the compose smoke test's checks.

`waiting.wait_for` polls a condition until it holds or a time-out passes; `compose_checks` is the
command line that scripts/compose-smoke.sh runs against the compose stack; `compose_host` does
the host-side chores of that script that need Python (free ports, requirements, wheel members).
"""
