//! The bench images' `__pre_init`: the same as the firmware's
//! (firmware/src/ramtext.rs), for memory.x's `.ramtext`.

// Copy the code that runs from SRAM (memory.x's `.ramtext`) from its image
// in flash before anything runs: cortex-m-rt calls `__pre_init` first
// thing in the reset handler, before it initialises RAM (which does not
// touch `.ramtext`). In assembly: no Rust code may run before RAM is
// initialised, and none of it may run from `.ramtext` before the copy.
core::arch::global_asm!(
    ".section .text.__pre_init,\"ax\",%progbits",
    ".global __pre_init",
    ".type __pre_init,%function",
    ".thumb_func",
    "__pre_init:",
    "    ldr r0, =__sramtext",
    "    ldr r1, =__eramtext",
    "    ldr r2, =__siramtext",
    "1:  cmp r0, r1",
    "    bhs 2f",
    "    ldr r3, [r2], #4",
    "    str r3, [r0], #4",
    "    b 1b",
    "2:  bx lr",
    ".ltorg",
    ".size __pre_init, . - __pre_init",
);
