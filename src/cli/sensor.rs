//! `easycalib sensor watch`: a user's first check that the sensor link works.
//! Per frame it shows gamma1, theta1, the contact radius, the link's frame
//! rate and lost frames — a live line on a terminal, JSON lines otherwise.

use std::future::Future;
use std::io::{IsTerminal, Write};
use std::net::SocketAddr;
use std::time::Duration;

use clap::{Args, Subcommand};
use devices::sensor::link::{LinkConfig, LinkReceiver};
use devices::sensor::tac3d::{Tac3dReceiver, Tac3dReceiverConfig};
use devices::sensor::{SensorError, SensorLink};
use serde::Serialize;

use super::CliError;
use crate::sensing::{SensingConfig, SensingError, measure};

#[derive(Debug, Args)]
pub struct SensorArgs {
    #[command(subcommand)]
    pub command: SensorCommand,
}

#[derive(Debug, Subcommand)]
pub enum SensorCommand {
    /// Show gamma1, theta1, contact radius, frame rate and lost frames live.
    Watch(WatchArgs),
}

#[derive(Debug, Args)]
#[command(group(clap::ArgGroup::new("source").required(true).args(["tac3d", "link"])))]
pub struct WatchArgs {
    /// Receive the Tac3D main program's UDP stream on this local port (it sends to 9988 by default).
    #[arg(long, value_name = "PORT")]
    pub tac3d: Option<u16>,
    /// With --tac3d: the local address to listen on (default 127.0.0.1, this
    /// computer only; 0.0.0.0 hears every interface — docs/hardening.md).
    #[arg(long, value_name = "ADDR", requires = "tac3d")]
    pub bind: Option<std::net::IpAddr>,
    /// easycalib link protocol: a serial device path, or udp://HOST:PORT of the device.
    #[arg(long, value_name = "PATH")]
    pub link: Option<String>,
    /// Baud rate for a serial link.
    #[arg(long, default_value_t = 115_200)]
    pub baud: u32,
    /// JSON lines even on a terminal.
    #[arg(long)]
    pub json: bool,
    /// Give up when no frame arrives for this long, s.
    #[arg(long, default_value_t = 3.0)]
    pub timeout_s: f64,
    /// Stop after this many frames (default: until Ctrl-C).
    #[arg(long)]
    pub count: Option<u64>,
    /// Radius of the indenter pressing the sensor, mm (default: the built-in
    /// script's): inside a wide contact the gel follows its sphere, whose sag
    /// the depth reading takes out (docs/sensing.md).
    #[arg(long, value_name = "MM")]
    pub indenter_r_mm: Option<f64>,
    /// Effective radius R1 of the sensor's elastomer, mm (`inf` for flat;
    /// default: the built-in script's).
    #[arg(long, value_name = "MM")]
    pub r1_mm: Option<f64>,
    /// The sensor's gel layer (`--thickness-mm`, `--base`): frames are read
    /// with the layer's own field (docs/sensing.md, "On a layer"; the
    /// indenter's modulus is the built-in script's, and the gel is taken
    /// halfway between nu1 0.35 and 0.49, as a run starts). Default: a
    /// half-space.
    #[command(flatten)]
    pub layer: super::LayerArgs,
}

impl WatchArgs {
    /// How frames are read: the contact of the indenter and gel given, or of
    /// the built-in script's.
    fn sensing(&self) -> Result<SensingConfig, CliError> {
        let script = crate::run::Script::default();
        let indenter = self.indenter_r_mm.unwrap_or(script.indenter.r_mm);
        let r1 = self.r1_mm.unwrap_or(script.sensor.elastomer_r_mm);
        if !(indenter.is_finite() && indenter > 0.0) {
            return Err(CliError::bad_input(format!("--indenter-r-mm must be a positive radius, got {indenter}")));
        }
        if r1.is_nan() || r1 <= 0.0 {
            return Err(CliError::bad_input(format!("--r1-mm must be a positive radius or inf, got {r1}")));
        }
        let mut sensing = SensingConfig::for_contact(indenter, r1);
        if let Some(layer) = self.layer.layer()? {
            let body = sim::physics::Body { r_mm: indenter, ..script.indenter };
            let surface = crate::sensing::LayerSurface::declared(layer, body).map_err(|e| {
                CliError::bad_input(format!(
                    "--thickness-mm {}: the layer's field cannot be computed ({e})",
                    layer.thickness_mm
                ))
            })?;
            sensing.layer = Some(surface);
        }
        Ok(sensing)
    }
}

