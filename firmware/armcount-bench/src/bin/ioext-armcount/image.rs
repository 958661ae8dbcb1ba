use armcount_bench::marker;
use bridge_logic::ioext::{
    Action, AxisOutputs, Clocks, Config, Input, InputBit, IoExtension, IoSettings, Output,
    OutputBit, SpiMode, WireBits,
};
use core::hint::black_box;
use cortex_m_rt::entry;

/// Iterations (xtask divides by it).
const N: u32 = 200;

marker!(mark_off, 0x1111_0000u32);
marker!(mark_tick, 0x2222_0001u32);
marker!(mark_spi, 0x3333_0002u32);
marker!(mark_complete, 0x4444_0003u32);
marker!(mark_timer, 0x5555_0004u32);
marker!(mark_cal, 0x6666_0005u32);
marker!(mark_dump, 0x7777_0006u32);

// Set-up and loop in one function on purpose: LTO inlines the extension's
// calls into it, so moving the set-up out changes the counted code (tried:
// IoExtension::tick 684 -> 676 instructions).
#[entry]
fn main() -> ! {
    let mut s = IoSettings::FACTORY;
    s.enabled = true;
    s.config = match Config::new(256, SpiMode::MODE0, 0) {
        Ok(c) => c.with_auto_restart(true),
        Err(_) => semihosting::process::exit(2),
    };
    for (k, a) in s.mapping.axes.iter_mut().enumerate() {
        for (j, i) in Input::ALL.into_iter().enumerate() {
            let bit = (k * 16 + j) as u8;
            a.set_input(
                i,
                Some(InputBit {
                    bit,
                    nc: j % 2 == 1,
                }),
            );
        }
        for (j, o) in Output::ALL.into_iter().enumerate() {
            let bit = (k * 16 + 8 + j) as u8;
            a.set_output(
                o,
                Some(OutputBit {
                    bit,
                    inverted: false,
                }),
            );
        }
    }
    let mut io = IoExtension::new(s, Clocks::BOARD);
    let outs = [AxisOutputs {
        moving: true,
        fault: false,
        idle: true,
    }; 8];
    let mut table = [0u32; 256];
    let mut samples = [0u16; 256];
    let mut spi_buf = [0u8; 32];
    for k in 0..N {
        for (j, v) in samples.iter_mut().enumerate() {
            *v = ((j as u32 ^ k) as u16).wrapping_mul(0x9E37);
        }
        mark_tick();
        let a = io.tick(black_box(&outs));
        mark_off();
        let Some(Action::Transfer(plan)) = a else {
            semihosting::process::exit(3)
        };
        mark_spi();
        let frames = usize::from(plan.bits / 8);
        for (j, b) in spi_buf.iter_mut().enumerate().take(frames) {
            *b = plan.tx_byte(j);
        }
        black_box(&mut spi_buf);
        let rx = WireBits::from_bytes(black_box(spi_buf.get(..frames).unwrap_or(&[])));
        mark_off();
        mark_complete();
        let r = io.complete(black_box(&rx));
        mark_off();
        if r.is_err() {
            semihosting::process::exit(4);
        }
        mark_timer();
        let n = plan.mosi_bsrr(15, &mut table);
        black_box(&mut table);
        let rx2 = WireBits::from_port_samples(black_box(samples.get(..n).unwrap_or(&[])), 14);
        black_box(rx2);
        mark_off();
        mark_cal();
        mark_off();
    }
    mark_dump();
    semihosting::process::exit(0)
}
