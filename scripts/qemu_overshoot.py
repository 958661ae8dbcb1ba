#!/usr/bin/env python3
"""The overshoot scenario against the QEMU image, with pymodbus: how far past
its target does each axis get?

Run by scripts/qemu-overshoot (which boots the image on a fresh settings
flash for every run); usable by hand against `QEMU_FRESH=1 cargo qemu`:

    python3 scripts/qemu_overshoot.py --port 5020

On every axis (server ids 1..4): max speed, acceleration and deceleration
65 535 (0x0051..0x0053), then a target of +150 000 steps (0x0050, two
registers, high word first) from 0; the positions (0x0040) are polled
round-robin, one axis per request, every ~20 ms per axis, until every axis
reads its target and is settled. The largest position read past the target
is the overshoot. It then reads the diagnostics' control-tick duration and
overruns (0x032A..) and prints one line:

    overshoot: 1:0 2:0 3:0 4:0 max 0 (tick max 812 us, 0 overruns; 3.41 s)

With --limit N it exits 1 when an axis passed its target by more than N
steps (0: none at all), 2 on a Modbus failure.
"""

import logging
import sys
import time

from modbus_e2e import Failure, client_args, connect, failed, i32, read, words
from modbus_e2e import write_many as write

POSITION = 0x0040
SET_POSITION = 0x0050
SET_MAX_SPEED, SET_ACC, SET_DEC = 0x0051, 0x0052, 0x0053
DIAG_TICK = 0x032A
SIDS = (1, 2, 3, 4)


def run(client, args):
    for sid in args.ids:
        for address in (SET_MAX_SPEED, SET_ACC, SET_DEC):
            write(client, address, [args.speed_acc_dec], sid)
    for sid in args.ids:
        pos = i32(read(client, POSITION, 2, sid))
        if pos != 0:
            raise Failure(f"id {sid}: position {pos} before the move, 0 expected (fresh image?)")
    start = time.monotonic()
    for sid in args.ids:
        write(client, SET_POSITION, words(args.target), sid)
    peak = {sid: 0 for sid in args.ids}
    at_target = {sid: 0 for sid in args.ids}
    trace = []
    while True:
        for sid in args.ids:
            t = time.monotonic()
            pos = i32(read(client, POSITION, 2, sid))
            trace.append((t - start, sid, pos))
            peak[sid] = max(peak[sid], pos)
            # Arrived: the target read twice in a row (a pass reads other values).
            at_target[sid] = at_target[sid] + 1 if pos == args.target else 0
            # ~20 ms between two reads of the same axis.
            time.sleep(max(0.0, args.poll / len(args.ids) - (time.monotonic() - t)))
        if all(n >= 2 for n in at_target.values()):
            break
        if time.monotonic() - start > args.move_timeout:
            raise Failure(f"not arrived after {args.move_timeout} s: {[(s, p) for _, s, p in trace[-len(args.ids):]]}")
    move_s = time.monotonic() - start
    last_us, max_us, overruns = ((hi << 16) | lo for hi, lo in zip(*[iter(read(client, DIAG_TICK, 6, 1))] * 2))
    over = {sid: peak[sid] - args.target for sid in args.ids}
    print(
        "overshoot: "
        + " ".join(f"{sid}:{over[sid]}" for sid in args.ids)
        + f" max {max(over.values())} (tick last {last_us} us, max {max_us} us, {overruns} overruns; {move_s:.2f} s)"
    )
    if args.trace:
        with open(args.trace, "w") as f:
            for t, sid, pos in trace:
                f.write(f"{t:.4f} {sid} {pos}\n")
    return max(over.values())


def main():
    ap = client_args(__doc__.splitlines()[0], "every axis")
    ap.add_argument("--ids", type=lambda s: [int(x) for x in s.split(",")], default=list(SIDS))
    ap.add_argument("--target", type=int, default=150_000, help="steps")
    ap.add_argument("--speed-acc-dec", type=int, default=65_535, help="max speed, acc and dec written")
    ap.add_argument("--poll", type=float, default=0.02, help="s between two reads of one axis")
    ap.add_argument("--limit", type=int, default=None, help="fail above this overshoot (steps)")
    ap.add_argument("--trace", help="write every position read (t id position) to this file")
    args = ap.parse_args()
    logging.getLogger("pymodbus").setLevel(logging.CRITICAL)

    client = connect(args.host, args.port, args.timeout, args.connect_timeout)
    if client is None:
        return 2
    try:
        worst = run(client, args)
    except Exception as e:
        failed(e)
        return 2
    finally:
        client.close()
    if args.limit is not None and worst > args.limit:
        print(f"FAIL: an axis passed its target by {worst} steps (limit {args.limit})", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
