//! The box's own use of the extension: which received bit is which axis
//! input, which transmitted bit shows which axis state, and the debounce.
//!
//! # Inputs
//!
//! Per axis, four optional inputs: BIN1, BIN2 (manual 7.5.2), the end switch
//! (7.5.1) and the auto-run run/stop switch (7.5.3). Each names a receive
//! bit (wire order, 0..=255) and a contact type:
//!
//! * **Electrical convention**, as on the PoStep60's own connector (manual
//!   4.5.1: inputs with pull-ups, switches to GND): a '165 input with a
//!   pull-up and the contact to GND, so **contact closed = bit 0**, open =
//!   bit 1.
//! * **NO/NC**: an input is *active* when a normally-open contact is closed,
//!   or a normally-closed one is open. Active means: BINx pressed, end switch
//!   reached, auto-run switch on (run). An NC end switch therefore also
//!   reads active when its wire breaks. For inputs wired the other way (to
//!   VCC with a pull-down), choose the other contact type.
//!
//! Edges (a press moves, a change of the end switch stops) are the device
//! model's business: it gets debounced levels ([`AxisInputs`]) every tick.
//!
//! # Debounce
//!
//! A level is accepted when [`Mapping::debounce`] consecutive transfers
//! (K, 1..=255, factory 5) all read it; until then the previous accepted
//! level stands (none at all after power-up, a mapping change, or while the
//! extension is off). With auto-restart at the 1 kHz control tick, K = 5 is
//! 5 ms: contact bounce shorter than that never shows, and a single-transfer
//! glitch never moves a motor. A lasting change reaches the device model at
//! the first control tick after the K-th transfer that reads it.
//!
//! # Outputs
//!
//! Per axis, three optional lamps: moving, fault, idle (plain bools the
//! caller computes). Each names a transmit bit and whether it is inverted
//! (lamp on = bit 0, e.g. an LED from VCC into a '595 output). Mapped bits
//! override the transmit data register on the wire at every transfer (the
//! register reads what the master wrote); if two lamps name the same bit,
//! the later one wins (axis order, then moving, fault, idle).
//!
//! # Registers
//!
//! Each input or output is one 16-bit register: bit 15 = mapped, bit 14 =
//! NC (inputs) / inverted (outputs), bits 7–0 = the bit number, every other
//! bit 0; an unmapped entry is 0x0000. Anything else is
//! [`IoError::IllegalValue`].

use super::IoError;
use crate::powerstep::chain::MAX_DEVICES;

/// Axes the mapping covers (the chain's maximum).
pub const MAX_AXES: usize = MAX_DEVICES;
/// Factory debounce: transfers that must agree.
pub const DEBOUNCE_FACTORY: u8 = 5;

/// An axis input.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Input {
    Bin1 = 0,
    Bin2 = 1,
    EndSwitch = 2,
    Run = 3,
}

impl Input {
    pub const ALL: [Input; 4] = [Input::Bin1, Input::Bin2, Input::EndSwitch, Input::Run];
}

/// An axis output.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Output {
    Moving = 0,
    Fault = 1,
    Idle = 2,
}

impl Output {
    pub const ALL: [Output; 3] = [Output::Moving, Output::Fault, Output::Idle];
}

/// A mapped input: receive bit and contact type.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct InputBit {
    pub bit: u8,
    /// Normally-closed contact (else normally open).
    pub nc: bool,
}

/// A mapped output: transmit bit and polarity.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct OutputBit {
    pub bit: u8,
    /// Lamp on = bit 0.
    pub inverted: bool,
}

/// The mapping of one axis.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct AxisMap {
    pub inputs: [Option<InputBit>; 4],
    pub outputs: [Option<OutputBit>; 3],
}

impl AxisMap {
    pub const NONE: AxisMap = AxisMap {
        inputs: [None; 4],
        outputs: [None; 3],
    };

    pub fn input(&self, i: Input) -> Option<InputBit> {
        self.inputs.get(i as usize).copied().flatten()
    }

    pub fn output(&self, o: Output) -> Option<OutputBit> {
        self.outputs.get(o as usize).copied().flatten()
    }

    pub fn set_input(&mut self, i: Input, m: Option<InputBit>) {
        if let Some(slot) = self.inputs.get_mut(i as usize) {
            *slot = m;
        }
    }

