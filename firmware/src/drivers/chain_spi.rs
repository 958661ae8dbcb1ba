//! The powerSTEP01 chain on SPI1, DMA2 streams 0/3, TIM7 and the CS line
//! PA4: the PAC glue under [`drivers_core::chain_spi`], where the blocking
//! windows, the DMA batch and every register sequence live (tested on the
//! host against the RM0090 model `host_tests::rm0090::chain_spi`, with the
//! bridge's control ticks through driver and model into the simulated
//! chips). This module clocks and resets SPI1 and TIM7, clocks DMA2, maps
//! the driver's register ids to the PAC's register blocks, drives CS
//! through GPIOA_BSRR, busy-waits CPU cycles, clears the two interrupts'
//! NVIC pending bits, and gives the DMA the `'static` buffers' addresses.

// Register blocks shared by the two halves, DMA addresses: each block says
// why it is sound.
#![allow(unsafe_code)]

use bridge_logic::powerstep::chain::Frames;
use core::sync::atomic::{AtomicBool, Ordering};
use cortex_m::peripheral::NVIC;
use drivers_core::chain_spi::{self as core_spi, ChainClocks, ChainHw, ChainMemory, ChainReg};
use drivers_core::Regs;
use stm32f4xx_hal::pac::{self, Interrupt};
use stm32f4xx_hal::rcc::{Enable, Rcc, Reset};

use crate::board::{
    ChainCs, ChainGapTimer, ChainMiso, ChainMosi, ChainSck, ChainSpi, CHAIN_CS_PIN,
};

pub use drivers_core::chain_spi::{
    ChainBuffers, ChainDmaStats, ChainSpiError, CS_DESELECT_NS, CS_SETUP_NS, DMEIF0, DMEIF3, FEIF0,
    SCK_MAX_HZ, TCIF0, TEIF0, TEIF3,
};

/// The blocking half (the bridge's `ChainBus`).
pub type ChainPort = core_spi::ChainPort<ChainRegs>;
/// The DMA half (the control tick's batches).
pub type ChainDma = core_spi::ChainDma<ChainDmaRegs>;

/// Set while a DMA batch owns SPI1 and CS (shared by both halves).
static BATCH_RUNNING: AtomicBool = AtomicBool::new(false);

/// SPI1's registers.
fn spi1() -> &'static pac::spi1::RegisterBlock {
    // SAFETY: SPI1 is always mapped; its PAC singleton was consumed by
    // `chain_spi`, and only the two halves use it, never at the same time:
    // the blocking half refuses while `BATCH_RUNNING` is set, which the DMA
    // half sets before it touches SPI1 for a batch and clears after.
    unsafe { &*pac::SPI1::ptr() }
}

/// DMA2's registers (streams 0 and 3 are this driver's).
fn dma2() -> &'static pac::dma2::RegisterBlock {
    // SAFETY: DMA2 is always mapped. This driver writes only streams 0 and
    // 3 and their bits of LIFCR (write-1-to-clear: other streams' bits are
    // written 0, which changes nothing); the I/O extension's driver uses
    // streams 2 and 6 only.
    unsafe { &*pac::DMA2::ptr() }
}

/// TIM7's registers.
fn tim7() -> &'static pac::tim6::RegisterBlock {
    // SAFETY: TIM7 is always mapped; its PAC singleton was consumed by
    // `chain_spi` and only the DMA half (one owner) uses it.
    unsafe { &*pac::TIM7::ptr() }
}

/// The chain's hardware as the blocking half's [`ChainHw`].
pub struct ChainRegs;

/// The DMA half's: the same registers, and the batch buffers.
pub struct ChainDmaRegs {
    bufs: &'static mut ChainBuffers,
}