/// One printed record.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct WatchLine {
    pub index: u64,
    pub t_s: f64,
    /// "ok", "no_contact" or "error".
    pub status: &'static str,
    pub gamma1_mm: Option<f64>,
    pub theta1_deg: Option<f64>,
    pub contact_radius_mm: Option<f64>,
    pub outliers: Option<usize>,
    pub rate_hz: f64,
    pub dropped: u64,
    pub bad: u64,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
}

impl WatchLine {
    /// The live terminal line.
    pub fn human(&self) -> String {
        let head = match self.status {
            "ok" => format!(
                "gamma1 {:8.4} mm  theta1 {:+8.4} deg  a {:6.3} mm",
                self.gamma1_mm.unwrap_or(0.0),
                self.theta1_deg.unwrap_or(0.0),
                self.contact_radius_mm.unwrap_or(0.0)
            ),
            "no_contact" => format!("{:<52}", "no contact"),
            _ => format!("{:<52}", self.error.as_deref().unwrap_or("error")),
        };
        format!("#{:<8} {head}  {:5.1} frames/s  dropped {}  bad {}", self.index, self.rate_hz, self.dropped, self.bad)
    }
}

/// How a watch ended.
#[derive(Debug, Clone, PartialEq)]
pub struct WatchSummary {
    pub frames: u64,
    pub dropped: u64,
    pub bad: u64,
}

/// Read frames from `link` and write one record per frame to `out` until
/// How a watch reads and shows frames.
#[derive(Debug, Clone)]
pub struct WatchOptions {
    /// How each frame is read (the indenter's and the dome's radii).
    pub sensing: SensingConfig,
    /// One live line on a terminal instead of JSON lines.
    pub live: bool,
    /// Longest wait for a frame.
    pub timeout: Duration,
    /// Stop after this many frames.
    pub count: Option<u64>,
}

/// `stop` resolves, `opts.count` frames were shown, or no frame arrives
/// within `opts.timeout` (an error naming `source`). The link must already
/// be started.
pub async fn watch_link<L, W>(
    link: &mut L,
    out: &mut W,
    opts: &WatchOptions,
    source: &str,
    stop: impl Future<Output = ()>,
) -> Result<WatchSummary, CliError>
where
    L: SensorLink + ?Sized,
    W: Write,
{
    let mut frames = 0u64;
    tokio::pin!(stop);
    loop {
        if opts.count.is_some_and(|c| frames >= c) {
            break;
        }
        let next = tokio::select! {
            _ = &mut stop => break,
            f = link.next_frame(opts.timeout) => f,
        };
        let frame = match next {
            Ok(f) => f,
            Err(SensorError::Timeout { waited }) => {
                if opts.live {
                    let _ = writeln!(out);
                }
                let what = if frames == 0 {
                    format!(
                        "no frame from {source} within {:.1} s: is the sensor streaming to this address/port?",
                        waited.as_secs_f64()
                    )
                } else {
                    format!(
                        "frames from {source} stopped: none for {:.1} s after {frames} frames",
                        waited.as_secs_f64()
                    )
                };
                let stats = link.stats();
                let bad = if stats.bad_total() > 0 {
                    format!(" ({} malformed inputs rejected: {:?})", stats.bad_total(), stats.bad)
                } else {
                    String::new()
                };
                return Err(CliError::other(format!("{what}{bad}")));
            }
            Err(e) => return Err(CliError::other(format!("sensor link {source}: {e}"))),
        };
        frames += 1;
        let stats = link.stats();
        let mut line = WatchLine {
            index: frame.index,
            t_s: frame.t_s,
            status: "ok",
            gamma1_mm: None,
            theta1_deg: None,
            contact_radius_mm: None,
            outliers: None,
            rate_hz: stats.rate_hz,
            dropped: stats.dropped,
            bad: stats.bad_total(),
            error: None,
        };
        match measure(&frame, &opts.sensing) {
            Ok(m) => {
                line.gamma1_mm = Some(m.gamma1_mm);
                line.theta1_deg = Some(m.theta1_deg);
                line.contact_radius_mm = Some(m.contact_radius_mm);
                line.outliers = Some(m.outliers);
            }
            Err(SensingError::NoContact { .. }) => line.status = "no_contact",
            Err(e) => {
                line.status = "error";
                line.error = Some(e.to_string());
            }
        }
        let written = if opts.live {
            write!(out, "\r{}", line.human()).and_then(|_| out.flush())
        } else {
            serde_json::to_string(&line)
                .map_err(std::io::Error::other)
                .and_then(|s| writeln!(out, "{s}"))
                .and_then(|_| out.flush())
        };
        // A closed pipe (e.g. `| head`) ends the watch quietly.
        if written.is_err() {
            break;
        }
    }
    if opts.live {
        let _ = writeln!(out);
    }
    let stats = link.stats();
    Ok(WatchSummary { frames, dropped: stats.dropped, bad: stats.bad_total() })
}

