#!/usr/bin/env python3
"""A Python client for the strand motion-controller service, over iceoryx2 (``pip install iceoryx2==0.10.0``).

``StrandClient(prefix)`` is a feeder and monitor: it publishes segment batches and control commands
(each send followed by a notify on the event service of the same name, as the Rust ports do) and
subscribes to the status and the joint commands. Services are opened with ``open_or_create`` and the
same quality of service as ``ipc/src/ports.rs``, so either side may start first.

Back-pressure is credit-based: ``send_segments`` sends segment sequence numbers only up to
``Status.last_received_seq + Status.queue_free`` of the newest Status, waiting for newer statuses
otherwise; nothing is dropped.

Run as a script, it is an end-to-end check against a running service (``run_client_test.sh``)::

    python3 tools/python/strand_client.py --prefix strand/pytest-1 --timeout 60

``--wait-service SECONDS`` only waits until a Status of the service is visible (exit 0) or not (1).
"""

from __future__ import annotations

import argparse
import collections
import ctypes
import math
import os
import sys
import time
from typing import Iterable, Optional

import iceoryx2 as iox2

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from strand_ipc import (  # noqa: E402
    CONTRACT_VERSION,
    SEGMENT_BATCH_CAPACITY,
    Command,
    Control,
    FaultCode,
    JobOutcome,
    JointCommand,
    RejectReason,
    RunState,
    Segment,
    SegmentBatch,
    SegmentFlags,
    Status,
    enum_name,
    service_names,
)

# Quality of service, identical to ipc/src/ports.rs: (buffer, history, max_publishers, max_subscribers).
SEGMENTS_QOS = (256, 0, 4, 8)
CONTROL_QOS = (64, 0, 4, 8)
MEASUREMENT_QOS = (16, 0, 4, 8)
OUTPUT_QOS = (16, 1, 1, 8)
MAX_NODES = 20
MAX_EVENT_PORTS = 16


def _quiet_iceoryx2() -> None:
    # As the Rust side: no WARN about a missing config file unless IOX2_LOG_LEVEL says otherwise.
    iox2.set_log_level_from_env_or(iox2.LogLevel.Error)


def _copy_payload(sample, cls):
    """Copies a received sample's payload out of shared memory and releases the sample."""
    value = cls()
    ctypes.memmove(ctypes.addressof(value), sample.payload_ptr, ctypes.sizeof(cls))
    sample.delete()
    return value


class _Channel:
    """One publish-subscribe service plus its event service of the same name."""

    def __init__(self, node, name: str, payload, qos, open_only: bool = False):
        buffer, history, max_publishers, max_subscribers = qos
        self.name = name
        service_name = iox2.ServiceName.new(name)
        builder = (
            node.service_builder(service_name)
            .publish_subscribe(payload)
            .subscriber_max_buffer_size(buffer)
            .history_size(history)
            .max_publishers(max_publishers)
            .max_subscribers(max_subscribers)
            .max_nodes(MAX_NODES)
            .enable_safe_overflow(True)
        )
        self.service = builder.open() if open_only else builder.open_or_create()
        event = node.service_builder(service_name).event().max_notifiers(MAX_EVENT_PORTS).max_listeners(MAX_EVENT_PORTS)
        self.event = event.open() if open_only else event.open_or_create()
        self.payload = payload

    def publishers(self) -> int:
        return self.service.dynamic_config.number_of_publishers


class _Outbox:
    """Publisher + notifier: send, then notify."""

    def __init__(self, channel: _Channel):
        self.channel = channel
        self.publisher = channel.service.publisher_builder().create()
        self.notifier = channel.event.notifier_builder().create()

    def send(self, value) -> int:
        delivered = self.publisher.send_copy(value)
        self.notifier.notify()
        return delivered


