//! Which serial ports are there, what USB device is behind each, which udev
//! symlinks point at it, and (on request) what protocol it speaks.
//!
//! serialport's enumeration needs libudev, which this build does not have
//! (crates.md), so the listing reads sysfs directly: every
//! `<sysfs>/class/tty/<name>` with a `device` link is a real port; the USB
//! device is the first ancestor of that link's target carrying `idVendor`.
//! Both roots are parameters so tests run against a fake tree.
//!
//! Probing never moves anything: each [`Prober`] only asks a port to identify
//! itself, and the probers to try are chosen from the USB ids so that a
//! Thorlabs cube never receives GRBL text and an Arduino never receives APT
//! frames.

use std::fmt;
use std::fs;
use std::future::Future;
use std::io;
use std::path::{Path, PathBuf};
use std::pin::Pin;
use std::sync::Arc;
use std::time::Duration;

use serde::Serialize;

use crate::motion::DeviceInfo;

/// USB identity of the device behind a port (sysfs attributes of the USB device).
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct UsbInfo {
    pub vid: u16,
    pub pid: u16,
    /// `serial` attribute (iSerial string); many CH340 boards have none.
    pub serial: Option<String>,
    pub manufacturer: Option<String>,
    pub product: Option<String>,
    /// `bInterfaceNumber` of the interface the port belongs to.
    pub interface: Option<u8>,
}

impl UsbInfo {
    /// `0403:faf0`.
    pub fn id(&self) -> String {
        format!("{:04x}:{:04x}", self.vid, self.pid)
    }
}

/// One serial port.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct PortInfo {
    /// Kernel name, e.g. `ttyUSB0`.
    pub name: String,
    /// Device node, e.g. `/dev/ttyUSB0`.
    pub path: PathBuf,
    /// Kernel driver bound to the port's device (`ftdi_sio`, `cdc_acm`, `ch341`...).
    pub driver: Option<String>,
    pub usb: Option<UsbInfo>,
    /// Symlinks under the dev root resolving to this node (`/dev/easycalib-stage`,
    /// `/dev/serial/by-id/...`), sorted.
    pub symlinks: Vec<PathBuf>,
    /// What the USB ids suggest, e.g. `Thorlabs KDC101 (APT)`.
    pub hint: Option<String>,
}

/// Protocols a port can be probed for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum ProbeKind {
    Apt,
    Grbl,
}

impl fmt::Display for ProbeKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::Apt => "apt",
            Self::Grbl => "grbl",
        })
    }
}

const THORLABS_APT: (u16, u16) = (0x0403, 0xfaf0);
/// Boards GRBL commonly runs on (docs/hardware.md B.1): Arduino Uno ids, CH340 clones, FTDI FT232.
const GRBL_BOARDS: &[(u16, u16)] = &[
    (0x2341, 0x0043),
    (0x2341, 0x0001),
    (0x2a03, 0x0043),
    (0x2341, 0x0243),
    (0x1a86, 0x7523),
    (0x1a86, 0x7522),
    (0x1a86, 0x5523),
    (0x0403, 0x6001),
];

/// What the USB ids (and for Thorlabs the serial prefix, docs/hardware.md A.7) suggest.
pub fn hint_for(usb: &UsbInfo) -> Option<String> {
    let ids = (usb.vid, usb.pid);
    if ids == THORLABS_APT {
        let prefix = usb.serial.as_deref().and_then(|s| s.get(..2));
        return Some(
            match prefix {
                Some("27") => "Thorlabs KDC101 DC servo K-Cube (APT)",
                Some("55") => "Thorlabs K10CR1/K10CR2 rotation mount (APT)",
                Some("83") => "Thorlabs TDC001 DC servo T-Cube (APT)",
                Some("26") => "Thorlabs KST101 stepper K-Cube (APT)",
                _ => "Thorlabs APT controller",
            }
            .to_string(),
        );
    }
    match ids {
        (0x2341 | 0x2a03, _) if GRBL_BOARDS.contains(&ids) => Some("Arduino Uno (GRBL?)".into()),
        (0x1a86, _) if GRBL_BOARDS.contains(&ids) => Some("CH340 USB-serial (GRBL clone board?)".into()),
        (0x0403, 0x6001) => Some("FTDI FT232 USB-serial (GRBL board?)".into()),
        _ => None,
    }
}

