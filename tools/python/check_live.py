#!/usr/bin/env python3
"""Checks a live view against the MCAP log of the same run, with independent decoders.

    python3 tools/python/check_live.py LIVE.json RUN.mcap [--json]

LIVE.json is what ``foxglove_client.py --json`` printed while it watched strand's live server;
RUN.mcap the log the same service wrote. Decoding is mcap + mcap-ros2-support on both sides (the
client decoded the WebSocket's CDR with mcap_ros2 too), never strand's own Rust code. Checked:

- every channel of the log is advertised live, with the same schema name and encoding;
- ``/robot_description`` arrived whole and equals the log's (and the log's URDF attachment);
- ``/tf`` names every link of that URDF (and ``tcp``) as a child frame, with finite transforms;
- every sampled live message equals, field for field, a message of the log on the same topic at
  the same log time (the live stream is the log's own bytes, decimated); on the trails (/bead,
  /path/executed) a message sent to a late subscriber holds the trail so far, and each of its
  chunks must be the log's chunk of the same id, or the start of it;
- the stream carried what it should: status, joints, TCP, extruder and the scene (path, bead).

Prints a summary (bytes per second per topic); exit 0 when everything holds, 1 otherwise.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import xml.etree.ElementTree as ET
from collections import defaultdict
from pathlib import Path

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

sys.path.insert(0, str(Path(__file__).resolve().parent))
from foxglove_client import to_plain  # noqa: E402  (the same plain-JSON conversion as the client)


TRAILS = ("/bead", "/path/executed")


def close(a, b) -> bool:
    """Equal, floats to the bit except NaN == NaN (the JSON round trip keeps doubles exact)."""
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(close(a[k], b[k]) for k in a)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(close(x, y) for x, y in zip(a, b))
    if isinstance(a, str) and a in ("nan", "inf", "-inf") and isinstance(b, float):
        return str(b) == a or (a == "nan" and math.isnan(b))
    if isinstance(a, float) or isinstance(b, float):
        return float(a) == float(b)
    return a == b


def layout_topics(node, key: str = "") -> set[str]:
    """Topics a layout shows: message paths (`/status.tcp_error`) and the 3D panel's topic keys,
    not the topics its publish tool would send on."""
    found: set[str] = set()
    if isinstance(node, dict):
        for k, v in node.items():
            if k == "publish":
                continue
            if key == "topics" and k.startswith("/"):
                found.add(k)
            found |= layout_topics(v, k)
    elif isinstance(node, list):
        for v in node:
            found |= layout_topics(v, key)
    elif isinstance(node, str) and node.startswith("/") and key in ("value", "topic", "topicPath", "path"):
        found.add(node.split(".")[0].split("[")[0].split("{")[0])
    return found


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("live")
    ap.add_argument("mcap")
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--layout", help="a Foxglove layout: every topic it shows must be a channel of the stream")
    args = ap.parse_args()
    live = json.loads(Path(args.live).read_text())
    failures: list[str] = []

    # The log, decoded by mcap_ros2, indexed by (topic, log time).
    by_time: dict[tuple[str, int], list] = defaultdict(list)
    channels = {}
    urdf_attachment = None
    with open(args.mcap, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        for ch in summary.channels.values():
            channels[ch.topic] = (summary.schemas[ch.schema_id].name, ch.message_encoding)
        for att in reader.iter_attachments():
            if att.name == "robot.urdf":
                urdf_attachment = att.data.decode()
        for _schema, channel, message, decoded in reader.iter_decoded_messages():
            by_time[(channel.topic, message.log_time)].append(to_plain(decoded))

    advertised = {c["topic"]: (c["schemaName"], c["encoding"]) for c in live["channels"]}
    for topic, (schema, encoding) in sorted(channels.items()):
        if advertised.get(topic) != (schema, encoding):
            failures.append(f"{topic}: log has {schema} ({encoding}), live advertised {advertised.get(topic)}")

    topics = live["topics"]
    description = (topics.get("/robot_description") or {}).get("first") or {}
    urdf = description.get("data", "")
    log_urdf = [m[0]["data"] for (t, _), m in by_time.items() if t == "/robot_description"]
    if not urdf or not log_urdf or urdf != log_urdf[0]:
        failures.append("/robot_description: missing live, or not the log's")
    links = {e.get("name") for e in ET.fromstring(urdf).iter("link")} if urdf else set()
    # The drawn URDF is the robot's with a stick figure added: the same links and joints.
    if urdf_attachment:
        robot = ET.fromstring(urdf_attachment)
        joints = lambda root: sorted((j.get("name"), j.find("parent").get("link"), j.find("child").get("link"))  # noqa: E731
                                     for j in root.iter("joint"))
        if links != {e.get("name") for e in robot.iter("link")} or (urdf and joints(ET.fromstring(urdf)) != joints(robot)):
            failures.append("/robot_description: not the robot's links and joints")
        if urdf and not any(True for _ in ET.fromstring(urdf).iter("visual")):
            failures.append("/robot_description: nothing to draw (no visual)")

    tf = (topics.get("/tf") or {}).get("last") or {}
    children = {t["child_frame_id"] for t in tf.get("transforms", [])}
    missing = (links | {"tcp"}) - children - {"world"}
    if not tf or missing:
        failures.append(f"/tf: child frames missing {sorted(missing)}")
    for t in tf.get("transforms", []):
        v = list(t["transform"]["translation"].values()) + list(t["transform"]["rotation"].values())
        if not all(isinstance(x, float) and math.isfinite(x) for x in v):
            failures.append(f"/tf: {t['child_frame_id']} not finite")

    # The trails' chunks as the log has them, each at its longest (last) version: a viewer that
    # subscribes late gets the whole trail in one message, which the log never holds as such; each
    # of its chunks must be the log's chunk or the start of it.
    chunks: dict[tuple[str, int], list] = {}
    for (topic, _), messages in by_time.items():
        if topic in TRAILS:
            for m in messages:
                for marker in m["markers"]:
                    key = (topic, marker["id"])
                    if len(marker["points"]) >= len(chunks.get(key, [])):
                        chunks[key] = marker["points"]

    def part_of_the_logged_trail(topic: str, message: dict) -> bool:
        return all(close(m["points"], chunks.get((topic, m["id"]), [])[:len(m["points"])]) for m in message["markers"])

    compared = 0
    for topic, stats in topics.items():
        for sample in stats.get("samples", []) + [{"log_time": stats.get("first_log_time"), "message": stats.get("first")}]:
            if topic in ("/robot_description", "/bed/mesh") or sample["message"] is None:
                continue
            candidates = by_time.get((topic, sample["log_time"]), [])
            if topic in TRAILS and not any(close(sample["message"], c) for c in candidates):
                if not part_of_the_logged_trail(topic, sample["message"]):
                    failures.append(f"{topic}: live message at {sample['log_time']} is not part of the logged trail")
                compared += 1
                continue
            if not candidates:
                failures.append(f"{topic}: live message at {sample['log_time']} is not in the log")
                continue
            if "...(+" in json.dumps(sample["message"]):
                continue  # a sample with a shortened string: /robot_description is checked whole above
            if not any(close(sample["message"], c) for c in candidates):
                failures.append(f"{topic}: live message at {sample['log_time']} differs from the log's")
                continue
            compared += 1

    for topic in ["/status", "/joint_states", "/joint_command", "/tcp/target", "/tcp/actual", "/extruder", "/tf",
                  "/joints/normalized", "/path/ahead", "/path/executed", "/bead", "/segments"]:
        if (topics.get(topic) or {}).get("count", 0) == 0:
            failures.append(f"{topic}: nothing received live")

    if args.layout:
        for topic in sorted(layout_topics(json.loads(Path(args.layout).read_text()))):
            if topic not in advertised:
                failures.append(f"layout {args.layout}: shows {topic}, which the stream does not have")

    seconds = max(live.get("seconds", 0.0), 1e-9)
    report = {
        "ok": not failures,
        "failures": failures[:20],
        "compared": compared,
        "channels": len(advertised),
        "bytes_per_s": round(live["total_bytes"] / seconds),
        "topic_bytes_per_s": {t: round(s["bytes"] / seconds) for t, s in sorted(topics.items())},
        "seconds": round(seconds, 2),
    }
    if args.json:
        print(json.dumps(report))
    else:
        for f in failures:
            print("FAIL", f)
        print(f"live view: {len(advertised)} channels, {compared} sampled messages equal the log's, "
              f"{report['bytes_per_s'] / 1e3:.1f} kB/s over {report['seconds']} s")
    return 0 if not failures else 1


if __name__ == "__main__":
    sys.exit(main())
