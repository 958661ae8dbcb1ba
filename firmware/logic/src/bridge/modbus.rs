//! The bridge as the Modbus target: axis k answers server id `base + k`.
//!
//! An address change (0x04) takes effect in [`Bridge::request`] at once (it
//! serves I2C too), which is already "after the reply" for Modbus: the
//! server builds the response with the id the request was addressed to, and
//! the master sends nothing before it has the response. System reset and
//! Write settings are deferred by the bridge itself (`take_reset`,
//! `take_save`); the firmware acts on them once the response is out.

use super::{Bridge, Bus, ExtError};
use crate::postep60::{CommandError, Effect, Query, Request, Value};
use crate::powerstep::chain::ChainBus;
use crate::transport::modbus::{ModbusTarget, ID_MAX};

impl<B: ChainBus> ModbusTarget for Bridge<B> {
    /// Axis k answers `base + k`; with no chip detected the base id still
    /// answers as axis 0 (the bridge-scope extension blocks read there,
    /// everything of an axis is an exception), so a box whose chain was
    /// not found can be asked why.
    fn axis_for_id(&self, id: u8) -> Option<usize> {
        if !(1..=ID_MAX).contains(&id) {
            return None;
        }
        self.axis_at(id)
            .or_else(|| (self.axes() == 0 && id == self.base_address()).then_some(0))
    }

    fn axes(&self) -> usize {
        Bridge::axes(self)
    }

    fn request(&mut self, axis: usize, req: Request) -> Result<Effect, CommandError> {
        self.request_from(Bus::Modbus, axis, req)
    }

    fn query(&mut self, axis: usize, q: Query) -> Option<Value> {
        self.heard(Bus::Modbus);
        Bridge::query(self, axis, q)
    }

    fn ext_read(&mut self, axis: usize, address: u16, out: &mut [u16]) -> Result<(), ExtError> {
        self.heard(Bus::Modbus);
        Bridge::ext_read(self, axis, address, out)
    }

    fn ext_write(&mut self, axis: usize, address: u16, data: &[u16]) -> Result<(), ExtError> {
        self.heard(Bus::Modbus);
        Bridge::ext_write_from(self, Bus::Modbus, axis, address, data)
    }
}