    pub fn set_output(&mut self, o: Output, m: Option<OutputBit>) {
        if let Some(slot) = self.outputs.get_mut(o as usize) {
            *slot = m;
        }
    }
}

/// The whole mapping (persisted with the extension's settings).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Mapping {
    /// Transfers that must agree before a level is accepted (1..=255).
    pub debounce: u8,
    pub axes: [AxisMap; MAX_AXES],
}

impl Mapping {
    /// Nothing mapped, factory debounce.
    pub const FACTORY: Mapping = Mapping {
        debounce: DEBOUNCE_FACTORY,
        axes: [AxisMap::NONE; MAX_AXES],
    };
}

const MAPPED: u16 = 1 << 15;
const FLAG: u16 = 1 << 14;
const BIT: u16 = 0xFF;

/// The register value of an input entry.
pub const fn input_register(m: Option<InputBit>) -> u16 {
    match m {
        None => 0,
        Some(m) => MAPPED | if m.nc { FLAG } else { 0 } | m.bit as u16,
    }
}

/// The register value of an output entry.
pub const fn output_register(m: Option<OutputBit>) -> u16 {
    match m {
        None => 0,
        Some(m) => MAPPED | if m.inverted { FLAG } else { 0 } | m.bit as u16,
    }
}

/// (bit, flag) of a valid entry register, `None` for 0x0000.
const fn parse_entry(v: u16) -> Result<Option<(u8, bool)>, IoError> {
    if v & !(MAPPED | FLAG | BIT) != 0 || (v & MAPPED == 0 && v != 0) {
        return Err(IoError::IllegalValue);
    }
    if v == 0 {
        Ok(None)
    } else {
        Ok(Some(((v & BIT) as u8, v & FLAG != 0)))
    }
}

/// An input entry from its register value.
pub const fn input_from_register(v: u16) -> Result<Option<InputBit>, IoError> {
    match parse_entry(v) {
        Ok(Some((bit, nc))) => Ok(Some(InputBit { bit, nc })),
        Ok(None) => Ok(None),
        Err(e) => Err(e),
    }
}

/// An output entry from its register value.
pub const fn output_from_register(v: u16) -> Result<Option<OutputBit>, IoError> {
    match parse_entry(v) {
        Ok(Some((bit, inverted))) => Ok(Some(OutputBit { bit, inverted })),
        Ok(None) => Ok(None),
        Err(e) => Err(e),
    }
}

/// A debounced input as the device model sees it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Contact {
    /// The contact is closed (its bit reads 0).
    pub closed: bool,
    /// NO and closed, or NC and open: BINx pressed, end switch reached,
    /// run/stop switch on.
    pub active: bool,
}

/// Debounced inputs of one axis; `None` = unmapped, or no accepted level
/// yet (after power-up, a mapping change, or while the extension is off).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct AxisInputs {
    pub bin1: Option<Contact>,
    pub bin2: Option<Contact>,
    pub end_switch: Option<Contact>,
    pub run: Option<Contact>,
}

impl AxisInputs {
    pub fn get(&self, i: Input) -> Option<Contact> {
        match i {
            Input::Bin1 => self.bin1,
            Input::Bin2 => self.bin2,
            Input::EndSwitch => self.end_switch,
            Input::Run => self.run,
        }
    }

    fn set(&mut self, i: Input, c: Option<Contact>) {
        match i {
            Input::Bin1 => self.bin1 = c,
            Input::Bin2 => self.bin2 = c,
            Input::EndSwitch => self.end_switch = c,
            Input::Run => self.run = c,
        }
    }
}

/// The state of one axis for its lamps.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct AxisOutputs {
    pub moving: bool,
    pub fault: bool,
    pub idle: bool,
}

impl AxisOutputs {
    pub fn get(&self, o: Output) -> bool {
        match o {
            Output::Moving => self.moving,
            Output::Fault => self.fault,
            Output::Idle => self.idle,
        }
    }
}

/// One input's debouncer: the accepted level and a candidate run.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct Debounce {
    level: Option<bool>,
    candidate: bool,
    run: u8,
}

impl Debounce {
    pub const NEW: Debounce = Debounce {
        level: None,
        candidate: false,
        run: 0,
    };

    /// The accepted level (the bit as received), if any.
    pub fn level(&self) -> Option<bool> {
        self.level
    }

