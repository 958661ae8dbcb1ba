//! The I/O extension driver's hardware map: the registers it touches
//! (SPI2, DMA1/DMA2, TIM1, GPIOB), their bits, the DMA buffers, the two
//! engines' streams, the hardware trait and the driver's errors. The
//! register sequence that uses them is the parent module's.

use bridge_logic::ioext::{WireBits, MAX_BITS};

use crate::dma::bits::{
    DMA_CR_DMEIE, DMA_CR_PL_HIGH, DMA_CR_PL_VERY_HIGH, DMA_CR_TCIE, DMA_CR_TEIE,
};
use crate::dma::{self, DmaReg, Flags, Role, Size, Stream};
use crate::spi::SpiReg;
use crate::Regs;

/// Most bits of a transfer, as a buffer length.
pub const MAX: usize = MAX_BITS as usize;

/// The registers the driver touches: SPI2, DMA1, DMA2, TIM1, GPIOB (RM0090
/// §28.5, §10.5, §17.4, §8.4).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum IoReg {
    Spi(SpiReg),
    Dma1(DmaReg),
    Dma2(DmaReg),
    Tim(TimReg),
    Gpio(GpioReg),
}

/// TIM1's registers the bit engine uses (RM0090 §17.4).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum TimReg {
    Cr1,
    Dier,
    Sr,
    Egr,
    Ccmr1,
    Ccmr2,
    Ccer,
    Cnt,
    Psc,
    Arr,
    Rcr,
    Ccr1,
    Ccr2,
    Ccr3,
    Bdtr,
}

/// GPIOB's registers (RM0090 §8.4).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum GpioReg {
    Moder,
    Pupdr,
    Afrh,
    Idr,
    Bsrr,
}

/// TIM1 and GPIO bits (RM0090 §17.4, §8.4).
pub mod bits {
    pub const TIM_CR1_CEN: u32 = 1 << 0;
    pub const TIM_CR1_OPM: u32 = 1 << 3;
    pub const TIM_DIER_CC2DE: u32 = 1 << 10;
    pub const TIM_DIER_CC3DE: u32 = 1 << 11;
    pub const TIM_EGR_UG: u32 = 1 << 0;
    pub const TIM_CCMR1_OC1M_SHIFT: u32 = 4;
    pub const TIM_CCMR1_OC1M_MASK: u32 = 0b111 << TIM_CCMR1_OC1M_SHIFT;
    pub const TIM_CCMR1_OC2M_SHIFT: u32 = 12;
    pub const TIM_CCMR2_OC3M_SHIFT: u32 = 4;
    /// OCxM codes: frozen, forced inactive, PWM mode 2.
    pub const TIM_OCM_FROZEN: u32 = 0b000;
    pub const TIM_OCM_FORCE_INACTIVE: u32 = 0b100;
    pub const TIM_OCM_PWM2: u32 = 0b111;
    pub const TIM_CCER_CC1E: u32 = 1 << 0;
    pub const TIM_CCER_CC1NE: u32 = 1 << 2;
    pub const TIM_CCER_CC1NP: u32 = 1 << 3;
    pub const TIM_BDTR_MOE: u32 = 1 << 15;
    /// MODER codes (2 bits a pin).
    pub const GPIO_MODE_INPUT: u32 = 0b00;
    pub const GPIO_MODE_OUTPUT: u32 = 0b01;
    pub const GPIO_MODE_AF: u32 = 0b10;
    /// PUPDR codes (2 bits a pin).
    pub const GPIO_PULL_UP: u32 = 0b01;
    pub const GPIO_PULL_DOWN: u32 = 0b10;
    /// Alternate functions of PB13–PB15 (datasheet table 9): SPI2, TIM1.
    pub const AF_SPI2: u32 = 5;
    pub const AF_TIM1: u32 = 1;
}

/// Where the DMA streams point (the firmware: `'static` buffers and the
/// peripherals' data registers; the model: its own addresses).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Target {
    TxBytes,
    RxBytes,
    MosiTable,
    Samples,
    SpiDr,
    GpioBsrr,
    GpioIdr,
}

/// The DMA buffers: `'static` on the chip, so a stream can own them while
/// it runs.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct IoExtBuffers {
    /// The SPI engine's frames out and in.
    pub tx: [u8; MAX / 8],
    pub rx: [u8; MAX / 8],
    /// The bit engine's GPIOB_BSRR words (one per bit) and IDR samples.
    pub mosi_bsrr: [u32; MAX],
    pub samples: [u16; MAX],
}

impl IoExtBuffers {
    pub const fn new() -> IoExtBuffers {
        IoExtBuffers {
            tx: [0; MAX / 8],
            rx: [0; MAX / 8],
            mosi_bsrr: [0; MAX],
            samples: [0; MAX],
        }
    }
}

impl Default for IoExtBuffers {
    fn default() -> Self {
        Self::new()
    }
}

