//! The GRBL emulator against the byte streams a GRBL host sends.

use super::*;
use crate::clock::VirtualClock;
use tokio::io::{AsyncBufReadExt, BufReader, DuplexStream, ReadHalf, WriteHalf};

fn rig(speedup: f64) -> Rig {
    Rig::new(VirtualClock::new(speedup), stepper_stage_axis(25.0), free_rotation_axis())
}

struct Host {
    rd: BufReader<ReadHalf<DuplexStream>>,
    wr: WriteHalf<DuplexStream>,
}

impl Host {
    async fn line(&mut self) -> String {
        let mut l = String::new();
        tokio::time::timeout(Duration::from_secs(5), self.rd.read_line(&mut l))
            .await
            .expect("emulator silent")
            .unwrap();
        l.trim_end().to_string()
    }
    /// Next line that is not a status report or empty.
    async fn reply(&mut self) -> String {
        loop {
            let l = self.line().await;
            if !l.is_empty() && !l.starts_with('<') {
                return l;
            }
        }
    }
    async fn send(&mut self, s: &str) {
        self.wr.write_all(s.as_bytes()).await.unwrap();
    }
    async fn status(&mut self) -> String {
        self.send("?").await;
        loop {
            let l = self.line().await;
            if l.starts_with('<') {
                return l;
            }
        }
    }
}

fn start(cfg: GrblEmulatorConfig, speedup: f64) -> (Host, GrblControl, Rig, JoinHandle<io::Result<GrblEmulatorStats>>) {
    let rig = rig(speedup);
    let (a, b) = tokio::io::duplex(4096);
    let (ctl, rx) = grbl_control();
    let task = tokio::spawn(run_grbl_emulator(b, rig.clone(), cfg, rx));
    let (rd, wr) = tokio::io::split(a);
    (Host { rd: BufReader::new(rd), wr }, ctl, rig, task)
}

fn z_of(status: &str) -> f64 {
    let p = status.split('|').nth(1).unwrap();
    p[5..].split(',').nth(2).unwrap().parse().unwrap()
}

