#!/usr/bin/env python3
"""scripts/tick-cpu's report: the shared analyze.py's breakdown, then the
per-axis figures and the CPU share of the control tick at 1, 2 and 5 kHz.

usage: tick-analyze.py DIS.txt ARMCOUNT.out N_TICKS TICK_US

Cycle model: analyze.py's Cortex-M4 timings at 0 wait states (mid: pipeline
refill 2, division 7) plus 5 wait states (168 MHz, 3.3 V: RM0090 table 10)
for every ART cache miss of the warm tick (sequential misses half hidden by
the prefetch buffer, so 2.5 each; jumps 5).
"""
import re, subprocess, sys, os

dis, out, n, tick_us = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4])
here = os.path.dirname(os.path.abspath(__file__))
tools = os.path.join(here, "..", "..", "shared", "tools", "qemu-armcount", "analyze.py")
text = subprocess.run([sys.executable, tools, dis, out, n], check=True,
                      capture_output=True, text=True).stdout
print(text)

net, cyc, divcalls, misses = {}, {}, {}, {}
k = None
for line in text.splitlines():
    m = re.match(r"counter (\d+):", line)
    if m:
        k = int(m.group(1)); continue
    m = re.search(r"([\d.]+) net", line)
    if m and k:
        net[k] = float(m.group(1))
    m = re.search(r"P=3,DIV=12\): (\d+) / (\d+) / (\d+)", line)
    if m and k:
        cyc[k] = int(m.group(2))
    if "calls/tick:" in line and k:
        # Only the entry points: __aeabi_*divmod calls the generic helper.
        divcalls[k] = sum(float(x) for x in re.findall(r"__aeabi_\w+ ([\d.]+)", line))
    m = re.search(r"misses/tick warm seq ([\d.]+) jump ([\d.]+)", line)
    if m and k:
        misses[k] = (float(m.group(1)), float(m.group(2)))

tick = [1, 2, 3]
insn = sum(net.get(i, 0) for i in tick)
cycles = sum(cyc.get(i, 0) for i in tick)
flash = sum(2.5 * misses.get(i, (0, 0))[0] + 5 * misses.get(i, (0, 0))[1] for i in tick)
div = sum(divcalls.get(i, 0) for i in tick)
print(f"RESULT tick {tick_us} us, 8 axes: {insn:.0f} Thumb-2 instructions per tick, "
      f"{insn / 8:.0f} per axis-tick; 64-bit division calls per tick: {div:.2f}")
print(f"RESULT profile generator: {net.get(4, 0):.0f} instructions per axis-tick")
total = cycles + flash
print(f"RESULT cycles per tick: {cycles:.0f} core + {flash:.0f} flash wait = {total:.0f}")
for hz in (1000, 2000, 5000):
    print(f"RESULT CPU share of the tick's computation at {hz // 1000} kHz: "
          f"{100 * total * hz / 168e6:.1f} %")