/// What the driver needs besides the registers.
pub trait IoExtHw: Regs<IoReg> {
    /// The port's pins on GPIOB (constants: the masks and BSRR words fold).
    const PINS: Pins;
    /// Busy-wait `cycles` CPU cycles (the half-period waits).
    fn delay_cycles(&mut self, cycles: u32);
    /// Run `f` with interrupts masked (read-modify-writes of GPIOB's mode
    /// registers, which other drivers' pins share).
    fn masked<R>(&mut self, f: impl FnOnce(&mut Self) -> R) -> R;
    /// The CPU's access to the DMA buffers (never while a stream runs).
    fn buffers<R>(&mut self, f: impl FnOnce(&mut IoExtBuffers) -> R) -> R;
    /// The bus address of `target` (PAR / M0AR).
    fn address(&self, target: Target) -> u32;
}

/// The port's GPIOB pins (`pins.rs`): SCK, MISO and MOSI must be 8..=15
/// (AFRH), CS any.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Pins {
    pub cs: u8,
    pub sck: u8,
    pub miso: u8,
    pub mosi: u8,
}

/// Why a transfer failed (the bridge counts it, `on_io_failed`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum IoExtError {
    /// A DMA stream reported an error, or the output stream had not moved
    /// all its items when the input stream had (module docs, "Errors").
    Dma,
    /// SPI2 still busy, TIM1 still counting after the last item, or a
    /// stream that does not stop.
    EngineStuck,
    /// No end within the plan's timeout: the driver stopped the engine.
    Timeout,
    /// A transfer was still running: nothing was started.
    Busy,
    /// The plan has no engine this driver can run (0 frames, or an empty
    /// MOSI table): nothing was started.
    BadPlan,
}

/// What [`super::IoExtPort::run`] did with an action.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Started {
    /// The transfer runs; its end comes from [`super::IoExtPort::on_interrupt`]
    /// (or [`super::IoExtPort::abort`] after
    /// [`bridge_logic::ioext::TransferPlan::timeout_us`]).
    Running,
    /// The transfer has already ended (or could not start): report this.
    Ended(Result<WireBits, IoExtError>),
    /// `Action::Disable` done: CS high, port released.
    Released,
}

/// The DMA controller of an engine.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Controller {
    Dma1,
    Dma2,
}

impl Controller {
    /// The register-name constructor (for [`crate::dma`]).
    pub fn reg(self) -> fn(DmaReg) -> IoReg {
        match self {
            Controller::Dma1 => IoReg::Dma1,
            Controller::Dma2 => IoReg::Dma2,
        }
    }
}

/// An engine's two DMA streams: `input` moves what comes back and
/// interrupts at its end, `output` moves what goes out; each with its
/// peripheral register and buffer.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct EngineStreams {
    pub controller: Controller,
    pub input: Stream,
    pub input_par: Target,
    pub input_mem: Target,
    pub output: Stream,
    pub output_par: Target,
    pub output_mem: Target,
    /// LIFCR/HIFCR words clearing both streams' flags.
    pub clear_all: [u32; 2],
}

const END_IRQ: u32 = DMA_CR_TCIE | DMA_CR_TEIE | DMA_CR_DMEIE;

/// SPI2_RX on DMA1 stream 3 channel 0, SPI2_TX on stream 4 channel 0
/// (RM0090 table 42); bytes.
pub const SPI_ENGINE: EngineStreams = EngineStreams {
    controller: Controller::Dma1,
    input: Stream {
        number: 3,
        channel: 0,
        role: Role::Receive,
        size: Size::Byte,
        priority: DMA_CR_PL_VERY_HIGH,
        interrupts: END_IRQ,
    },
    input_par: Target::SpiDr,
    input_mem: Target::RxBytes,
    output: Stream {
        number: 4,
        channel: 0,
        role: Role::TransmitWaited,
        size: Size::Byte,
        priority: DMA_CR_PL_HIGH,
        interrupts: 0,
    },
    output_par: Target::SpiDr,
    output_mem: Target::TxBytes,
    clear_all: dma::clear_words(&[(3, Flags::ALL), (4, Flags::ALL)]),
};

/// TIM1_CH2 on DMA2 stream 2 channel 6 (GPIOB_IDR into the samples,
/// half-words), TIM1_CH3 on stream 6 channel 6 (the MOSI table into
/// GPIOB_BSRR, words: the reset half is the upper one) (RM0090 table 43).
pub const TIMER_ENGINE: EngineStreams = EngineStreams {
    controller: Controller::Dma2,
    input: Stream {
        number: 2,
        channel: 6,
        role: Role::Receive,
        size: Size::HalfWord,
        priority: DMA_CR_PL_VERY_HIGH,
        interrupts: END_IRQ,
    },
    input_par: Target::GpioIdr,
    input_mem: Target::Samples,
    output: Stream {
        number: 6,
        channel: 6,
        role: Role::TransmitTimed,
        size: Size::Word,
        priority: DMA_CR_PL_VERY_HIGH,
        interrupts: 0,
    },
    output_par: Target::GpioBsrr,
    output_mem: Target::MosiTable,
    clear_all: dma::clear_words(&[(2, Flags::ALL), (6, Flags::ALL)]),
};