    /// One transfer's sample; `k` = transfers that must agree (0 acts as 1).
    pub fn feed(&mut self, sample: bool, k: u8) {
        if self.level == Some(sample) {
            self.run = 0;
            return;
        }
        if self.run > 0 && self.candidate == sample {
            self.run = self.run.saturating_add(1);
        } else {
            self.candidate = sample;
            self.run = 1;
        }
        if self.run >= k.max(1) {
            self.level = Some(sample);
            self.run = 0;
        }
    }
}

/// Debouncers of every mapped input, fed by completed transfers.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct InputFilter {
    state: [[Debounce; 4]; MAX_AXES],
}

impl Default for InputFilter {
    fn default() -> Self {
        InputFilter::NEW
    }
}

impl InputFilter {
    pub const NEW: InputFilter = InputFilter {
        state: [[Debounce::NEW; 4]; MAX_AXES],
    };

    /// Forget every accepted level.
    pub fn reset(&mut self) {
        *self = InputFilter::NEW;
    }

    /// Forget one input's level (its mapping changed).
    pub fn reset_input(&mut self, axis: usize, i: Input) {
        if let Some(d) = self.state.get_mut(axis).and_then(|a| a.get_mut(i as usize)) {
            *d = Debounce::NEW;
        }
    }

    /// Feed the received bits of a transfer of `bits` bits: inputs whose bit
    /// was not clocked get no sample.
    pub fn feed(&mut self, map: &Mapping, rx: &super::WireBits, bits: u16) {
        for (axis_map, axis_state) in map.axes.iter().zip(self.state.iter_mut()) {
            for (m, d) in axis_map.inputs.iter().zip(axis_state.iter_mut()) {
                if let Some(m) = m {
                    if u16::from(m.bit) < bits {
                        d.feed(rx.get(usize::from(m.bit)), map.debounce);
                    }
                }
            }
        }
    }

    /// The debounced inputs of `axis` (all `None` past [`MAX_AXES`]).
    pub fn inputs(&self, map: &Mapping, axis: usize) -> AxisInputs {
        let mut out = AxisInputs::default();
        let (Some(m), Some(s)) = (map.axes.get(axis), self.state.get(axis)) else {
            return out;
        };
        for (i, d) in Input::ALL.iter().zip(s.iter()) {
            let c = m.input(*i).and_then(|ib| {
                d.level().map(|bit| Contact {
                    closed: !bit,
                    active: bit == ib.nc,
                })
            });
            out.set(*i, c);
        }
        out
    }
}

