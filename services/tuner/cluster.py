"""Fitness evaluation on a Ray cluster, for `swarm tune --ray` and `bench/tuner_comparison.py`.

The tuner's objective takes a generation's whole batch of decision vectors (P, 16) and returns
their eq. 16 costs (:mod:`services.tuner.fitness`). A candidate's cost does not depend on which
other candidates share its batch, so :meth:`RayCluster.objective` cuts each batch into one
slice per CPU of the cluster, evaluates the slices as Ray tasks and joins their costs in order:
the optimiser sees the very costs a local run computes, so the same seeds give the same best
value and history. The optimiser loop, its random generator and its checkpoints stay in the
calling process, which remains the only authority on a run's state.

What crosses the network: the scenario, once per objective (``ray.put``); per slice, the rows
of decision vectors (k x 16 float64) there and k costs back. Every node imports the project's
own code, so each one needs the project installed (``pip install .[cluster]``) at the same
version.

A task lost with its worker or node (the node died, the worker process crashed or was killed)
is submitted again, up to :data:`MAX_ATTEMPTS` times; finished slices are kept, so a lost
worker costs only its unfinished slice. :meth:`RayCluster.map` does the same for any picklable
function (the benchmark spreads whole optimiser runs with it).

Ray is imported here only, inside :func:`connect_cluster`: a run without ``--ray`` never
imports it. A bad or unreachable address, or Ray not being installed, is a
:class:`ClusterError` with a one-line message.
"""

from __future__ import annotations

import logging
import socket
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from types import ModuleType, TracebackType
from typing import Any, TypeVar

import numpy as np

from services.tuner.evaluation import FloatArray, Objective
from services.tuner.fitness import DEFAULT_COLLISION_PENALTY, evaluate_fitness, evaluation_scenario
from swarm_config.scenario import Scenario

LOGGER = logging.getLogger(__name__)

MAX_ATTEMPTS = 4
"""Submissions of one task before a run gives up on the cluster (a first try and 3 retries)."""
CONNECT_TIMEOUT_S = 5.0
"""Time allowed for the address to answer before Ray is asked to connect."""
IDLE_CHECK_S = 10.0
"""While no task finishes for this long, the cluster is checked for CPUs left."""
HOW_TO_START = (
    "start one with `ray start --head --port 6379` (docs/tuning.md, Tuning on Ray) and pass "
    "its HOST:PORT"
)

ResultT = TypeVar("ResultT")


class ClusterError(ValueError):
    """The Ray cluster cannot be used: bad address, not reachable, Ray missing, or lost."""


@dataclass(frozen=True)
class ClusterAddress:
    """The head node's GCS address, ``HOST:PORT`` as ``ray start --head`` prints it."""

    host: str
    port: int

    @staticmethod
    def parse(text: str) -> ClusterAddress:
        """``HOST:PORT`` (``[V6]:PORT`` for IPv6) or ClusterError saying what is wrong."""
        stripped = text.strip()
        host, colon, port_text = stripped.rpartition(":")
        if not colon or not host or not port_text:
            raise ClusterError(
                f"--ray {text!r}: expected the head node's HOST:PORT, e.g. 10.0.0.5:6379"
            )
        if host.startswith("[") and host.endswith("]"):
            host = host[1:-1]
        if "://" in host or "/" in host:
            raise ClusterError(
                f"--ray {text!r}: give the head node's HOST:PORT without a scheme "
                "(the driver connects to the cluster's GCS, e.g. 10.0.0.5:6379)"
            )
        try:
            port = int(port_text)
        except ValueError:
            raise ClusterError(f"--ray {text!r}: port {port_text!r} is not a number") from None
        if not 0 < port < 65536:
            raise ClusterError(f"--ray {text!r}: port {port} is not in 1-65535")
        return ClusterAddress(host, port)

    def __str__(self) -> str:
        return f"[{self.host}]:{self.port}" if ":" in self.host else f"{self.host}:{self.port}"


HTTP2_PREFACE = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n"
HTTP2_EMPTY_SETTINGS_FRAME = b"\x00\x00\x00\x04\x00\x00\x00\x00\x00"
HTTP2_FRAME_HEADER_BYTES = 9
HTTP2_SETTINGS_FRAME_TYPE = 0x4


