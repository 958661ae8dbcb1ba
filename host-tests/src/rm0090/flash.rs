//! RM0090 §3: the flash interface of the STM32F405 as
//! `drivers_core::flash` sees it — FLASH_ACR, FLASH_KEYR, FLASH_SR,
//! FLASH_CR and the array — for the two sectors the settings store owns
//! (10 and 11, 0x080C_0000..0x0810_0000), with power cuts.
//!
//! # Rules (RM0090 rev 19; the register subsections are §3.8.x in older
//! revisions and §3.9.x in newer ones: numbering UNCONFIRMED)
//!
//! | # | rule | section |
//! |---|---|---|
//! | F1 | After reset FLASH_CR is locked (LOCK = 1). Writing KEY1 = 0x4567_0123 then KEY2 = 0xCDEF_89AB to FLASH_KEYR unlocks it; any other value or order is a bus error and locks FLASH_CR until the next reset | §3.5.1 |
//! | F2 | While LOCK = 1, FLASH_CR ignores writes; writing LOCK = 1 locks it again | §3.5.1, FLASH_CR (LOCK) |
//! | F3 | A write to the flash array with PG = 0 (or with FLASH_CR locked) is not performed and sets PGSERR | §3.5.4 "Programming errors", FLASH_SR (PGSERR) |
//! | F4 | The access size of a program write must match PSIZE (byte for x8); otherwise it is not performed and PGPERR sets | §3.5.2, §3.5.4 "Programming errors" |
//! | F5 | Programming can only clear bits (1 → 0); 1s need an erase. Successive programs of the same place are allowed | §3.5.4 note |
//! | F6 | Sector erase: SER and SNB in FLASH_CR, then STRT; BSY while it runs; the sector reads 0xFF after | §3.5.3 |
//! | F7 | Check BSY clear before starting an operation and wait for it to clear after (the model records an operation started while BSY as a violation; what the chip does then is UNCONFIRMED) | §3.5.3 step 1, §3.5.4 steps 1 and 4 |
//! | F8 | The error flags OPERR, WRPERR, PGAERR, PGPERR, PGSERR and EOP are sticky and cleared by writing 1 (rc_w1); EOP sets only with EOPIE | FLASH_SR |
//! | F9 | FLASH_ACR.DCRST can be written only while DCEN = 0 | FLASH_ACR (DCRST) |
//! | F10 | An erase that crosses sectors outside the store would erase firmware: the model refuses it as a violation (not a chip rule; our memory map, memory.x) | – |
//!
//! # Modelling choices (UNCONFIRMED)
//!
//! * Timing: an erase keeps BSY set for [`ERASE_POLLS`] reads of FLASH_SR, a
//!   byte program for [`PROGRAM_POLLS`]; the effect on the array is
//!   immediate (on the chip a read of the array during BSY stalls until the
//!   operation ends, so nothing can see the difference).
//! * The data cache: with DCEN = 1, array reads go through 8 lines of 16
//!   bytes (the F405's D-cache is 8 × 128 bit) that programs and erases do
//!   not update — a driver that does not reset it reads stale data back.
//! * Writing FLASH_KEYR while FLASH_CR is already unlocked is taken as a
//!   wrong key sequence (F1).
//! * Power cuts: [`FlashModel::cut_power_at`] tears the array operation
//!   (byte program or sector erase) with that number, like
//!   `bridge_logic::persist::sim::SimFlash` tears its operations: a torn byte keeps
//!   an arbitrary subset of its 1 → 0 transitions, a torn sector word by
//!   word is erased, unchanged, or noise. From then on the model is
//!   unpowered: writes do nothing and FLASH_SR reads OPERR, so the driver
//!   returns at once (the CPU would be gone);
//!   [`FlashModel::restore_power`] is the next boot.

use bridge_logic::persist::sim::SplitMix64;
use drivers_core::flash::bits::*;
use drivers_core::flash::{FlashPort, FlashReg, SECTOR_SIZE, STORE_BASE, STORE_SIZE};
use drivers_core::Regs;

