# Shared by scripts/qemu-e2e and scripts/stepctl-e2e (sourced, not run):
# boot the QEMU image in the background, wait for its boot log line, stop it
# on every exit path. The caller sets ELF, BOOT_TIMEOUT and BOOT_LINE (and
# E2E_NAME, the temporary directory's prefix) before sourcing, and
# `t_start=$(now)` after; `work` is the temporary directory (removed on
# exit) and FLASH the settings flash file in it.
# shellcheck shell=bash

work=$(mktemp -d "${TMPDIR:-/tmp}/${E2E_NAME:-stepbridge-e2e}.XXXXXX")
qemu_pid=""
holder_open=0

now() { date +%s.%N; }
since() { awk -v a="$1" -v b="$(now)" 'BEGIN { printf "%.2f", b - a }'; }
log() { printf '[e2e %6ss] %s\n' "$(since "$t_start")" "$*"; }
fail() {
    echo "qemu-e2e: FAIL: $*" >&2
    if [ -n "${log_file:-}" ] && [ -f "$log_file" ]; then
        echo "--- firmware log ($log_file) ---" >&2
        cat "$log_file" >&2 || true
        echo "--- QEMU stderr ---" >&2
        cat "$err_file" >&2 || true
    fi
    exit 1
}

stop_qemu() {
    if [ "$holder_open" = 1 ]; then
        exec 3<&-
        holder_open=0
    fi
    if [ -n "$qemu_pid" ]; then
        # The runner leads its own process group (setsid): QEMU and
        # defmt-print go with it.
        kill -TERM -- "-$qemu_pid" 2>/dev/null || true
        wait "$qemu_pid" 2>/dev/null || true
        qemu_pid=""
    fi
}
cleanup() {
    stop_qemu
    rm -rf "$work"
}
trap cleanup EXIT
trap 'exit 130' INT TERM

FLASH="$work/flash.bin"

# start_qemu NAME CHARDEV FRESH [CONSOLE]: boot the image in the background,
# Modbus on CHARDEV, settings flash $FLASH (deleted first if FRESH is 1), the
# I/O-extension console on CONSOLE (default: none).
start_qemu() {
    log_file="$work/$1.log"
    err_file="$work/$1.err"
    QEMU_MODBUS=$2 QEMU_FLASH=$FLASH QEMU_FRESH=$3 QEMU_CONSOLE=${4:-null} setsid cargo xtask qemu-run "$ELF" >"$log_file" 2>"$err_file" </dev/null &
    qemu_pid=$!
}

# wait_for_log LINE WHAT: LINE in the firmware log within BOOT_TIMEOUT s.
wait_for_log() {
    local deadline=$(($(date +%s) + BOOT_TIMEOUT))
    until grep -q "$1" "$log_file" 2>/dev/null; do
        kill -0 "$qemu_pid" 2>/dev/null || fail "QEMU exited before $2"
        [ "$(date +%s)" -lt "$deadline" ] || fail "no '$1' in the firmware log within ${BOOT_TIMEOUT} s: $2"
        sleep 0.1
    done
}

# wait_for_boot: the boot log line, within BOOT_TIMEOUT s, QEMU still alive.
wait_for_boot() {
    local t0 deadline
    t0=$(now)
    deadline=$(($(date +%s) + BOOT_TIMEOUT))
    until grep -q "$BOOT_LINE" "$log_file" 2>/dev/null; do
        if ! kill -0 "$qemu_pid" 2>/dev/null; then
            fail "QEMU exited before the firmware booted"
        fi
        if [ "$(date +%s)" -ge "$deadline" ]; then
            fail "no '$BOOT_LINE' in the firmware log within ${BOOT_TIMEOUT} s: QEMU did not boot"
        fi
        sleep 0.1
    done
    boot_s=$(since "$t0")
    log "booted in ${boot_s} s: $(grep "$BOOT_LINE" "$log_file")"
}

