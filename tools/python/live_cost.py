#!/usr/bin/env python3
"""What the live view costs the control loop: `strand run` on the timer clock, interleaved runs with
the view off and on (a Foxglove client connected and subscribed to everything), each printing its
tick cost and wake-up lateness; the medians of the runs side by side, and the WebSocket's bytes
per second at the default decimation.

    python3 tools/python/live_cost.py [--strand target/release/strand] [--pairs 3] [--seconds 15]
        [--rate 1000] [--fifo 80] [--json]

The service echoes its commands (no robot); the log is written in both arms (the view is fed by
the log writer thread, so "off" is the log alone). Needs websockets + mcap-ros2-support for the
client (tools/python/foxglove_client.py).
"""

from __future__ import annotations

import argparse
import json
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
FIGURES = {
    "step_p50": r"step p50 ([\d.]+) µs",
    "step_p99": r"step p50 [\d.]+ µs p99 ([\d.]+) µs",
    "tick_p50": r"tick p50 ([\d.]+) µs",
    "tick_p99": r"tick p50 [\d.]+ µs p99 ([\d.]+) µs",
    "late_p50": r"lateness p50 ([\d.]+) µs",
    "late_p99": r"lateness p50 [\d.]+ µs p99 ([\d.]+) µs",
}


def one_run(strand: str, view: bool, seconds: float, rate: float, port: int, tmp: Path, k: int, fifo: int) -> dict:
    ticks = int(seconds * rate)
    args = [strand, "run", "--echo", "--clock", "timer", "--ticks", str(ticks), "--prefix", f"strand/livecost-{k}",
            "--log", str(tmp / f"run{k}.mcap"), "--set", f"controller.rate_hz={rate}", "--set", f"realtime.fifo_priority={fifo}"]
    if view:
        args += ["--view", "--set", f'view.address="127.0.0.1:{port}"']
    svc = subprocess.Popen(args, stderr=subprocess.PIPE, text=True)
    client = None
    if view:
        client = subprocess.Popen([sys.executable, str(HERE / "foxglove_client.py"), f"ws://127.0.0.1:{port}",
                                   "--seconds", str(seconds + 30), "--json", "--count-only"], stdout=subprocess.PIPE, text=True)
    _, err = svc.communicate(timeout=seconds * 3 + 60)
    out = {}
    for name, pattern in FIGURES.items():
        m = re.search(pattern, err)
        out[name] = float(m.group(1)) if m else float("nan")
    if client is not None:
        stdout, _ = client.communicate(timeout=60)
        live = json.loads(stdout)
        out["ws_bytes_per_s"] = live["total_bytes"] / max(live["seconds"], 1e-9)
    (tmp / f"run{k}.mcap").unlink(missing_ok=True)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--strand", default="target/release/strand")
    ap.add_argument("--pairs", type=int, default=3)
    ap.add_argument("--seconds", type=float, default=15.0)
    ap.add_argument("--rate", type=float, default=1000.0)
    ap.add_argument("--port", type=int, default=18765)
    ap.add_argument("--fifo", type=int, default=0, help="SCHED_FIFO priority of the tick thread (0: SCHED_OTHER)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    runs = {False: [], True: []}
    with tempfile.TemporaryDirectory() as d:
        for k in range(args.pairs):
            for view in (False, True) if k % 2 == 0 else (True, False):
                runs[view].append(one_run(args.strand, view, args.seconds, args.rate, args.port, Path(d), 2 * k + view, args.fifo))
                time.sleep(0.5)
    med = {v: {f: statistics.median(r[f] for r in runs[v]) for f in runs[v][0]} for v in runs}
    if args.json:
        print(json.dumps({"off": med[False], "on": med[True], "runs": {"off": runs[False], "on": runs[True]}}))
        return 0
    policy = f"SCHED_FIFO {args.fifo}" if args.fifo else "SCHED_OTHER"
    print(f"{args.pairs} interleaved pairs of {args.seconds:.0f} s at {args.rate:.0f} Hz, tick thread {policy} (medians, µs)")
    print(f"{'figure':<10} {'view off':>9} {'view on':>9} {'on/off':>7}")
    for f in FIGURES:
        a, b = med[False][f], med[True][f]
        print(f"{f:<10} {a:>9.1f} {b:>9.1f} {b / a if a else float('nan'):>7.2f}")
    print(f"WebSocket: {med[True]['ws_bytes_per_s'] / 1e3:.1f} kB/s to one client at the default decimation")
    return 0


if __name__ == "__main__":
    sys.exit(main())