async fn open(args: &WatchArgs) -> Result<(Box<dyn SensorLink>, String), CliError> {
    if let Some(port) = args.tac3d {
        let ip = args.bind.unwrap_or(std::net::IpAddr::from([127, 0, 0, 1]));
        let cfg = Tac3dReceiverConfig { bind: SocketAddr::new(ip, port), ..Tac3dReceiverConfig::default() };
        let rx = Tac3dReceiver::bind(cfg)
            .await
            .map_err(|e| CliError::bad_input(format!("cannot listen for Tac3D frames on UDP port {port}: {e}")))?;
        return Ok((Box::new(rx), format!("Tac3D on udp port {port}")));
    }
    let Some(path) = args.link.as_deref() else {
        return Err(CliError::bad_input("give --tac3d PORT or --link PATH"));
    };
    if let Some(addr) = path.strip_prefix("udp://") {
        let device: SocketAddr =
            addr.parse().map_err(|e| CliError::bad_input(format!("--link udp://{addr}: not HOST:PORT ({e})")))?;
        let bind = if device.ip().is_loopback() {
            SocketAddr::from(([127, 0, 0, 1], 0))
        } else {
            SocketAddr::from(([0, 0, 0, 0], 0))
        };
        let rx = LinkReceiver::udp(bind, device, LinkConfig::default())
            .await
            .map_err(|e| CliError::bad_input(format!("cannot open UDP link to {device}: {e}")))?;
        return Ok((Box::new(rx), format!("link udp://{device}")));
    }
    let rx = LinkReceiver::open_serial(path, args.baud, LinkConfig::default())
        .map_err(|e| CliError::bad_input(format!("cannot open serial link {path}: {e}")))?;
    Ok((Box::new(rx), format!("link {path}")))
}

/// `easycalib sensor ...`
pub fn run(args: &SensorArgs) -> Result<(), CliError> {
    match &args.command {
        SensorCommand::Watch(w) => watch(w),
    }
}

/// Longest wait for a frame, s: an hour (a longer one is a typo, not a wish).
const MAX_TIMEOUT_S: f64 = 3600.0;

