//! The bridge as the Modbus target: axis k answers server id `base + k`.
//!
//! An address change (0x04) takes effect in [`Bridge::request`] at once (it
//! serves I2C too), which is already "after the reply" for Modbus: the
//! server builds the response with the id the request was addressed to, and
//! the master sends nothing before it has the response. System reset and
//! Write settings are deferred by the bridge itself (`take_reset`,
//! `take_save`); the firmware acts on them once the response is out.

use super::Bridge;
use crate::postep60::{CommandError, Effect, Query, Request, Value};
use crate::powerstep::chain::ChainBus;
use crate::transport::modbus::{ModbusTarget, ID_MAX};

impl<B: ChainBus> ModbusTarget for Bridge<B> {
    fn axis_for_id(&self, id: u8) -> Option<usize> {
        if (1..=ID_MAX).contains(&id) {
            self.axis_at(id)
        } else {
            None
        }
    }

    fn axes(&self) -> usize {
        Bridge::axes(self)
    }

    fn request(&mut self, axis: usize, req: Request) -> Result<Effect, CommandError> {
        Bridge::request(self, axis, req)
    }

    fn query(&self, axis: usize, q: Query) -> Option<Value> {
        Bridge::query(self, axis, q)
    }
}
