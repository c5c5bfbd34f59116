#!/usr/bin/env python3
"""Checks `strand-plan base` against SciPy: the base trajectory it writes (--csv) must equal
scipy.signal.filtfilt(*butter(2, fc / (fs / 2)), tcp) with SciPy's default padding, at the cut-off it
reports (--json), and its reported r_max must follow from those columns.

usage: check_filter.py STRAND_PLAN JOB [extra strand-plan base flags]
"""
import csv
import json
import subprocess
import sys
import tempfile

import numpy as np
from scipy import signal


def main() -> int:
    plan, job, extra = sys.argv[1], sys.argv[2], sys.argv[3:]
    with tempfile.NamedTemporaryFile(suffix=".csv") as f:
        out = subprocess.run([plan, "base", job, "--json", "--csv", f.name, *extra], check=True, capture_output=True, text=True)
        summary = json.loads(out.stdout)
        with open(f.name, newline="") as fh:
            rows = list(csv.DictReader(fh))
    col = lambda k: np.array([float(r[k]) for r in rows])
    t, tcp_x, tcp_y, base_x, base_y = (col(k) for k in ("t", "tcp_x", "tcp_y", "base_x", "base_y"))
    dt = t[1] - t[0]
    fc = summary["fc_hz"]
    b, a = signal.butter(2, fc / (0.5 / dt))
    want_x = signal.filtfilt(b, a, tcp_x)
    want_y = signal.filtfilt(b, a, tcp_y)
    err = max(np.max(np.abs(want_x - base_x)), np.max(np.abs(want_y - base_y)))
    span = max(np.ptp(tcp_x), np.ptp(tcp_y), 1e-3)
    direction = summary["direction_rad"]
    off = -summary["r_nom_m"] * np.array([np.cos(direction), np.sin(direction)])
    r_max = np.max(np.hypot(tcp_x - base_x - off[0], tcp_y - base_y - off[1]))
    print(f"check_filter {job}: {len(t)} samples, fc {fc * 1e3:.3f} mHz, max |strand − scipy| = {err:.3e} m "
          f"(span {span:.3f} m), r_max {r_max * 1e3:.3f} mm vs reported {summary['r_max_m'] * 1e3:.3f} mm")
    ok = err <= 1e-9 * span and abs(r_max - summary["r_max_m"]) < 1e-9
    if not ok:
        print("check_filter: 0 passed, 1 failed", file=sys.stderr)
        return 1
    print("check_filter: 1 passed, 0 failed")
    return 0


if __name__ == "__main__":
    sys.exit(main())
