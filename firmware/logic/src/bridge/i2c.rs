//! The bridge as the PoStep60 I2C target: OAR1 is axis 0's address, OAR2
//! axis 1's; extension 0x70 selects another axis for the following commands
//! on an address. Unknown and short writes are counted and change nothing;
//! a read after them returns zeros.

use super::{Bridge, Bus, ExtError};
use crate::postep60::{Query, Request};
use crate::powerstep::chain::ChainBus;
use crate::transport::i2c::{
    self, ext_status, I2cCommand, I2cError, I2cTarget, Which, Write, EXT_MAX, RESPONSE_MAX,
};

/// The extension status byte of an outcome.
fn status_of(r: Result<(), ExtError>) -> u8 {
    match r {
        Ok(()) => ext_status::OK,
        Err(ExtError::NotYet) => ext_status::NOT_YET,
        Err(ExtError::IllegalAddress) => ext_status::ILLEGAL_ADDRESS,
        Err(ExtError::IllegalValue) => ext_status::ILLEGAL_VALUE,
        Err(ExtError::Refused) => ext_status::REFUSED,
    }
}

fn port(which: Which) -> usize {
    match which {
        Which::Primary => 0,
        Which::Secondary => 1,
    }
}

impl<B: ChainBus> I2cTarget for Bridge<B> {
    fn i2c_write(&mut self, w: Write<'_>) {
        let p = port(w.which);
        let decoded = match w.bytes.first() {
            Some(&command) if w.overlong => Err(I2cError::Long { command, takes: 0 }),
            _ => i2c::decode(w.bytes),
        };
        let axis = self
            .ports
            .get(p)
            .map(|port| usize::from(port.axis))
            .unwrap_or(0);
        let last = match decoded {
            Err(I2cError::Unknown(_)) => {
                self.diag.i2c_unknown = self.diag.i2c_unknown.saturating_add(1);
                None
            }
            Err(I2cError::Short { .. }) => {
                self.diag.i2c_short = self.diag.i2c_short.saturating_add(1);
                None
            }
            Err(I2cError::Long { .. }) => {
                self.diag.i2c_long = self.diag.i2c_long.saturating_add(1);
                None
            }
            Ok(I2cCommand::SelectAxis(k)) => {
                if usize::from(k) < self.axes() {
                    if let Some(port) = self.ports.get_mut(p) {
                        port.axis = k;
                    }
                } else {
                    self.diag.refused = self.diag.refused.saturating_add(1);
                }
                Some(I2cCommand::Selection)
            }
            Ok(I2cCommand::Request(r)) => {
                // I2C has no error reply: a refused request is only counted.
                let _ = self.request_from(Bus::I2c, axis, r);
                Some(I2cCommand::Request(r))
            }
            Ok(I2cCommand::ExtWrite { address, data, len }) => {
                let n = usize::from(len).min(EXT_MAX);
                let r = self.ext_write_from(Bus::I2c, axis, address, data.get(..n).unwrap_or(&[]));
                Some(I2cCommand::ExtStatus(status_of(r)))
            }
            Ok(other) => Some(other),
        };
        if decoded.is_ok() {
            self.heard(Bus::I2c);
        }
        if let Some(port) = self.ports.get_mut(p) {
            port.last = last;
        }
    }

    fn i2c_read(&mut self, which: Which, out: &mut [u8; RESPONSE_MAX]) -> usize {
        *out = [0; RESPONSE_MAX];
        let Some(port) = self.ports.get(port(which)).copied() else {
            return 0;
        };
        let axis = usize::from(port.axis);
        match port.last {
            Some(I2cCommand::Query(q)) => self
                .query(axis, q)
                .map(|v| i2c::encode(v, out))
                .unwrap_or(0),
            Some(I2cCommand::Request(Request::Loopback(_))) => self
                .query(axis, Query::Loopback)
                .map(|v| i2c::encode(v, out))
                .unwrap_or(0),
            Some(I2cCommand::Selection) => {
                out[0] = port.axis;
                out[1] = self.axes() as u8;
                2
            }
            Some(I2cCommand::ExtRead { address, quantity }) => {
                let n = usize::from(quantity);
                let mut regs = [0u16; EXT_MAX];
                let r = match regs.get_mut(..n).filter(|r| !r.is_empty()) {
                    Some(regs) => self.ext_read(axis, address, regs),
                    None => Err(ExtError::IllegalValue),
                };
                out[0] = status_of(r);
                if r.is_err() {
                    return 1;
                }
                for (pair, v) in out[1..].chunks_exact_mut(2).zip(regs.iter().take(n)) {
                    pair.copy_from_slice(&v.to_be_bytes());
                }
                // n ≤ EXT_MAX (3): the response fits RESPONSE_MAX.
                n.saturating_mul(2).saturating_add(1)
            }
            Some(I2cCommand::ExtStatus(st)) => {
                out[0] = st;
                1
            }
            _ => 0,
        }
    }
}
