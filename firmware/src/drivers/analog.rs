//! ADC1 sampling of the motor supply, the die temperature and VREFINT.
//!
//! [`Analog::sample`] returns raw 12-bit counts only; every conversion to
//! volts, degrees or PoStep60 units is in the logic crate
//! (`bridge_logic::postep60::analog`).
//!
//! # Timing
//!
//! * ADCCLK = APB2 / 4 = 21 MHz (the F405's ADC allows at most 36 MHz, so
//!   the HAL's default APB2 / 2 = 42 MHz is too fast).
//! * Every channel samples for 480 cycles (22.9 µs), the longest setting:
//!   the temperature sensor and VREFINT need at least 10 µs (datasheet
//!   T_S_temp, T_S_vrefint), and the supply divider's source impedance wants
//!   a long sample too. With 12 cycles of conversion one channel takes
//!   ~23.4 µs, a whole [`Analog::sample`] ~71 µs of blocking single
//!   conversions (the HAL's `convert`, which polls EOC of a conversion it has
//!   just started). Call it from a low-priority context.
//!
//! The HAL's `Adc::new` reads the factory VREFINT calibration from system
//! memory (0x1FFF_7A2A, next to the unique ID that HardFaults under QEMU's
//! `netduinoplus2`): the QEMU platform never starts it (nor the I2C
//! driver), it uses a stand-in. `convert` polls the ADC's start and end flags without a
//! limit; on working silicon that is the ~23 µs of one conversion.

use bridge_logic::postep60::analog::AnalogSample;
use stm32f4xx_hal::adc::config::{AdcConfig, Clock, Resolution, SampleTime};
use stm32f4xx_hal::adc::{Adc, Temperature, Vref};
use stm32f4xx_hal::rcc::Rcc;

use crate::pins::{SenseAdc, SupplySense};

/// Sample time of every channel (see the module docs).
const SAMPLE_TIME: SampleTime = SampleTime::Cycles_480;

/// ADC1 with the supply-sense pin and the internal channels switched on.
pub struct Analog {
    adc: Adc<SenseAdc>,
    supply: SupplySense,
}

impl Analog {
    /// Enable and reset ADC1 (12-bit, right-aligned, single conversions)
    /// and switch on the temperature sensor and VREFINT (ADC_CCR.TSVREFE).
    pub fn new(adc: SenseAdc, supply: SupplySense, rcc: &mut Rcc) -> Analog {
        let config = AdcConfig::default()
            .clock(Clock::Pclk2_div_4)
            .resolution(Resolution::Twelve)
            .default_sample_time(SAMPLE_TIME);
        let mut adc = Adc::new(adc, true, config, rcc);
        // Also turns VBAT off, which would block the other two channels.
        // The sensor's start-up time (≤ 10 µs) is over long before the first
        // sample: `new` runs in init.
        adc.enable_temperature_and_vref();
        Analog { adc, supply }
    }

    /// One blocking conversion of each channel (~71 µs in all): raw counts.
    pub fn sample(&mut self) -> AnalogSample {
        let supply = self.adc.convert(&self.supply, SAMPLE_TIME);
        let temperature = self.adc.convert(&Temperature, SAMPLE_TIME);
        let vrefint = self.adc.convert(&Vref, SAMPLE_TIME);
        AnalogSample {
            supply,
            temperature,
            vrefint,
        }
    }
}
