#!/usr/bin/env python3
"""End-to-end Modbus RTU scenario against the QEMU image, with pymodbus.

Talks RTU frames (no MBAP header) over the TCP socket that QEMU's second
`-serial` (USART2) listens on. Run by scripts/qemu-e2e; usable by hand
against `cargo qemu`:

    python3 scripts/modbus_e2e.py --port 5020

The scenario (PoStep60 register map: address 0x00nn = command nn):
  1. HW/FW info (0x000A, 3 registers) of axes 1 and 2: first register 0x0041.
  2. Position (0x0040, 2 registers, high word first) of both: 0 after boot.
  3. Max speed / acceleration / deceleration (0x0041..0x0043) of both: the
     factory 1000 / 1000 / 1000 (the image booted on a fresh settings flash).
  4. Max speed / acceleration / deceleration (0x0051..0x0053): axis 1 by FC
     0x06, axis 2 by FC 0x10; read back through 0x0041..0x0043.
  5. Target (0x0050, FC 0x10, 2 registers, high word first) on both axes.
  6. Poll both positions until they equal their targets (timeout).
  7. An unknown command (register 0x0099) gets exception 02.
  8. Diagnostics (extension space 0x0300..): the Modbus counters count the
     frames and the exception so far, the control tick's duration is
     measured (max > 0 us).
  9. Extension space on id 4 (the QEMU image's axis with a home switch: a
     cam on its simulated shaft closes SW 25 full steps below 0): read the
     chip's OCD_TH (0x0113, GetParam through the chain), write it (tuning)
     and read it back; enable the end switch (0x040B) and home the axis
     (0x0400 = 1) until done; homed (0x0402) = 1 and position 0 at the edge.
 10. With --save: write settings (0x003F), retried while it is refused with
     exception 04 (an axis still landing); scripts/qemu-e2e then waits for
     the firmware's "settings: saved" log line.
With --check-saved it runs only the restart check instead: after QEMU was
restarted on the same settings flash, both axes read back the max speed /
acceleration / deceleration of step 4, and their positions are 0 again; id
4's OCD_TH and end-switch setting are the ones step 9 wrote.
Exits non-zero on the first failure; prints per-request timings.
"""

import argparse
import logging
import statistics
import sys
import time

import pymodbus
from pymodbus import FramerType
from pymodbus.client import ModbusTcpClient
from pymodbus.pdu import ExceptionResponse

HW_FW_INFO = 0x000A
POSITION = 0x0040
MAX_SPEED, ACC, DEC = 0x0041, 0x0042, 0x0043
SET_POSITION = 0x0050
SET_MAX_SPEED, SET_ACC, SET_DEC = 0x0051, 0x0052, 0x0053
UNKNOWN = 0x0099
WRITE_SETTINGS = 0x003F
# Diagnostics (u32 high word first): Modbus frames, CRC errors, framing
# errors, exceptions from 0x0300; tick last / max us and overruns from 0x032A.
DIAG_MODBUS = 0x0300
DIAG_TICK = 0x032A
TICK_US = 1000
FACTORY_SPEED_ACC_DEC = [1000, 1000, 1000]
# Extension space: chip register nn at 0x01nn; homing block 0x04nn.
HOME_SID = 4
OCD_TH = 0x0113
OCD_TH_TUNED = 10
HOMING_CMD, HOMING_RESULT, HOMED, END_SWITCH = 0x0400, 0x0401, 0x0402, 0x040B
HOMING_STATES = {0: "idle", 1: "clearing the switch", 2: "searching", 3: "releasing", 4: "done", 5: "failed"}

# (server id, max speed steps/s, acc, dec steps/s², target steps)
AXES = [
    (1, 2000, 4000, 4000, 3000),
    (2, 1500, 3000, 6000, -2000),
]

round_trips = []


class Failure(Exception):
    pass


def timed(call, *args, **kwargs):
    t = time.monotonic()
    r = call(*args, **kwargs)
    round_trips.append(time.monotonic() - t)
    return r


def read(client, address, count, sid):
    r = timed(client.read_holding_registers, address, count=count, device_id=sid)
    if r.isError():
        raise Failure(f"id {sid}: read 0x{address:04X} x{count} failed: {r}")
    return r.registers


def write_one(client, address, value, sid, multiple):
    if multiple:
        r = timed(client.write_registers, address, [value], device_id=sid)
    else:
        r = timed(client.write_register, address, value, device_id=sid)
    if r.isError():
        raise Failure(f"id {sid}: write 0x{address:04X} = {value} failed: {r}")


def write_many(client, address, values, sid=1):
    r = timed(client.write_registers, address, values, device_id=sid)
    if r.isError():
        raise Failure(f"id {sid}: write 0x{address:04X} = {[hex(v) for v in values]} failed: {r}")


