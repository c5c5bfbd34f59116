#!/usr/bin/env bash
# End-to-end check of the Python client against the strand service.
#
#   tools/python/run_client_test.sh            # from the repo root; uses target/debug/strand
#   STRAND_BIN=target/release/strand tools/python/run_client_test.sh
#
# Starts the service on a private prefix with a timer clock, echoed joint state and
# --exit-when-done, waits until its Status is visible (up to 10 s), runs strand_client.py (60 s
# limit), waits for the service to exit (it does when the job ends), kills it if it does not, and
# exits with the client's status. First checks strand_ipc.py against wire/src/lib.rs
# (test_strand_ipc.py, no service needed). Needs `pip install iceoryx2==0.10.0`.
# Environment: STRAND_BIN (service binary, default target/debug/strand), PYTHON (interpreter,
# default python3), CLIENT_ARGS (extra client arguments, e.g. -v), STRAND_LOG (keep the service's
# MCAP log in this file).
set -u

here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
root=$(cd "$here/../.." && pwd)
bin=${STRAND_BIN:-target/debug/strand}
# A relative STRAND_BIN is taken from the current directory, else from the repo root.
case "$bin" in
    /*) ;;
    *) if [ -x "$PWD/$bin" ]; then bin="$PWD/$bin"; else bin="$root/$bin"; fi ;;
esac
python=${PYTHON:-python3}
prefix="strand/pytest-$$"
cd "$root" || exit 2

if [ ! -x "$bin" ]; then
    echo "run_client_test: no service binary at $bin (set STRAND_BIN)" >&2
    exit 2
fi

# The ctypes mirrors against wire/src/lib.rs (field order, type names, enums): no service needed.
if ! "$python" "$here/test_strand_ipc.py" >/dev/null; then
    "$python" "$here/test_strand_ipc.py" >&2
    echo "run_client_test: strand_ipc.py does not match wire/src/lib.rs" >&2
    exit 1
fi

log=$(mktemp "${TMPDIR:-/tmp}/strand-pytest-$$.XXXXXX.log")
# STRAND_LOG=FILE keeps the service's MCAP log there (CI reads it back); otherwise no log.
if [ -n "${STRAND_LOG:-}" ]; then log_args=(--log "$STRAND_LOG"); else log_args=(--no-log); fi
"$bin" run --config config/default.toml --prefix "$prefix" --clock timer --echo --exit-when-done "${log_args[@]}" >"$log" 2>&1 &
svc=$!
t_start=$(date +%s.%N)

cleanup() {
    if kill -0 "$svc" 2>/dev/null; then
        kill -TERM "$svc" 2>/dev/null
        for _ in $(seq 1 20); do kill -0 "$svc" 2>/dev/null || break; sleep 0.1; done
        kill -0 "$svc" 2>/dev/null && kill -KILL "$svc" 2>/dev/null
    fi
    wait "$svc" 2>/dev/null
}
trap cleanup EXIT
trap 'exit 130' INT TERM

# Wait for the service's Status (or for the service to die, or 10 s).
"$python" "$here/strand_client.py" --prefix "$prefix" --wait-service 10 &
probe=$!
while kill -0 "$probe" 2>/dev/null; do
    if ! kill -0 "$svc" 2>/dev/null; then kill "$probe" 2>/dev/null; break; fi
    sleep 0.05
done
wait "$probe"
probe_rc=$?
if [ "$probe_rc" -ne 0 ]; then
    if kill -0 "$svc" 2>/dev/null; then
        echo "run_client_test: the service's Status did not appear within 10 s; service log:" >&2
    else
        wait "$svc"
        echo "run_client_test: the service exited (code $?) before its Status appeared; service log:" >&2
    fi
    cat "$log" >&2
    exit 1
fi
t_up=$(date +%s.%N)

# shellcheck disable=SC2086
"$python" "$here/strand_client.py" --prefix "$prefix" --timeout 60 ${CLIENT_ARGS:-}
rc=$?
t_client=$(date +%s.%N)

# The service exits by itself when the job has ended; give it 10 s.
for _ in $(seq 1 100); do kill -0 "$svc" 2>/dev/null || break; sleep 0.1; done
if kill -0 "$svc" 2>/dev/null; then
    echo "run_client_test: the service did not exit after the job; killing it" >&2
    kill -TERM "$svc" 2>/dev/null
    for _ in $(seq 1 20); do kill -0 "$svc" 2>/dev/null || break; sleep 0.1; done
    kill -0 "$svc" 2>/dev/null && kill -KILL "$svc" 2>/dev/null
fi
wait "$svc" 2>/dev/null
svc_rc=$?
t_end=$(date +%s.%N)

awk -v a="$t_start" -v b="$t_up" -v c="$t_client" -v d="$t_end" -v s="$svc_rc" \
    'BEGIN { printf "run_client_test: service up after %.2f s, client %.2f s, service exit %d after %.2f s more\n", b - a, c - b, s, d - c }'
if [ "$rc" -ne 0 ]; then
    echo "run_client_test: client failed (exit $rc); service log:" >&2
    cat "$log" >&2
fi
rm -f "$log"
exit "$rc"
