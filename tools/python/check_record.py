#!/usr/bin/env python3
"""Decodes strand's compact replay record from its documentation alone and checks it against the
full record of the same run.

    python3 tools/python/check_record.py COMPACT.mcap FULL.mcap

COMPACT is a log as the service writes it (``[log] record = "compact"``: ``/strand/ticks``,
``strand_msgs/msg/TickBlock``); FULL is the same run with every tick whole (``strand-replay
regenerate COMPACT -o FULL`` writes ``/strand/tick``, ``strand_msgs/msg/Tick``). The blocks are read
with the official ``mcap`` + ``mcap-ros2-support`` readers and unpacked here, by the layout that
``src/log/record.rs`` documents (not by strand's decoder): per column one header byte
(``order | planes << 4``), byte planes of zig-zagged residuals, predictions by the previous value, a
line or a parabola, in wrapping 64-bit integers. Every tick's fixed fields (tick, time, flags and
counts, cycle counters, timing, the joint state's and the heater state's every word, floats by their
bits) must equal the full record's, and the blocks must cover the run without a gap.

The last line is ``check_record: P passed, F failed``; the exit status is 0 only if nothing failed.
"""

from __future__ import annotations

import struct
import sys

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

TICKS = "/strand/ticks"
TICK = "/strand/tick"
MASK = (1 << 64) - 1
MAX_JOINTS = 8
ROW_WORDS = 12 + (3 + 5 * MAX_JOINTS) + 7 + 2


def predict(col: list[int], k: int, order: int) -> int:
    if k == 0:
        return 0
    order = min(order, k - 1, 2)
    if order == 0:
        return col[k - 1]
    if order == 1:
        return (2 * col[k - 1] - col[k - 2]) & MASK
    return (3 * (col[k - 1] - col[k - 2]) + col[k - 3]) & MASK


def unzigzag(u: int) -> int:
    return ((u >> 1) ^ -(u & 1)) & MASK


def rows_of(columns: bytes, count: int) -> list[list[int]]:
    if columns[0] != ROW_WORDS:
        raise ValueError(f"row width {columns[0]}, expected {ROW_WORDS}")
    rows = [[0] * ROW_WORDS for _ in range(count)]
    at = 1
    for c in range(ROW_WORDS):
        head = columns[at]
        at += 1
        order, planes = head & 0x0F, head >> 4
        if order > 2 or planes > 8:
            raise ValueError(f"column {c}: header {head:#x}")
        data = columns[at:at + planes * count]
        at += planes * count
        col = [0] * count
        for k in range(count):
            zz = 0
            for p in range(planes):
                zz |= data[p * count + k] << (8 * p)
            col[k] = (predict(col, k, order) + unzigzag(zz)) & MASK
            rows[k][c] = col[k]
    if at != len(columns):
        raise ValueError(f"{len(columns) - at} bytes left after the columns")
    return rows


def bits(x: float) -> int:
    return struct.unpack("<Q", struct.pack("<d", x))[0]


def expected_row(t) -> list[int | None]:
    """The fixed words of a full record's tick (None: not checked — the digest, which this script does
    not compute, and the words of a state that did not arrive)."""
    i = t.input
    # A joint or heater state that did not arrive: its words are unspecified (the flags say so).
    r: list[int | None] = [0] * 12 + [None] * (ROW_WORDS - 14) + [t.receive_ns, None]
    r[0], r[1] = i.tick, i.time_ns
    r[2] = (int(i.feeder_lost) | (len(i.joint_state) > 0) << 1 | (len(t.heater_state) > 0) << 2
            | len(i.segments) << 8 | len(i.controls) << 16 | len(i.base_poses) << 24)
    c = i.cycle
    r[3:8] = [c.overruns, c.late_wakeups, c.worst_lateness_ns, c.log_drops, c.log_state]
    tm = t.timing
    command_part = (t.command_ns - (t.receive_ns + tm.step_ns)) & MASK
    r[8:11] = [tm.wake_lateness_ns, tm.step_ns, (tm.tick_ns - t.command_ns) & MASK]
    r[11] = None
    r[ROW_WORDS - 1] = command_part
    if i.joint_state:
        js = i.joint_state[0]
        words = [js.seq, js.stamp_ns, js.dof | js.flags << 32]
        for a in (js.position, js.velocity, js.effort, js.robot_target, js.robot_target_velocity):
            words += [bits(v) for v in a]
        r[12:12 + len(words)] = words
    if t.heater_state:
        h = t.heater_state[0]
        r[55:62] = [h.seq, h.stamp_ns, bits(h.hot_end), bits(h.bed), bits(h.hot_end_power), bits(h.bed_power), h.flags]
    return r


def messages(path: str, topic: str):
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, _, _, msg in reader.iter_decoded_messages(topics=[topic], log_time_order=False):
            yield msg


def main() -> int:
    if len(sys.argv) != 3:
        print(__doc__, file=sys.stderr)
        return 2
    compact, full = sys.argv[1], sys.argv[2]
    passed = failed = 0
    problems: list[str] = []
    full_ticks = messages(full, TICK)
    expected_first = None
    ticks = blocks = 0
    for block in messages(compact, TICKS):
        blocks += 1
        if block.version != 1:
            problems.append(f"block {blocks}: version {block.version}")
            break
        if expected_first is not None and block.first_tick != expected_first:
            problems.append(f"block {blocks}: first tick {block.first_tick}, expected {expected_first} (a gap)")
        expected_first = block.first_tick + block.count
        rows = rows_of(bytes(block.columns), block.count)
        for k, row in enumerate(rows):
            t = next(full_ticks, None)
            if t is None:
                problems.append(f"tick {row[0]}: not in the full record")
                break
            want = expected_row(t)
            if row[0] != block.first_tick + k:
                problems.append(f"block {blocks} row {k}: tick {row[0]}, expected {block.first_tick + k}")
            for w, (got, exp) in enumerate(zip(row, want)):
                if exp is not None and got != exp:
                    problems.append(f"tick {row[0]}: word {w} is {got:#x}, the full record says {exp:#x}")
                    break
            ticks += 1
    if next(full_ticks, None) is not None:
        problems.append("the full record has ticks the blocks do not")
    checks = [
        ("blocks were read", blocks > 0),
        (f"{ticks} ticks decoded by the documented layout equal the full record", ticks > 0 and not problems),
    ]
    for name, ok in checks:
        if ok:
            passed += 1
            print(f"ok: {name}")
        else:
            failed += 1
            print(f"FAILED: {name}")
    for p in problems[:10]:
        print(f"  {p}")
    print(f"check_record: {passed} passed, {failed} failed")
    return 0 if failed == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
