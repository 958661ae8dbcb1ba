//! What the bench images share: the marker functions' macro, the panic
//! handler (semihosting exit status 1) and the firmware's own `__pre_init`,
//! so the images copy `.ramtext` the same way as the firmware. Target only,
//! like the images; on the host this library is empty.
#![cfg_attr(target_os = "none", no_std)]

/// memory.x's code in SRAM, copied before anything runs.
#[cfg(target_os = "none")]
#[path = "../../src/ramtext.rs"]
mod ramtext;

#[cfg(target_os = "none")]
#[panic_handler]
fn panic(_: &core::panic::PanicInfo) -> ! {
    semihosting::process::exit(1)
}

/// `marker!(name, value)`: a marker function for the armcount plugin
/// (tools/armcount), found by its unmangled `name` (xtask's bench tables)
/// and never inlined; the distinct `value` keeps the linker from folding
/// the markers into one.
#[macro_export]
macro_rules! marker {
    ($name:ident, $v:expr) => {
        #[inline(never)]
        #[no_mangle]
        pub extern "C" fn $name() {
            ::core::hint::black_box($v as u32);
        }
    };
}
