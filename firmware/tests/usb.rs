//! USB OTG FS as the app starts it (`platform::start_usb`, `drivers::usb`):
//! the 48 MHz PLL48CLK beside an unchanged 168 MHz clock tree, the port
//! built (bus allocator with its endpoint memory, HID class, device) and
//! the core in full-speed device mode, connected, with the PoStep60's
//! serial number from the unique id. The last test enumerates: it needs
//! the board's USB socket connected to a PC (it waits 10 s for the host to
//! configure the device, then checks the FIFO layout the endpoint memory
//! gave). Board only: QEMU maps OTG FS as an unimplemented device, the
//! allocator's core reset waits for ever there, and it has no unique id.
#![cfg_attr(target_os = "none", no_std, no_main)]
// An on-target test, not bus input: it may index, unwrap, panic and (like
// the drivers) touch registers in `unsafe` blocks.
#![allow(unsafe_code, clippy::indexing_slicing, clippy::arithmetic_side_effects)]
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
#[cfg(not(target_os = "none"))]
fn main() {}

#[cfg(target_os = "none")]
mod common;

#[cfg(target_os = "none")]
mod support {
    use firmware::platform::Usb;
    use stm32f4xx_hal::pac;
    use stm32f4xx_hal::rcc::Rcc;

    pub struct State {
        pub rcc: Rcc,
        pub otg: Option<firmware::pins::UsbOtg>,
        pub pins: Option<(firmware::pins::UsbDm, firmware::pins::UsbDp)>,
        pub usb: Option<Usb>,
        pub sysclk_hz: u32,
    }

    /// (GUSBCFG, GCCFG, DCFG, DCTL) of the OTG FS core.
    #[allow(unsafe_code)]
    pub fn core_registers() -> (u32, u32, u32, u32) {
        // SAFETY: reads of OTG FS registers; the port under test only
        // changes them inside `poll`, called from this thread.
        unsafe {
            let global = &*pac::OTG_FS_GLOBAL::ptr();
            let device = &*pac::OTG_FS_DEVICE::ptr();
            (
                global.gusbcfg().read().bits(),
                global.gccfg().read().bits(),
                device.dcfg().read().bits(),
                device.dctl().read().bits(),
            )
        }
    }

    /// (GRXFSIZ, DIEPTXF0, DIEPTXF1): RX FIFO depth, EP0 and EP1 TX FIFOs
    /// (depth << 16 | start).
    #[allow(unsafe_code)]
    pub fn fifo_registers() -> (u32, u32, u32) {
        // SAFETY: as in `core_registers`.
        unsafe {
            let global = &*pac::OTG_FS_GLOBAL::ptr();
            (
                global.grxfsiz().read().bits(),
                global.dieptxf0().read().bits(),
                global.dieptxf1().read().bits(),
            )
        }
    }

    /// RCC_PLLCFGR.
    #[allow(unsafe_code)]
    pub fn pllcfgr() -> u32 {
        // SAFETY: one read of a register nobody writes after `freeze`.
        unsafe { (*pac::RCC::ptr()).pllcfgr().read().bits() }
    }
}

#[cfg(target_os = "none")]
#[defmt_test::tests]
mod tests {
    use bridge_logic::transport::usb::serial_number;
    use firmware::drivers::usb::{Link, EP_MEMORY_WORDS};
    use firmware::platform;
    use usb_device::device::UsbDeviceState;

    use super::common;
    use super::support::{core_registers, fifo_registers, pllcfgr, State};

    #[init]
    fn init() -> State {
        let t = common::setup();
        State {
            rcc: t.rcc,
            otg: Some(t.usb_otg),
            pins: Some((t.pins.usb_dm, t.pins.usb_dp)),
            usb: None,
            sysclk_hz: t.sysclk_hz,
        }
    }

