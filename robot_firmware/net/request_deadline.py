"""An admin request's deadline, carried in its Zenoh attachment.

A request whose sender was told "no answer" must not take effect later.  Two ways it did:

* the sender gave up (its time-out passed) while the request waited: in a process stopped with
  SIGSTOP, behind a world forwarding it, in a slow loop; continued, the process carried it out;
* the receiving process froze for longer than its session's lease (1 s,
  configs/zenoh/client.json5): the router closed that session, which ended the sender's request
  at once ("no answer"), yet the request, already in the frozen process's socket, was read and
  carried out once the process continued, its answer going nowhere.

So every request says when it was sent and until when its sender waits (wall-clock
nanoseconds), and on which machine (its kernel's boot id: containers on one host share it,
and their clock), and the process that serves it refuses, as `expired`, one served after its
deadline or received more than `TRANSIT_MAX_S` after it was sent.  Both compare wall clocks,
so only a request from the same machine is checked: the swarm needs no clock synchronisation
between hosts (docs/multi-host.md), and a request from another host is served as before.  So
is a request without the attachment (another tool's); a malformed one is refused as
`invalid_request`.
"""

from __future__ import annotations

import re
import socket
import time
from functools import cache
from pathlib import Path

NS_PER_S = 1_000_000_000
TRANSIT_MAX_S = 1.0
"""The longest a request may take from its sender to the receiving process's callback: the
clients' session lease, after which the router has closed the session it came on, and ended
the request at its sender."""
FORM = "sent_unix_ns=N;reply_by_unix_ns=N;machine=ID"
"""What the attachment says, N a count of nanoseconds since the Unix epoch, ID the sender's
`machine_id()`."""
_ATTACHMENT = re.compile(
    rb"sent_unix_ns=([0-9]{1,20});reply_by_unix_ns=([0-9]{1,20});machine=([0-9A-Za-z_.-]{1,64})"
)
BOOT_ID_PATH = Path("/proc/sys/kernel/random/boot_id")


@cache
def machine_id() -> str:
    """This machine's running kernel: its boot id (Linux), else its host name.  Two processes
    with the same id read the same wall clock."""
    try:
        boot_id = BOOT_ID_PATH.read_text(encoding="ascii").strip()
    except OSError:
        boot_id = ""
    found = re.fullmatch(r"[0-9A-Za-z_.-]{1,64}", boot_id or socket.gethostname())
    return found.group(0) if found else "unknown"


def request_attachment(timeout_s: float, now_unix_ns: int | None = None) -> bytes:
    """The attachment of a request sent now whose sender waits `timeout_s` for the answer."""
    sent = time.time_ns() if now_unix_ns is None else now_unix_ns
    reply_by = sent + round(timeout_s * NS_PER_S)
    return f"sent_unix_ns={sent};reply_by_unix_ns={reply_by};machine={machine_id()}".encode()


def reply_by_unix_ns(attachment: bytes | None) -> int | None:
    """The deadline a well-formed attachment from this machine gives, else None."""
    found = None if attachment is None else _ATTACHMENT.fullmatch(attachment)
    if found is None or found.group(3).decode() != machine_id():
        return None
    return int(found.group(2))


def expired_request_problem(
    attachment: bytes | None, received_unix_ns: int, now_unix_ns: int
) -> tuple[str, bool] | None:
    """Why a request must not be carried out now, with whether it is the attachment's form
    (True) rather than its time (False); None to serve it."""
    if attachment is None:
        return None
    found = _ATTACHMENT.fullmatch(attachment)
    if found is None:
        shown = attachment[:60]
        return f"a request attachment not of the form {FORM}: {shown!r}", True
    if found.group(3).decode() != machine_id():
        return None  # another machine's clock: not compared
    sent_ns, reply_by_ns = int(found.group(1)), int(found.group(2))
    transit_s = (received_unix_ns - sent_ns) / NS_PER_S
    if transit_s > TRANSIT_MAX_S:
        return (
            f"the request came {transit_s:.1f} s after it was sent (this process was stopped "
            "or starved): its sender has had no answer, so it is not carried out",
            False,
        )
    if now_unix_ns > reply_by_ns:
        late_s = (now_unix_ns - reply_by_ns) / NS_PER_S
        return (
            f"the request's sender stopped waiting {late_s:.1f} s before it could be served: "
            "it is not carried out",
            False,
        )
    return None
