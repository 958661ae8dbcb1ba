//! The bridge as the PoStep60 I2C target: OAR1 is axis 0's address, OAR2
//! axis 1's; extension 0x70 selects another axis for the following commands
//! on an address. Unknown and short writes are counted and change nothing;
//! a read after them returns zeros.

use super::Bridge;
use crate::postep60::{Query, Request};
use crate::powerstep::chain::ChainBus;
use crate::transport::i2c::{self, I2cCommand, I2cError, I2cTarget, Which, Write, RESPONSE_MAX};

fn port(which: Which) -> usize {
    match which {
        Which::Primary => 0,
        Which::Secondary => 1,
    }
}

impl<B: ChainBus> I2cTarget for Bridge<B> {
    fn i2c_write(&mut self, w: Write<'_>) {
        let p = port(w.which);
        let decoded = i2c::decode(w.bytes);
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
                let _ = self.request(axis, r);
                Some(I2cCommand::Request(r))
            }
            Ok(other) => Some(other),
        };
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
            _ => 0,
        }
    }
}
