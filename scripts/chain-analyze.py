#!/usr/bin/env python3
"""scripts/chain-cpu's report: instructions per event of the chain's DMA
driver from the armcount plugin's totals, then per batch, a cycle
estimate and the CPU share at 1, 2 and 5 kHz.

usage: chain-analyze.py DIS.txt ARMCOUNT.out N_BATCHES WINDOWS

Cycle estimate (not measured; tests/chain_spi.rs logs the real cycles on a
board): 1.5 cycles per instruction (the control tick's own CPI from
scripts/tick-cpu is ~1.9 with flash wait states; these paths are short and
straight), plus 4 cycles per load or store that is not a stack or
literal-pool access — a peripheral access costs 1 to 4 wait cycles (AHB1
DMA2 / GPIOA, APB2 SPI1 at 84 MHz, APB1 TIM7 at 42 MHz), RAM ones less, so
the estimate errs high —, plus the
exception entry and return of every interrupt (12 + 10 cycles on the
Cortex-M4 with the FPU context unused; tail-chaining would save some).
"""
import re, sys

dis, out, n, windows = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4])

totals, perpc = {}, {}
for line in open(out):
    f = line.split()
    if f[0] == "T":
        totals[int(f[1])] = int(f[2])
    elif f[0] == "P":
        perpc.setdefault(int(f[3]), {})[int(f[1], 16)] = int(f[4])

# Loads and stores of the disassembly other than stack and literal-pool
# ones: every peripheral access is one of them (RAM ones are counted too:
# the estimate errs high).
ldst = {}
for line in open(dis):
    m = re.match(r"^ *([0-9a-f]+):\s+(ldr|str)\S*\s+(.*)$", line)
    if m and "[sp" not in m.group(3) and "[pc" not in m.group(3):
        ldst[int(m.group(1), 16)] = True

events = {1: ("start of a batch (control tick)", 1),
          2: ("end of a gap (TIM7): CS low, set-up timed", windows),
          3: ("end of a set-up (TIM7): TXDMAEN", windows),
          4: ("end of a window (DMA2_STREAM0): CS high, next armed, gap", windows - 1),
          5: ("end of the last window (DMA2_STREAM0)", 1),
          6: ("hand-over (poll, control tick)", 1)}
cal = totals.get(7, 0) / n
ENTRY_EXIT = 22
print(f"chain DMA driver, streaming batch of {windows} windows x 8 bytes "
      f"({n} batches; empty marker pair {cal:.0f} instructions, subtracted)")
batch_insn = batch_cyc = isr_insn = isr_cyc = 0.0
for k, (name, per) in events.items():
    calls = n * per
    insn = totals.get(k, 0) / calls - cal
    acc = sum(c for pc, c in perpc.get(k, {}).items() if pc in ldst) / calls
    isr = k in (2, 3, 4, 5)
    cyc = 1.5 * insn + 4 * acc + (ENTRY_EXIT if isr else 0)
    print(f"  {name:58s} {insn:6.0f} instructions, ~{acc:4.0f} loads/stores, ~{cyc:5.0f} cycles"
          + (" (with entry/return)" if isr else ""))
    batch_insn += insn * per
    batch_cyc += cyc * per
    if isr:
        isr_insn += insn * per
        isr_cyc += cyc * per
print(f"RESULT per batch: {batch_insn:.0f} instructions ({isr_insn:.0f} in {3 * windows} interrupts), "
      f"~{batch_cyc:.0f} cycles ({isr_cyc:.0f} in the interrupts)")
for hz in (1000, 2000, 5000):
    print(f"RESULT CPU share of the chain driver at {hz // 1000} kHz: {100 * batch_cyc * hz / 168e6:.2f} %")
