//! The bridge as a Modbus target.
//!
//! `after_reply` is a no-op for the bridge: [`Bridge::request`] applies an
//! address change at once (it serves I2C too), and that is already "after
//! the reply" for Modbus because the server builds the response with the id
//! the request was addressed to, and the master sends nothing more before it
//! has the response. System reset and Write settings are deferred by the
//! bridge itself (`take_reset`, `take_save`); the firmware acts on them once
//! the response has been transmitted.

use super::{ModbusTarget, ID_MAX};
use crate::bridge::Bridge;
use crate::postep::{CommandError, Effect, Query, Request, Value};
use crate::powerstep::chain::ChainBus;

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

    fn after_reply(&mut self) {}
}
