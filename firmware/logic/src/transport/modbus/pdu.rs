//! The PDU of one request (Modbus application protocol V1.1b3 §6.3, 6.6,
//! 6.12 and §7): structure checks ([`parse`]), execution on the target, the
//! response or the exception, and broadcast writes. The framing around it
//! (silence, CRC, server ids) is the parent module's.

use heapless::Vec;

use super::map::{self, Exception};
use super::{
    bump, crc16, ModbusTarget, Stats, ADU_MAX, ID_MAX, READ_QUANTITY_MAX, WRITE_QUANTITY_MAX,
};
use crate::ext_space::ExtError;
use crate::postep60::Request;

const READ_HOLDING_REGISTERS: u8 = 0x03;
const WRITE_SINGLE_REGISTER: u8 = 0x06;
const WRITE_MULTIPLE_REGISTERS: u8 = 0x10;

/// Why `serve` did not answer normally.
enum NotServed {
    Exception(Exception),
    /// An extension read waits for the chip.
    Wait,
}

impl From<Exception> for NotServed {
    fn from(e: Exception) -> NotServed {
        NotServed::Exception(e)
    }
}

fn ext_exception(e: ExtError) -> NotServed {
    NotServed::Exception(match e {
        ExtError::IllegalAddress => Exception::IllegalDataAddress,
        ExtError::IllegalValue => Exception::IllegalDataValue,
        ExtError::Refused => Exception::ServerDeviceFailure,
        ExtError::NotYet => return NotServed::Wait,
    })
}

/// Big-endian registers of `data` (2 bytes each) into `regs`; how many.
fn registers_of(data: &[u8], regs: &mut [u16; WRITE_QUANTITY_MAX as usize]) -> usize {
    let mut n: usize = 0;
    for (slot, pair) in regs.iter_mut().zip(data.chunks_exact(2)) {
        *slot = be16(pair, 0);
        n = n.saturating_add(1);
    }
    n
}

/// A structurally valid request PDU.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Pdu<'a> {
    Read {
        address: u16,
        quantity: u16,
    },
    WriteSingle {
        address: u16,
        data: &'a [u8],
    },
    WriteMultiple {
        address: u16,
        quantity: u16,
        data: &'a [u8],
    },
}

impl<'a> Pdu<'a> {
    /// A write's start address, quantity (1 for 06) and register bytes.
    fn write_parts(&self) -> Option<(u16, u16, &'a [u8])> {
        match *self {
            Pdu::Read { .. } => None,
            Pdu::WriteSingle { address, data } => Some((address, 1, data)),
            Pdu::WriteMultiple {
                address,
                quantity,
                data,
            } => Some((address, quantity, data)),
        }
    }

    fn address_is_extension(&self) -> bool {
        match *self {
            Pdu::Read { address, .. }
            | Pdu::WriteSingle { address, .. }
            | Pdu::WriteMultiple { address, .. } => map::is_extension(address),
        }
    }
}

fn be16(b: &[u8], at: usize) -> u16 {
    u16::from_be_bytes([
        b.get(at).copied().unwrap_or(0),
        b.get(at.saturating_add(1)).copied().unwrap_or(0),
    ])
}