/// Protocols to try on `port`, most likely first. Known ids get only their
/// own protocol; unknown ports (ptys, other bridges) get APT first, because
/// APT frames carry no line feed and so cannot complete a G-code line on a
/// GRBL, whereas GRBL text would desynchronise an APT unit's framing.
pub fn probe_order(port: &PortInfo) -> Vec<ProbeKind> {
    match &port.usb {
        Some(u) if (u.vid, u.pid) == THORLABS_APT => vec![ProbeKind::Apt],
        Some(u) if GRBL_BOARDS.contains(&(u.vid, u.pid)) => vec![ProbeKind::Grbl],
        _ => vec![ProbeKind::Apt, ProbeKind::Grbl],
    }
}

fn read_attr(dir: &Path, name: &str) -> Option<String> {
    let s = fs::read_to_string(dir.join(name)).ok()?;
    let s = s.trim();
    if s.is_empty() { None } else { Some(s.to_string()) }
}

fn read_hex16(dir: &Path, name: &str) -> Option<u16> {
    u16::from_str_radix(&read_attr(dir, name)?, 16).ok()
}

/// USB info from the first ancestor of `dev` (a canonical sysfs path) that
/// has `idVendor`, without walking above `sysfs_root`.
fn usb_info(dev: &Path, sysfs_root: &Path) -> Option<UsbInfo> {
    let mut interface = None;
    for dir in dev.ancestors() {
        if !dir.starts_with(sysfs_root) || dir == sysfs_root {
            break;
        }
        if interface.is_none() {
            interface = read_attr(dir, "bInterfaceNumber").and_then(|s| u8::from_str_radix(&s, 16).ok());
        }
        if let (Some(vid), Some(pid)) = (read_hex16(dir, "idVendor"), read_hex16(dir, "idProduct")) {
            return Some(UsbInfo {
                vid,
                pid,
                serial: read_attr(dir, "serial"),
                manufacturer: read_attr(dir, "manufacturer"),
                product: read_attr(dir, "product"),
                interface,
            });
        }
    }
    None
}

/// Symlinks in `dev_root`, `dev_root/serial/by-id` and `dev_root/serial/by-path`,
/// with the canonical node each resolves to. Dangling links are skipped.
pub fn scan_symlinks(dev_root: &Path) -> Vec<(PathBuf, PathBuf)> {
    let mut out = Vec::new();
    for dir in [dev_root.to_path_buf(), dev_root.join("serial/by-id"), dev_root.join("serial/by-path")] {
        let Ok(entries) = fs::read_dir(&dir) else { continue };
        for e in entries.flatten() {
            let link = e.path();
            let is_link = fs::symlink_metadata(&link).map(|m| m.file_type().is_symlink()).unwrap_or(false);
            if !is_link {
                continue;
            }
            if let Ok(target) = fs::canonicalize(&link) {
                out.push((link, target));
            }
        }
    }
    out.sort();
    out
}

fn links_to(node: &Path, links: &[(PathBuf, PathBuf)]) -> Vec<PathBuf> {
    let Ok(canon) = fs::canonicalize(node) else { return Vec::new() };
    links.iter().filter(|(_, t)| *t == canon).map(|(l, _)| l.clone()).collect()
}

/// Natural order: `ttyACM0 < ttyUSB0 < ttyUSB2 < ttyUSB10`.
fn sort_key(name: &str) -> (String, u64) {
    let split = name.trim_end_matches(|c: char| c.is_ascii_digit()).len();
    (name[..split].to_string(), name[split..].parse().unwrap_or(0))
}

