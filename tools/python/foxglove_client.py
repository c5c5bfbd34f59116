#!/usr/bin/env python3
"""An independent Foxglove WebSocket client, used by the tests to check strand's live server.

Needs ``pip install websockets==15.0.1 mcap-ros2-support==0.6.0``. CDR payloads of ``ros2msg``
channels are decoded with mcap_ros2 (not with strand's Rust CDR code), JSON payloads with json::

    python3 tools/python/foxglove_client.py ws://127.0.0.1:8765 --seconds 5 --json \\
        [--topics /status,/tf] [--publish /control '{"command": "pause"}']

It connects (retrying every 0.2 s for up to --connect-timeout s, as the server may be starting),
collects advertisements for 0.5 s, subscribes to every advertised channel (or only --topics; later
advertisements too), optionally publishes one JSON message on a client channel, and after
--seconds prints a summary: with --json one JSON object (server_info, channels, per-topic counts,
bytes, log times, first/last/sampled decoded messages, total_bytes, seconds, publish).

The foxglove crate 0.30.x negotiates only ``foxglove.sdk.v1`` (and ``.v1.1``, whose schema tables
this client does not read); older servers speak ``foxglove.websocket.v1``. Both use the same
messages, so both v1 names are offered. Exit 0 on success, 1 if no connection could be made,
3 if the server closed the connection before --seconds (the summary is printed all the same).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import math
import struct
import sys
import time
from typing import Any, Optional

from mcap.records import Schema
from mcap_ros2.decoder import DecoderFactory
from websockets.asyncio.client import ClientConnection, connect
from websockets.exceptions import ConnectionClosed, InvalidHandshake, InvalidStatus


class ConnectError(Exception):
    pass

SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]
OP_MESSAGE_DATA = 0x01  # server: subscription id u32, log time u64, payload; client: channel id u32, payload
OP_TIME = 0x02
MAX_SAMPLES = 50
SAMPLE_STRING_LIMIT = 256  # samples cut long strings (a URDF is ~20 kB); first and last keep them whole
PUBLISH_CHANNEL_ID = 1
PUBLISH_SCHEMA_NAME = "strand_msgs/msg/ControlRequest"


def to_plain(value: Any, limit: Optional[int] = None) -> Any:
    """Converts a decoded message to JSON-able values; non-finite floats become "nan"/"inf"/"-inf"."""
    if value is None or isinstance(value, (bool, int)):
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else str(value)
    if isinstance(value, str):
        if limit is not None and len(value) > limit:
            return f"{value[:limit]}...(+{len(value) - limit} chars)"
        return value
    if isinstance(value, (bytes, bytearray, memoryview)):
        return list(bytes(value))
    if isinstance(value, dict):
        return {str(k): to_plain(v, limit) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [to_plain(v, limit) for v in value]
    if hasattr(value, "tolist"):  # numpy arrays and scalars, array.array
        return to_plain(value.tolist(), limit)
    slots = getattr(type(value), "__slots__", None)  # mcap_ros2 message classes list their fields here
    if slots:
        return {name: to_plain(getattr(value, name, None), limit) for name in slots}
    if hasattr(value, "__dict__"):
        return {k: to_plain(v, limit) for k, v in vars(value).items() if not k.startswith("_")}
    return str(value)


class TopicStats:
    """Counts one topic's messages and keeps the first, the last and an evenly spread sample."""

    def __init__(self) -> None:
        self.count = 0
        self.bytes = 0
        self.first_log_time: Optional[int] = None
        self.last_log_time: Optional[int] = None
        self.first: Any = None
        self.last: Any = None
        self.decode_errors = 0
        self.decode_error: Optional[str] = None
        # Every stride-th message is kept; when 2*MAX_SAMPLES are kept, every other one is dropped
        # and the stride doubles, so the kept ones stay evenly spread without knowing the total.
        self._kept: list[dict] = []
        self._stride = 1

    def add(self, log_time: int, size: int, decoded: Any) -> None:
        if self.count % self._stride == 0:
            self._kept.append({"log_time": log_time, "message": to_plain(decoded, SAMPLE_STRING_LIMIT)})
            if len(self._kept) >= 2 * MAX_SAMPLES:
                self._kept = self._kept[::2]
                self._stride *= 2
        if self.count == 0:
            self.first_log_time, self.first = log_time, to_plain(decoded)
        self.count += 1
        self.bytes += size
        self.last_log_time, self.last = log_time, decoded

    def to_json(self) -> dict:
        n = len(self._kept)
        picks = range(n)
        if n > MAX_SAMPLES:
            picks = sorted({round(i * (n - 1) / (MAX_SAMPLES - 1)) for i in range(MAX_SAMPLES)})
        out = {
            "count": self.count, "bytes": self.bytes,
            "first_log_time": self.first_log_time, "last_log_time": self.last_log_time,
            "first": self.first, "last": to_plain(self.last),
            "samples": [self._kept[i] for i in picks],
        }
        if self.decode_errors:
            out.update(decode_errors=self.decode_errors, decode_error=self.decode_error)
        return out


