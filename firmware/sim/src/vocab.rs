//! The driver crate's names for the model's registers.
//!
//! The receive log and the register accessors speak the driver crate's
//! value types ([`Register`], [`powerstep01::Command`]) so that tests can
//! compare what the chip received with what the driver meant to send. This
//! module is the only bridge between the two: which [`Register`] variant
//! names the register at which address, stated here variant by variant (not
//! by the variant's discriminant, and without the driver's register table).
//! Whether the driver agrees — `Register::X.address()` and its table row —
//! is what host-tests' cross-check asks.

use powerstep01::Register;

use crate::datasheet::addr;

/// The model's address of the register the driver calls `r`.
pub const fn address(r: Register) -> u8 {
    match r {
        Register::AbsPos => addr::ABS_POS,
        Register::ElPos => addr::EL_POS,
        Register::Mark => addr::MARK,
        Register::Speed => addr::SPEED,
        Register::Acc => addr::ACC,
        Register::Dec => addr::DEC,
        Register::MaxSpeed => addr::MAX_SPEED,
        Register::MinSpeed => addr::MIN_SPEED,
        Register::KvalHold => addr::KVAL_HOLD,
        Register::KvalRun => addr::KVAL_RUN,
        Register::KvalAcc => addr::KVAL_ACC,
        Register::KvalDec => addr::KVAL_DEC,
        Register::IntSpeed => addr::INT_SPEED,
        Register::StSlp => addr::ST_SLP,
        Register::FnSlpAcc => addr::FN_SLP_ACC,
        Register::FnSlpDec => addr::FN_SLP_DEC,
        Register::KTherm => addr::K_THERM,
        Register::AdcOut => addr::ADC_OUT,
        Register::OcdTh => addr::OCD_TH,
        Register::StallTh => addr::STALL_TH,
        Register::FsSpd => addr::FS_SPD,
        Register::StepMode => addr::STEP_MODE,
        Register::AlarmEn => addr::ALARM_EN,
        Register::GateCfg1 => addr::GATECFG1,
        Register::GateCfg2 => addr::GATECFG2,
        Register::Config => addr::CONFIG,
        Register::Status => addr::STATUS,
    }
}

/// The driver's name of the register at `address`, `None` where the model
/// has no register.
pub const fn register(address: u8) -> Option<Register> {
    Some(match address {
        addr::ABS_POS => Register::AbsPos,
        addr::EL_POS => Register::ElPos,
        addr::MARK => Register::Mark,
        addr::SPEED => Register::Speed,
        addr::ACC => Register::Acc,
        addr::DEC => Register::Dec,
        addr::MAX_SPEED => Register::MaxSpeed,
        addr::MIN_SPEED => Register::MinSpeed,
        addr::KVAL_HOLD => Register::KvalHold,
        addr::KVAL_RUN => Register::KvalRun,
        addr::KVAL_ACC => Register::KvalAcc,
        addr::KVAL_DEC => Register::KvalDec,
        addr::INT_SPEED => Register::IntSpeed,
        addr::ST_SLP => Register::StSlp,
        addr::FN_SLP_ACC => Register::FnSlpAcc,
        addr::FN_SLP_DEC => Register::FnSlpDec,
        addr::K_THERM => Register::KTherm,
        addr::ADC_OUT => Register::AdcOut,
        addr::OCD_TH => Register::OcdTh,
        addr::STALL_TH => Register::StallTh,
        addr::FS_SPD => Register::FsSpd,
        addr::STEP_MODE => Register::StepMode,
        addr::ALARM_EN => Register::AlarmEn,
        addr::GATECFG1 => Register::GateCfg1,
        addr::GATECFG2 => Register::GateCfg2,
        addr::CONFIG => Register::Config,
        addr::STATUS => Register::Status,
        _ => return None,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::datasheet::REGISTERS;

    #[test]
    fn every_model_register_has_one_driver_name_and_back() {
        for spec in REGISTERS.iter() {
            let r = register(spec.address).expect("named");
            assert_eq!(address(r), spec.address, "{}", spec.name);
        }
        for a in (0..=0xFF).filter(|a| crate::datasheet::register(*a).is_none()) {
            assert_eq!(register(a), None, "{a:#04x}");
        }
    }
}