class _Inbox:
    """Subscriber (+ optional listener)."""

    def __init__(self, channel: _Channel, listener: bool):
        self.channel = channel
        self.listener = channel.event.listener_builder().create() if listener else None
        self.subscriber = channel.service.subscriber_builder().create()

    def receive(self):
        sample = self.subscriber.receive()
        if sample is None:
            return None
        return _copy_payload(sample, self.channel.payload)

    def wait(self, timeout: float) -> bool:
        """Blocks up to ``timeout`` s for a notification, draining every pending one."""
        if self.listener is None:
            return False
        if timeout <= 0:
            events = self.listener.try_wait()
        else:
            # The wait has microsecond resolution and a zero timeout would mean "forever": round up.
            events = self.listener.timed_wait(iox2.Duration.from_micros(max(1, math.ceil(timeout * 1e6))))
        return len(events) > 0


class StrandClient:
    """A feeder and monitor of one strand cell (service names under ``prefix``).

    Single-threaded, like the iceoryx2 ports it holds. Keep it open until the controller has
    received what was sent (a sample of a publisher dropped before the subscriber connected is
    lost) and for as long as a job runs: the controller stops a running job when its segment
    feeder goes away.
    """

    def __init__(self, prefix: str, node_name: str = "strand-py-client", keep_joint_commands: int = 100_000):
        _quiet_iceoryx2()
        self.names = service_names(prefix)
        self.node = (
            iox2.NodeBuilder.new()
            .name(iox2.NodeName.new(node_name))
            .signal_handling_mode(iox2.SignalHandlingMode.Disabled)
            .create(iox2.ServiceType.Ipc)
        )
        n = self.names
        self._segments = _Outbox(_Channel(self.node, n.segments, SegmentBatch, SEGMENTS_QOS))
        self._control = _Outbox(_Channel(self.node, n.control, Control, CONTROL_QOS))
        self._status = _Inbox(_Channel(self.node, n.status, Status, OUTPUT_QOS), listener=True)
        self._joint_command = _Inbox(_Channel(self.node, n.joint_command, JointCommand, OUTPUT_QOS), listener=False)
        self._status_latest: Optional[Status] = None
        self._jc_queue: collections.deque = collections.deque(maxlen=keep_joint_commands)
        self._batch_seq = 0
        self._control_seq = 0
        #: Statuses received so far (count).
        self.statuses_received = 0
        #: Joint commands received so far (count).
        self.joint_commands_received = 0
        #: Segment batches and segments sent so far (counts).
        self.batches_sent = 0
        self.segments_sent = 0

    # -- receiving -----------------------------------------------------------------------------------

    def _pump(self) -> None:
        """Moves every queued status and joint command out of the (16-deep) subscriber queues."""
        while True:
            s = self._status.receive()
            if s is None:
                break
            self._status_latest = s
            self.statuses_received += 1
        while True:
            c = self._joint_command.receive()
            if c is None:
                break
            self._jc_queue.append(c)
            self.joint_commands_received += 1

    def latest_status(self) -> Optional[Status]:
        """The newest Status received so far (draining the queue first), or None before any."""
        self._pump()
        return self._status_latest

    def wait_status(self, timeout: float) -> Optional[Status]:
        """Blocks until a Status is announced or ``timeout`` s pass; returns the newest Status so far
        (None if none ever arrived). Also collects the joint commands queued meanwhile."""
        self._pump()
        before = self.statuses_received
        deadline = time.monotonic() + timeout
        while True:
            remaining = deadline - time.monotonic()
            self._status.wait(min(max(remaining, 0.0), 0.005))
            self._pump()
            if self.statuses_received != before or time.monotonic() >= deadline:
                return self._status_latest

    def joint_commands(self) -> list[JointCommand]:
        """The joint commands received since the last call, oldest first. The subscriber queue holds
        16 (16 ms at 1 kHz): call this, ``wait_status`` or ``latest_status`` often enough, or the
        oldest are overwritten."""
        self._pump()
        out = list(self._jc_queue)
        self._jc_queue.clear()
        return out

    def status_publishers(self) -> int:
        """Publishers of the status now: 0 means no controller is running."""
        return self._status.channel.publishers()

    # -- sending -------------------------------------------------------------------------------------

    def _send_batch(self, batch: SegmentBatch, deadline: Optional[float]) -> None:
        while True:
            if self._segments.send(batch) > 0:
                return
            # Nobody received it (no controller subscribed yet): it was not delivered, so resending
            # cannot duplicate it.
            if deadline is not None and time.monotonic() >= deadline:
                raise TimeoutError(f"{self.names.segments}: no controller is subscribed")
            self.wait_status(0.01)

    def send_segments(self, segments: Iterable[Segment], timeout: Optional[float] = 30.0) -> int:
        """Sends ``segments`` (their ``seq`` set by the caller, consecutive within a job) in batches of
        up to 32, never past the credit of the newest Status (``last_received_seq + queue_free``),
        waiting for newer statuses when the credit is used up. Returns the number sent. Raises
        TimeoutError if no credit comes within ``timeout`` s (None: wait for ever)."""
        segments = list(segments)
        deadline = None if timeout is None else time.monotonic() + timeout
        k = 0
        while k < len(segments):
            status = self.latest_status()
            limit = status.credit_limit() if status is not None else -1
            n = 0
            while n < SEGMENT_BATCH_CAPACITY and k + n < len(segments) and segments[k + n].seq <= limit:
                n += 1
            if n == 0:
                if deadline is not None and time.monotonic() >= deadline:
                    have = "no status" if status is None else f"credit up to seq {limit}"
                    raise TimeoutError(f"no credit for segment seq {segments[k].seq} ({have})")
                self.wait_status(0.01 if deadline is None else max(0.0, min(0.01, deadline - time.monotonic())))
                continue
            batch = SegmentBatch()
            self._batch_seq += 1
            batch.seq = self._batch_seq
            now = time.monotonic_ns()
            batch.stamp_ns = now
            batch.len = n
            for j in range(n):
                seg = segments[k + j]
                batch.segments[j] = seg
                if batch.segments[j].stamp_ns == 0:
                    batch.segments[j].stamp_ns = now
            self._send_batch(batch, deadline)
            self.batches_sent += 1
            self.segments_sent += n
            k += n
        return len(segments)

    def send_control(self, cmd: int, value: float = 0.0) -> int:
        """Sends a control command (``Command``) with its argument; returns the subscribers reached."""
        c = Control()
        self._control_seq += 1
        c.seq = self._control_seq
        c.stamp_ns = time.monotonic_ns()
        c.command = int(cmd)
        c.value = float(value)
        return self._control.send(c)

    def close(self) -> None:
        """Drops the ports, then the node."""
        for attr in ("_segments", "_control", "_status", "_joint_command"):
            port = getattr(self, attr, None)
            if port is None:
                continue
            for p in ("publisher", "notifier", "subscriber", "listener"):
                obj = getattr(port, p, None)
                if obj is not None:
                    obj.delete()
            setattr(self, attr, None)
        self.node = None

    def __enter__(self) -> "StrandClient":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def wait_for_service(prefix: str, timeout: float) -> Optional[Status]:
    """Waits up to ``timeout`` s for a Status of the service under ``prefix``, without creating any
    service (opens only). Returns the Status, or None."""
    _quiet_iceoryx2()
    names = service_names(prefix)
    node = iox2.NodeBuilder.new().signal_handling_mode(iox2.SignalHandlingMode.Disabled).create(iox2.ServiceType.Ipc)
    deadline = time.monotonic() + timeout
    inbox = None
    while time.monotonic() < deadline:
        if inbox is None:
            try:
                inbox = _Inbox(_Channel(node, names.status, Status, OUTPUT_QOS, open_only=True), listener=True)
            except Exception:  # not there yet
                time.sleep(0.05)
                continue
        inbox.wait(0.05)
        s = inbox.receive()
        if s is not None:
            return s
    return None


