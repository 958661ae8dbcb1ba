//! The kernel's side: modules, the box process, list/import/attach, and what
//! sysfs says about the device the kernel enumerated.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use usbip_box::protocol::SPEED_FULL;
use usbip_box::vhci;

use crate::{Args, Checks};

use host_tests::usb_manual::{MANUAL_CONFIG, MANUAL_DEVICE, REPORT_DESCRIPTOR};

const WAIT: Duration = Duration::from_secs(30);

fn read(p: &Path) -> String {
    std::fs::read_to_string(p)
        .map(|s| s.trim().to_string())
        .unwrap_or_default()
}

fn link_name(p: &Path) -> String {
    std::fs::read_link(p)
        .ok()
        .and_then(|t| t.file_name().map(|n| n.to_string_lossy().into_owned()))
        .unwrap_or_default()
}

fn entries(dir: &Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .map(|r| r.filter_map(|e| e.ok().map(|e| e.path())).collect())
        .unwrap_or_default();
    v.sort();
    v
}

/// Wait until `f` gives something (or `WAIT` passed).
fn wait_for<T>(what: &str, mut f: impl FnMut() -> Option<T>) -> Result<T, String> {
    let t0 = Instant::now();
    loop {
        if let Some(v) = f() {
            return Ok(v);
        }
        if t0.elapsed() > WAIT {
            return Err(format!("{what}: not within {} s", WAIT.as_secs()));
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

pub fn modules(c: &mut Checks) {
    for m in ["usbip_core", "vhci_hcd", "usbhid", "hid_generic"] {
        c.check(
            &format!("module {m} loaded"),
            Path::new("/sys/module").join(m).exists(),
            "/sys/module",
        );
    }
    c.check(
        "hidraw built in",
        Path::new("/sys/class/hidraw").exists(),
        "/sys/class/hidraw",
    );
    c.check(
        "vhci-hcd has its controller",
        Path::new(vhci::VHCI).join("attach").exists(),
        vhci::VHCI,
    );
}

/// The box, a child process.
pub struct BoxProcess(Child);

impl BoxProcess {
    pub fn start(args: &Args) -> Result<BoxProcess, String> {
        let child = Command::new(&args.box_bin)
            .args(["--listen", &args.listen, "--axes", "4", "--trace"])
            .stdin(Stdio::null())
            .spawn()
            .map_err(|e| format!("cannot start {}: {e}", args.box_bin))?;
        let b = BoxProcess(child);
        wait_for("the box listening", || {
            std::net::TcpStream::connect(&args.listen).ok().map(drop)
        })?;
        Ok(b)
    }

    pub fn stop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

impl Drop for BoxProcess {
    fn drop(&mut self) {
        self.stop();
    }
}

pub fn devlist(c: &mut Checks, addr: &str) -> Result<(), String> {
    let list = vhci::devlist(addr).map_err(|e| format!("OP_REQ_DEVLIST: {e}"))?;
    c.eq("devlist: one device", list.len(), 1);
    if let Some(d) = list.first() {
        c.eq("devlist: bus id", d.busid.as_str(), "1-1");
        c.eq(
            "devlist: VID/PID/bcdDevice",
            (d.vendor, d.product, d.bcd_device),
            (0x1DC3, 0x0641, 0x0100),
        );
        c.eq("devlist: full speed", d.speed, SPEED_FULL);
        c.eq(
            "devlist: one HID interface",
            d.interfaces.clone(),
            vec![(3, 0, 0)],
        );
    }
    Ok(())
}

/// The device as attached: its sysfs directories and hidraw node.
pub struct Attached {
    pub port: u32,
    /// /sys/bus/usb/devices/N-M
    pub usb: PathBuf,
    /// The HID device under the interface.
    pub hid: PathBuf,
    /// /dev/hidrawN
    pub hidraw: PathBuf,
}

fn find_usb_device() -> Option<PathBuf> {
    entries(Path::new("/sys/bus/usb/devices"))
        .into_iter()
        .find(|d| read(&d.join("idVendor")) == "1dc3" && read(&d.join("idProduct")) == "0641")
}

impl Attached {
    /// Import, attach, and wait for the kernel to bind hidraw.
    pub fn attach(addr: &str) -> Result<Attached, String> {
        let (stream, info) = vhci::import(addr, "1-1").map_err(|e| format!("import: {e}"))?;
        let port = vhci::attach(Path::new(vhci::VHCI), &stream, &info)
            .map_err(|e| format!("vhci attach: {e}"))?;
        // The kernel holds the socket now.
        drop(stream);
        let usb = wait_for("the USB device in sysfs", find_usb_device)?;
        let name = usb
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let intf = usb.join(format!("{name}:1.0"));
        let hid = wait_for("a HID device under the interface", || {
            entries(&intf).into_iter().find(|p| {
                p.file_name()
                    .is_some_and(|n| n.to_string_lossy().starts_with("0003:1DC3:0641."))
            })
        })?;
        let node = wait_for("the hidraw node", || {
            let n = entries(&hid.join("hidraw")).into_iter().next()?;
            let dev = Path::new("/dev").join(n.file_name()?);
            dev.exists().then_some(dev)
        })?;
        Ok(Attached {
            port,
            usb,
            hid,
            hidraw: node,
        })
    }

    /// Wait until the kernel has removed the device (it was unplugged).
    pub fn wait_gone(&self) -> Result<Duration, String> {
        let t0 = Instant::now();
        wait_for("the device to go", || (!self.usb.exists()).then_some(()))?;
        // The port is freed once the kernel's threads have stopped.
        let port = format!("{:04}", self.port);
        wait_for("the vhci port to be free", || {
            let status = std::fs::read_to_string(Path::new(vhci::VHCI).join("status")).ok()?;
            status
                .lines()
                .any(|l| {
                    let f: Vec<&str> = l.split_whitespace().collect();
                    f.get(1) == Some(&port.as_str()) && f.get(2) == Some(&"004")
                })
                .then_some(())
        })?;
        Ok(t0.elapsed())
    }

    /// Detach through vhci-hcd (the host unplugs it); the box sees the
    /// connection end.
    pub fn detach_check(&self, c: &mut Checks) {
        let ok =
            std::fs::write(Path::new(vhci::VHCI).join("detach"), self.port.to_string()).is_ok();
        let gone = ok && self.wait_gone().is_ok();
        c.check(
            "detach: vhci-hcd lets the device go",
            gone,
            format!("port {}", self.port),
        );
    }
}

pub fn kernel_view(c: &mut Checks, a: &Attached) -> Result<(), String> {
    let name = a
        .usb
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let attr = |n: &str| read(&a.usb.join(n));
    c.eq(
        "sysfs: speed (Mbit/s): full speed",
        attr("speed").as_str(),
        "12",
    );
    c.eq("sysfs: USB version", attr("version").as_str(), "2.00");
    c.eq(
        "sysfs: manufacturer (string 1)",
        attr("manufacturer").as_str(),
        "PoLabs",
    );
    c.eq(
        "sysfs: product (string 2)",
        attr("product").as_str(),
        "PoStep60-256",
    );
    let serial = attr("serial");
    let groups: Vec<&str> = serial.split('-').collect();
    c.check(
        "sysfs: serial (string 3) has the manual's 8-8-8-8 shape",
        groups.len() == 4
            && groups.iter().all(|g| {
                g.len() == 8
                    && g.chars()
                        .all(|ch| ch.is_ascii_hexdigit() && !ch.is_ascii_lowercase())
            }),
        &serial,
    );
    c.eq(
        "sysfs: bConfigurationValue",
        attr("bConfigurationValue").as_str(),
        "1",
    );
    c.eq("sysfs: bmAttributes", attr("bmAttributes").as_str(), "c0");
    c.eq("sysfs: bMaxPower", attr("bMaxPower").as_str(), "100mA");
    let d = std::fs::read(a.usb.join("descriptors")).map_err(|e| format!("descriptors: {e}"))?;
    c.eq(
        "descriptors: the device descriptor is the manual's, byte for byte",
        d.get(..18).map(<[u8]>::to_vec),
        Some(MANUAL_DEVICE.to_vec()),
    );
    c.eq(
        "descriptors: the configuration is the manual's 41 bytes, byte for byte",
        d.get(18..).map(<[u8]>::to_vec),
        Some(MANUAL_CONFIG.to_vec()),
    );
    let intf = a.usb.join(format!("{name}:1.0"));
    c.eq(
        "interface string 4 (sysfs interface)",
        read(&intf.join("interface")).as_str(),
        "HID",
    );
    c.eq(
        "usbhid binds the interface",
        link_name(&intf.join("driver")).as_str(),
        "usbhid",
    );
    c.eq(
        "hid-generic binds the HID device",
        link_name(&a.hid.join("driver")).as_str(),
        "hid-generic",
    );
    c.eq(
        "report descriptor as the kernel read it (33 bytes)",
        std::fs::read(a.hid.join("report_descriptor")).ok(),
        Some(REPORT_DESCRIPTOR.to_vec()),
    );
    c.check("a hidraw node", a.hidraw.exists(), a.hidraw.display());
    Ok(())
}