/// The register access and the CS, delay and flag hooks are the same for
/// both halves (one set of registers; the DMA half adds the buffers).
macro_rules! chain_hw {
    ($t:ty) => {
        impl Regs<ChainReg> for $t {
            #[inline]
            fn read(&mut self, reg: ChainReg) -> u32 {
                read(reg)
            }

            #[inline]
            fn write(&mut self, reg: ChainReg, value: u32) {
                write(reg, value);
            }
        }

        impl ChainHw for $t {
            #[inline]
            fn cs(&mut self, high: bool) {
                cs(high);
            }

            #[inline]
            fn delay_cycles(&mut self, cycles: u32) {
                cortex_m::asm::delay(cycles);
            }

            fn unpend_interrupts(&mut self) {
                NVIC::unpend(Interrupt::TIM7);
                NVIC::unpend(Interrupt::DMA2_STREAM0);
            }

            #[inline]
            fn batch_running(&self) -> bool {
                BATCH_RUNNING.load(Ordering::Acquire)
            }

            #[inline]
            fn set_batch_running(&mut self, running: bool) {
                BATCH_RUNNING.store(running, Ordering::Release);
            }
        }
    };
}

chain_hw!(ChainRegs);
chain_hw!(ChainDmaRegs);

/// CS (PA4) high or low.
#[inline]
fn cs(high: bool) {
    // SAFETY: GPIOA is always mapped; BSRR writes are atomic and touch
    // only the bit written. The CS pin's HAL handle was consumed by
    // `chain_spi` (configured as a push-pull output, high); nothing else
    // drives it.
    let gpioa = unsafe { &*pac::GPIOA::ptr() };
    gpioa.bsrr().write(|w| {
        if high {
            w.bs(CHAIN_CS_PIN).set_bit()
        } else {
            w.br(CHAIN_CS_PIN).set_bit()
        }
    });
}

/// One read of the chain register `reg`.
#[inline]
fn read(reg: ChainReg) -> u32 {
    let (spi, dma, tim) = (spi1(), dma2(), tim7());
    let st = |n: u8| dma.st(usize::from(n));
    match reg {
        ChainReg::SpiCr1 => u32::from(spi.cr1().read().bits()),
        ChainReg::SpiCr2 => u32::from(spi.cr2().read().bits()),
        ChainReg::SpiSr => u32::from(spi.sr().read().bits()),
        ChainReg::SpiDr => u32::from(spi.dr8().read().dr().bits()),
        ChainReg::DmaLisr => dma.lisr().read().bits(),
        ChainReg::DmaLifcr => 0,
        ChainReg::DmaCr(n) => st(n).cr().read().bits(),
        ChainReg::DmaNdtr(n) => st(n).ndtr().read().bits(),
        ChainReg::DmaPar(n) => st(n).par().read().bits(),
        ChainReg::DmaM0ar(n) => st(n).m0ar().read().bits(),
        ChainReg::DmaFcr(n) => st(n).fcr().read().bits(),
        ChainReg::TimCr1 => tim.cr1().read().bits(),
        ChainReg::TimDier => tim.dier().read().bits(),
        ChainReg::TimSr => tim.sr().read().bits(),
        ChainReg::TimEgr => 0,
        ChainReg::TimCnt => tim.cnt().read().bits(),
        ChainReg::TimPsc => tim.psc().read().bits(),
        ChainReg::TimArr => tim.arr().read().bits(),
    }
}

