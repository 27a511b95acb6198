//! `easycalib devices` end to end: the real binary lists ports from a fake
//! sysfs/dev tree, and `--probe` identifies the GRBL emulator on a real pty
//! without moving the emulated stage.

use std::fs;
use std::os::unix::fs::symlink;
use std::path::Path;
use std::process::Output;
use std::time::Duration;

use sim::clock::VirtualClock;
use sim::emulator::grbl::{GrblEmulatorConfig, free_rotation_axis, serve_grbl_stage, stepper_stage_axis};
use sim::emulator::rig::Rig;

const BIN: &str = env!("CARGO_BIN_EXE_easycalib");

/// sysfs with one FTDI Thorlabs cube on ttyUSB0 and a udev link to it.
fn fake_tree(root: &Path) {
    let sys = root.join("sys");
    let dev = root.join("dev");
    let usb = sys.join("devices/pci0000:00/usb1/1-2");
    let port = usb.join("1-2:1.0/ttyUSB0");
    fs::create_dir_all(port.join("tty/ttyUSB0")).unwrap();
    for (k, v) in [
        ("idVendor", "0403"),
        ("idProduct", "faf0"),
        ("serial", "27000001"),
        ("product", "Kinesis K-Cube  DC Driver"),
        ("manufacturer", "Thorlabs"),
    ] {
        fs::write(usb.join(k), format!("{v}\n")).unwrap();
    }
    symlink(&port, port.join("tty/ttyUSB0/device")).unwrap();
    fs::create_dir_all(sys.join("class/tty")).unwrap();
    symlink(port.join("tty/ttyUSB0"), sys.join("class/tty/ttyUSB0")).unwrap();
    fs::create_dir_all(&dev).unwrap();
    fs::write(dev.join("ttyUSB0"), "").unwrap();
    symlink("ttyUSB0", dev.join("easycalib-stage")).unwrap();
}

async fn run(root: &Path, extra: &[&str]) -> Output {
    let sys = root.join("sys");
    let dev = root.join("dev");
    let mut cmd = tokio::process::Command::new(BIN);
    cmd.arg("devices").arg("--sysfs-root").arg(&sys).arg("--dev-root").arg(&dev).args(extra);
    tokio::time::timeout(Duration::from_secs(20), cmd.output()).await.expect("easycalib devices hung").unwrap()
}

fn rig() -> Rig {
    Rig::new(VirtualClock::new(50.0), stepper_stage_axis(25.0), free_rotation_axis())
}

#[tokio::test]
async fn lists_usb_ids_serial_product_and_udev_link() {
    let tmp = tempfile::tempdir().unwrap();
    fake_tree(tmp.path());
    let out = run(tmp.path(), &[]).await;
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let text = String::from_utf8(out.stdout).unwrap();
    let dev = tmp.path().join("dev");
    let first = text.lines().next().unwrap();
    assert_eq!(
        first,
        format!(
            "{}  0403:faf0  serial 27000001  \"Kinesis K-Cube  DC Driver\" (Thorlabs)",
            dev.join("ttyUSB0").display()
        )
    );
    assert!(text.contains(&format!("links: {}", dev.join("easycalib-stage").display())), "{text}");
    assert!(text.contains("looks like: Thorlabs KDC101 DC servo K-Cube (APT)"), "{text}");

    let out = run(tmp.path(), &["--json"]).await;
    let doc: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let p = &doc["ports"][0];
    assert_eq!(p["name"], "ttyUSB0");
    assert_eq!(p["usb"]["vid"], 0x0403);
    assert_eq!(p["usb"]["pid"], 0xfaf0);
    assert_eq!(p["usb"]["serial"], "27000001");
    assert_eq!(p["symlinks"][0], dev.join("easycalib-stage").display().to_string());
    assert!(p.get("probe").is_none(), "no probe without --probe");
}

#[tokio::test]
async fn missing_explicit_port_is_bad_input() {
    let tmp = tempfile::tempdir().unwrap();
    fake_tree(tmp.path());
    let out = run(tmp.path(), &["/dev/easycalib-no-such-port"]).await;
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("no such device"));
}

#[tokio::test]
async fn probe_identifies_grbl_emulator_on_a_pty_without_moving_it() {
    let tmp = tempfile::tempdir().unwrap();
    // An empty sysfs: only the pty given on the command line is listed.
    fs::create_dir_all(tmp.path().join("sys/class/tty")).unwrap();
    fs::create_dir_all(tmp.path().join("dev")).unwrap();
    let rig = rig();
    let port = serve_grbl_stage(rig.clone(), GrblEmulatorConfig::default()).await.unwrap();
    let before = rig.pose().stage_mm;
    let path = port.path().display().to_string();
    let out = run(tmp.path(), &["--probe", "--json", "--timeout-ms", "800", &path]).await;
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let doc: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let ports = doc["ports"].as_array().unwrap();
    assert_eq!(ports.len(), 1);
    assert_eq!(ports[0]["path"], path);
    let attempts = ports[0]["probe"].as_array().unwrap();
    // Unknown port: APT is asked first, then GRBL, which answers.
    assert_eq!(attempts[0]["kind"], "apt");
    let last = attempts.last().unwrap();
    assert_eq!(last["kind"], "grbl");
    assert_eq!(last["info"]["model"], "GRBL 1.1h");
    assert_eq!(last["info"]["firmware"], "1.1h.20190830");
    assert!(!rig.with_stage(|ax, _| ax.is_moving()));
    assert_eq!(rig.pose().stage_mm, before);
    port.cut_cable();
    let stats = port.task.await.unwrap().unwrap();
    assert_eq!(stats.alarms, 0, "{stats:?}");
}