    #[test]
    fn pll48clk_is_48_mhz_and_the_other_clocks_are_unchanged(s: &mut State) {
        let c = &s.rcc.clocks;
        defmt::assert_eq!(c.pll48clk().map(|f| f.raw()), Some(48_000_000));
        defmt::assert_eq!(c.sysclk().raw(), 168_000_000);
        defmt::assert_eq!(c.pclk1().raw(), 42_000_000);
        defmt::assert_eq!(c.pclk2().raw(), 84_000_000);
        // M 4 (2 MHz VCO input), N 168 (336 MHz VCO), P /2 (bits 0), Q 7.
        let pll = pllcfgr();
        defmt::assert_eq!(pll & 0x3F, 4, "PLLM");
        defmt::assert_eq!((pll >> 6) & 0x1FF, 168, "PLLN");
        defmt::assert_eq!((pll >> 16) & 0x3, 0, "PLLP");
        defmt::assert_eq!((pll >> 24) & 0xF, 7, "PLLQ");
    }

    #[test]
    fn the_port_starts_with_its_endpoint_memory(s: &mut State) {
        let (Some(otg), Some(pins)) = (s.otg.take(), s.pins.take()) else {
            defmt::panic!("OTG FS taken");
        };
        // EP0 OUT + EP1 OUT, 64 bytes each.
        defmt::assert_eq!(EP_MEMORY_WORDS, 32);
        let uid = platform::unique_id();
        s.usb = platform::start_usb(otg, pins, &s.rcc, uid);
        defmt::assert!(s.usb.is_some(), "USB did not start");
    }

    #[test]
    fn the_core_is_a_connected_full_speed_device() {
        let (gusbcfg, gccfg, dcfg, dctl) = core_registers();
        defmt::assert!(gusbcfg & 1 << 30 != 0, "FDMOD: forced device mode");
        defmt::assert!(gusbcfg & 1 << 6 != 0, "PHYSEL: internal FS PHY");
        defmt::assert!(gccfg & 1 << 16 != 0, "PWRDWN: transceiver on");
        defmt::assert!(gccfg & 1 << 21 != 0, "NOVBUSSENS: PA9 not used");
        defmt::assert_eq!(dcfg & 0b11, 0b11, "DSPD: full speed");
        defmt::assert_eq!(dctl & 1 << 1, 0, "SDIS: connected");
    }

    #[test]
    fn the_unique_id_is_read_and_makes_the_serial() {
        let uid = platform::unique_id();
        defmt::assert!(uid != [0; 3] && uid != [u32::MAX; 3], "no unique id");
        let serial = serial_number(uid);
        defmt::info!("serial number {=str}", serial.as_str());
        defmt::assert_eq!(serial.len(), 35);
    }

    #[test]
    fn a_host_enumerates_it_with_the_fifos_the_endpoints_need(s: &mut State) {
        let Some(usb) = s.usb.as_mut() else {
            defmt::panic!("USB not started");
        };
        defmt::info!("waiting up to 10 s for a host: connect the board's USB socket to a PC");
        let start = common::cycles_now();
        let ten_s = s.sysclk_hz.saturating_mul(10);
        let mut link = Link::Down;
        while link != Link::Up {
            link = usb.poll();
            if common::cycles_since(start) > ten_s {
                defmt::panic!("not configured by a host within 10 s: {}", usb.state());
            }
        }
        defmt::assert_eq!(usb.state(), UsbDeviceState::Configured);
        // synopsys-usb-otg 0.4: RX FIFO = OUT memory + 30 words; EP0 and
        // EP1 TX FIFOs of 16 words each, one after the other.
        let (rx, tx0, tx1) = fifo_registers();
        let rx_words = EP_MEMORY_WORDS as u32 + 30;
        defmt::assert_eq!(rx, rx_words);
        defmt::assert_eq!(tx0, 16 << 16 | rx_words);
        defmt::assert_eq!(tx1, 16 << 16 | (rx_words + 16));
    }
}