/// One write of `value` to the chain register `reg`.
#[inline]
fn write(reg: ChainReg, value: u32) {
    let (spi, dma, tim) = (spi1(), dma2(), tim7());
    let st = |n: u8| dma.st(usize::from(n));
    // SPI1's registers are 16 bits wide (RM0090 §28.5).
    let v16 = value as u16;
    // SAFETY: one volatile write of the whole register. The values come
    // from `drivers_core::chain_spi` (SPI1 mode 3 master, DMA2 streams
    // 0/3 on channel 3 with PAR = SPI1_DR and M0AR = a row of this
    // driver's `'static` buffers, TIM7 one-pulse), checked against the
    // RM0090 model on the host. Only streams 0 and 3 are ever named.
    unsafe {
        match reg {
            ChainReg::SpiCr1 => {
                spi.cr1().write(|w| w.bits(v16));
            }
            ChainReg::SpiCr2 => {
                spi.cr2().write(|w| w.bits(v16));
            }
            ChainReg::SpiSr => {
                spi.sr().write(|w| w.bits(v16));
            }
            ChainReg::SpiDr => {
                spi.dr8().write(|w| w.dr().set(value as u8));
            }
            ChainReg::DmaLisr => {}
            ChainReg::DmaLifcr => {
                dma.lifcr().write(|w| w.bits(value));
            }
            ChainReg::DmaCr(n) => {
                st(n).cr().write(|w| w.bits(value));
            }
            ChainReg::DmaNdtr(n) => {
                st(n).ndtr().write(|w| w.bits(value));
            }
            ChainReg::DmaPar(n) => {
                st(n).par().write(|w| w.bits(value));
            }
            ChainReg::DmaM0ar(n) => {
                st(n).m0ar().write(|w| w.bits(value));
            }
            ChainReg::DmaFcr(n) => {
                st(n).fcr().write(|w| w.bits(value));
            }
            ChainReg::TimCr1 => {
                tim.cr1().write(|w| w.bits(value));
            }
            ChainReg::TimDier => {
                tim.dier().write(|w| w.bits(value));
            }
            ChainReg::TimSr => {
                tim.sr().write(|w| w.bits(value));
            }
            ChainReg::TimEgr => {
                tim.egr().write(|w| w.bits(value));
            }
            ChainReg::TimCnt => {
                tim.cnt().write(|w| w.bits(value));
            }
            ChainReg::TimPsc => {
                tim.psc().write(|w| w.bits(value));
            }
            ChainReg::TimArr => {
                tim.arr().write(|w| w.bits(value));
            }
        };
    }
}

impl ChainMemory for ChainDmaRegs {
    #[inline]
    fn write_tx_rows(&mut self, frames: &Frames, windows: usize) {
        for (dst, src) in self.bufs.tx.iter_mut().zip(frames).take(windows) {
            *dst = *src;
        }
    }

    #[inline]
    fn read_rx_rows(&self, out: &mut Frames, windows: usize) {
        for (dst, src) in out.iter_mut().zip(&self.bufs.rx).take(windows) {
            *dst = *src;
        }
    }

    #[inline]
    fn row_address(&self, rx: bool, w: usize) -> Option<u32> {
        let row = if rx {
            self.bufs.rx.get(w)?
        } else {
            self.bufs.tx.get(w)?
        };
        // RAM addresses fit in 32 bits on the Cortex-M4.
        Some(row.as_ptr() as usize as u32)
    }

    fn dr_address(&self) -> u32 {
        spi1().dr().as_ptr() as usize as u32
    }
}

/// Take SPI1, TIM7 and the chain's pins as `board::configure` left them (CS
/// high): the blocking half for the bridge and the DMA half for the control
/// tick. Clocks and resets SPI1 and TIM7, clocks DMA2 (never reset: the I/O
/// extension uses it too).
pub fn chain_spi(
    spi: ChainSpi,
    pins: (ChainSck, ChainMiso, ChainMosi),
    cs_pin: ChainCs,
    tim: ChainGapTimer,
    bufs: &'static mut ChainBuffers,
    rcc: &mut Rcc,
) -> (ChainPort, ChainDma) {
    ChainSpi::enable(rcc);
    ChainSpi::reset(rcc);
    ChainGapTimer::enable(rcc);
    ChainGapTimer::reset(rcc);
    pac::DMA2::enable(rcc);
    let clocks = ChainClocks {
        pclk2_hz: rcc.clocks.pclk2().raw(),
        sysclk_hz: rcc.clocks.sysclk().raw(),
        timclk_hz: rcc.clocks.timclk1().raw(),
    };
    // The pins keep the modes `board::configure` gave them; from here on
    // SPI1, TIM7 and CS are driven through their registers (module docs).
    let _ = (spi, pins, cs_pin, tim);
    core_spi::chain_spi(ChainRegs, ChainDmaRegs { bufs }, clocks)
}