/// List serial ports from `<sysfs_root>/class/tty`, device nodes and symlinks
/// from `dev_root`. Only USB-backed ports unless `include_non_usb` (on-board
/// `ttyS*` ports are listed by the kernel whether or not a UART is fitted).
pub fn list_ports_in(sysfs_root: &Path, dev_root: &Path, include_non_usb: bool) -> io::Result<Vec<PortInfo>> {
    let sysfs_root = fs::canonicalize(sysfs_root)?;
    let class = sysfs_root.join("class/tty");
    let links = scan_symlinks(dev_root);
    let mut ports = Vec::new();
    for e in fs::read_dir(&class)? {
        let e = e?;
        let name = e.file_name().to_string_lossy().into_owned();
        // Virtual terminals, ptmx, console: no `device` link.
        let Ok(dev) = fs::canonicalize(e.path().join("device")) else { continue };
        let driver = fs::read_link(dev.join("driver"))
            .ok()
            .and_then(|d| d.file_name().map(|n| n.to_string_lossy().into_owned()));
        let usb = usb_info(&dev, &sysfs_root);
        if usb.is_none() && !include_non_usb {
            continue;
        }
        let path = dev_root.join(&name);
        let symlinks = links_to(&path, &links);
        let hint = usb.as_ref().and_then(hint_for);
        ports.push(PortInfo { name, path, driver, usb, symlinks, hint });
    }
    ports.sort_by_key(|p| sort_key(&p.name));
    Ok(ports)
}

/// [`list_ports_in`] on the running system (`/sys`, `/dev`).
pub fn list_ports(include_non_usb: bool) -> io::Result<Vec<PortInfo>> {
    list_ports_in(Path::new("/sys"), Path::new("/dev"), include_non_usb)
}

/// A port given by path (an emulator's pty, a symlink): the listed port it
/// resolves to if any, else a bare entry with the symlinks found for it.
pub fn port_for_path(path: &Path, listed: &[PortInfo], dev_root: &Path) -> PortInfo {
    let canon = fs::canonicalize(path).ok();
    if let Some(p) = listed.iter().find(|p| canon.is_some() && fs::canonicalize(&p.path).ok() == canon) {
        return p.clone();
    }
    let links = scan_symlinks(dev_root);
    PortInfo {
        name: path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default(),
        path: path.to_path_buf(),
        driver: None,
        usb: None,
        symlinks: links_to(path, &links),
        hint: None,
    }
}

/// A probe's future: identity on success, a printable reason otherwise.
pub type ProbeFuture = Pin<Box<dyn Future<Output = Result<DeviceInfo, String>> + Send>>;

/// One protocol's "what are you?" question, as a function of (path, timeout).
#[derive(Clone)]
pub struct Prober {
    pub kind: ProbeKind,
    run: Arc<dyn Fn(PathBuf, Duration) -> ProbeFuture + Send + Sync>,
}

impl fmt::Debug for Prober {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Prober").field("kind", &self.kind).finish_non_exhaustive()
    }
}

impl Prober {
    /// Wrap any async `probe(path, timeout) -> Result<DeviceInfo, E>`.
    pub fn new<F, Fut, E>(kind: ProbeKind, probe: F) -> Self
    where
        F: Fn(PathBuf, Duration) -> Fut + Send + Sync + 'static,
        Fut: Future<Output = Result<DeviceInfo, E>> + Send + 'static,
        E: fmt::Display,
    {
        let run = move |path: PathBuf, timeout: Duration| -> ProbeFuture {
            let fut = probe(path, timeout);
            Box::pin(async move { fut.await.map_err(|e| e.to_string()) })
        };
        Self { kind, run: Arc::new(run) }
    }

    /// GRBL: `?` and `$I` only (see [`crate::grbl::probe`]).
    pub fn grbl() -> Self {
        Self::new(ProbeKind::Grbl, |path: PathBuf, timeout| async move { crate::grbl::probe(path, timeout).await })
    }