def connect(host, port, timeout=2.0, connect_timeout=20.0):
    """A pymodbus client, RTU framing over the TCP socket QEMU serves the
    USART on, once connected; None after `connect_timeout` s (reported)."""
    client = ModbusTcpClient(host, port=port, framer=FramerType.RTU, timeout=timeout, retries=0)
    deadline = time.monotonic() + connect_timeout
    while not client.connect():
        if time.monotonic() > deadline:
            print(f"FAIL: cannot connect to {host}:{port}", file=sys.stderr)
            return None
        time.sleep(0.2)
    return client


def failed(e):
    """Print why a scenario stopped: a check (Failure) or pymodbus, which
    raises ModbusIOException on timeouts."""
    if isinstance(e, Failure):
        print(f"FAIL: {e}", file=sys.stderr)
    else:
        print(f"FAIL: {type(e).__name__}: {e}", file=sys.stderr)


def i32(words):
    v = (words[0] << 16) | words[1]
    return v - (1 << 32) if v & 0x8000_0000 else v


def words(v):
    v &= 0xFFFF_FFFF
    return [v >> 16, v & 0xFFFF]


def check(cond, what):
    if not cond:
        raise Failure(what)
    print(f"ok: {what}")


def scenario(client, move_timeout):
    for sid, *_ in AXES:
        info = read(client, HW_FW_INFO, 3, sid)
        check(info[0] == 0x0041, f"id {sid}: HW/FW info {[hex(w) for w in info]} starts with 0x0041")
    for sid, *_ in AXES:
        pos = i32(read(client, POSITION, 2, sid))
        check(pos == 0, f"id {sid}: position {pos} after boot")
    for sid, *_ in AXES:
        back = [read(client, a, 1, sid)[0] for a in (MAX_SPEED, ACC, DEC)]
        check(back == FACTORY_SPEED_ACC_DEC, f"id {sid}: factory max speed/acc/dec {back} after boot")

    for n, (sid, speed, acc, dec, _) in enumerate(AXES):
        multiple = n % 2 == 1
        for address, value in ((SET_MAX_SPEED, speed), (SET_ACC, acc), (SET_DEC, dec)):
            write_one(client, address, value, sid, multiple)
        back = [read(client, a, 1, sid)[0] for a in (MAX_SPEED, ACC, DEC)]
        fc = "0x10" if multiple else "0x06"
        check(back == [speed, acc, dec], f"id {sid}: max speed/acc/dec {back} written by FC {fc}")

    start = time.monotonic()
    for sid, *_, target in AXES:
        r = timed(client.write_registers, SET_POSITION, words(target), device_id=sid)
        if r.isError():
            raise Failure(f"id {sid}: set position {target} failed: {r}")
    print(f"ok: targets {[(a[0], a[4]) for a in AXES]} written by FC 0x10")

    polls = 0
    while True:
        positions = [i32(read(client, POSITION, 2, sid)) for sid, *_ in AXES]
        polls += 1
        if positions == [a[4] for a in AXES]:
            break
        if time.monotonic() - start > move_timeout:
            raise Failure(f"positions {positions} after {move_timeout} s, targets {[a[4] for a in AXES]}")
        time.sleep(0.05)
    move_s = time.monotonic() - start
    check(True, f"both axes arrived: positions {positions} after {move_s:.2f} s ({polls} polls)")

    r = timed(client.read_holding_registers, UNKNOWN, count=1, device_id=1)
    check(
        isinstance(r, ExceptionResponse) and r.exception_code == 2,
        f"unknown command 0x{UNKNOWN:04X}: exception {getattr(r, 'exception_code', r)} (02 expected)",
    )

    requests = len(round_trips)
    frames, crc, framing, exceptions = (
        (hi << 16) | lo for hi, lo in zip(*[iter(read(client, DIAG_MODBUS, 8, 1))] * 2)
    )
    # The counters are handed over after each request: this one's own frame
    # may not be in them yet.
    check(
        frames >= requests and exceptions >= 1 and crc == 0 and framing == 0,
        f"diagnostics: {frames} Modbus frames (>= {requests} requests before), "
        f"{exceptions} exception(s), {crc} CRC / {framing} framing errors",
    )
    last_us, max_us, overruns = (
        (hi << 16) | lo for hi, lo in zip(*[iter(read(client, DIAG_TICK, 6, 1))] * 2)
    )
    # Measured: > 0. Under QEMU a host that preempts the emulator in the
    # middle of a tick stretches it, so overruns are shown, not judged.
    check(
        max_us > 0 and last_us <= max_us,
        f"diagnostics: control tick last {last_us} us, max {max_us} us, "
        f"{overruns} overruns of {TICK_US} us",
    )
    return move_s