def check_answers_grpc(address: ClusterAddress, timeout_s: float = CONNECT_TIMEOUT_S) -> None:
    """Raise ClusterError unless something at ``address`` speaks gRPC, as a Ray head's GCS does.

    Ray itself would wait about two minutes on a wrong address and then exit the process; this
    check takes one TCP connection and the HTTP/2 preface, whose answer is a SETTINGS frame.
    """
    try:
        connection = socket.create_connection((address.host, address.port), timeout=timeout_s)
    except TimeoutError:
        raise ClusterError(
            f"no Ray cluster answers at {address} within {timeout_s:g} s; {HOW_TO_START}"
        ) from None
    except OSError as exc:
        reason = exc.strerror or str(exc)
        raise ClusterError(
            f"cannot reach a Ray cluster at {address}: {reason}; {HOW_TO_START}"
        ) from None
    header = b""
    with connection:
        try:
            connection.sendall(HTTP2_PREFACE + HTTP2_EMPTY_SETTINGS_FRAME)
            while len(header) < HTTP2_FRAME_HEADER_BYTES:
                chunk = connection.recv(HTTP2_FRAME_HEADER_BYTES - len(header))
                if not chunk:
                    break
                header += chunk
        except OSError:  # reset, or silent past the timeout
            pass
    if len(header) < HTTP2_FRAME_HEADER_BYTES or header[3] != HTTP2_SETTINGS_FRAME_TYPE:
        raise ClusterError(
            f"{address} answers, but not as a Ray cluster's GCS (no gRPC); pass the port "
            "`ray start --head` printed (6379 unless --port was given)"
        )


def import_ray() -> ModuleType:
    """The ``ray`` module, or ClusterError saying how to install it."""
    try:
        import ray
    except ImportError as exc:
        raise ClusterError(
            f"--ray needs Ray, which is not installed ({exc}); install it with "
            "`pip install .[cluster]`"
        ) from None
    return ray


def evaluate_candidate_slice(
    scenario: Scenario,
    unit_vectors: FloatArray,
    duration_s: float | None,
    collision_penalty: float,
) -> FloatArray:
    """Costs of one slice of a batch; what a Ray task runs on a worker (eq. 16)."""
    return evaluate_fitness(
        unit_vectors, scenario, duration_s=duration_s, collision_penalty=collision_penalty
    ).cost


def connect_cluster(address: str) -> RayCluster:
    """Connect this process to the Ray cluster whose head is at ``address`` (``HOST:PORT``).

    Raises ClusterError when the address is malformed, nothing answers there, Ray is not
    installed or Ray refuses the connection (e.g. token authentication without the token).
    """
    parsed = ClusterAddress.parse(address)
    check_answers_grpc(parsed)
    ray = import_ray()
    try:
        ray.init(
            address=str(parsed),
            logging_level=logging.WARNING,
            log_to_driver=False,
            configure_logging=False,
        )
    except (Exception, SystemExit) as exc:
        raise ClusterError(
            f"Ray could not connect to the cluster at {parsed}: {exc} (a cluster started with "
            "token authentication needs RAY_AUTH_MODE=token and RAY_AUTH_TOKEN here too)"
        ) from None
    return RayCluster(ray, parsed)


