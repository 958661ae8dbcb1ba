//! The client side of an import, as the `usbip attach` tool does it: list
//! and import over TCP, then hand the connected socket to the kernel's
//! vhci-hcd through sysfs (`attach`: "port sockfd devid speed"). The kernel
//! then owns the connection and enumerates the device; closing our file
//! descriptor afterwards is what `usbip` does too (the kernel holds its own
//! reference).

use std::io::{self, Read, Write};
use std::net::TcpStream;
use std::path::Path;
use std::time::Duration;

use crate::protocol::{
    decode_devlist, encode_req_devlist, encode_req_import, DeviceInfo, DEVICE_RECORD_LEN,
    OP_HEADER_LEN, OP_REP_IMPORT, VERSION,
};

/// vhci-hcd's first controller in sysfs.
pub const VHCI: &str = "/sys/devices/platform/vhci_hcd.0";

/// `enum vdev_state` VDEV_ST_NULL: the port is free.
const PORT_FREE: &str = "004";

fn proto(what: &str) -> io::Error {
    io::Error::new(io::ErrorKind::InvalidData, what.to_string())
}

fn connect(addr: &str) -> io::Result<TcpStream> {
    let s = TcpStream::connect(addr)?;
    s.set_read_timeout(Some(Duration::from_secs(5)))?;
    s.set_nodelay(true)?;
    Ok(s)
}

/// OP_REQ_DEVLIST: the devices the server at `addr` exports.
pub fn devlist(addr: &str) -> io::Result<Vec<DeviceInfo>> {
    let mut s = connect(addr)?;
    s.write_all(&encode_req_devlist())?;
    let mut b = Vec::new();
    s.read_to_end(&mut b)?;
    decode_devlist(&b).ok_or_else(|| proto("not an OP_REP_DEVLIST"))
}

/// OP_REQ_IMPORT of `busid`: the connection (now carrying URBs) and the
/// device record.
pub fn import(addr: &str, busid: &str) -> io::Result<(TcpStream, DeviceInfo)> {
    let mut s = connect(addr)?;
    s.write_all(&encode_req_import(busid))?;
    let mut head = [0u8; OP_HEADER_LEN];
    s.read_exact(&mut head)?;
    let version = u16::from_be_bytes([head[0], head[1]]);
    let code = u16::from_be_bytes([head[2], head[3]]);
    let status = u32::from_be_bytes([head[4], head[5], head[6], head[7]]);
    if version != VERSION || code != OP_REP_IMPORT {
        return Err(proto("not an OP_REP_IMPORT"));
    }
    if status != 0 {
        return Err(proto(&format!(
            "import of {busid} refused (status {status})"
        )));
    }
    let mut record = [0u8; DEVICE_RECORD_LEN];
    s.read_exact(&mut record)?;
    let info = DeviceInfo::decode_record(&record).ok_or_else(|| proto("short device record"))?;
    s.set_read_timeout(None)?;
    Ok((s, info))
}

/// The first free port of vhci-hcd's USB 2.0 hub ("hs": low, full and high
/// speed devices) in the text of its `status` file.
pub fn free_hs_port(status: &str) -> Option<u32> {
    status.lines().find_map(|line| {
        let mut f = line.split_whitespace();
        let hub = f.next()?;
        let port = f.next()?;
        let state = f.next()?;
        (hub == "hs" && state == PORT_FREE)
            .then(|| port.parse().ok())
            .flatten()
    })
}

/// The line `attach` takes.
pub fn attach_line(port: u32, sockfd: i32, devid: u32, speed: u32) -> String {
    format!("{port} {sockfd} {devid} {speed}")
}

/// Attach the imported connection to a free port of the vhci controller
/// in `vhci` (sysfs directory); the port.
#[cfg(unix)]
pub fn attach(vhci: &Path, stream: &TcpStream, info: &DeviceInfo) -> io::Result<u32> {
    use std::os::fd::AsRawFd;
    let status = std::fs::read_to_string(vhci.join("status"))?;
    let port = free_hs_port(&status).ok_or_else(|| proto("no free vhci hs port"))?;
    let line = attach_line(port, stream.as_raw_fd(), info.devid(), info.speed);
    std::fs::write(vhci.join("attach"), line)?;
    Ok(port)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_first_free_hs_port_is_taken_ss_ports_never() {
        let status = "hub port sta spd dev      sockfd local_busid\n\
                      hs  0000 006 002 00010002 000003 1-1\n\
                      hs  0001 004 000 00000000 000000 0-0\n\
                      hs  0002 004 000 00000000 000000 0-0\n\
                      ss  0015 004 000 00000000 000000 0-0\n";
        assert_eq!(free_hs_port(status), Some(1));
        let full = "hub port sta spd dev      sockfd local_busid\n\
                    hs  0000 006 002 00010002 000003 1-1\n\
                    ss  0015 004 000 00000000 000000 0-0\n";
        assert_eq!(free_hs_port(full), None);
    }

    #[test]
    fn the_attach_line_is_port_fd_devid_speed() {
        assert_eq!(attach_line(3, 7, 0x0001_0002, 2), "3 7 65538 2");
    }
}