class FoxgloveClient:
    def __init__(self, topics: Optional[set[str]], publish: Optional[tuple[str, str]]) -> None:
        self.topics = topics  # None: every topic
        self.publish_request = publish
        self.server_info: Optional[dict] = None
        self.channels: dict[int, dict] = {}  # advertised and not unadvertised, by channel id
        self.channel_log: list[dict] = []  # every advertisement, in order, for the summary
        self.subscriptions: dict[int, dict] = {}  # subscription id -> channel
        self.decoders: dict[int, Any] = {}  # channel id -> decode function, or None (undecodable)
        self.stats: dict[str, TopicStats] = {}
        self.statuses: list[dict] = []
        self.total_bytes = 0
        self.subscribing = False  # becomes True after the initial wait for advertisements
        self.publish_result: Optional[str] = None
        self.elapsed = 0.0
        self._factory = DecoderFactory()
        self._schema_ids = 0  # DecoderFactory caches by schema id: one fresh id per advertisement
        self._next_sub_id = 1
        self.count_only = False  # --count-only: bytes and counts, no decoding (a cheap viewer, for cost measurements)

    def _decoder_for(self, ch: dict) -> Any:
        if ch.get("encoding") == "json":
            return json.loads
        if ch.get("encoding") != "cdr" or ch.get("schemaEncoding") != "ros2msg":
            return None
        self._schema_ids += 1
        schema = Schema(id=self._schema_ids, name=ch["schemaName"], encoding="ros2msg",
                        data=ch.get("schema", "").encode())
        return self._factory.decoder_for("cdr", schema)

    def on_text(self, text: str) -> list[dict]:
        """Handles a JSON message; returns newly advertised channels that want a subscription."""
        msg = json.loads(text)
        op = msg.get("op")
        if op == "serverInfo":
            self.server_info = {k: v for k, v in msg.items() if k != "op"}
            self.server_info.setdefault("capabilities", [])
            self.server_info.setdefault("supportedEncodings", [])
        elif op == "advertise":
            for ch in msg.get("channels", []):
                self.channels[ch["id"]] = ch
                keys = ("id", "topic", "encoding", "schemaName", "schemaEncoding")
                self.channel_log.append({k: ch.get(k) for k in keys})
                try:
                    self.decoders[ch["id"]] = self._decoder_for(ch)
                except Exception as e:  # a schema mcap_ros2 cannot parse: count its messages undecoded
                    self.decoders[ch["id"]] = None
                    print(f"foxglove_client: cannot decode {ch['topic']} ({ch['schemaName']}): {e}",
                          file=sys.stderr)
            return [ch for ch in msg.get("channels", []) if self.wanted(ch)]
        elif op == "unadvertise":
            # The server drops its subscriptions to these; a re-advertised id is subscribed anew.
            gone = set(msg.get("channelIds", []))
            for cid in gone:
                self.channels.pop(cid, None)
            self.subscriptions = {s: ch for s, ch in self.subscriptions.items() if ch["id"] not in gone}
        elif op == "status":
            self.statuses.append({k: v for k, v in msg.items() if k != "op"})
            print(f"foxglove_client: server status level {msg.get('level')}: {msg.get('message')}",
                  file=sys.stderr)
        return []

    def wanted(self, ch: dict) -> bool:
        return self.topics is None or ch["topic"] in self.topics

    def on_binary(self, data: bytes) -> None:
        if not data or data[0] != OP_MESSAGE_DATA:
            return  # Time (0x02) and the replies to requests this client never makes
        sub_id, log_time = struct.unpack_from("<IQ", data, 1)
        payload = data[13:]
        ch = self.subscriptions.get(sub_id)
        if ch is None:
            return
        stats = self.stats.setdefault(ch["topic"], TopicStats())
        decoded = None
        decoder = None if self.count_only else self.decoders.get(ch["id"])
        if decoder is not None:
            try:
                decoded = decoder(payload)
            except Exception as e:  # a payload that does not match its schema is what the tests look for
                stats.decode_errors += 1
                stats.decode_error = stats.decode_error or f"{type(e).__name__}: {e}"
        stats.add(log_time, len(payload), decoded)

    async def subscribe(self, ws: ClientConnection, channels: list[dict]) -> None:
        subs = []
        for ch in sorted(channels, key=lambda c: c["id"]):
            if any(s["id"] == ch["id"] for s in self.subscriptions.values()):
                continue
            self.subscriptions[self._next_sub_id] = ch
            self.stats.setdefault(ch["topic"], TopicStats())  # listed even if nothing arrives
            subs.append({"id": self._next_sub_id, "channelId": ch["id"]})
            self._next_sub_id += 1
        if subs:
            await ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))

    async def publish(self, ws: ClientConnection) -> None:
        topic, text = self.publish_request
        if "clientPublish" not in (self.server_info or {}).get("capabilities", []):
            self.publish_result = "refused: no clientPublish capability"
            return
        channel = {"id": PUBLISH_CHANNEL_ID, "topic": topic, "encoding": "json",
                   "schemaName": PUBLISH_SCHEMA_NAME}
        await ws.send(json.dumps({"op": "advertise", "channels": [channel]}))
        await ws.send(struct.pack("<BI", OP_MESSAGE_DATA, PUBLISH_CHANNEL_ID) + text.encode("utf-8"))
        self.publish_result = "sent"

    async def run(self, ws: ClientConnection, seconds: float) -> Optional[str]:
        """Collects for `seconds`; returns why the connection closed early, or None."""
        start = time.monotonic()
        subscribe_at, end = start + min(0.5, seconds / 2), start + seconds
        try:
            while (now := time.monotonic()) < end:
                if not self.subscribing and now >= subscribe_at:
                    self.subscribing = True
                    await self.subscribe(ws, [ch for ch in self.channels.values() if self.wanted(ch)])
                    if self.publish_request:
                        await self.publish(ws)
                try:
                    msg = await asyncio.wait_for(ws.recv(), (end if self.subscribing else subscribe_at) - now)
                except TimeoutError:
                    continue
                if isinstance(msg, str):
                    self.total_bytes += len(msg.encode("utf-8"))
                    new = self.on_text(msg)
                    if self.subscribing and new:
                        await self.subscribe(ws, new)
                else:
                    self.total_bytes += len(msg)
                    self.on_binary(msg)
        except ConnectionClosed as e:
            return f"server closed the connection after {time.monotonic() - start:.2f} s: {e}"
        finally:
            self.elapsed = time.monotonic() - start
        return None

    def summary(self) -> dict:
        return {
            "server_info": self.server_info,
            "channels": self.channel_log,
            "topics": {topic: s.to_json() for topic, s in sorted(self.stats.items())},
            "statuses": self.statuses,
            "total_bytes": self.total_bytes,
            "seconds": round(self.elapsed, 3),
            "publish": self.publish_result,
        }


