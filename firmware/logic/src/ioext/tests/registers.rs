//! The register page: Copley's bits, the address rules, bad input.

use super::*;

#[test]
fn factory_registers_read_disabled_8_bits_spi_mode() {
    let mut r = Rig::new();
    assert_eq!(r.read(addr::IO_OPTIONS, 2).unwrap(), [0, 0]);
    assert_eq!(r.config_reg(), cfg::SPI_MODE | 10 << 16 | 7);
    assert_eq!(r.read(addr::DEBOUNCE, 1).unwrap(), [5]);
}

#[test]
fn every_configuration_bit_reads_back_as_written() {
    for bit in [
        0, 1, 2, 3, 4, 5, 6, 7, 9, 10, 12, 13, 16, 17, 18, 19, 20, 21, 22, 23,
    ] {
        let mut r = Rig::new();
        let v = cfg::SPI_MODE | 1 << bit;
        r.set_config(v).unwrap();
        assert_eq!(r.config_reg(), v, "bit {bit}");
        assert_eq!(r.io.diagnostics().reserved_ignored, 0);
    }
}

#[test]
fn undocumented_configuration_bits_are_dropped_read_0_and_counted() {
    let mut r = Rig::new();
    for (k, bit) in [8, 14, 15, 24, 25, 26, 27, 29, 30, 31]
        .into_iter()
        .enumerate()
    {
        r.set_config(cfg::SPI_MODE | 1 << bit | 31).unwrap();
        assert_eq!(r.config_reg(), cfg::SPI_MODE | 31, "bit {bit}");
        assert_eq!(r.io.diagnostics().reserved_ignored, k as u32 + 1);
        assert_eq!(r.read(addr::RESERVED_IGNORED, 1).unwrap(), [k as u16 + 1]);
    }
}

#[test]
fn writing_the_status_bit_neither_sets_nor_clears_it() {
    let mut r = Rig::new();
    r.set_config(cfg::SPI_MODE | cfg::STATUS).unwrap();
    assert!(!r.io.status());
    r.setup(8, SpiMode::MODE0, 0, 0);
    r.write(addr::TX, &[0]).unwrap();
    r.tick().unwrap();
    assert!(r.io.status());
    r.set_config(cfg::SPI_MODE | 7).unwrap();
    assert!(r.io.status(), "a write without bit 11 does not clear it");
    assert_eq!(r.io.diagnostics().reserved_ignored, 0);
}

#[test]
fn io_options_bit_0_enables_and_other_bits_read_0() {
    let mut r = Rig::new();
    r.write(addr::IO_OPTIONS, &[0xFFFF, 0xFFFF]).unwrap();
    assert!(r.io.enabled());
    assert_eq!(r.read(addr::IO_OPTIONS, 2).unwrap(), [0, 1]);
    assert_eq!(r.io.diagnostics().reserved_ignored, 1);
    // Bit 1 (SLI LED style) is not implemented: dropped like the rest.
    r.write(addr::IO_OPTIONS, &[0, 2]).unwrap();
    assert!(!r.io.enabled());
    assert_eq!(r.read(addr::IO_OPTIONS, 2).unwrap(), [0, 0]);
    assert_eq!(r.io.diagnostics().reserved_ignored, 2);
}

#[test]
fn sli_mode_is_refused_and_changes_nothing() {
    let mut r = Rig::new();
    let before = r.io;
    assert_eq!(r.set_config(0), Err(IoError::Unsupported));
    assert_eq!(r.set_config(0x00FF_3FFF), Err(IoError::Unsupported));
    assert_eq!(r.io, before);
}

#[test]
fn thirty_two_bit_registers_are_read_and_written_whole() {
    let mut r = Rig::new();
    for (a, n) in [
        (addr::IO_OPTIONS, 1),
        (addr::IO_OPTIONS + 1, 1),
        (addr::CONFIG + 1, 1),
        (addr::IO_OPTIONS + 1, 2),
        (addr::CONFIG, 1),
    ] {
        assert_eq!(r.read(a, n), Err(IoError::IllegalAddress), "{a:#06x} × {n}");
        assert_eq!(
            r.write(a, &vec![0; n]),
            Err(IoError::IllegalAddress),
            "{a:#06x} × {n}"
        );
    }
    // Both registers in one request.
    r.write(addr::IO_OPTIONS, &[0, 1, 0x1000, 15]).unwrap();
    assert_eq!(r.read(addr::IO_OPTIONS, 4).unwrap(), [0, 1, 0x1000, 15]);
}

