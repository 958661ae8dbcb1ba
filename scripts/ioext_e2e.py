#!/usr/bin/env python3
"""End-to-end I/O extension scenario against the QEMU image, with pymodbus.

The QEMU image runs the extension's transfers through simulated shift
registers (two 74HC165 = 16 buttons with pull-ups, one 74HC595); its
USART1 console (QEMU's first `-serial`) takes "press N" / "release N" for
input N (receive bit N, wire order). Run by scripts/qemu-e2e; by hand:

    QEMU_CONSOLE=tcp:127.0.0.1:5021,server=on,wait=off QEMU_FRESH=1 cargo qemu
    python3 scripts/ioext_e2e.py --port 5020 --console-port 5021

The scenario (docs/ioext.md, "In short"; unit 1 = axis 0):
  1. Transfers (0x0204, u32 high word first) 0 and no receive data while
     the extension is off (factory).
  2. Configuration 0x0202 = 0x100A, 0x020F (SPI mode, 16 bits, mode 0,
     N = 10, auto-restart), I/O options 0x0200 = 0, 1 (enabled); engine
     (0x020A) 1 = SPI2.
  3. BIN1 of axis 0 mapped to receive bit 3 (0x0240 = 0x8003); axis 0 in
     BINx mode (PoStep60 register 0x0005 = 5, read back at 0x0014).
  4. The transfers counter grows; receive data (0x0220) reads 0xFFFF: every
     contact open.
  5. "press 3": receive bit 3 reads 0 (0xEFFF), and axis 0 moves by its
     BIN1 steps (factory 100) and stays there while the button is held.
  6. "release 3": 0xFFFF again, the position does not change; a second
     press moves another 100 steps.
Exits non-zero on the first failure.
"""

import argparse
import logging
import socket
import sys
import time

import pymodbus

from modbus_e2e import Failure, check, connect, failed, i32, read, write_many

OPTIONS, CONFIG, TRANSFERS, ENGINE, RECEIVE = 0x0200, 0x0202, 0x0204, 0x020A, 0x0220
MAP_AXIS0_BIN1 = 0x0240
DRIVER_MODE_SET, DRIVER_MODE = 0x0005, 0x0014
POSITION, SPEED = 0x0040, 0x0044
BIN1_STEPS = 100  # PoStep60 factory BIN1 steps
BUTTON = 3


def u32(client, address):
    w = read(client, address, 2, 1)
    return (w[0] << 16) | w[1]


def wait_for(what, timeout, probe, want):
    """Poll probe() until want(value); return the value."""
    deadline = time.monotonic() + timeout
    while True:
        v = probe()
        if want(v):
            return v
        if time.monotonic() > deadline:
            raise Failure(f"{what}: still {v!r} after {timeout} s")
        time.sleep(0.05)


def position(client):
    return i32(read(client, POSITION, 2, 1))


def settled(client, want, timeout):
    """The position reads `want` with speed 0 (0x0044) in 5 reads 0.1 s
    apart. (Under QEMU a simulated chip's read-back may pass the target
    and come back: its time and the control tick's drift apart.)"""
    deadline = time.monotonic() + timeout
    calm = 0
    while calm < 5:
        p, speed = position(client), read(client, SPEED, 1, 1)[0]
        calm = calm + 1 if (p, speed) == (want, 0) else 0
        if time.monotonic() > deadline:
            raise Failure(f"axis 0 at {p}, speed {speed} after {timeout} s ({want} expected)")
        time.sleep(0.1)
    check(True, f"axis 0 at {want}, at rest")


def scenario(client, console, timeout):
    check(u32(client, TRANSFERS) == 0, "transfers 0 while the extension is off (factory)")
    write_many(client, CONFIG, [0x100A, 0x020F])
    write_many(client, OPTIONS, [0x0000, 0x0001])
    cfg = read(client, CONFIG, 2, 1)
    check(cfg[0] == 0x100A and cfg[1] & ~0x0800 == 0x020F, f"configuration {[hex(w) for w in cfg]} (16 bits, mode 0, N = 10, auto-restart)")
    check(read(client, ENGINE, 1, 1)[0] == 1, "engine 1 (SPI2) for 16 bits at N = 10")
    write_many(client, MAP_AXIS0_BIN1, [0x8000 | BUTTON])
    write_many(client, DRIVER_MODE_SET, [5])
    check(read(client, DRIVER_MODE, 1, 1)[0] & 0xFF == 5, "axis 0 in BINx mode (5)")

    t1 = wait_for("transfers", timeout, lambda: u32(client, TRANSFERS), lambda n: n > 10)
    time.sleep(0.2)
    t2 = u32(client, TRANSFERS)
    check(t2 > t1, f"transfers counter grows with auto-restart: {t1} -> {t2}")
    rx = read(client, RECEIVE, 1, 1)[0]
    check(rx == 0xFFFF, f"receive data 0x{rx:04X}: every contact open")
    start = position(client)
    check(start == 0, f"axis 0 at {start} before the press")

    for n in (1, 2):
        console.sendall(f"press {BUTTON}\n".encode())
        rx = wait_for("receive data after press", timeout, lambda: read(client, RECEIVE, 1, 1)[0], lambda v: v != 0xFFFF)
        check(rx == 0xFFFF & ~(0x8000 >> BUTTON), f"press {BUTTON}: receive data 0x{rx:04X} (bit {BUTTON} closed = 0)")
        settled(client, n * BIN1_STEPS, timeout)
        check(True, f"press {n} (button held): axis 0 moved by BIN1 steps once, to {n * BIN1_STEPS}")
        console.sendall(f"release {BUTTON}\n".encode())
        rx = wait_for("receive data after release", timeout, lambda: read(client, RECEIVE, 1, 1)[0], lambda v: v == 0xFFFF)
        check(rx == 0xFFFF, f"release {BUTTON}: receive data 0x{rx:04X}")
        time.sleep(0.3)
        settled(client, n * BIN1_STEPS, timeout)
    t3 = u32(client, TRANSFERS)
    check(t3 > t2, f"transfers counter still grows: {t2} -> {t3}")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--host", default="127.0.0.1")
    ap.add_argument("--port", type=int, default=5020, help="Modbus (USART2) TCP port")
    ap.add_argument("--console-port", type=int, default=5021, help="I/O console (USART1) TCP port")
    ap.add_argument("--timeout", type=float, default=20.0, help="s to wait for each effect")
    args = ap.parse_args()
    logging.getLogger("pymodbus").setLevel(logging.CRITICAL)

    print(f"pymodbus {pymodbus.__version__}, RTU over tcp {args.host}:{args.port}, console on {args.console_port}")
    client = connect(args.host, args.port)
    if client is None:
        return 1
    try:
        console = socket.create_connection((args.host, args.console_port), timeout=20)
    except OSError as e:
        print(f"FAIL: console {args.host}:{args.console_port}: {e}", file=sys.stderr)
        return 1
    t0 = time.monotonic()
    try:
        scenario(client, console, args.timeout)
    except Exception as e:
        failed(e)
        return 1
    finally:
        client.close()
        console.close()
    print(f"ioext scenario passed in {time.monotonic() - t0:.2f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