/// Check function code (01), then quantity, byte count and length (03).
pub(super) fn parse(pdu: &[u8]) -> Result<Pdu<'_>, Exception> {
    let Some((&function, rest)) = pdu.split_first() else {
        return Err(Exception::IllegalFunction);
    };
    match function {
        READ_HOLDING_REGISTERS => {
            let quantity = be16(rest, 2);
            if rest.len() != 4 || !(1..=READ_QUANTITY_MAX).contains(&quantity) {
                return Err(Exception::IllegalDataValue);
            }
            Ok(Pdu::Read {
                address: be16(rest, 0),
                quantity,
            })
        }
        WRITE_SINGLE_REGISTER => match rest {
            [a, b, data @ ..] if data.len() == 2 => Ok(Pdu::WriteSingle {
                address: u16::from_be_bytes([*a, *b]),
                data,
            }),
            _ => Err(Exception::IllegalDataValue),
        },
        WRITE_MULTIPLE_REGISTERS => match rest {
            [a, b, q0, q1, count, data @ ..] => {
                let quantity = u16::from_be_bytes([*q0, *q1]);
                let expected = usize::from(quantity) * 2;
                if !(1..=WRITE_QUANTITY_MAX).contains(&quantity)
                    || usize::from(*count) != expected
                    || data.len() != expected
                {
                    return Err(Exception::IllegalDataValue);
                }
                Ok(Pdu::WriteMultiple {
                    address: u16::from_be_bytes([*a, *b]),
                    quantity,
                    data,
                })
            }
            _ => Err(Exception::IllegalDataValue),
        },
        _ => Err(Exception::IllegalFunction),
    }
}

/// Execute a request on `axis`; `Ignored` counts and answers normally.
fn execute(
    axis: usize,
    req: Request,
    stats: &mut Stats,
    target: &mut impl ModbusTarget,
) -> Result<(), Exception> {
    match target.request(axis, req) {
        Ok(_) => Ok(()),
        Err(e) => match Exception::for_error(e) {
            None => {
                bump(&mut stats.ignored_values);
                Ok(())
            }
            Some(x) => Err(x),
        },
    }
}

/// The response PDU (without the server id) for a unicast request.
fn serve(
    axis: usize,
    pdu: &[u8],
    out: &mut Vec<u8, ADU_MAX>,
    stats: &mut Stats,
    target: &mut impl ModbusTarget,
) -> Result<(), NotServed> {
    // Responses are at most 1 + 2 + 2·125 bytes: they fit the 256-byte buffer.
    let request = parse(pdu)?;
    if request.address_is_extension() {
        return serve_extension(axis, request, pdu, out, target);
    }
    match request {
        Pdu::Read { address, quantity } => {
            let query = map::read(address, quantity)?;
            let value = target
                .query(axis, query)
                .ok_or(Exception::ServerDeviceFailure)?;
            let mut regs = [0u8; 2 * map::REGISTERS_MAX];
            let n = map::encode(value, &mut regs);
            if n != 2 * usize::from(quantity) {
                return Err(Exception::ServerDeviceFailure.into());
            }
            let count = u8::try_from(n).map_err(|_| Exception::ServerDeviceFailure)?;
            let _ = out.push(READ_HOLDING_REGISTERS);
            let _ = out.push(count);
            let _ = out.extend_from_slice(regs.get(..n).unwrap_or(&[]));
        }
        Pdu::WriteSingle { .. } | Pdu::WriteMultiple { .. } => {
            if let Some((address, quantity, data)) = request.write_parts() {
                let req = map::write(address, quantity, data)?;
                execute(axis, req, stats, target)?;
                write_response(request, pdu, out);
            }
        }
    }
    Ok(())
}

/// A served write's response: 06 echoes the request, 16 answers its
/// function code, start address and quantity.
fn write_response(request: Pdu<'_>, pdu: &[u8], out: &mut Vec<u8, ADU_MAX>) {
    if let Pdu::WriteMultiple {
        address, quantity, ..
    } = request
    {
        let _ = out.push(WRITE_MULTIPLE_REGISTERS);
        let _ = out.extend_from_slice(&address.to_be_bytes());
        let _ = out.extend_from_slice(&quantity.to_be_bytes());
    } else {
        let _ = out.extend_from_slice(pdu);
    }
}

