//! The workspace's tasks (the cargo `xtask` convention): `cargo qemu` and
//! the other aliases of `.cargo/config.toml` run this program, which sets
//! up what is missing, builds and runs. `cargo xtask help` lists them.

mod apt;
mod armcount;
mod callgrind;
mod cargo_tasks;
mod examples;
mod qemu_run;
mod setup;
mod size;
mod util;

use util::{Error, Result};

const USAGE: &str = "\
usage: cargo xtask COMMAND [ARGS]   (or the cargo alias of the same name)

The firmware (each sets up the Cortex-M target first):
  fw [CARGO ARGS]        release build of the board image (cargo fw)
  fw-run [CARGO ARGS]    build, flash and run on a probe-attached board (cargo fw-run)
  fw-test [CARGO ARGS]   the on-target tests on a board (cargo fw-test)
  qemu [CARGO ARGS]      set up QEMU 7.x and defmt-print, build the QEMU image and boot it (cargo qemu)
  qemu-build             build the QEMU image only (cargo qemu-build)
  qemu-test              the on-target tests QEMU models, each booted by qemu-run --test (cargo qemu-test)
  qemu-run [--test] ELF  the QEMU runner those use (QEMU_MODBUS, QEMU_CONSOLE, QEMU_FLASH, QEMU_FRESH, QEMU_RAW)
  setup                  check and install what cargo qemu needs, build nothing

Measurements (not timed tests):
  fw-size                build both images and print their text/data/bss (llvm-size)
  bench                  callgrind instruction counts of the control tick (host)
  tick-cpu               Thumb-2 instruction counts of the control tick under QEMU (tools/armcount),
                         ART misses, a Cortex-M4 cycle estimate, CPU share at 1/2/5/10 kHz
  chain-cpu              the same for the chain's DMA driver per streaming batch
  ioext-cpu              the same for the I/O extension per transfer

Checks:
  readme-examples        run the README's marked examples as written (against cargo qemu)
";

fn run(args: &[String]) -> Result {
    let Some((cmd, rest)) = args.split_first() else {
        eprint!("{USAGE}");
        return Err(Error::Exit(2));
    };
    match cmd.as_str() {
        "fw" => cargo_tasks::fw(rest),
        "fw-run" => cargo_tasks::fw_run(rest),
        "fw-test" => cargo_tasks::fw_test(rest),
        "qemu" => cargo_tasks::qemu(rest),
        "qemu-build" => cargo_tasks::qemu_build(rest),
        "qemu-test" => cargo_tasks::qemu_test(rest),
        "qemu-run" => qemu_run::main(rest),
        "setup" => setup::all(),
        "fw-size" => size::main(rest),
        "bench" => callgrind::main(rest),
        "tick-cpu" => armcount::tick_cpu(rest),
        "chain-cpu" => armcount::chain_cpu(rest),
        "ioext-cpu" => armcount::ioext_cpu(rest),
        "readme-examples" => examples::main(rest),
        "help" | "-h" | "--help" => {
            print!("{USAGE}");
            Ok(())
        }
        other => {
            eprint!("xtask: unknown command '{other}'\n\n{USAGE}");
            Err(Error::Exit(2))
        }
    }
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let code = match run(&args) {
        Ok(()) => 0,
        Err(Error::Exit(c)) => c,
        Err(Error::Msg(m)) => {
            eprintln!("xtask: {m}");
            1
        }
    };
    std::process::exit(code);
}