/// FLASH_SR reads with BSY set after a sector erase starts.
pub const ERASE_POLLS: u32 = 5;
/// FLASH_SR reads with BSY set after a byte program starts.
pub const PROGRAM_POLLS: u32 = 1;
/// FLASH_ACR as the firmware's clock set-up leaves it at 168 MHz: 5 wait
/// states, prefetch, instruction and data cache on.
pub const ACR_AT_168MHZ: u32 = 5 | (1 << 8) | (1 << 9) | ACR_DCEN;
/// Data cache: lines and line size (bytes).
const CACHE_LINES: usize = 8;
const LINE: usize = 16;

/// What the model counted.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FlashCounters {
    /// Byte programs performed (torn ones included).
    pub programs: u64,
    /// Sector erases performed (torn ones included).
    pub erases: u64,
    /// Bytes programmed while not erased with a value that clears a bit.
    pub overwrites: u64,
    /// Unlock sequences that worked.
    pub unlocks: u64,
    /// Writes to FLASH_CR ignored because it was locked.
    pub locked_writes: u64,
}

/// The flash interface and the store's two sectors (see the module docs).
#[derive(Clone)]
pub struct FlashModel {
    acr: u32,
    cr: u32,
    sr: u32,
    /// The next FLASH_KEYR write must be KEY2.
    key1_seen: bool,
    /// A wrong key sequence: FLASH_CR locked until reset.
    key_fault: bool,
    busy_polls: u32,
    array: Vec<u8>,
    /// Data cache lines: (line address, bytes), oldest first.
    cache: Vec<(u32, [u8; LINE])>,
    /// Array operations so far (program bytes and sector erases).
    ops: u64,
    cut: Option<(u64, u64)>,
    powered: bool,
    /// FLASH_SR flags the next array operation fails with.
    fail_next: u32,
    counters: FlashCounters,
    violations: Vec<String>,
}

impl std::fmt::Debug for FlashModel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FlashModel")
            .field("cr", &format_args!("{:#010x}", self.cr))
            .field("sr", &format_args!("{:#010x}", self.sr))
            .field("acr", &format_args!("{:#010x}", self.acr))
            .field("ops", &self.ops)
            .field("powered", &self.powered)
            .field("violations", &self.violations)
            .finish()
    }
}

impl Default for FlashModel {
    fn default() -> Self {
        FlashModel::new()
    }
}

impl FlashModel {
    /// Factory-fresh (both sectors erased), as the firmware's boot leaves
    /// the registers: FLASH_CR locked, FLASH_ACR at [`ACR_AT_168MHZ`].
    pub fn new() -> FlashModel {
        FlashModel {
            acr: ACR_AT_168MHZ,
            cr: CR_LOCK,
            sr: 0,
            key1_seen: false,
            key_fault: false,
            busy_polls: 0,
            array: vec![0xFF; STORE_SIZE],
            cache: Vec::new(),
            ops: 0,
            cut: None,
            powered: true,
            fail_next: 0,
            counters: FlashCounters::default(),
            violations: Vec::new(),
        }
    }

    pub fn cr(&self) -> u32 {
        self.cr
    }

    pub fn sr(&self) -> u32 {
        self.sr
    }

    pub fn acr(&self) -> u32 {
        self.acr
    }

    pub fn counters(&self) -> FlashCounters {
        self.counters
    }

    /// Array operations so far; the number the next one gets.
    pub fn ops(&self) -> u64 {
        self.ops
    }

    pub fn violations(&self) -> &[String] {
        &self.violations
    }

    /// The store's bytes (sector 10, then 11).
    pub fn array(&self) -> &[u8] {
        &self.array
    }

    pub fn array_mut(&mut self) -> &mut [u8] {
        &mut self.array
    }

    /// Set FLASH_SR flags as a failed operation would (WRPERR, OPERR…).
    pub fn inject_sr(&mut self, flags: u32) {
        self.sr |= flags;
    }

    /// Make the next program or erase fail with `flags` (WRPERR, OPERR…)
    /// instead of changing the array.
    pub fn fail_next_operation(&mut self, flags: u32) {
        self.fail_next = flags & SR_ERRORS;
    }

    /// Tear array operation number `op` (see the module docs).
    pub fn cut_power_at(&mut self, op: u64, seed: u64) {
        self.cut = Some((op, seed));
    }

    /// Power back: the registers as after a reset and the boot's clock
    /// set-up; the array as the cut left it.
    pub fn restore_power(&mut self) {
        let array = std::mem::take(&mut self.array);
        let (ops, counters) = (self.ops, self.counters);
        let violations = std::mem::take(&mut self.violations);
        *self = FlashModel::new();
        self.array = array;
        self.ops = ops;
        self.counters = counters;
        self.violations = violations;
    }