    pub async fn probe(&self, path: &Path, timeout: Duration) -> Result<DeviceInfo, String> {
        (self.run)(path.to_path_buf(), timeout).await
    }
}

/// The probers `easycalib devices --probe` uses.
pub fn default_probers() -> Vec<Prober> {
    vec![
        Prober::new(ProbeKind::Apt, |path: PathBuf, timeout| async move { crate::apt::probe(path, timeout).await }),
        Prober::grbl(),
    ]
}

/// One probe attempt on one port.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct ProbeAttempt {
    pub kind: ProbeKind,
    pub info: Option<DeviceInfo>,
    pub error: Option<String>,
}

/// Try the probers for `order` in turn on `path`, stopping at the first that
/// identifies the device. A kind with no prober is reported as such.
pub async fn probe_port(path: &Path, order: &[ProbeKind], probers: &[Prober], timeout: Duration) -> Vec<ProbeAttempt> {
    let mut attempts = Vec::new();
    for &kind in order {
        let Some(prober) = probers.iter().find(|p| p.kind == kind) else {
            attempts.push(ProbeAttempt { kind, info: None, error: Some(format!("no {kind} prober in this build")) });
            continue;
        };
        match prober.probe(path, timeout).await {
            Ok(info) => {
                attempts.push(ProbeAttempt { kind, info: Some(info), error: None });
                break;
            }
            Err(e) => attempts.push(ProbeAttempt { kind, info: None, error: Some(e) }),
        }
    }
    attempts
}

