//! Instruction counts of the chain's DMA driver (`drivers::chain_spi`,
//! the board's code) per streaming batch on 8 chips (5 windows of 8 bytes),
//! under QEMU with the armcount plugin (`cargo chain-cpu`): a bench, not
//! a test. Counted: the control tick's start of a batch (plan copied,
//! streams armed, first gap) and its hand-over (`poll`: 5 rows copied
//! out), and each interrupt's work: the end of a gap (TIM7), the end of a
//! set-up (TIM7), the end of a window that is not the last (DMA2 stream 0:
//! CS, next window armed, gap started) and of the last one. QEMU only
//! (feature `qemu`): it has no DMA controller and no TIM7 (their registers
//! read 0), so the events are handed to the driver as its interrupt
//! handlers would (`on_timer`, and `dma_event` with the transfer-complete
//! flag instead of `on_dma`'s read of DMA2_LISR); every register access
//! runs as on a board. Exits QEMU with status 0.
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

/// Batches (cargo chain-cpu divides by it).
#[cfg(target_os = "none")]
const N: u32 = 200;

#[cfg(target_os = "none")]
marker!(armcost_mark_off, 0x1111_0000u32);
#[cfg(target_os = "none")]
marker!(armcost_mark_start, 0x2222_0001u32);
#[cfg(target_os = "none")]
marker!(armcost_mark_gap, 0x3333_0002u32);
#[cfg(target_os = "none")]
marker!(armcost_mark_setup, 0x4444_0003u32);
#[cfg(target_os = "none")]
marker!(armcost_mark_window, 0x5555_0004u32);
#[cfg(target_os = "none")]
marker!(armcost_mark_last, 0x6666_0005u32);
#[cfg(target_os = "none")]
marker!(armcost_mark_poll, 0x7777_0006u32);
#[cfg(target_os = "none")]
marker!(armcost_mark_cal, 0x8888_0007u32);
#[cfg(target_os = "none")]
marker!(armcost_mark_dump, 0x9999_0008u32);

#[cfg(target_os = "none")]
#[cortex_m_rt::entry]
fn main() -> ! {
    use bridge_logic::bridge::BatchState;
    use bridge_logic::powerstep::chain::{Frames, MAX_DEVICES, MAX_WINDOWS};
    use firmware::drivers::chain_spi::TCIF0;

    let mut dma = common::chain(common::setup());
    // No SysTick interrupt inside the counted regions (the driver gets its
    // time as an argument).
    #[allow(unsafe_code)]
    // SAFETY: only the SysTick interrupt enable is cleared; nothing in this
    // bench reads the monotonic afterwards.
    unsafe {
        (*cortex_m::peripheral::SYST::PTR).csr.modify(|v| v & !0b10);
    }
    let plan = common::streaming_plan(8);
    let windows = plan.windows();
    let mut rx: Frames = [[0; MAX_DEVICES]; MAX_WINDOWS];
    let mut ok = 0u32;
    for _ in 0..N {
        armcost_mark_start();
        let started = dma.start(&plan, 0);
        armcost_mark_off();
        ok += u32::from(started.is_ok());
        for w in 0..windows {
            armcost_mark_gap();
            dma.on_timer();
            armcost_mark_off();
            armcost_mark_setup();
            dma.on_timer();
            armcost_mark_off();
            if w + 1 < windows {
                armcost_mark_window();
                dma.dma_event(TCIF0);
                armcost_mark_off();
            } else {
                armcost_mark_last();
                dma.dma_event(TCIF0);
                armcost_mark_off();
            }
        }
        armcost_mark_poll();
        let done = matches!(dma.poll(0, &mut rx), BatchState::Done(Ok(_)));
        armcost_mark_off();
        // The copied rows are used (the control tick decodes them).
        core::hint::black_box(&mut rx);
        ok += u32::from(done);
        armcost_mark_cal();
        armcost_mark_off();
    }
    armcost_mark_dump();
    defmt::info!(
        "chain_cost: {=u32} batches of {=usize} windows, {=u32} started and handed over",
        N,
        windows,
        ok / 2
    );
    semihosting::process::exit(if ok == 2 * N { 0 } else { 1 })
}
