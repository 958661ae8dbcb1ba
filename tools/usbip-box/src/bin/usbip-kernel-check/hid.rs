//! The device through hidapi on the kernel's hidraw, as a PC program uses it.

use std::ffi::CString;
use std::time::{Duration, Instant};

use hidapi::{HidApi, HidDevice};

use crate::device::Attached;
use crate::Checks;

pub const VID: u16 = 0x1DC3;
pub const PID: u16 = 0x0641;
/// How long a report that gets no answer is watched.
pub const NO_ANSWER_WAIT: Duration = Duration::from_millis(300);

/// An IN report (64 bytes with the report id) and when it came.
pub type In = (Vec<u8>, Instant);

pub struct Hid {
    pub dev: HidDevice,
}

impl Hid {
    /// Find the device with hidapi's enumeration and open it.
    pub fn open(c: &mut Checks, att: &Attached) -> Result<Hid, String> {
        let api = HidApi::new().map_err(|e| format!("hidapi: {e}"))?;
        let found: Vec<_> = api
            .device_list()
            .filter(|d| d.vendor_id() == VID && d.product_id() == PID)
            .collect();
        c.eq("hidapi: one PoStep60 device", found.len(), 1);
        let d = found.first().ok_or("hidapi finds no device")?;
        let path = d.path().to_string_lossy().into_owned();
        c.eq(
            "hidapi: its path is the hidraw node",
            path.as_str(),
            att.hidraw.to_string_lossy().as_ref(),
        );
        c.eq(
            "hidapi: product string",
            d.product_string(),
            Some("PoStep60-256"),
        );
        c.eq(
            "hidapi: manufacturer string",
            d.manufacturer_string(),
            Some("PoLabs"),
        );
        c.check(
            "hidapi: serial number",
            d.serial_number().is_some_and(|s| s.len() == 35),
            format!("{:?}", d.serial_number()),
        );
        let cpath = CString::new(path).map_err(|_| "a path with NUL")?;
        let dev = api.open_path(&cpath).map_err(|e| format!("open: {e}"))?;
        Ok(Hid { dev })
    }

    pub fn write(&self, report: &[u8]) -> Result<usize, String> {
        self.dev.write(report).map_err(|e| format!("write: {e}"))
    }

    /// One IN report within `ms`: always 64 bytes (the report id and
    /// `InDATA[1..63]`); any other length is an error.
    pub fn read(&self, ms: i32) -> Result<Option<In>, String> {
        let mut buf = [0u8; 65];
        match self.dev.read_timeout(&mut buf, ms) {
            Ok(0) => Ok(None),
            Ok(64) => Ok(Some((buf[..64].to_vec(), Instant::now()))),
            Ok(n) => Err(format!("a {n}-byte IN report from hidraw, 64 expected")),
            Err(e) => Err(format!("read: {e}")),
        }
    }

    /// Everything hidraw has queued now.
    pub fn drain(&self) -> Result<Vec<In>, String> {
        let mut v = Vec::new();
        while let Some(r) = self.read(0)? {
            v.push(r);
        }
        Ok(v)
    }

    /// Write `out`, return the first reply that is not a stream report
    /// (within 1 s; `None` when none came).
    pub fn transact(&self, out: &[u8]) -> Result<Option<Vec<u8>>, String> {
        self.write(out)?;
        self.reply(Duration::from_secs(1))
    }

    /// Write `out` that must not be answered: what came within
    /// [`NO_ANSWER_WAIT`] (a reply takes a few ms here).
    pub fn unanswered(&self, out: &[u8]) -> Result<Option<Vec<u8>>, String> {
        self.write(out)?;
        self.reply(NO_ANSWER_WAIT)
    }

    /// The next reply that is not a 0xA0 stream report, within `within`.
    pub fn reply(&self, within: Duration) -> Result<Option<Vec<u8>>, String> {
        let deadline = Instant::now() + within;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            let ms = i32::try_from(left.as_millis()).unwrap_or(i32::MAX);
            match self.read(ms)? {
                None => return Ok(None),
                Some((r, _)) if is_stream(&r) => continue,
                Some((r, _)) => return Ok(Some(r)),
            }
        }
    }
}

/// A 0xA0 data-stream report: packet id 0, response byte 0xA0.
pub fn is_stream(r: &[u8]) -> bool {
    r.get(1) == Some(&0x00) && r.get(15) == Some(&0xA0)
}
