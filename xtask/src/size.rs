//! `cargo xtask fw-size`: build both images (QEMU, then board: both land on
//! the same path, so the board image is built last and left in place) and
//! print their text/data/bss (llvm-size, Berkeley format: text is flash
//! code, rodata and the vector table; data the initialised RAM, also stored
//! in flash; bss the zeroed RAM).

use crate::cargo_tasks;
use crate::setup;
use crate::util::{self, Result};

pub fn main(_args: &[String]) -> Result {
    let size = setup::llvm_tool("llvm-size")?;
    let elf = cargo_tasks::image();
    cargo_tasks::qemu_build(&[])?;
    println!("QEMU image (cargo qemu-build, feature qemu):");
    util::run_or_say(&mut util::cmd(&size, [&elf]))?;
    cargo_tasks::fw(&[])?;
    println!("board image (cargo fw):");
    util::run_or_say(&mut util::cmd(&size, [&elf]))
}