fn watch(args: &WatchArgs) -> Result<(), CliError> {
    if !(args.timeout_s > 0.0 && args.timeout_s <= MAX_TIMEOUT_S) {
        return Err(CliError::bad_input(format!(
            "--timeout-s must lie in (0, {MAX_TIMEOUT_S}] s, got {}",
            args.timeout_s
        )));
    }
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .map_err(|e| CliError::other(format!("cannot start the async runtime: {e}")))?;
    let sensing = args.sensing()?;
    rt.block_on(async {
        let (mut link, source) = open(args).await?;
        link.start().await.map_err(|e| CliError::other(format!("cannot start {source}: {e}")))?;
        let live = !args.json && std::io::stdout().is_terminal();
        let mut out = std::io::stdout().lock();
        let stop = async {
            // Without a signal handler, Ctrl-C kills the process as usual.
            if tokio::signal::ctrl_c().await.is_err() {
                std::future::pending::<()>().await;
            }
        };
        let opts = WatchOptions { sensing, live, timeout: Duration::from_secs_f64(args.timeout_s), count: args.count };
        let result = watch_link(link.as_mut(), &mut out, &opts, &source, stop).await;
        // Best effort: the device may already be gone.
        let _ = link.stop().await;
        let summary = result?;
        eprintln!("{}: {} frames, {} dropped, {} malformed", source, summary.frames, summary.dropped, summary.bad);
        Ok(())
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use async_trait::async_trait;
    use devices::sensor::{LinkStats, SensorFrame};
    use sim::rng::Rng;
    use sim::sensor::field::{ContactState, MarkerGrid, NoiseConfig, no_contact_frame, synth_frame};
    use std::collections::VecDeque;

    /// A link that hands out queued frames, then times out.
    struct Queued {
        frames: VecDeque<SensorFrame>,
        delivered: u64,
    }

    #[async_trait]
    impl SensorLink for Queued {
        async fn start(&mut self) -> Result<(), SensorError> {
            Ok(())
        }
        async fn stop(&mut self) -> Result<(), SensorError> {
            Ok(())
        }
        async fn next_frame(&mut self, timeout: Duration) -> Result<SensorFrame, SensorError> {
            let f = self.frames.pop_front().ok_or(SensorError::Timeout { waited: timeout })?;
            self.delivered += 1;
            Ok(f)
        }
        fn discard_queued(&mut self) -> usize {
            0
        }
        async fn tare(&mut self) -> Result<(), SensorError> {
            Ok(())
        }
        fn stats(&self) -> LinkStats {
            LinkStats { frames: self.delivered, rate_hz: 30.0, dropped: 2, ..LinkStats::default() }
        }
    }

    fn frames() -> VecDeque<SensorFrame> {
        let grid = MarkerGrid::tac3d();
        let mut rng = Rng::seed_from(1);
        // The built-in script's indenter on its domed gel, as `watch` reads it by default.
        let state = ContactState::new([0.2, -0.1], 1.5, 3.5, 2f64.to_radians()).with_spheres(5.0, 33.0);
        VecDeque::from(vec![
            no_contact_frame(&grid, 100, 0.0),
            synth_frame(&state, &grid, &NoiseConfig::NONE, &mut rng, 101, 0.033),
        ])
    }

    #[tokio::test]
    async fn json_lines_per_frame_then_a_clear_error_when_frames_stop() {
        let mut link = Queued { frames: frames(), delivered: 0 };
        let mut out = Vec::new();
        let sensing = SensingConfig::for_contact(5.0, 33.0);
        let opts = WatchOptions { sensing, live: false, timeout: Duration::from_millis(50), count: None };
        let r = watch_link(&mut link, &mut out, &opts, "test link", std::future::pending()).await;
        let err = r.unwrap_err();
        assert!(err.message.contains("stopped") && err.message.contains("after 2 frames"), "{}", err.message);
        let text = String::from_utf8(out).unwrap();
        let lines: Vec<serde_json::Value> = text.lines().map(|l| serde_json::from_str(l).unwrap()).collect();
        assert_eq!(lines.len(), 2);
        assert_eq!(lines[0]["status"], "no_contact");
        assert_eq!(lines[0]["gamma1_mm"], serde_json::Value::Null);
        assert_eq!(lines[1]["status"], "ok");
        // Within 0.1 µm with the spheres' sag taken out; read without it the
        // same frame reads 9.6 µm deep (a = 3.5 mm on the 5 mm sphere).
        let g = lines[1]["gamma1_mm"].as_f64().unwrap();
        let unaware = measure(&frames()[1], &SensingConfig::default()).unwrap().gamma1_mm;
        println!("gamma1 {g} mm; without the sag {unaware} mm");
        assert!((g - 1.5).abs() < 1e-4, "{g}");
        assert!((unaware - 1.5).abs() > 0.005, "{unaware}");
        let t = lines[1]["theta1_deg"].as_f64().unwrap();
        assert!((t - 2.0).abs() < 1e-4, "theta1 {t}");
        assert_eq!(lines[1]["dropped"], 2);
        assert_eq!(lines[1]["rate_hz"], 30.0);
    }

    /// `--thickness-mm` (and `--base`): a frame of a bonded 5 mm gel's own field (the
    /// layer's departure from Hertz's shape drawn in, a 1.25 mm contact read
    /// on its own, nothing learnt) reads its depth with the flag, and not
    /// without it; a thickness that is no thickness names the flag.
    #[test]
    fn a_declared_layer_is_read_with_its_own_field() {
        use clap::Parser;
        #[derive(Parser)]
        struct Cli {
            #[command(flatten)]
            watch: WatchArgs,
        }
        let args = |extra: &[&str]| {
            let argv = ["watch", "--tac3d", "9988", "--r1-mm", "inf"].iter().chain(extra).copied();
            Cli::try_parse_from(argv).expect("valid flags").watch.sensing()
        };
        let layered = args(&["--thickness-mm", "5"]).expect("a layer");
        let shape = layered.layer.as_ref().expect("the layer's field").shape.clone();
        let state = ContactState::new([0.3, -0.2], 0.2, 1.25, 0.0).with_spheres(5.0, f64::INFINITY);
        let frame = sim::sensor::field::synth_frame_on(
            &state,
            Some(&shape),
            &MarkerGrid::tac3d(),
            &NoiseConfig::NONE,
            &mut Rng::seed_from(1),
            1,
            0.0,
        );
        let read = measure(&frame, &layered).unwrap().gamma1_mm;
        let as_half_space = measure(&frame, &args(&[]).unwrap()).unwrap().gamma1_mm;
        println!("gamma1 0.2 mm read {read:.5} with the layer, {as_half_space:.5} as a half-space");
        assert!((read - 0.2).abs() < 5e-4, "{read}");
        assert!((as_half_space - 0.2).abs() > 2e-3, "{as_half_space}");
        for bad in ["--thickness-mm=-1", "--thickness-mm=0", "--thickness-mm=nan"] {
            let err = args(&[bad]).unwrap_err();
            assert!(err.message.contains("--thickness-mm"), "{}", err.message);
        }
        // `--base sliding`: the layer on that base, whose contact stiffens
        // less as it widens (gamma1 / a² falls 9 % from 0.5 to 3 mm, a
        // bonded gel's 19 %); another word names the flag.
        let sliding = args(&["--thickness-mm", "5", "--base", "sliding"]).expect("a sliding layer");
        let fall = |c: &SensingConfig| c.layer.as_ref().expect("a layer").drift.ratio(3.0, 0.5);
        assert!(fall(&sliding) < fall(&layered) - 0.05, "sliding {} bonded {}", fall(&sliding), fall(&layered));
        let err = args(&["--thickness-mm", "5", "--base", "glued"]).unwrap_err();
        assert!(err.message.contains("--base glued"), "{}", err.message);
    }

    #[tokio::test]
    async fn nothing_arriving_names_the_source_and_count_stops_cleanly() {
        let mut empty = Queued { frames: VecDeque::new(), delivered: 0 };
        let mut out = Vec::new();
        let quiet = WatchOptions {
            sensing: SensingConfig::default(),
            live: false,
            timeout: Duration::from_millis(10),
            count: None,
        };
        let err = watch_link(&mut empty, &mut out, &quiet, "Tac3D on udp port 9988", async {
            std::future::pending::<()>().await
        })
        .await
        .unwrap_err();
        assert!(err.message.starts_with("no frame from Tac3D on udp port 9988 within"), "{}", err.message);

        let mut link = Queued { frames: frames(), delivered: 0 };
        let mut out = Vec::new();
        let one_live = WatchOptions { live: true, count: Some(1), ..quiet };
        let s = watch_link(&mut link, &mut out, &one_live, "x", std::future::pending()).await.unwrap();
        assert_eq!(s, WatchSummary { frames: 1, dropped: 2, bad: 0 });
        let text = String::from_utf8(out).unwrap();
        assert!(text.starts_with("\r#100") && text.contains("no contact") && text.ends_with('\n'), "{text:?}");
    }
}