#[tokio::test]
async fn power_up_lock_home_and_move() {
    let (mut h, _ctl, rig, _t) = start(GrblEmulatorConfig::default(), 100.0);
    assert_eq!(h.line().await, "");
    assert_eq!(h.line().await, "Grbl 1.1h ['$' for help]");
    assert_eq!(h.line().await, "[MSG:'$H'|'$X' to unlock]");
    assert!(h.status().await.starts_with("<Alarm|MPos:0.000,0.000,3.000"));
    h.send("G1 Z1 F60\n").await;
    assert_eq!(h.reply().await, "error:9");
    h.send("$H\n").await;
    assert_eq!(h.reply().await, "ok");
    assert!(rig.with_stage(|ax, _| ax.is_homed()));
    let s = h.status().await;
    assert!(s.starts_with("<Idle|MPos:0.000,0.000,0.000"), "{s}");
    h.send("G1 Z2.5\n").await;
    assert_eq!(h.reply().await, "error:22");
    h.send("G90 G1 Z2.5 F120\n").await;
    assert_eq!(h.reply().await, "ok");
    assert!(h.status().await.starts_with("<Run|"));
    loop {
        let s = h.status().await;
        if s.starts_with("<Idle") {
            assert!((z_of(&s) - 2.5).abs() < 1e-3, "{s}");
            break;
        }
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    h.send("G91 G0 Z-0.5\n").await;
    assert_eq!(h.reply().await, "ok");
    h.send("G4 P0.1\n").await;
    assert_eq!(h.reply().await, "ok");
    assert!((z_of(&h.status().await) - 2.0).abs() < 1e-3);
}

#[tokio::test]
async fn soft_limit_alarm_is_critical_until_reset() {
    let cfg = GrblEmulatorConfig { homing_enabled: false, banner_on_start: false, ..Default::default() };
    let (mut h, _ctl, rig, _t) = start(cfg, 100.0);
    h.send("G90 G1 Z30 F60\n").await;
    assert_eq!(h.reply().await, "ALARM:2");
    assert_eq!(h.reply().await, "[MSG:Reset to continue]");
    assert!(!rig.with_stage(|ax, _| ax.is_moving()));
    // Critical: lines and status requests get no answer until a reset.
    h.send("?$X\n").await;
    h.send("\u{18}").await;
    assert_eq!(h.line().await, "");
    assert_eq!(h.line().await, "Grbl 1.1h ['$' for help]");
    assert_eq!(h.line().await, "[MSG:'$H'|'$X' to unlock]");
    h.send("$X\n").await;
    assert_eq!(h.reply().await, "[MSG:Caution: Unlocked]");
    assert_eq!(h.reply().await, "ok");
    assert!((z_of(&h.status().await) - 3.0).abs() < 1e-9);
}

#[tokio::test]
async fn hard_limit_when_soft_limits_off() {
    let cfg =
        GrblEmulatorConfig { homing_enabled: false, soft_limits: false, banner_on_start: false, ..Default::default() };
    let (mut h, _ctl, _rig, _t) = start(cfg, 200.0);
    h.send("G90 G0 Z-1\n").await;
    assert_eq!(h.reply().await, "ok");
    assert_eq!(h.reply().await, "ALARM:1");
}

#[tokio::test]
async fn hold_resume_and_reset_during_motion() {
    let cfg = GrblEmulatorConfig { homing_enabled: false, banner_on_start: false, ..Default::default() };
    let (mut h, _ctl, _rig, _t) = start(cfg, 20.0);
    h.send("G90 G1 Z20 F60\n").await;
    assert_eq!(h.reply().await, "ok");
    h.send("!").await;
    loop {
        let s = h.status().await;
        if s.starts_with("<Hold:0") {
            break;
        }
        assert!(s.starts_with("<Hold:1") || s.starts_with("<Run"), "{s}");
    }
    let held = z_of(&h.status().await);
    assert!(held < 20.0);
    h.send("~").await;
    assert!(h.status().await.starts_with("<Run"));
    // Reset while running: ALARM:3, banner, lock.
    h.send("\u{18}").await;
    assert_eq!(h.reply().await, "ALARM:3");
    assert_eq!(h.reply().await, "Grbl 1.1h ['$' for help]");
    assert_eq!(h.reply().await, "[MSG:'$H'|'$X' to unlock]");
    assert!(h.status().await.starts_with("<Alarm"));
}

#[tokio::test]
async fn rx_buffer_overflow_drops_bytes() {
    let cfg =
        GrblEmulatorConfig { homing_enabled: false, banner_on_start: false, planner_blocks: 1, ..Default::default() };
    let (mut h, ctl, _rig, task) = start(cfg, 1.0);
    // One block runs, the next waits for planner space, the rest pile up in the RX buffer.
    let mut blast = String::new();
    for k in 0..10 {
        blast += &format!("G90 G1 Z{}.0000 F60.0000\n", 10 + k);
    }
    h.send(&blast).await;
    assert_eq!(h.reply().await, "ok");
    tokio::time::sleep(Duration::from_millis(50)).await;
    ctl.cut_cable();
    let stats = task.await.unwrap().unwrap();
    assert_eq!(stats.rx_high_water, 128);
    assert!(stats.rx_overflow_bytes > 0, "{stats:?}");
}

#[tokio::test]
async fn errors_for_bad_lines() {
    let cfg = GrblEmulatorConfig { homing_enabled: false, banner_on_start: false, ..Default::default() };
    let (mut h, _ctl, _rig, _t) = start(cfg, 1.0);
    for (line, want) in [
        ("1G0\n", "error:1"),
        ("G1 Zabc F10\n", "error:2"),
        ("$Q\n", "error:3"),
        ("G0 G1 Z1\n", "error:21"),
        ("G0 Z1 Z2\n", "error:25"),
        ("G1\n", "error:26"),
        ("G4\n", "error:28"),
        ("M3\n", "error:20"),
        ("$J=G91 Z1\n", "error:16"),
        ("$J=G90 Z99 F10\n", "error:15"),
        (&format!("G0 Z1 ({})\n", "x".repeat(90)), "error:11"),
        ("\n", "ok"),
    ] {
        h.send(line).await;
        assert_eq!(h.reply().await, want, "{line}");
    }
    h.send("$I\n").await;
    assert_eq!(h.reply().await, "[VER:1.1h.20190830:]");
    assert_eq!(h.reply().await, "[OPT:V,16,128]");
    assert_eq!(h.reply().await, "ok");
    h.send("$$\n").await;
    assert_eq!(h.reply().await, "$0=10");
}

#[tokio::test]
async fn injected_alarm_and_cut() {
    let cfg = GrblEmulatorConfig { homing_enabled: false, banner_on_start: false, ..Default::default() };
    let (mut h, ctl, _rig, task) = start(cfg, 1.0);
    ctl.inject_alarm(1);
    assert_eq!(h.reply().await, "ALARM:1");
    ctl.cut_cable();
    task.await.unwrap().unwrap();
    let mut rest = String::new();
    h.rd.read_line(&mut rest).await.unwrap();
    // The stream is closed after the pending message.
    let mut more = String::new();
    assert_eq!(h.rd.read_line(&mut more).await.unwrap(), 0);
}

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig::with_cases(64))]
    /// Whatever a client sends, the emulator answers without panicking,
    /// and every complete line gets at most one `ok`/`error:N`.
    #[test]
    fn random_input_never_panics(bytes in proptest::collection::vec(proptest::prelude::any::<u8>(), 0..400)) {
        let cfg = GrblEmulatorConfig { homing_enabled: false, ..Default::default() };
        let mut emu = Emulator::new(rig(1000.0), cfg);
        emu.ingest(&bytes);
        emu.step();
        let out = String::from_utf8(emu.out.clone()).unwrap();
        let acks = out.lines().filter(|l| *l == "ok" || l.starts_with("error:")).count();
        let lines = bytes.iter().filter(|b| matches!(b, b'\n' | b'\r')).count();
        proptest::prop_assert!(acks <= lines, "{acks} answers to {lines} lines");
    }
}