    pub fn powered(&self) -> bool {
        self.powered
    }

    fn violate(&mut self, what: impl Into<String>) {
        self.violations.push(what.into());
    }

    /// The store offset of `address`, if inside the store.
    fn offset(address: u32) -> Option<usize> {
        let off = address.checked_sub(STORE_BASE)? as usize;
        (off < STORE_SIZE).then_some(off)
    }

    /// Start an array operation: its number, and whether it is the torn one
    /// (with the tearing PRNG).
    fn begin_op(&mut self) -> Option<SplitMix64> {
        let n = self.ops;
        self.ops += 1;
        match self.cut {
            Some((op, seed)) if op == n => {
                self.powered = false;
                Some(SplitMix64::new(seed))
            }
            _ => None,
        }
    }

    /// F7: an operation starting while the previous one runs.
    fn check_idle(&mut self, what: &str) {
        if self.busy_polls > 0 {
            self.violate(format!("{what} while BSY"));
            self.busy_polls = 0;
        }
    }

    fn cr_write(&mut self, value: u32) {
        self.check_idle("FLASH_CR written");
        if self.cr & CR_LOCK != 0 {
            // F2.
            self.counters.locked_writes += 1;
            return;
        }
        self.cr = value & !CR_STRT;
        if value & CR_STRT != 0 {
            self.start(value);
        }
    }

    /// F6: STRT.
    fn start(&mut self, cr: u32) {
        if cr & CR_SER == 0 || cr & CR_MER != 0 {
            self.violate(format!("STRT with FLASH_CR = {cr:#010x}: no sector erase"));
            return;
        }
        let snb = (cr & CR_SNB_MASK) >> CR_SNB_SHIFT;
        let sector = match snb {
            10 => 0,
            11 => 1,
            other => {
                self.violate(format!("erase of sector {other}, outside the store (F10)"));
                return;
            }
        };
        if self.fail_next != 0 {
            self.sr |= std::mem::take(&mut self.fail_next);
            return;
        }
        self.counters.erases += 1;
        let range = sector * SECTOR_SIZE..(sector + 1) * SECTOR_SIZE;
        match self.begin_op() {
            None => self.array[range].fill(0xFF),
            Some(mut rng) => {
                let outcome = rng.below(4);
                for word in self.array[range].chunks_mut(4) {
                    let pick = match outcome {
                        0 => 0, // untouched
                        1 => 1, // erased
                        _ => 2 + rng.below(3),
                    };
                    match pick {
                        0 | 3 => {}
                        1 | 2 => word.fill(0xFF),
                        _ => {
                            let r = rng.next_u32().to_le_bytes();
                            word.copy_from_slice(&r);
                        }
                    }
                }
            }
        }
        self.busy_polls = ERASE_POLLS;
    }

    /// F3–F5: one byte write to the array.
    fn program(&mut self, address: u32, byte: u8) {
        if !self.powered {
            return;
        }
        self.check_idle("flash array written");
        let Some(off) = Self::offset(address) else {
            self.violate(format!("array write at {address:#010x}, outside the store"));
            return;
        };
        if self.cr & CR_LOCK != 0 || self.cr & CR_PG == 0 || self.cr & (CR_SER | CR_MER) != 0 {
            self.sr |= SR_PGSERR;
            return;
        }
        if self.cr & CR_PSIZE_MASK != CR_PSIZE_X8 {
            self.sr |= SR_PGPERR;
            return;
        }
        if self.fail_next != 0 {
            self.sr |= std::mem::take(&mut self.fail_next);
            return;
        }
        self.counters.programs += 1;
        let old = self.array[off];
        if old != 0xFF && old & !byte != 0 {
            self.counters.overwrites += 1;
        }
        self.array[off] = match self.begin_op() {
            None => old & byte,
            Some(mut rng) => {
                let clears = old & !byte;
                let kept = clears & (rng.next_u32() as u8);
                old & !kept
            }
        };
        self.busy_polls = PROGRAM_POLLS;
    }