/// The response PDU for a request to the extension space (address high
/// byte ≠ 0): registers through the target's `ext_read` / `ext_write`.
fn serve_extension(
    axis: usize,
    request: Pdu<'_>,
    pdu: &[u8],
    out: &mut Vec<u8, ADU_MAX>,
    target: &mut impl ModbusTarget,
) -> Result<(), NotServed> {
    match request {
        Pdu::Read { address, quantity } => {
            let mut regs = [0u16; READ_QUANTITY_MAX as usize];
            let regs = regs
                .get_mut(..usize::from(quantity))
                .ok_or(Exception::IllegalDataValue)?;
            target
                .ext_read(axis, address, regs)
                .map_err(ext_exception)?;
            let count = u8::try_from(regs.len().saturating_mul(2))
                .map_err(|_| Exception::IllegalDataValue)?;
            let _ = out.push(READ_HOLDING_REGISTERS);
            let _ = out.push(count);
            for r in regs.iter() {
                let _ = out.extend_from_slice(&r.to_be_bytes());
            }
        }
        Pdu::WriteSingle { address, data } | Pdu::WriteMultiple { address, data, .. } => {
            let mut regs = [0u16; WRITE_QUANTITY_MAX as usize];
            let n = registers_of(data, &mut regs);
            target
                .ext_write(axis, address, regs.get(..n).unwrap_or(&[]))
                .map_err(ext_exception)?;
            write_response(request, pdu, out);
        }
    }
    Ok(())
}

/// Build the response ADU for server id `id` in `tx`; true (and no
/// response) when an extension read waits for the chip and `may_wait`.
pub(super) fn respond(
    id: u8,
    axis: usize,
    pdu: &[u8],
    tx: &mut Vec<u8, ADU_MAX>,
    stats: &mut Stats,
    target: &mut impl ModbusTarget,
    may_wait: bool,
) -> bool {
    tx.clear();
    let _ = tx.push(id);
    let e = match serve(axis, pdu, tx, stats, target) {
        Ok(()) => None,
        Err(NotServed::Wait) if may_wait => {
            tx.clear();
            return true;
        }
        // Waited long enough: the read could not be performed.
        Err(NotServed::Wait) => Some(Exception::ServerDeviceFailure),
        Err(NotServed::Exception(e)) => Some(e),
    };
    if let Some(e) = e {
        let function = pdu.first().copied().unwrap_or(0);
        tx.clear();
        let _ = tx.extend_from_slice(&[id, function | 0x80, e.code()]);
        bump(&mut stats.exceptions);
        if let Some(c) = stats
            .exceptions_by_code
            .get_mut(usize::from(e.code()).wrapping_sub(1))
        {
            bump(c);
        }
    } else {
        bump(&mut stats.responses);
    }
    let crc = crc16(tx);
    let _ = tx.extend_from_slice(&crc.to_le_bytes());
    false
}

/// Execute a broadcast write on every axis; never answers.
pub(super) fn broadcast(pdu: &[u8], stats: &mut Stats, target: &mut impl ModbusTarget) {
    let Ok(request) = parse(pdu) else {
        return;
    };
    let Some((address, quantity, data)) = request.write_parts() else {
        return;
    };
    if request.address_is_extension() {
        let mut regs = [0u16; WRITE_QUANTITY_MAX as usize];
        let n = registers_of(data, &mut regs);
        // A bridge-wide block once (a second start would be refused busy).
        let axes = if crate::ext_space::is_bridge_wide(address) {
            target.axes().min(1)
        } else {
            target.axes()
        };
        for axis in 0..axes {
            let _ = target.ext_write(axis, address, regs.get(..n).unwrap_or(&[]));
        }
        return;
    }
    let Ok(req) = map::write(address, quantity, data) else {
        return;
    };
    if let Request::SetAddress { current, .. } = req {
        // Only the axis answering `current` now may take the new address;
        // executing on every axis would let the axes that move onto
        // `current` accept it too.
        let axis = Some(current)
            .filter(|id| (1..=ID_MAX).contains(id))
            .and_then(|id| target.axis_for_id(id));
        if let Some(axis) = axis {
            let _ = execute(axis, req, stats, target);
        }
        return;
    }
    for axis in 0..target.axes() {
        let _ = execute(axis, req, stats, target);
    }
}
