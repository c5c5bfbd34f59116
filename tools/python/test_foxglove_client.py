#!/usr/bin/env python3
"""Checks foxglove_client.py against a real Foxglove server: the Python foxglove-sdk's, built from
the same Rust crate (foxglove 0.30.3) as strand's live server.

The test process runs the server and logs hand-encoded CDR (``std_msgs/msg/String`` and
``geometry_msgs/msg/PoseStamped``, ros2msg schemas) on it; the client runs as a subprocess, as the
tests run it. Checked: connecting to a server that starts late, decoding, counts and byte totals,
evenly spread samples, a channel advertised after the initial subscribe, --topics, --publish with
and without the clientPublish capability, and the exit status when nothing listens.

Runs under pytest or as a script (exit 0 on success). Skipped if foxglove-sdk cannot be imported
(``pip install foxglove-sdk==0.30.3 websockets==15.0.1 mcap-ros2-support==0.6.0``).
"""

from __future__ import annotations

import json
import os
import socket
import struct
import subprocess
import sys
import threading
import time
import unittest

try:
    import foxglove
    from foxglove.websocket import Capability, ServerListener
except ImportError as e:  # the client itself does not need the SDK
    foxglove = None
    ServerListener = object
    _IMPORT_ERROR = e

CLIENT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "foxglove_client.py")

STRING_SCHEMA = "string data\n"
POSE_STAMPED_SCHEMA = """std_msgs/Header header
geometry_msgs/Pose pose
================================================================================
MSG: std_msgs/Header
builtin_interfaces/Time stamp
string frame_id
================================================================================
MSG: geometry_msgs/Pose
Point position
Quaternion orientation
================================================================================
MSG: geometry_msgs/Point
float64 x
float64 y
float64 z
================================================================================
MSG: geometry_msgs/Quaternion
float64 x 0
float64 y 0
float64 z 0
float64 w 1
"""
# ~20 kB, like a robot's URDF on /robot_description.
URDF = '<?xml version="1.0"?>\n<robot name="selftest">\n' + "".join(
    f'  <link name="link_{i}"><inertial><mass value="{i}.5"/></inertial></link>\n' for i in range(300)
) + "</robot>\n"


class Cdr:
    """A little-endian CDR writer, by hand, so the decoding side (mcap_ros2) is checked against it."""

    def __init__(self) -> None:
        self.buf = bytearray(b"\x00\x01\x00\x00")  # encapsulation header: CDR_LE

    def _put(self, fmt: str, value) -> "Cdr":
        size = struct.calcsize(fmt)
        self.buf += b"\x00" * (-(len(self.buf) - 4) % size)  # aligned from the end of the header
        self.buf += struct.pack("<" + fmt, value)
        return self

    def i32(self, v: int) -> "Cdr":
        return self._put("i", v)

    def u32(self, v: int) -> "Cdr":
        return self._put("I", v)

    def f64(self, v: float) -> "Cdr":
        return self._put("d", v)

    def string(self, s: str) -> "Cdr":
        data = s.encode() + b"\x00"
        self.u32(len(data)).buf += data
        return self


def string_cdr(text: str) -> bytes:
    return bytes(Cdr().string(text).buf)