    fn sr_read(&mut self) -> u32 {
        if !self.powered {
            return SR_OPERR;
        }
        if self.busy_polls > 0 {
            self.busy_polls -= 1;
            if self.busy_polls == 0 && self.cr & CR_EOPIE != 0 {
                self.sr |= SR_EOP;
            }
            return self.sr | SR_BSY;
        }
        self.sr
    }

    fn keyr_write(&mut self, value: u32) {
        if self.key_fault {
            return;
        }
        let ok = if self.cr & CR_LOCK == 0 {
            self.violate("FLASH_KEYR written while FLASH_CR is unlocked");
            false
        } else if !self.key1_seen {
            self.key1_seen = value == KEY1;
            value == KEY1
        } else {
            self.key1_seen = false;
            if value == KEY2 {
                self.cr &= !CR_LOCK;
                self.counters.unlocks += 1;
            }
            value == KEY2
        };
        if !ok {
            // F1: bus error, locked until reset.
            self.violate(format!(
                "wrong key sequence ({value:#010x}): bus error, FLASH_CR locked until reset"
            ));
            self.key_fault = true;
            self.key1_seen = false;
            self.cr |= CR_LOCK;
        }
    }

    fn acr_write(&mut self, value: u32) {
        let mut value = value;
        if value & ACR_DCRST != 0 {
            if self.acr & ACR_DCEN != 0 || value & ACR_DCEN != 0 {
                // F9: not writable with the cache on.
                self.violate("FLASH_ACR.DCRST written with DCEN = 1");
                value &= !ACR_DCRST;
            } else {
                self.cache.clear();
            }
        }
        self.acr = value;
    }

    /// The bytes of the cache line at `line` (a multiple of [`LINE`]): from
    /// the data cache if it holds it, else from the array (filling the
    /// cache when it is on).
    fn line(&mut self, line: usize) -> [u8; LINE] {
        let mut bytes = [0u8; LINE];
        bytes.copy_from_slice(&self.array[line..line + LINE]);
        if self.acr & ACR_DCEN == 0 {
            return bytes;
        }
        if let Some((_, cached)) = self.cache.iter().find(|(a, _)| *a as usize == line) {
            return *cached;
        }
        if self.cache.len() == CACHE_LINES {
            self.cache.remove(0);
        }
        self.cache.push((line as u32, bytes));
        bytes
    }
}

impl Regs<FlashReg> for FlashModel {
    fn read(&mut self, reg: FlashReg) -> u32 {
        match reg {
            FlashReg::Acr => self.acr,
            FlashReg::Sr => self.sr_read(),
            FlashReg::Cr => self.cr,
            FlashReg::Keyr | FlashReg::Optkeyr => 0,
            FlashReg::Optcr => 0x0FFF_AAED,
        }
    }

    fn write(&mut self, reg: FlashReg, value: u32) {
        if !self.powered {
            return;
        }
        match reg {
            FlashReg::Acr => self.acr_write(value),
            FlashReg::Keyr => self.keyr_write(value),
            // F8: rc_w1.
            FlashReg::Sr => self.sr &= !(value & (SR_ERRORS | SR_EOP)),
            FlashReg::Cr => self.cr_write(value),
            FlashReg::Optkeyr | FlashReg::Optcr => {
                self.violate(format!(
                    "{reg:?} written: the option bytes are not the store's"
                ));
            }
        }
    }
}

impl FlashPort for FlashModel {
    fn read_array(&mut self, address: u32, dst: &mut [u8]) {
        if self.busy_polls > 0 {
            // The read stalls until the operation ends.
            self.busy_polls = 0;
        }
        let Some(start) = Self::offset(address).filter(|s| s + dst.len() <= STORE_SIZE) else {
            self.violate(format!("array read at {address:#010x}, outside the store"));
            dst.fill(0xFF);
            return;
        };
        if !self.powered {
            dst.fill(0xFF);
            return;
        }
        let mut at = start;
        for out in dst.chunks_mut(LINE) {
            // Split at line boundaries: each piece from one line.
            let mut done = 0;
            while done < out.len() {
                let line = (at / LINE) * LINE;
                let bytes = self.line(line);
                let from = at - line;
                let n = (LINE - from).min(out.len() - done);
                out[done..done + n].copy_from_slice(&bytes[from..from + n]);
                done += n;
                at += n;
            }
        }
    }

    fn write_array_u8(&mut self, address: u32, byte: u8) {
        self.program(address, byte);
    }
}