# --- the end-to-end check --------------------------------------------------------------------------

# Nozzle down: 180° about y, so the tool z axis points along -z of W.
NOZZLE_DOWN = (0.0, 0.0, 1.0, 0.0)
FILAMENT_PER_M = 0.0333  # m of filament per m of path


def demo_job(first_seq: int = 1) -> list[Segment]:
    """A travel line to (0.45, -0.02, 0.2) m, then a 20 mm square of extruding lines at 0.03 m/s."""
    start = (0.45, -0.02, 0.2)
    corners = [(0.47, -0.02, 0.2), (0.47, 0.0, 0.2), (0.45, 0.0, 0.2), (0.45, -0.02, 0.2)]
    segs = [Segment.line(first_seq, start, feed=0.03, orientation=NOZZLE_DOWN, flags=SegmentFlags.TRAVEL, source_line=1)]
    prev = start
    for i, c in enumerate(corners):
        length = math.dist(prev, c)
        flags = SegmentFlags.EXTRUDE
        if i == 0:
            flags |= SegmentFlags.LAYER_START
        if i == len(corners) - 1:
            flags |= SegmentFlags.LAST
        segs.append(
            Segment.line(
                first_seq + 1 + i,
                c,
                feed=0.03,
                orientation=NOZZLE_DOWN,
                filament=FILAMENT_PER_M * length,
                flags=flags,
                source_line=2 + i,
            )
        )
        prev = c
    return segs