#[test]
fn read_only_registers_refuse_writes() {
    let mut r = Rig::new();
    for a in [
        addr::TRANSFERS,
        addr::SKIPPED,
        addr::RESERVED_IGNORED,
        addr::PERIOD_PS,
        addr::ENGINE,
        addr::FAILURES,
        addr::RX,
    ] {
        let n = if a == addr::TRANSFERS || a == addr::PERIOD_PS {
            2
        } else {
            1
        };
        assert_eq!(
            r.write(a, &vec![0; n]),
            Err(IoError::IllegalAddress),
            "{a:#06x}"
        );
    }
}

#[test]
fn addresses_outside_the_table_are_illegal() {
    let mut r = Rig::new();
    for a in [
        0x0000, 0x01FF, 0x020C, 0x020F, 0x0231, 0x023F, 0x0280, 0x02FF, 0x0300, 0xFFFF,
    ] {
        assert_eq!(r.read(a, 1), Err(IoError::IllegalAddress), "{a:#06x}");
        assert_eq!(r.write(a, &[0]), Err(IoError::IllegalAddress), "{a:#06x}");
    }
    // Ranges that run into a gap or past the page.
    assert_eq!(r.read(addr::FAILURES, 2), Err(IoError::IllegalAddress));
    assert_eq!(r.read(0x027F, 2), Err(IoError::IllegalAddress));
    assert_eq!(r.read(0xFFFF, 2), Err(IoError::IllegalAddress));
    assert_eq!(r.read(addr::TX, 70_000), Err(IoError::IllegalAddress));
}

#[test]
fn an_empty_range_is_an_illegal_value() {
    let mut r = Rig::new();
    assert_eq!(r.read(addr::TX, 0), Err(IoError::IllegalValue));
    assert_eq!(r.write(addr::TX, &[]), Err(IoError::IllegalValue));
}

#[test]
fn receive_words_exist_up_to_the_configured_bit_count() {
    let mut r = Rig::new();
    for (bits, words) in [
        (1u16, 1usize),
        (16, 1),
        (17, 2),
        (32, 2),
        (33, 3),
        (255, 16),
        (256, 16),
    ] {
        r.set_config(
            Config::new(bits, SpiMode::MODE0, 0)
                .unwrap()
                .register(false),
        )
        .unwrap();
        assert!(r.read(addr::RX, words).is_ok(), "{bits} bits");
        if words < 16 {
            assert_eq!(
                r.read(addr::RX, words + 1),
                Err(IoError::IllegalAddress),
                "{bits} bits"
            );
            assert_eq!(
                r.read(addr::RX + words as u16, 1),
                Err(IoError::IllegalAddress)
            );
        }
    }
}

#[test]
fn transmit_data_reads_back_all_16_words_whatever_the_bit_count() {
    let mut r = Rig::new();
    r.setup(8, SpiMode::MODE0, 0, cfg::AUTO_RESTART);
    let words: Vec<u16> = (0..16).map(|k| 0x0101 * k).collect();
    r.write(addr::TX, &words).unwrap();
    assert_eq!(r.read(addr::TX, 16).unwrap(), words);
}

#[test]
fn transmit_data_longer_than_configured_is_stored_and_not_sent() {
    let mut r = Rig::new();
    r.setup(8, SpiMode::MODE0, 0, 0);
    r.write(addr::TX, &[0xA5FF, 0xFFFF, 0x1234]).unwrap();
    let p = r.tick().unwrap();
    assert_eq!(p.bits, 8);
    assert_eq!(p.tx.words()[..3], [0xA500, 0, 0]);
    assert_eq!(r.chain.latches(), 1);
    for i in 0..8 {
        assert_eq!(r.chain.tx_bit_output(8, i), 0xA5 & (0x80 >> i) != 0);
    }
    // Growing the bit count sends the stored words.
    r.set_config(Config::new(48, SpiMode::MODE0, 0).unwrap().register(false))
        .unwrap();
    r.write(addr::TX + 3, &[0]).unwrap();
    assert_eq!(r.tick().unwrap().tx.words()[..3], [0xA5FF, 0xFFFF, 0x1234]);
}

#[test]
fn a_write_replaces_exactly_the_words_it_covers() {
    let mut r = Rig::new();
    r.setup(64, SpiMode::MODE0, 0, cfg::AUTO_RESTART);
    r.write(addr::TX, &[1, 2, 3, 4]).unwrap();
    r.write(addr::TX + 2, &[0x33]).unwrap();
    assert_eq!(r.read(addr::TX, 4).unwrap(), [1, 2, 0x33, 4]);
}

#[test]
fn transmit_data_written_while_disabled_is_refused() {
    let mut r = Rig::new();
    let before = r.io;
    assert_eq!(r.write(addr::TX, &[1]), Err(IoError::Disabled));
    assert_eq!(r.io, before);
}

