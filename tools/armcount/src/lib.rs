//! armcount: the repository's instruction counter, a TCG plugin for QEMU
//! 7.2 (`qemu-system-arm`; Debian bookworm builds it with plugin support
//! but ships no plugin header, so `ffi` declares the few functions of the
//! plugin API it calls itself). `cargo xtask tick-cpu`, `chain-cpu` and
//! `ioext-cpu` build it and hand it to QEMU with `-plugin`.
//!
//! What it relies on from QEMU: the plugin API of version 1 (QEMU 6.0 to
//! 8.1; `include/qemu/qemu-plugin.h` of QEMU 7.2): a plugin exports
//! `qemu_plugin_version` (the API version it was written for) and
//! `qemu_plugin_install`; it registers a callback for every translated
//! block (`qemu_plugin_register_vcpu_tb_trans_cb`), reads the block's
//! instructions there (`qemu_plugin_tb_n_insns`, `qemu_plugin_tb_get_insn`,
//! `qemu_plugin_insn_vaddr`, `qemu_plugin_insn_size`) and registers a
//! callback QEMU calls each time the block is about to run
//! (`qemu_plugin_register_vcpu_tb_exec_cb`); `qemu_plugin_register_atexit_cb`
//! and `qemu_plugin_outs` (to QEMU's log, shown with `-d plugin`) do the
//! rest. A block runs whole unless an exception ends it early, which these
//! benches do not cause inside a counted region: the counts are exact.
//!
//! Arguments: `mark=ADDR` (repeated: counter 0, 1, 2, …), `dump=ADDR`,
//! `out=FILE`, `epoch=ADDR` (a block there ends an epoch, e.g. a bench's
//! tick); see `counter`. The cache model is in `art`.
//!
//! Report (`out=`, text, one record a line):
//!
//! ```text
//! armcount-report 1
//! counters N                          (marks given; counter 0 counts nothing)
//! counter K insns I blocks B lines L warm S J cold S J epochmax E at N
//! epochs N max M at E                (with epoch=: the most instructions of all
//!                                     counters together in one epoch, and which)
//! pc ADDR SIZE K COUNT TAKEN          (hex address; per instruction and counter)
//! ```
//!
//! `lines` is the cache lines fetched while K counted; `warm` the
//! sequential and jump misses of a cache that sees only counted blocks (the
//! measured code alone, as on an otherwise idle CPU), `cold` those of one
//! that sees every block (the bench's other code evicts lines in between).
//! `epochmax` is the most instructions K counted within one epoch that an
//! epoch block ended (0 without `epoch=`), in epoch N (counted from 0,
//! before the first epoch block). Code outside the flash (run from SRAM) is not
//! fetched through the cache and never misses. TAKEN counts the runs after which the next block did not start right
//! after this instruction (kept for the block's last instruction only).

mod art;
mod counter;
#[cfg(not(test))]
mod ffi;

pub use art::{Art, Fetch, Misses};
pub use counter::{parse_args, Config, Counter};