/// Probe every port in turn (each with its own [`probe_order`]); results in port order.
/// Sequential on purpose: two probers never hold ports at once, and with
/// short timeouts a handful of ports takes a few seconds at most.
pub async fn probe_all(ports: &[PortInfo], probers: &[Prober], timeout: Duration) -> Vec<Vec<ProbeAttempt>> {
    let mut out = Vec::with_capacity(ports.len());
    for p in ports {
        out.push(probe_port(&p.path, &probe_order(p), probers, timeout).await);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::os::unix::fs::symlink;

    /// A sysfs + dev tree shaped like the kernel's: an FTDI Thorlabs cube on
    /// ttyUSB0 (usb-serial: the tty's device is the port under the interface),
    /// an Arduino on ttyACM0 (cdc_acm: the device is the interface), a CH340
    /// without serial on ttyUSB10, an on-board ttyS0, and a virtual tty0.
    fn fake_tree() -> tempfile::TempDir {
        let root = tempfile::tempdir().unwrap();
        let sys = root.path().join("sys");
        let dev = root.path().join("dev");
        let w = |p: &Path, s: &str| {
            fs::create_dir_all(p.parent().unwrap()).unwrap();
            fs::write(p, format!("{s}\n")).unwrap();
        };
        let usb_dev = |bus: &str, vid: &str, pid: &str, serial: Option<&str>, product: &str, manuf: &str| {
            let d = sys.join("devices/pci0000:00/0000:00:14.0/usb1").join(bus);
            w(&d.join("idVendor"), vid);
            w(&d.join("idProduct"), pid);
            if let Some(s) = serial {
                w(&d.join("serial"), s);
            }
            w(&d.join("product"), product);
            w(&d.join("manufacturer"), manuf);
            w(&d.join(format!("{bus}:1.0/bInterfaceNumber")), "00");
            d
        };
        let drivers = sys.join("bus/usb-serial/drivers");
        for d in ["ftdi_sio", "ch341-uart"] {
            fs::create_dir_all(drivers.join(d)).unwrap();
        }
        fs::create_dir_all(sys.join("bus/usb/drivers/cdc_acm")).unwrap();
        fs::create_dir_all(sys.join("class/tty")).unwrap();
        fs::create_dir_all(&dev).unwrap();

        let tty = |name: &str, device_dir: PathBuf, driver: &Path| {
            let node = device_dir.join("tty").join(name);
            fs::create_dir_all(&node).unwrap();
            symlink(&device_dir, node.join("device")).unwrap();
            let _ = symlink(driver, device_dir.join("driver"));
            symlink(&node, sys.join("class/tty").join(name)).unwrap();
            fs::write(dev.join(name), "").unwrap();
        };
        let ftdi = usb_dev("1-2", "0403", "faf0", Some("27000001"), "Kinesis K-Cube  DC Driver", "Thorlabs");
        tty("ttyUSB0", ftdi.join("1-2:1.0/ttyUSB0"), &drivers.join("ftdi_sio"));
        let uno =
            usb_dev("1-3", "2341", "0043", Some("95735353032351F0E1E1"), "Arduino Uno", "Arduino (www.arduino.cc)");
        tty("ttyACM0", uno.join("1-3:1.0"), &sys.join("bus/usb/drivers/cdc_acm"));
        let ch = usb_dev("1-4", "1a86", "7523", None, "USB2.0-Serial", "QinHeng");
        tty("ttyUSB10", ch.join("1-4:1.0/ttyUSB10"), &drivers.join("ch341-uart"));
        tty("ttyS0", sys.join("devices/pnp0/00:00"), &sys.join("bus/pnp/drivers/serial"));
        // A virtual terminal: no device link.
        fs::create_dir_all(sys.join("devices/virtual/tty/tty0")).unwrap();
        symlink(sys.join("devices/virtual/tty/tty0"), sys.join("class/tty/tty0")).unwrap();

        symlink("ttyUSB0", dev.join("easycalib-stage")).unwrap();
        symlink("ttyACM0", dev.join("easycalib-grbl")).unwrap();
        symlink("missing", dev.join("dangling")).unwrap();
        fs::create_dir_all(dev.join("serial/by-id")).unwrap();
        symlink("../../ttyUSB0", dev.join("serial/by-id/usb-Thorlabs_Kinesis_K-Cube_DC_Driver_27000001-if00-port0"))
            .unwrap();
        symlink("../../ttyACM0", dev.join("serial/by-id/usb-Arduino_Uno_95735353032351F0E1E1-if00")).unwrap();
        root
    }

    #[test]
    fn lists_usb_ports_with_ids_strings_and_symlinks() {
        let root = fake_tree();
        let dev = root.path().join("dev");
        let ports = list_ports_in(&root.path().join("sys"), &dev, false).unwrap();
        let names: Vec<_> = ports.iter().map(|p| p.name.as_str()).collect();
        assert_eq!(names, ["ttyACM0", "ttyUSB0", "ttyUSB10"]);

        let cube = &ports[1];
        assert_eq!(cube.path, dev.join("ttyUSB0"));
        assert_eq!(cube.driver.as_deref(), Some("ftdi_sio"));
        let usb = cube.usb.as_ref().unwrap();
        assert_eq!(usb.id(), "0403:faf0");
        assert_eq!(usb.serial.as_deref(), Some("27000001"));
        assert_eq!(usb.product.as_deref(), Some("Kinesis K-Cube  DC Driver"));
        assert_eq!(usb.manufacturer.as_deref(), Some("Thorlabs"));
        assert_eq!(usb.interface, Some(0));
        assert_eq!(
            cube.symlinks,
            vec![
                dev.join("easycalib-stage"),
                dev.join("serial/by-id/usb-Thorlabs_Kinesis_K-Cube_DC_Driver_27000001-if00-port0")
            ]
        );
        assert_eq!(cube.hint.as_deref(), Some("Thorlabs KDC101 DC servo K-Cube (APT)"));
        assert_eq!(probe_order(cube), vec![ProbeKind::Apt]);

        let uno = &ports[0];
        assert_eq!(uno.usb.as_ref().unwrap().id(), "2341:0043");
        assert_eq!(uno.driver.as_deref(), Some("cdc_acm"));
        assert_eq!(uno.symlinks.len(), 2);
        assert!(uno.symlinks.contains(&dev.join("easycalib-grbl")));
        assert_eq!(probe_order(uno), vec![ProbeKind::Grbl]);

        let ch = &ports[2];
        assert_eq!(ch.usb.as_ref().unwrap().serial, None);
        assert!(ch.symlinks.is_empty());
        assert_eq!(ch.hint.as_deref(), Some("CH340 USB-serial (GRBL clone board?)"));

        let all = list_ports_in(&root.path().join("sys"), &dev, true).unwrap();
        let names: Vec<_> = all.iter().map(|p| p.name.as_str()).collect();
        assert_eq!(names, ["ttyACM0", "ttyS0", "ttyUSB0", "ttyUSB10"]);
        assert_eq!(all[1].usb, None);
        assert_eq!(probe_order(&all[1]), vec![ProbeKind::Apt, ProbeKind::Grbl]);
    }

    #[test]
    fn missing_sysfs_is_an_error_and_explicit_paths_resolve() {
        let root = fake_tree();
        let dev = root.path().join("dev");
        assert!(list_ports_in(&root.path().join("nope"), &dev, false).is_err());
        let ports = list_ports_in(&root.path().join("sys"), &dev, false).unwrap();
        // Through the udev name: the listed port, with its USB info.
        let p = port_for_path(&dev.join("easycalib-stage"), &ports, &dev);
        assert_eq!(p.name, "ttyUSB0");
        assert!(p.usb.is_some());
        // Not in sysfs (an emulator's pty): a bare entry.
        let pty = root.path().join("pts7");
        fs::write(&pty, "").unwrap();
        let p = port_for_path(&pty, &ports, &dev);
        assert_eq!(p.name, "pts7");
        assert_eq!(p.usb, None);
        assert_eq!(probe_order(&p), vec![ProbeKind::Apt, ProbeKind::Grbl]);
    }

    #[test]
    fn thorlabs_serial_prefix_names_the_model() {
        let mk = |serial: &str| UsbInfo {
            vid: 0x0403,
            pid: 0xfaf0,
            serial: Some(serial.into()),
            manufacturer: None,
            product: None,
            interface: None,
        };
        assert_eq!(hint_for(&mk("55000001")).unwrap(), "Thorlabs K10CR1/K10CR2 rotation mount (APT)");
        assert_eq!(hint_for(&mk("9")).unwrap(), "Thorlabs APT controller");
        let other = UsbInfo { vid: 0x1234, pid: 0x5678, ..mk("1") };
        assert_eq!(hint_for(&other), None);
    }

    #[tokio::test]
    async fn probing_stops_at_the_first_success_and_reports_missing_probers() {
        let found = DeviceInfo { model: "X".into(), serial: "1".into(), firmware: "f".into() };
        let f2 = found.clone();
        let probers = vec![
            Prober::new(ProbeKind::Apt, |_p, _t| async { Err::<DeviceInfo, _>("no answer") }),
            Prober::new(ProbeKind::Grbl, move |_p, _t| {
                let f = f2.clone();
                async move { Ok::<_, String>(f) }
            }),
        ];
        let path = Path::new("/nonexistent");
        let t = Duration::from_millis(10);
        let a = probe_port(path, &[ProbeKind::Apt, ProbeKind::Grbl], &probers, t).await;
        assert_eq!(a.len(), 2);
        assert_eq!(a[0].error.as_deref(), Some("no answer"));
        assert_eq!(a[1].info.as_ref(), Some(&found));
        let a = probe_port(path, &[ProbeKind::Grbl, ProbeKind::Apt], &probers, t).await;
        assert_eq!(a.len(), 1, "APT must not be tried after GRBL answered");
        let a = probe_port(path, &[ProbeKind::Apt], &probers[1..], t).await;
        assert_eq!(a[0].error.as_deref(), Some("no apt prober in this build"));
        // The real GRBL prober on a path that does not exist: an error, not a panic.
        let a = probe_port(path, &[ProbeKind::Grbl], &default_probers(), t).await;
        assert!(a[0].info.is_none() && a[0].error.is_some());
    }
}