/// Put every mapped lamp of `outputs` (axis 0 first) into `tx`.
pub fn apply_outputs(map: &Mapping, outputs: &[AxisOutputs], tx: &mut super::WireBits) {
    for (m, state) in map.axes.iter().zip(outputs.iter()) {
        for o in Output::ALL {
            if let Some(ob) = m.output(o) {
                tx.set(usize::from(ob.bit), state.get(o) != ob.inverted);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    #![allow(
        clippy::indexing_slicing,
        clippy::arithmetic_side_effects,
        clippy::unwrap_used
    )]
    #![allow(clippy::panic)]
    use super::super::WireBits;
    use super::*;

    #[test]
    fn a_level_is_accepted_after_k_agreeing_samples() {
        let mut d = Debounce::NEW;
        for _ in 0..4 {
            d.feed(true, 5);
            assert_eq!(d.level(), None);
        }
        d.feed(true, 5);
        assert_eq!(d.level(), Some(true));
    }

    #[test]
    fn bounce_shorter_than_k_never_shows() {
        let mut d = Debounce::NEW;
        for _ in 0..5 {
            d.feed(true, 5);
        }
        // Bouncing: never 5 lows in a row.
        for s in [
            false, true, false, false, true, false, false, false, false, true,
        ] {
            d.feed(s, 5);
            assert_eq!(d.level(), Some(true));
        }
        for _ in 0..4 {
            d.feed(false, 5);
            assert_eq!(d.level(), Some(true));
        }
        d.feed(false, 5);
        assert_eq!(d.level(), Some(false));
    }

    #[test]
    fn k_of_1_and_0_accept_every_sample() {
        for k in [0, 1] {
            let mut d = Debounce::NEW;
            for s in [true, false, false, true] {
                d.feed(s, k);
                assert_eq!(d.level(), Some(s));
            }
        }
    }

    #[test]
    fn k_of_255_needs_255_samples() {
        let mut d = Debounce::NEW;
        for _ in 0..254 {
            d.feed(false, 255);
        }
        assert_eq!(d.level(), None);
        d.feed(false, 255);
        assert_eq!(d.level(), Some(false));
    }

    #[test]
    fn entry_registers_round_trip_and_reject_reserved_bits() {
        for bit in [0u8, 1, 127, 255] {
            for flag in [false, true] {
                let i = Some(InputBit { bit, nc: flag });
                assert_eq!(input_from_register(input_register(i)), Ok(i));
                let o = Some(OutputBit {
                    bit,
                    inverted: flag,
                });
                assert_eq!(output_from_register(output_register(o)), Ok(o));
            }
        }
        assert_eq!(input_register(Some(InputBit { bit: 3, nc: true })), 0xC003);
        assert_eq!(input_from_register(0), Ok(None));
        for bad in [0x0001u16, 0x4000, 0x4003, 0x8100, 0xA000, 0x8000 | 1 << 13] {
            assert_eq!(
                input_from_register(bad),
                Err(IoError::IllegalValue),
                "{bad:#06x}"
            );
            assert_eq!(
                output_from_register(bad),
                Err(IoError::IllegalValue),
                "{bad:#06x}"
            );
        }
    }

    fn map_axis1_bin1(nc: bool) -> Mapping {
        let mut m = Mapping::FACTORY;
        m.debounce = 1;
        m.axes[1].set_input(Input::Bin1, Some(InputBit { bit: 9, nc }));
        m
    }

    #[test]
    fn no_contact_closed_reads_bit_0_and_is_active() {
        let m = map_axis1_bin1(false);
        let mut f = InputFilter::NEW;
        f.feed(&m, &WireBits::ZERO, 16);
        let c = f.inputs(&m, 1).bin1.unwrap();
        assert_eq!(
            c,
            Contact {
                closed: true,
                active: true
            }
        );
        assert_eq!(f.inputs(&m, 0), AxisInputs::default());
    }

    #[test]
    fn nc_contact_is_active_when_open() {
        let m = map_axis1_bin1(true);
        let mut f = InputFilter::NEW;
        let mut rx = WireBits::ZERO;
        rx.set(9, true);
        f.feed(&m, &rx, 16);
        assert_eq!(
            f.inputs(&m, 1).bin1,
            Some(Contact {
                closed: false,
                active: true
            })
        );
        f.feed(&m, &WireBits::ZERO, 16);
        assert_eq!(
            f.inputs(&m, 1).bin1,
            Some(Contact {
                closed: true,
                active: false
            })
        );
    }

    #[test]
    fn inputs_past_the_transferred_bits_get_no_sample() {
        let m = map_axis1_bin1(false);
        let mut f = InputFilter::NEW;
        f.feed(&m, &WireBits::ZERO, 9);
        assert_eq!(f.inputs(&m, 1).bin1, None);
        assert_eq!(f.inputs(&m, MAX_AXES), AxisInputs::default());
    }

    #[test]
    fn lamps_override_their_bits_with_polarity_and_later_wins() {
        let mut m = Mapping::FACTORY;
        m.axes[0].set_output(
            Output::Moving,
            Some(OutputBit {
                bit: 0,
                inverted: false,
            }),
        );
        m.axes[0].set_output(
            Output::Fault,
            Some(OutputBit {
                bit: 1,
                inverted: true,
            }),
        );
        m.axes[2].set_output(
            Output::Idle,
            Some(OutputBit {
                bit: 0,
                inverted: false,
            }),
        );
        let mut tx = WireBits::from_words([0xFFFF; 16]);
        let outs = [
            AxisOutputs {
                moving: true,
                fault: true,
                idle: false,
            },
            AxisOutputs::default(),
            AxisOutputs {
                idle: false,
                ..AxisOutputs::default()
            },
        ];
        apply_outputs(&m, &outs, &mut tx);
        // Bit 0: axis 2's idle (false) overrides axis 0's moving (true).
        assert!(!tx.get(0));
        // Bit 1: fault inverted.
        assert!(!tx.get(1));
        assert!(tx.get(2));
        // Fewer outputs than axes: the rest are left alone.
        let mut tx = WireBits::ZERO;
        apply_outputs(&m, &outs[..1], &mut tx);
        assert!(tx.get(0));
    }
}