class CheckFailed(Exception):
    pass


def run_check(prefix: str, timeout: float, verbose: bool = False) -> str:
    """Runs the demo job against the service under ``prefix``; returns the summary line or raises
    CheckFailed."""
    t0 = time.monotonic()
    deadline = t0 + timeout

    def log(msg: str) -> None:
        if verbose:
            print(f"[{time.monotonic() - t0:7.3f} s] {msg}", file=sys.stderr)

    with StrandClient(prefix) as client:
        # 1. The service is there and speaks our contract.
        status = None
        while status is None and time.monotonic() < deadline:
            status = client.wait_status(0.1)
        if status is None:
            raise CheckFailed(f"no Status on {client.names.status} within {timeout} s (is the service running?)")
        if status.contract_version != CONTRACT_VERSION:
            raise CheckFailed(f"service speaks contract v{status.contract_version}, this client v{CONTRACT_VERSION}")
        log(f"service up: {status.describe()}")
        if status.run_state != RunState.IDLE:
            raise CheckFailed(f"service not idle: {status.describe()}")
        rejected0 = status.rejected

        # 2. Queue the job.
        segs = demo_job(first_seq=1)
        last_seq = segs[-1].seq
        client.send_segments(segs, timeout=max(0.1, deadline - time.monotonic()))
        log(f"sent {len(segs)} segments in {client.batches_sent} batch(es)")
        while True:
            status = client.wait_status(0.05)
            if status.rejected != rejected0:
                raise CheckFailed(
                    f"segment rejected: {enum_name(RejectReason, status.last_reject_reason)} "
                    f"(seq {status.last_rejected_seq}); {status.describe()}"
                )
            if status.last_received_seq >= last_seq:
                break
            if time.monotonic() >= deadline:
                raise CheckFailed(f"segments not received within {timeout} s: {status.describe()}")
        log(f"queued: {status.describe()}")

        # 3. Start and follow the job.
        if client.send_control(Command.START) == 0:
            raise CheckFailed("Start reached no subscriber")
        log("sent Start")
        commands: list[JointCommand] = []
        seen_moving = False
        states_seen = []
        status_gone_since = None
        while True:
            status = client.wait_status(0.05)
            commands.extend(client.joint_commands())
            if not states_seen or states_seen[-1] != status.run_state:
                states_seen.append(status.run_state)
                log(f"state {enum_name(RunState, status.run_state)}: {status.describe()}")
            if status.rejected != rejected0:
                raise CheckFailed(
                    f"rejected: {enum_name(RejectReason, status.last_reject_reason)} "
                    f"(seq {status.last_rejected_seq}); {status.describe()}"
                )
            if status.run_state != RunState.IDLE:
                seen_moving = True
            outcome = status.job_outcome
            if seen_moving and outcome == JobOutcome.FINISHED and status.run_state == RunState.IDLE:
                break
            if outcome in (JobOutcome.STOPPED, JobOutcome.FAULTED) or status.run_state == RunState.FAULT:
                raise CheckFailed(
                    f"job ended {enum_name(JobOutcome, outcome)}, fault {enum_name(FaultCode, status.fault)} "
                    f"at segment {status.executing_seq} (line {status.executing_line}): {status.describe()}"
                )
            if client.status_publishers() == 0:
                # The service is gone; give the last samples a moment, then give up.
                status_gone_since = status_gone_since or time.monotonic()
                if time.monotonic() - status_gone_since > 0.5:
                    raise CheckFailed(f"service exited before the job finished: {status.describe()}")
            if time.monotonic() >= deadline:
                raise CheckFailed(f"job not finished within {timeout} s: {status.describe()}")
        commands.extend(client.joint_commands())
        log(f"finished: {status.describe()}")
        path = [enum_name(RunState, s) for s in states_seen]
        log(f"run states: {' -> '.join(path)}")

        # 4. Check what came back.
        problems = []
        if len(commands) < 100:
            problems.append(f"only {len(commands)} joint commands (want >= 100)")
        bad_dof = [c.seq for c in commands if c.dof != 7]
        if bad_dof:
            problems.append(f"{len(bad_dof)} joint commands with dof != 7 (first seq {bad_dof[0]})")
        nonfinite = [
            c.seq
            for c in commands
            if not all(math.isfinite(x) for arr in (c.position, c.velocity, c.acceleration) for x in arr[: c.dof])
        ]
        if nonfinite:
            problems.append(f"{len(nonfinite)} joint commands with non-finite values (first seq {nonfinite[0]})")
        invalid = [c.seq for c in commands if c.valid != 1]
        if invalid:
            problems.append(f"{len(invalid)} joint commands not valid (first seq {invalid[0]})")
        ticks = [c.tick for c in commands]
        not_increasing = [i for i in range(1, len(ticks)) if ticks[i] <= ticks[i - 1]]
        if not_increasing:
            i = not_increasing[0]
            problems.append(f"tick numbers not increasing: {ticks[i - 1]} then {ticks[i]}")
        if status.segments_accepted < len(segs):
            problems.append(f"only {status.segments_accepted} segments accepted (sent {len(segs)})")
        if problems:
            raise CheckFailed("; ".join(problems))
        gaps = sum(1 for i in range(1, len(ticks)) if ticks[i] != ticks[i - 1] + 1)
        log(
            f"{len(commands)} joint commands, ticks {ticks[0]}..{ticks[-1]} ({gaps} gaps), "
            f"{time.monotonic() - t0:.2f} s; underruns {status.underruns} overruns {status.overruns} "
            f"clamps {status.clamps}"
        )
        return (
            f"python client: job finished, {len(commands)} joint commands, "
            f"{client.statuses_received} status messages, segments accepted {status.segments_accepted}"
        )


def main(argv: Optional[list[str]] = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--prefix", default="strand/cell", help="service-name prefix (default strand/cell)")
    ap.add_argument("--timeout", type=float, default=60.0, help="overall time limit in s (default 60)")
    ap.add_argument("--wait-service", type=float, metavar="SECONDS", help="only wait for the service's Status")
    ap.add_argument("-v", "--verbose", action="store_true", help="log progress to stderr")
    args = ap.parse_args(argv)
    if args.wait_service is not None:
        s = wait_for_service(args.prefix, args.wait_service)
        if s is None:
            print(f"python client: no Status under {args.prefix} within {args.wait_service} s", file=sys.stderr)
            return 1
        return 0
    try:
        print(run_check(args.prefix, args.timeout, args.verbose))
        return 0
    except CheckFailed as e:
        print(f"python client: FAILED: {e}")
        return 1
    except Exception as e:  # iceoryx2 errors, timeouts
        print(f"python client: FAILED: {type(e).__name__}: {e}")
        return 1


if __name__ == "__main__":
    sys.exit(main())