def pose_cdr(seq: int) -> bytes:
    """PoseStamped number `seq`: stamp.sec = seq, so each decoded sample can be checked alone."""
    c = Cdr().i32(seq).u32(500).string("base")
    for v in (seq * 0.001, -1.5, 2.25, 0.0, 0.0, 0.0, 1.0):
        c.f64(v)
    return bytes(c.buf)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def run_client(port: int, *args: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, CLIENT, f"ws://127.0.0.1:{port}", *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def finish(proc: subprocess.Popen, timeout: float = 30) -> tuple[int, dict, str]:
    out, err = proc.communicate(timeout=timeout)
    try:
        return proc.returncode, json.loads(out) if out.strip() else {}, err
    except json.JSONDecodeError:
        raise AssertionError(f"client printed no JSON object: {out!r}\nstderr: {err}")


class Listener(ServerListener):
    """Records what clients publish; the base class ignores the other callbacks."""

    def __init__(self) -> None:
        self.advertised: list = []
        self.messages: list = []

    def on_client_advertise(self, client, channel) -> None:
        self.advertised.append((channel.topic, channel.encoding, channel.schema_name))

    def on_message_data(self, client, client_channel_id, data) -> None:
        self.messages.append((client_channel_id, bytes(data)))


class Feed:
    """A server on `port` logging /pose at ~100 Hz and /robot_description every 0.2 s; /late is
    created `late_after` s after start, after the client's initial subscribe."""

    def __init__(self, port: int, publish: bool, late_after: float = 1.0) -> None:
        self.ctx = foxglove.Context()
        self.listener = Listener()
        self.server = foxglove.start_server(
            name="strand-selftest", host="127.0.0.1", port=port, context=self.ctx,
            capabilities=[Capability.ClientPublish] if publish else [],
            supported_encodings=["json"] if publish else None,
            server_listener=self.listener)
        self.pose = self._channel("/pose", "geometry_msgs/msg/PoseStamped", POSE_STAMPED_SCHEMA)
        self.urdf = self._channel("/robot_description", "std_msgs/msg/String", STRING_SCHEMA)
        self.late_after = late_after
        self.stop_event = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _channel(self, topic: str, name: str, schema: str):
        return foxglove.Channel(topic, message_encoding="cdr", context=self.ctx,
                                schema=foxglove.Schema(name=name, encoding="ros2msg", data=schema.encode()))

    def _run(self) -> None:
        start, seq, late = time.monotonic(), 0, None
        while not self.stop_event.wait(0.01):
            self.pose.log(pose_cdr(seq), log_time=time.time_ns())
            if seq % 20 == 0:
                self.urdf.log(string_cdr(URDF))
            if late is None and time.monotonic() - start > self.late_after:
                late = self._channel("/late", "std_msgs/msg/String", STRING_SCHEMA)
            if late is not None:
                late.log(string_cdr(f"late {seq}"))
            seq += 1

    def stop(self) -> None:
        self.stop_event.set()
        self.thread.join()
        self.server.stop()


def _require_sdk() -> None:
    if foxglove is None:
        raise unittest.SkipTest(f"foxglove-sdk cannot be imported ({_IMPORT_ERROR})")


def test_decode_subscribe_publish() -> None:
    _require_sdk()
    port = free_port()
    request = '{"command": "pause", "seq": 7}'
    # The client starts first: it must keep retrying until the server is up.
    proc = run_client(port, "--seconds", "3", "--json", "--publish", "/control", request)
    time.sleep(0.8)
    feed = Feed(port, publish=True)
    try:
        rc, out, err = finish(proc)
    finally:
        feed.stop()
    assert rc == 0, f"exit {rc}: {err}"
    assert out["subprotocol"] == "foxglove.sdk.v1", out["subprotocol"]
    assert out["server_info"]["name"] == "strand-selftest"
    assert "clientPublish" in out["server_info"]["capabilities"]
    assert out["server_info"]["supportedEncodings"] == ["json"]
    assert {c["topic"] for c in out["channels"]} == {"/pose", "/robot_description", "/late"}
    assert all(c["encoding"] == "cdr" and c["schemaEncoding"] == "ros2msg" for c in out["channels"])

    pose = out["topics"]["/pose"]
    assert pose["count"] > 100 and "decode_errors" not in pose, pose["count"]
    assert pose["bytes"] == pose["count"] * len(pose_cdr(0))
    assert pose["first_log_time"] <= pose["last_log_time"]
    assert len(pose["samples"]) == 50
    times = [s["log_time"] for s in pose["samples"]]
    assert times == sorted(times) and times[0] == pose["first_log_time"]
    for m in [pose["first"], pose["last"]] + [s["message"] for s in pose["samples"]]:
        seq = m["header"]["stamp"]["sec"]
        assert m["header"] == {"stamp": {"sec": seq, "nanosec": 500}, "frame_id": "base"}, m
        assert m["pose"]["position"] == {"x": seq * 0.001, "y": -1.5, "z": 2.25}, m
        assert m["pose"]["orientation"] == {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}, m
    seqs = [s["message"]["header"]["stamp"]["sec"] for s in pose["samples"]]
    gaps = [b - a for a, b in zip(seqs, seqs[1:])]
    assert min(gaps) > 0 and max(gaps) <= 3 * min(gaps) + 2, f"samples not spread evenly: {seqs}"

    urdf = out["topics"]["/robot_description"]
    assert urdf["first"] == {"data": URDF} and urdf["last"] == {"data": URDF}
    assert urdf["bytes"] == urdf["count"] * len(string_cdr(URDF))
    assert urdf["samples"][0]["message"]["data"].endswith(f"...(+{len(URDF) - 256} chars)")
    late = out["topics"]["/late"]
    assert late["count"] > 10 and late["first"]["data"].startswith("late "), late

    assert out["total_bytes"] > sum(t["bytes"] for t in out["topics"].values())
    assert 3.0 <= out["seconds"] < 4.0
    assert out["publish"] == "sent"
    assert feed.listener.advertised == [("/control", "json", "strand_msgs/msg/ControlRequest")]
    assert feed.listener.messages == [(1, request.encode())], feed.listener.messages


def test_topics_filter_and_refused_publish() -> None:
    _require_sdk()
    port = free_port()
    feed = Feed(port, publish=False, late_after=0.1)
    try:
        rc, out, err = finish(run_client(port, "--seconds", "1.5", "--json", "--topics", "/pose,/late",
                                         "--publish", "/control", "{}"))
    finally:
        feed.stop()
    assert rc == 0, f"exit {rc}: {err}"
    assert set(out["topics"]) == {"/pose", "/late"}, set(out["topics"])
    assert out["publish"] == "refused: no clientPublish capability"
    assert out["server_info"]["capabilities"] == [] and feed.listener.messages == []


def test_no_server() -> None:
    port = free_port()  # nothing listens there
    start = time.monotonic()
    proc = subprocess.run([sys.executable, CLIENT, f"ws://127.0.0.1:{port}", "--json",
                           "--connect-timeout", "1"], capture_output=True, text=True, timeout=30)
    assert proc.returncode == 1 and proc.stdout == "", proc
    assert "cannot connect" in proc.stderr and time.monotonic() - start < 10, proc.stderr


def main() -> int:
    tests = [test_decode_subscribe_publish, test_topics_filter_and_refused_publish, test_no_server]
    passed = failed = skipped = 0
    for test in tests:
        try:
            test()
            passed += 1
            print(f"ok      {test.__name__}")
        except unittest.SkipTest as e:
            skipped += 1
            print(f"skipped {test.__name__}: {e}")
        except Exception as e:
            failed += 1
            print(f"FAILED  {test.__name__}: {type(e).__name__}: {e}")
    print(f"test_foxglove_client: {passed} passed, {failed} failed, {skipped} skipped")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
