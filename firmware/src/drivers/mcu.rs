//! The MCU itself: the reset handoff word, the 96-bit unique id and the jump
//! into ST's ROM bootloader. What the handoff word means is the logic
//! crate's (`bridge_logic::bridge::handoff`); this module only keeps it.
//!
//! * **Handoff word**: one `u32` in `.uninit` RAM (cortex-m-rt neither zeroes
//!   nor initialises it), so it survives `SCB::sys_reset()` — SRAM keeps its
//!   contents through a system reset — and is noise after power-up, which
//!   the codec's check turns into a normal start.
//! * **Unique id**: three words at 0x1FFF_7A10 (RM0090 39.1). Board only:
//!   under QEMU that address is unmapped and reading it HardFaults.
//! * **ROM bootloader**: the STM32F405's system memory at 0x1FFF_0000
//!   (AN2606: DFU on OTG FS PA11/PA12 with the 8 MHz HSE). Board only: QEMU
//!   has no system memory.

use core::mem::MaybeUninit;
use core::ptr::{addr_of, addr_of_mut};

use bridge_logic::bridge::handoff::{self, CLEARED};
use bridge_logic::bridge::ResetTarget;
use stm32f4xx_hal::pac;

// SAFETY: `.uninit.*` is a NOLOAD RAM section of cortex-m-rt's link.x,
// placed like `.bss` but never zeroed; nothing else is put at this name.
#[allow(unsafe_code)]
#[link_section = ".uninit.STEPBRIDGE_HANDOFF"]
static mut HANDOFF: MaybeUninit<u32> = MaybeUninit::uninit();

fn read_handoff() -> u32 {
    // SAFETY: a volatile word read of a static that only `init` (before any
    // task runs) and the lowest-priority task (right before the reset) touch,
    // never at once; any bit pattern is a valid u32 — after power-up it is
    // noise, which the codec's check rejects.
    #[allow(unsafe_code)]
    unsafe {
        core::ptr::read_volatile(addr_of!(HANDOFF).cast::<u32>())
    }
}

fn write_handoff(word: u32) {
    // SAFETY: as in `read_handoff`: a volatile aligned word write to our
    // own static, by one context at a time.
    #[allow(unsafe_code)]
    unsafe {
        core::ptr::write_volatile(addr_of_mut!(HANDOFF).cast::<u32>(), word)
    }
}

/// What the last run asked this start to do (None: a normal start), and
/// the word cleared, so any later reset that is not a handoff starts
/// normally. Call it once, first thing in `init`.
pub fn take_handoff() -> Option<ResetTarget> {
    let target = handoff::decode(read_handoff());
    write_handoff(CLEARED);
    target
}

/// Make the next start go to `target`; call `SCB::sys_reset()` right after.
pub fn store_handoff(target: ResetTarget) {
    write_handoff(handoff::encode(target));
}

/// Address of the 96-bit unique id (RM0090 39.1).
const UID_ADDRESS: usize = 0x1FFF_7A10;

/// The MCU's 96-bit unique id. Board only (module docs).
pub fn unique_id() -> [u32; 3] {
    let base = UID_ADDRESS as *const u32;
    // SAFETY: three aligned reads of the read-only unique-id words in the
    // STM32F405's system memory, mapped on every F405 (not under QEMU: the
    // QEMU platform never calls this).
    #[allow(unsafe_code)]
    unsafe {
        [
            core::ptr::read_volatile(base),
            core::ptr::read_volatile(base.add(1)),
            core::ptr::read_volatile(base.add(2)),
        ]
    }
}

/// System memory: the ROM bootloader's vector table.
const SYSTEM_MEMORY: usize = 0x1FFF_0000;

/// Jump into ST's ROM bootloader (DFU on USB for dfu-util). Call it at the
/// very top of `init`, with the clocks and every peripheral as the reset
/// left them (HSI, no PLL, IWDG off): the bootloader expects a reset state.
/// Interrupts are still off (RTIC runs `init` with them masked), but RTIC
/// has already enabled its bound interrupts in the NVIC: they are disabled
/// and cleared here, SysTick is stopped, VTOR set to 0, SYSCFG maps system
/// memory at 0, and the core takes the bootloader's stack pointer and reset
/// vector. Board only.
pub fn jump_to_rom_bootloader(rcc: &pac::RCC, syscfg: &pac::SYSCFG) -> ! {
    cortex_m::interrupt::disable();
    // SAFETY: the NVIC's interrupt clear-enable and clear-pending registers
    // are write-1-to-clear; with interrupts masked nothing else touches the
    // NVIC, and nothing of this firmware runs after the jump.
    #[allow(unsafe_code)]
    unsafe {
        let nvic = &*cortex_m::peripheral::NVIC::PTR;
        for (icer, icpr) in nvic.icer.iter().zip(nvic.icpr.iter()) {
            icer.write(u32::MAX);
            icpr.write(u32::MAX);
        }
    }
    // SysTick off (RTIC has not started it yet, but be sure), and the vector
    // table offset at its reset value 0, where system memory is about to be
    // mapped (a debugger may have moved it to the flash's address).
    // SAFETY: SYST_CSR and SCB_VTOR writes; neither belongs to anybody any
    // more, and no interrupt or exception can be taken until the jump.
    #[allow(unsafe_code)]
    unsafe {
        (*cortex_m::peripheral::SYST::PTR).csr.write(0);
        (*cortex_m::peripheral::SCB::PTR).vtor.write(0);
    }
    rcc.apb2enr().modify(|_, w| w.syscfgen().set_bit());
    // System flash at 0x0000_0000 (MEM_MODE = 0b01, RM0090 9.2.1).
    syscfg.memrmp().modify(|_, w| w.mem_mode().system_flash());
    cortex_m::asm::dsb();
    cortex_m::asm::isb();
    // The bootloader expects interrupts on, as after a reset; nothing is
    // enabled or pending any more.
    // SAFETY: no interrupt is enabled in the NVIC, so none can fire before
    // the jump.
    #[allow(unsafe_code)]
    unsafe {
        cortex_m::interrupt::enable();
    }
    // SAFETY: 0x1FFF_0000 holds the ROM bootloader's vector table (its
    // initial stack pointer and reset vector), which is valid code on every
    // STM32F405.
    #[allow(unsafe_code)]
    unsafe {
        cortex_m::asm::bootload(SYSTEM_MEMORY as *const u32)
    }
}
