//! RM0090 §21: the independent watchdog as `drivers_core::iwdg` sees it,
//! on an LSI clock the test drives ([`IwdgModel::lsi`]).
//!
//! # Rules (RM0090 rev 19 section numbers)
//!
//! | # | rule | section |
//! |---|---|---|
//! | W1 | KR = 0xCCCC starts the watchdog (and the LSI); nothing stops it but a reset; the counter starts at 0xFFF with PR = 0 (÷4) | §21.3.1 |
//! | W2 | PR and RLR are write-protected: a write takes effect only after KR = 0x5555; any other KR value (0xAAAA, 0xCCCC included) protects them again | §21.3.2 |
//! | W3 | A PR or RLR write is carried into the LSI domain in up to 5 LSI cycles; SR.PVU / SR.RVU are set meanwhile, and the register may be written only while its flag is clear | §21.4.4, §21.4.2, §21.4.3 |
//! | W4 | KR = 0xAAAA reloads the counter with the RLR value in effect | §21.3.1 |
//! | W5 | The counter counts down at f_LSI / (4 · 2^PR); at 0 the MCU is reset | §21.3.1, §21.4.2 |
//!
//! # Modelling choices (UNCONFIRMED)
//!
//! * An update takes exactly 5 LSI cycles, and runs only while the LSI does
//!   (after 0xCCCC).
//! * Time passes while the driver polls SR: [`POLLS_PER_LSI_CYCLE`] reads of
//!   SR are one LSI cycle (a poll is a few APB1 cycles at 42 MHz).
//! * A PR/RLR write while its update flag is set is ignored and recorded as
//!   a violation.
//! * A feed does not restart the prescaler: the first count after it comes
//!   after 1 to 4 · 2^PR LSI cycles.
//! * [`IwdgModel::stop_lsi`] stands for a dead LSI: nothing counts, no
//!   update completes.

use drivers_core::iwdg::bits::*;
use drivers_core::iwdg::IwdgReg;
use drivers_core::Regs;

/// SR reads per LSI cycle (see the module docs).
pub const POLLS_PER_LSI_CYCLE: u32 = 300;
/// LSI cycles a PR/RLR update takes.
pub const UPDATE_CYCLES: u32 = 5;

/// The IWDG (see the module docs).
#[derive(Clone, Debug)]
pub struct IwdgModel {
    running: bool,
    access: bool,
    pr: u32,
    rlr: u32,
    pr_pending: Option<(u32, u32)>,
    rlr_pending: Option<(u32, u32)>,
    counter: u32,
    /// LSI cycles towards the next count.
    prescale: u64,
    polls: u32,
    /// LSI cycles since start.
    cycles: u64,
    /// When the watchdog reset the MCU (LSI cycles since start).
    reset_at: Option<u64>,
    /// The LSI stopped ([`IwdgModel::stop_lsi`]).
    lsi_stopped: bool,
    /// PR/RLR writes ignored because they were protected.
    pub protected_writes: u32,
    /// SR reads (the driver's polls).
    pub sr_reads: u64,
    violations: Vec<String>,
}

impl Default for IwdgModel {
    fn default() -> Self {
        IwdgModel::new()
    }
}

impl IwdgModel {
    /// After a reset: stopped, PR 0, RLR 0xFFF.
    pub fn new() -> IwdgModel {
        IwdgModel {
            running: false,
            access: false,
            pr: 0,
            rlr: RLR_MAX,
            pr_pending: None,
            rlr_pending: None,
            counter: RLR_MAX,
            prescale: 0,
            polls: 0,
            cycles: 0,
            reset_at: None,
            lsi_stopped: false,
            protected_writes: 0,
            sr_reads: 0,
            violations: Vec::new(),
        }
    }

    pub fn running(&self) -> bool {
        self.running
    }

    /// PR and RLR in effect.
    pub fn pr(&self) -> u32 {
        self.pr
    }

    pub fn rlr(&self) -> u32 {
        self.rlr
    }

    pub fn counter(&self) -> u32 {
        self.counter
    }

    /// PR/RLR writable now.
    pub fn access(&self) -> bool {
        self.access
    }

    /// LSI cycles since start.
    pub fn cycles(&self) -> u64 {
        self.cycles
    }

    /// LSI cycles since start at which the watchdog reset the MCU.
    pub fn reset_at(&self) -> Option<u64> {
        self.reset_at
    }

    pub fn violations(&self) -> &[String] {
        &self.violations
    }

    /// From now on the LSI does not run (a failure, see the module docs).
    pub fn stop_lsi(&mut self) {
        self.lsi_stopped = true;
    }

    /// `n` LSI cycles pass.
    pub fn lsi(&mut self, n: u64) {
        for _ in 0..n {
            self.lsi_cycle();
        }
    }

    fn lsi_cycle(&mut self) {
        if !self.running || self.lsi_stopped || self.reset_at.is_some() {
            return;
        }
        self.cycles += 1;
        for (pending, reg) in [
            (&mut self.pr_pending, &mut self.pr),
            (&mut self.rlr_pending, &mut self.rlr),
        ] {
            if let Some((value, left)) = *pending {
                if left <= 1 {
                    *reg = value;
                    *pending = None;
                } else {
                    *pending = Some((value, left - 1));
                }
            }
        }
        self.prescale += 1;
        if self.prescale >= 4u64 << self.pr {
            self.prescale = 0;
            if self.counter == 0 {
                self.reset_at = Some(self.cycles);
            } else {
                self.counter -= 1;
            }
        }
    }

    fn protected_write(&mut self, reg: IwdgReg, value: u32) {
        if !self.access {
            self.protected_writes += 1;
            return;
        }
        let (pending, mask) = match reg {
            IwdgReg::Pr => (&mut self.pr_pending, 0b111),
            _ => (&mut self.rlr_pending, RLR_MAX),
        };
        if pending.is_some() {
            self.violations
                .push(format!("{reg:?} written while its update flag is set"));
            return;
        }
        *pending = Some((value & mask, UPDATE_CYCLES));
    }
}

impl Regs<IwdgReg> for IwdgModel {
    fn read(&mut self, reg: IwdgReg) -> u32 {
        match reg {
            IwdgReg::Kr => 0,
            IwdgReg::Pr => self.pr,
            IwdgReg::Rlr => self.rlr,
            IwdgReg::Sr => {
                self.sr_reads += 1;
                self.polls += 1;
                if self.polls >= POLLS_PER_LSI_CYCLE {
                    self.polls = 0;
                    self.lsi_cycle();
                }
                (u32::from(self.pr_pending.is_some()) * SR_PVU)
                    | (u32::from(self.rlr_pending.is_some()) * SR_RVU)
            }
        }
    }

    fn write(&mut self, reg: IwdgReg, value: u32) {
        match reg {
            IwdgReg::Kr => {
                let key = value & 0xFFFF;
                self.access = key == KEY_ACCESS;
                match key {
                    KEY_START => self.running = true,
                    KEY_RELOAD => self.counter = self.rlr,
                    _ => {}
                }
            }
            IwdgReg::Pr | IwdgReg::Rlr => self.protected_write(reg, value),
            IwdgReg::Sr => self.violations.push("SR is read-only".into()),
        }
    }
}