def extensions(client, timeout):
    sid = HOME_SID
    before = read(client, OCD_TH, 1, sid)[0]
    check(0 <= before <= 0x1F, f"id {sid}: chip register OCD_TH (0x{OCD_TH:04X}) reads {before} (5 bits)")
    write_one(client, OCD_TH, OCD_TH_TUNED, sid, False)
    back = read(client, OCD_TH, 1, sid)[0]
    check(back == OCD_TH_TUNED, f"id {sid}: tuning write OCD_TH = {OCD_TH_TUNED} reads back {back} from the chip")

    write_one(client, END_SWITCH, 1, sid, False)
    check(read(client, END_SWITCH, 1, sid)[0] == 1, f"id {sid}: end switch enabled (0x{END_SWITCH:04X} = 1)")
    start = time.monotonic()
    write_one(client, HOMING_CMD, 1, sid, False)
    seen = []
    while True:
        state = read(client, HOMING_CMD, 1, sid)[0]
        if not seen or seen[-1] != state:
            seen.append(state)
        if state >= 4:
            break
        if time.monotonic() - start > timeout:
            raise Failure(f"id {sid}: homing still {HOMING_STATES.get(state, state)} after {timeout} s")
        time.sleep(0.05)
    result = read(client, HOMING_RESULT, 1, sid)[0]
    check(state == 4 and result == 0,
          f"id {sid}: homed in {time.monotonic() - start:.2f} s through "
          f"{' -> '.join(HOMING_STATES.get(x, str(x)) for x in seen)} (result {result})")
    check(read(client, HOMED, 1, sid)[0] == 1, f"id {sid}: homed flag 1")
    pos = i32(read(client, POSITION, 2, sid))
    check(pos == 0, f"id {sid}: position {pos} at the switch edge")


def save(client, timeout):
    """Write settings. Refused with exception 04 while an axis still moves
    (the last axis may still be landing when its position reads the target):
    retried until accepted. The flash task then writes them within 100 ms;
    the caller waits for the firmware's "settings: saved" log line."""
    start = time.monotonic()
    refusals = 0
    while True:
        r = timed(client.write_register, WRITE_SETTINGS, 0, device_id=1)
        if not r.isError():
            break
        if not (isinstance(r, ExceptionResponse) and r.exception_code == 4):
            raise Failure(f"write settings failed: {r}")
        if time.monotonic() - start > timeout:
            raise Failure(f"write settings still refused (04) after {timeout} s")
        refusals += 1
        time.sleep(0.05)
    check(True, f"write settings (0x{WRITE_SETTINGS:04X}) accepted ({refusals} refusals while axes settled)")


def check_saved(client):
    for sid, speed, acc, dec, _ in AXES:
        back = [read(client, a, 1, sid)[0] for a in (MAX_SPEED, ACC, DEC)]
        check(back == [speed, acc, dec], f"id {sid}: max speed/acc/dec {back} after the restart (saved)")
        pos = i32(read(client, POSITION, 2, sid))
        check(pos == 0, f"id {sid}: position {pos} after the restart")
    back = read(client, OCD_TH, 1, HOME_SID)[0]
    check(back == OCD_TH_TUNED, f"id {HOME_SID}: tuned OCD_TH {back} after the restart (saved, re-applied)")
    check(read(client, END_SWITCH, 1, HOME_SID)[0] == 1, f"id {HOME_SID}: end switch still enabled after the restart")


def client_args(description, move_what):
    """The options every Modbus client script takes: where the image's
    USART2 socket is, the response and connect timeouts, and how long to
    wait for `move_what` to arrive."""
    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("--host", default="127.0.0.1")
    ap.add_argument("--port", type=int, default=5020)
    ap.add_argument("--timeout", type=float, default=2.0, help="response timeout per request, s")
    ap.add_argument("--connect-timeout", type=float, default=20.0, help="s to wait for the port")
    ap.add_argument("--move-timeout", type=float, default=30.0, help=f"s to wait for {move_what}")
    return ap


def main():
    ap = client_args(__doc__.splitlines()[0], "both axes")
    ap.add_argument("--save", action="store_true", help="write settings after the scenario")
    ap.add_argument("--check-saved", action="store_true", help="only check the saved settings after a restart")
    args = ap.parse_args()
    # pymodbus logs every exception response it decodes; the scenario checks them.
    logging.getLogger("pymodbus").setLevel(logging.CRITICAL)

    print(f"pymodbus {pymodbus.__version__}, RTU framer over tcp {args.host}:{args.port}")
    client = connect(args.host, args.port, args.timeout, args.connect_timeout)
    if client is None:
        return 1
    t0 = time.monotonic()
    move_s = 0.0
    try:
        if args.check_saved:
            check_saved(client)
        else:
            move_s = scenario(client, args.move_timeout)
            extensions(client, args.move_timeout)
            if args.save:
                save(client, args.move_timeout)
    except Exception as e:
        failed(e)
        return 1
    finally:
        client.close()
    rt = sorted(round_trips)
    print(
        f"pymodbus: {len(rt)} requests in {time.monotonic() - t0:.2f} s (move {move_s:.2f} s); "
        f"round trip min {rt[0] * 1e3:.1f} / median {statistics.median(rt) * 1e3:.1f} / "
        f"max {rt[-1] * 1e3:.1f} ms"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
