//! Instruction counts of the I/O extension driver's start of a transfer
//! (`IoExtPort::run`: buffers, registers, pins, CS) on the board driver's
//! code, under QEMU with the armcount plugin (`cargo ioext-cpu`): a bench,
//! not a test. QEMU only (feature `qemu`), and only the start: QEMU's
//! STM32F405 has no DMA controller and no TIM1 (their registers read 0), so
//! the start runs every instruction it runs on a board, while the end (the
//! DMA transfer-complete flag) never comes; each start is undone with
//! `abort` outside the counted region. Exits QEMU with status 0.
#![cfg_attr(target_os = "none", no_std, no_main)]
// An on-target test, not bus input: it may index, unwrap, panic and (like
// the drivers) touch registers in `unsafe` blocks.
#![allow(unsafe_code, clippy::indexing_slicing, clippy::arithmetic_side_effects)]
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
#[cfg(not(target_os = "none"))]
fn main() {}

#[cfg(target_os = "none")]
#[macro_use]
mod common;

/// Iterations (cargo ioext-cpu divides by it).
#[cfg(target_os = "none")]
const N: u32 = 200;

#[cfg(target_os = "none")]
marker!(mark_off, 0x1111_0000u32);
#[cfg(target_os = "none")]
marker!(mark_spi, 0x2222_0001u32);
#[cfg(target_os = "none")]
marker!(mark_timer, 0x3333_0002u32);
#[cfg(target_os = "none")]
marker!(mark_cal, 0x4444_0003u32);
#[cfg(target_os = "none")]
marker!(mark_dump, 0x5555_0004u32);

#[cfg(target_os = "none")]
#[cortex_m_rt::entry]
fn main() -> ! {
    use bridge_logic::ioext::{Action, Clocks, SpiMode, TransferPlan, WireBits};
    let mut port = common::ioext_port(common::setup());
    let plan = |bits: u16, n: u8| {
        let tx = WireBits::from_fn(bits, |i| i % 3 == 0);
        // The board's clocks: the plans the board runs.
        Action::Transfer(TransferPlan::single(
            bits,
            SpiMode::MODE0,
            n,
            Clocks::BOARD,
            tx,
        ))
    };
    // 256 bits on SPI2 at N = 0 (the CS set-up wait is 1 cycle there) and
    // on TIM1 at N = 255.
    let (spi, timer) = (plan(256, 0), plan(256, 255));
    for _ in 0..N {
        mark_spi();
        let started = port.run(&spi);
        mark_off();
        core::hint::black_box(started);
        let _ = port.abort();
        mark_timer();
        let started = port.run(&timer);
        mark_off();
        core::hint::black_box(started);
        let _ = port.abort();
        mark_cal();
        mark_off();
    }
    mark_dump();
    defmt::info!("ioext_cost: done");
    semihosting::process::exit(0)
}