#[test]
fn a_second_write_before_the_first_went_out_is_busy() {
    let mut r = Rig::new();
    r.setup(16, SpiMode::MODE0, 0, 0);
    r.write(addr::TX, &[1]).unwrap();
    let before = r.io;
    assert_eq!(r.write(addr::TX, &[2]), Err(IoError::Busy));
    assert_eq!(r.io, before);
    assert_eq!(r.tick().unwrap().tx.words()[0], 1);
    r.write(addr::TX, &[2]).unwrap();
    assert_eq!(r.tick().unwrap().tx.words()[0], 2);
}

#[test]
fn with_auto_restart_a_write_just_replaces_the_data() {
    let mut r = Rig::new();
    r.setup(16, SpiMode::MODE0, 0, cfg::AUTO_RESTART);
    r.write(addr::TX, &[1]).unwrap();
    r.write(addr::TX, &[2]).unwrap();
    assert_eq!(r.tick().unwrap().tx.words()[0], 2);
}

#[test]
fn a_refused_write_changes_nothing_even_after_valid_words() {
    let mut r = Rig::new();
    let before = r.io;
    // Axis 0: BIN1 valid, BIN2 with a reserved bit.
    assert_eq!(
        r.write(addr::map(0, addr::BIN1), &[0x8001, 0x2001]),
        Err(IoError::IllegalValue)
    );
    assert_eq!(r.io, before);
    // Address errors win over value errors.
    assert_eq!(
        r.write(addr::map(7, addr::IDLE), &[0x2001, 0, 0]),
        Err(IoError::IllegalAddress)
    );
}

#[test]
fn debounce_register_takes_1_to_255() {
    let mut r = Rig::new();
    for bad in [0, 256, 0xFFFF] {
        assert_eq!(r.write(addr::DEBOUNCE, &[bad]), Err(IoError::IllegalValue));
    }
    r.write(addr::DEBOUNCE, &[255]).unwrap();
    assert_eq!(r.read(addr::DEBOUNCE, 1).unwrap(), [255]);
    assert_eq!(r.io.mapping().debounce, 255);
}

#[test]
fn mapping_registers_round_trip_per_axis_and_entry() {
    let mut r = Rig::new();
    let block: Vec<u16> = vec![0x8000, 0xC001, 0x80FF, 0, 0x8010, 0xC011, 0, 0];
    r.write(addr::map(3, 0), &block).unwrap();
    assert_eq!(r.read(addr::map(3, 0), 8).unwrap(), block);
    let m = r.io.mapping().axes[3];
    assert_eq!(m.input(Input::Bin2), Some(InputBit { bit: 1, nc: true }));
    assert_eq!(
        m.input(Input::EndSwitch),
        Some(InputBit {
            bit: 255,
            nc: false
        })
    );
    assert_eq!(m.input(Input::Run), None);
    assert_eq!(
        m.output(Output::Fault),
        Some(OutputBit {
            bit: 0x11,
            inverted: true
        })
    );
    assert_eq!(r.io.mapping().axes[2], AxisMap::NONE);
    // The eighth register of a block is reserved: 0 only.
    assert_eq!(r.write(addr::map(3, 7), &[1]), Err(IoError::IllegalValue));
    // All 64 mapping registers in one read.
    assert_eq!(r.read(addr::MAP, 64).unwrap().len(), 64);
}

#[test]
fn the_real_period_and_engine_are_readable() {
    let mut r = Rig::new();
    let period = |r: &mut Rig| {
        let w = r.read(addr::PERIOD_PS, 3).unwrap();
        ((u32::from(w[0]) << 16) | u32::from(w[1]), w[2])
    };
    for (n, bits, ps, engine) in [
        (0u8, 8u16, 47_620u32, 1u16),
        (1, 8, 190_477, 1),
        (5, 8, 761_905, 1),
        (50, 8, 6_095_239, 1),
        (255, 8, 25_523_810, 2),
        (0, 9, 1_000_000, 2),
        (50, 9, 5_023_810, 2),
    ] {
        r.set_config(
            Config::new(bits, SpiMode::MODE0, n)
                .unwrap()
                .register(false),
        )
        .unwrap();
        assert_eq!(period(&mut r), (ps, engine), "N {n} bits {bits}");
    }
}

#[test]
fn the_same_page_serves_any_bus_word_by_word() {
    // Bus-neutral: a master that reads one register at a time gets the same
    // words as one that reads a block (except 32-bit halves).
    let mut r = Rig::new();
    r.setup(40, SpiMode::MODE3, 7, cfg::AUTO_RESTART);
    r.write(addr::TX, &[0xDEAD, 0xBEEF, 0xF00D]).unwrap();
    let block = r.read(addr::TX, 16).unwrap();
    for (k, w) in block.iter().enumerate() {
        assert_eq!(r.read(addr::TX + k as u16, 1).unwrap()[0], *w);
    }
}