class RayCluster:
    """A connection to a Ray cluster that runs fitness slices and whole functions as tasks.

    Use it as a context manager, or call :meth:`close`; both disconnect (the cluster runs on).
    """

    def __init__(self, ray: ModuleType, address: ClusterAddress) -> None:
        self._ray = ray
        self.address = address
        self._lost_errors: tuple[type[BaseException], ...] = (
            ray.exceptions.NodeDiedError,
            ray.exceptions.WorkerCrashedError,
            ray.exceptions.LocalRayletDiedError,
            ray.exceptions.ObjectLostError,
            ray.exceptions.OutOfMemoryError,
        )
        self._remote_functions: dict[Callable[..., Any], Any] = {}

    def __enter__(self) -> RayCluster:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        self.close()

    def close(self) -> None:
        """Disconnect from the cluster."""
        self._ray.shutdown()

    @property
    def cpu_count(self) -> int:
        """CPUs of the cluster's live nodes now (at least 1)."""
        return max(1, int(self._ray.cluster_resources().get("CPU", 0)))

    @property
    def node_count(self) -> int:
        """Live nodes of the cluster now."""
        return sum(1 for node in self._ray.nodes() if node.get("Alive"))

    def describe(self) -> str:
        """``Ray cluster at HOST:PORT, C CPUs on N nodes`` for a report line."""
        return f"Ray cluster at {self.address}, {self.cpu_count} CPUs on {self.node_count} nodes"

    def map(
        self,
        function: Callable[..., ResultT],
        argument_tuples: Sequence[tuple[Any, ...]],
        *,
        on_result: Callable[[int, ResultT], None] | None = None,
    ) -> list[ResultT]:
        """``[function(*arguments) for arguments in argument_tuples]``, one Ray task each.

        Tasks run in any order on the cluster's CPUs (one CPU each); results come back in the
        order of ``argument_tuples``, and ``on_result(index, result)`` sees each one as soon as
        it arrives. A task lost with its worker or node is submitted again (up to
        :data:`MAX_ATTEMPTS` submissions); an exception raised by ``function`` itself is raised
        here. ``function`` must be importable or picklable on the workers.
        """
        ray = self._ray
        remote = self._remote_functions.get(function)
        if remote is None:
            # Ray's own retries are off: a lost task is submitted again below, and logged.
            remote = ray.remote(num_cpus=1, max_retries=0)(function)
            self._remote_functions[function] = remote
        count = len(argument_tuples)
        results: dict[int, ResultT] = {}
        attempts = [1] * count
        pending = {remote.remote(*arguments): i for i, arguments in enumerate(argument_tuples)}
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1, timeout=IDLE_CHECK_S)
            if not ready:
                if not ray.cluster_resources().get("CPU", 0):
                    raise ClusterError(
                        f"the Ray cluster at {self.address} has no CPUs left; "
                        f"{len(pending)} of {count} tasks are unfinished"
                    )
                continue
            reference = ready[0]
            index = pending.pop(reference)
            try:
                value: ResultT = ray.get(reference)
            except self._lost_errors as exc:
                if attempts[index] >= MAX_ATTEMPTS:
                    raise ClusterError(
                        f"task {index + 1} of {count} was lost {attempts[index]} times on the "
                        f"Ray cluster at {self.address}; last: {type(exc).__name__}"
                    ) from None
                attempts[index] += 1
                LOGGER.warning(
                    "task %d of %d lost with its worker (%s); submitted again (attempt %d of %d)",
                    index + 1,
                    count,
                    type(exc).__name__,
                    attempts[index],
                    MAX_ATTEMPTS,
                )
                pending[remote.remote(*argument_tuples[index])] = index
                continue
            results[index] = value
            if on_result is not None:
                on_result(index, value)
        return [results[index] for index in range(count)]

    def objective(
        self,
        scenario: Scenario,
        *,
        duration_s: float | None = None,
        collision_penalty: float = DEFAULT_COLLISION_PENALTY,
    ) -> Objective:
        """:func:`~services.tuner.fitness.make_objective`'s objective, evaluated on the cluster.

        Each batch is cut into one slice per CPU of the cluster at that moment (a node that
        joins or leaves changes the slicing, never the costs).
        """
        evaluation_scenario(scenario, duration_s)  # a bad duration fails before any task
        if collision_penalty < 0.0:
            raise ValueError(f"collision_penalty must be non-negative, got {collision_penalty}")
        scenario_reference = self._ray.put(scenario)

        def objective(unit_vectors: FloatArray) -> FloatArray:
            slices = np.array_split(unit_vectors, min(len(unit_vectors), self.cpu_count))
            costs = self.map(
                evaluate_candidate_slice,
                [(scenario_reference, rows, duration_s, collision_penalty) for rows in slices],
            )
            joined: FloatArray = np.concatenate(costs)
            return joined

        return objective