async def open_connection(url: str, timeout: float, subprotocols: list[str]) -> ClientConnection:
    deadline = time.monotonic() + timeout
    while True:
        try:
            return await connect(url, subprotocols=subprotocols, max_size=None, max_queue=4096,
                                 compression=None, open_timeout=max(0.5, deadline - time.monotonic()))
        except InvalidStatus as e:  # the server answered and refused: retrying will not help
            body = (e.response.body or b"").decode("utf-8", "replace")
            raise ConnectError(f"{url} refused the WebSocket handshake: {e} {body}".rstrip())
        except (OSError, InvalidHandshake, TimeoutError) as e:
            if time.monotonic() + 0.2 >= deadline:
                raise ConnectError(f"cannot connect to {url} within {timeout:g} s: {e}")
        await asyncio.sleep(0.2)


async def main_async(args: argparse.Namespace) -> int:
    topics = {t for t in args.topics.split(",") if t} if args.topics else None
    client = FoxgloveClient(topics, tuple(args.publish) if args.publish else None)
    async with await open_connection(args.url, args.connect_timeout, args.subprotocol or SUBPROTOCOLS) as ws:
        closed = await client.run(ws, args.seconds)
        summary = dict(client.summary(), subprotocol=ws.subprotocol)
    if args.json:
        print(json.dumps(summary, allow_nan=False))
    else:
        info = summary["server_info"] or {}
        print(f"server {info.get('name')!r} ({summary['subprotocol']}), capabilities {info.get('capabilities')}")
        for topic, s in summary["topics"].items():
            print(f"  {topic}: {s['count']} messages ({s['count'] / max(summary['seconds'], 1e-9):.1f}/s), "
                  f"{s['bytes']} bytes, {s.get('decode_errors', 0)} decode errors")
        print(f"  total {summary['total_bytes']} bytes in {summary['seconds']} s; publish: {summary['publish']}")
    if closed:
        print(f"foxglove_client: {closed}", file=sys.stderr)
        return 3
    return 0


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("url", help="server URL, e.g. ws://127.0.0.1:8765")
    p.add_argument("--seconds", type=float, default=5.0, help="how long to collect (default 5)")
    p.add_argument("--topics", help="comma-separated topics to subscribe to (default: all)")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of a text summary")
    p.add_argument("--publish", nargs=2, metavar=("TOPIC", "JSON_TEXT"),
                   help="publish JSON_TEXT once on TOPIC (needs the clientPublish capability)")
    p.add_argument("--connect-timeout", type=float, default=10.0, help="seconds to keep retrying (default 10)")
    p.add_argument("--subprotocol", action="append",
                   help=f"offer this subprotocol instead of {', '.join(SUBPROTOCOLS)} (repeatable)")
    p.add_argument("--count-only", action="store_true",
                   help="count messages and bytes without decoding them (keeps this client's CPU off a cost measurement)")
    args = p.parse_args()
    if args.seconds <= 0:
        p.error("--seconds must be positive")
    try:
        return asyncio.run(main_async(args))
    except ConnectError as e:
        print(f"foxglove_client: {e}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
