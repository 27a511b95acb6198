//! End to end on loopback (127.0.0.1 only) and a pseudo-terminal: a sender
//! task (the emulated device side, `sim::emulator`) streams frames, the receiver is used only through `SensorLink`
//! (start, next_frame, tare, stop, stats); dropouts give `Timeout`, bad input
//! is counted by reason, and the link keeps going.

use std::net::SocketAddr;
use std::time::{Duration, Instant};

use devices::sensor::link::{
    LinkCommand, LinkConfig, LinkMessage, LinkReceiver, encode, encode_raw, encode_raw_version, kind,
};
use devices::sensor::tac3d::{
    Tac3dCommand, Tac3dFrame, Tac3dItem, Tac3dReceiver, Tac3dReceiverConfig, Tac3dValue, encode_frame,
};
use devices::sensor::{BadReason, SensorError, SensorFrame, SensorLink};
use sim::emulator::sensor_link::LinkDevice;
use sim::emulator::tac3d::{Tac3dSender, Tac3dSenderConfig};
use tokio::net::UdpSocket;
use tokio::sync::watch;

const LOOPBACK: &str = "127.0.0.1:0";
/// Generous real-time bound for one frame to arrive (frames come every 2 ms).
const WAIT: Duration = Duration::from_secs(2);
/// Short wait used to observe a dropout.
const SILENCE: Duration = Duration::from_millis(30);

fn lo() -> SocketAddr {
    LOOPBACK.parse().unwrap()
}

/// The emulated sensor: a 20 x 20 grid at 1 mm pitch, held pressed so every
/// marker reads dz = -0.2 mm until a tare makes the held press the new zero.
#[derive(Debug)]
struct Emulated {
    index: u64,
    zero_dz: f64,
}

impl Emulated {
    fn new(index: u64) -> Self {
        Self { index, zero_dz: 0.0 }
    }

    fn frame(&self) -> SensorFrame {
        let positions = (0..400).map(|i| [(i % 20) as f64 - 9.5, (i / 20) as f64 - 9.5, 0.0]).collect();
        let dz = -0.2 - self.zero_dz;
        SensorFrame {
            index: self.index,
            // Sensor time follows the counter: exactly 30 frames/s.
            t_s: self.index as f64 / 30.0,
            positions,
            displacements: vec![[0.0, 0.0, dz]; 400],
        }
    }

    fn tare(&mut self) {
        self.zero_dz = -0.2;
    }

    /// The next frame.
    fn advance(&mut self) {
        self.index += 1;
    }

    /// `n` frames are produced but lost on the way.
    fn lose(&mut self, n: u64) {
        self.index += n;
    }
}

/// What a test tells its sender task.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Mode {
    Stream,
    /// Silent, as if the cable were pulled (the counter does not advance).
    Pause,
    /// Lose `n` frames once, then stream.
    Gap(u64),
    Quit,
}

/// Wait for a frame whose displacements are all zero (after a tare), reading
/// at most `limit` frames; returns it.
async fn first_zeroed(link: &mut dyn SensorLink, limit: usize, held: f64) -> SensorFrame {
    for _ in 0..limit {
        let f = link.next_frame(WAIT).await.expect("frame after tare");
        if f.displacements.iter().all(|d| *d == [0.0, 0.0, 0.0]) {
            return f;
        }
        assert!(f.displacements.iter().all(|d| *d == [0.0, 0.0, held]), "{:?}", &f.displacements[..2]);
    }
    panic!("no zeroed frame within {limit} frames after tare");
}

/// Read frames until the link stays silent for SILENCE (bounded).
async fn drain_until_silent(link: &mut dyn SensorLink) -> SensorError {
    for _ in 0..10_000 {
        match link.next_frame(SILENCE).await {
            Ok(_) => continue,
            Err(e) => return e,
        }
    }
    panic!("link never went silent");
}

/// Wait (bounded, polling) until `cond` holds on the link's stats.
async fn until_stats(link: &dyn SensorLink, what: &str, cond: impl Fn(&devices::sensor::LinkStats) -> bool) {
    let deadline = Instant::now() + WAIT;
    while !cond(&link.stats()) {
        assert!(Instant::now() < deadline, "{what}: {:?}", link.stats());
        tokio::time::sleep(Duration::from_millis(2)).await;
    }
}

async fn tac3d_sensor(mut tx: Tac3dSender, mut mode: watch::Receiver<Mode>) -> u64 {
    let mut s = Emulated::new(5000);
    let mut tick = tokio::time::interval(Duration::from_millis(2));
    // No catch-up bursts after a busy moment: a steady stream, like a camera.
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let mut sent = 0;
    let mut gap_taken = false;
    loop {
        // Mark the mode seen, so `changed()` fires only for the next change.
        let m = *mode.borrow_and_update();
        tokio::select! {
            c = tx.recv_command() => match c.expect("command") {
                Tac3dCommand::Calibrate => s.tare(),
                Tac3dCommand::Quit => return sent,
            },
            _ = tick.tick(), if m != Mode::Pause => {
                if let Mode::Gap(n) = m && !gap_taken {
                    s.lose(n);
                    gap_taken = true;
                }
                tx.send(&s.frame()).await.expect("send");
                sent += 1;
                s.advance();
            },
            r = mode.changed() => {
                if r.is_err() || *mode.borrow() == Mode::Quit {
                    return sent;
                }
                gap_taken = false;
            }
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn tac3d_stream_over_loopback() {
    let cfg = Tac3dReceiverConfig {
        bind: lo(),
        reassembly_timeout: Duration::from_millis(100),
        queue_capacity: 1024,
        serial_filter: None,
        source: None,
    };
    let mut rx = Tac3dReceiver::bind(cfg).await.unwrap();
    let link: &mut dyn SensorLink = &mut rx;
    assert!(matches!(link.next_frame(SILENCE).await, Err(SensorError::NotStreaming)));
    // No frame yet: the sensor's address is unknown, so a tare cannot be sent.
    assert!(matches!(link.tare().await, Err(SensorError::NoPeer { .. })));

    let to = rx.local_addr().unwrap();
    let tx =
        Tac3dSender::bind(lo(), to, Tac3dSenderConfig { sn: "AD2-0065L".into(), max_datagram: 1472 }).await.unwrap();
    let (mode_tx, mode_rx) = watch::channel(Mode::Stream);
    let sensor = tokio::spawn(tac3d_sensor(tx, mode_rx));
    let link: &mut dyn SensorLink = &mut rx;

    link.start().await.unwrap();
    let f = link.next_frame(WAIT).await.unwrap();
    assert_eq!(f.marker_count(), 400);
    assert_eq!(f.positions[21], [-8.5, -8.5, 0.0]);
    assert!(f.displacements.iter().all(|d| *d == [0.0, 0.0, -0.2]));
    assert_eq!(rx.sensor_serial().as_deref(), Some("AD2-0065L"));

    // Consecutive frames, then a gap of 3 lost frames.
    let link: &mut dyn SensorLink = &mut rx;
    let a = link.next_frame(WAIT).await.unwrap();
    let b = link.next_frame(WAIT).await.unwrap();
    assert!(b.index > a.index);
    let dropped_before = link.stats().dropped;
    mode_tx.send(Mode::Gap(3)).unwrap();
    until_stats(link, "gap counted", |s| s.dropped >= dropped_before + 3).await;
    mode_tx.send(Mode::Stream).unwrap();

    // Tare: `$C` goes back to the sender, whose next frames read zero.
    link.tare().await.unwrap();
    first_zeroed(link, 2000, -0.2).await;

    // Garbage from another socket: every kind is counted, none ends the link.
    let junk = UdpSocket::bind(lo()).await.unwrap();
    junk.send_to(b"hello", to).await.unwrap(); // shorter than the header
    let mut nan = Emulated::new(1).frame();
    nan.displacements[7][2] = f64::NAN;
    for p in encode_frame(&Tac3dFrame::from_sensor_frame(&nan, "X"), 60_000).unwrap() {
        junk.send_to(&p, to).await.unwrap();
    }
    let mut init = Tac3dFrame::from_sensor_frame(&Emulated::new(2).frame(), "X");
    init.items.push(Tac3dItem { name: "InitializeProgress".into(), value: Tac3dValue::I32(40) });
    for p in encode_frame(&init, 60_000).unwrap() {
        junk.send_to(&p, to).await.unwrap();
    }
    let mut bad_yaml = vec![9, 0, 0, 0, 0, 0, 0, 0];
    bad_yaml.extend_from_slice(b"index: [1, 2\n");
    junk.send_to(&bad_yaml, to).await.unwrap();
    junk.send_to(&[10, 0, 0, 0, 1, 0, 2, 0], to).await.unwrap(); // packet 2 of 0..=1
    junk.send_to(&[11, 0, 0, 0, 3, 0, 0, 0, b'x'], to).await.unwrap(); // never completed
    let link: &mut dyn SensorLink = &mut rx;
    until_stats(link, "every bad datagram counted", |s| {
        [
            BadReason::ShortDatagram,
            BadReason::NotFinite,
            BadReason::Initializing,
            BadReason::Yaml,
            BadReason::PacketIndex,
            BadReason::Incomplete,
        ]
        .iter()
        .all(|r| s.bad_count(*r) == 1)
    })
    .await;
    // Still streaming good frames from the sensor.
    let g = link.next_frame(WAIT).await.unwrap();
    assert_eq!(g.marker_count(), 400);

    // Dropout: the sender goes silent, next_frame times out, the link survives.
    mode_tx.send(Mode::Pause).unwrap();
    let e = drain_until_silent(link).await;
    assert!(matches!(e, SensorError::Timeout { waited } if waited == SILENCE), "{e}");
    mode_tx.send(Mode::Stream).unwrap();
    let mut last = link.next_frame(WAIT).await.unwrap();
    // 40 more frames: the rate window (32 frames) then spans no gap.
    for _ in 0..40 {
        let f = link.next_frame(WAIT).await.unwrap();
        assert!(f.index > last.index);
        last = f;
    }
    let s = link.stats();
    assert!((s.rate_hz - 30.0).abs() < 1e-6, "sensor-time rate {}", s.rate_hz);
    // The injected gap; a loaded machine may also lose a datagram on loopback.
    assert!(s.dropped >= 3, "{s:?}");
    assert_eq!(s.bad_total(), 6, "{s:?}");

    link.stop().await.unwrap();
    assert!(matches!(link.next_frame(SILENCE).await, Err(SensorError::NotStreaming)));
    rx.quit_sensor().await.unwrap();
    let sent = tokio::time::timeout(WAIT, sensor).await.expect("sender quits on $Q").unwrap();
    assert!(sent as u64 >= rx.stats().frames);
}

/// A link-protocol device: streams between START and STOP, tares on TARE,
/// acks every command; the test can inject a gap, garbage and a corrupt frame.
async fn link_device(mut dev: LinkDevice, mut mode: watch::Receiver<Mode>) -> u64 {
    let mut s = Emulated::new(70);
    let mut streaming = false;
    let mut tick = tokio::time::interval(Duration::from_millis(2));
    // No catch-up bursts after a busy moment: a steady stream, like a camera.
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let mut sent = 0u64;
    let mut gap_taken = false;
    loop {
        // Mark the mode seen, so `changed()` fires only for the next change.
        let m = *mode.borrow_and_update();
        tokio::select! {
            c = dev.next_command() => {
                let c = match c {
                    Ok(c) => c,
                    Err(_) => return sent,
                };
                match c {
                    LinkCommand::Start => streaming = true,
                    LinkCommand::Stop => streaming = false,
                    LinkCommand::Tare => s.tare(),
                }
                dev.ack(c).await.expect("ack");
            }
            _ = tick.tick(), if streaming && m != Mode::Pause => {
                if let Mode::Gap(n) = m && !gap_taken {
                    // A gap arrives with some noise around it.
                    gap_taken = true;
                    s.lose(n);
                    dev.send_raw(b"\x00\xff noise \xec").await.unwrap();
                    let mut bad = encode(&LinkMessage::Frame(s.frame())).unwrap();
                    bad[100] ^= 0x01;
                    dev.send_raw(&bad).await.unwrap();
                    let payload = encode(&LinkMessage::Frame(s.frame())).unwrap();
                    let payload = &payload[12..payload.len() - 4];
                    dev.send_raw(&encode_raw_version(2, kind::FRAME, payload).unwrap()).await.unwrap();
                    dev.send_raw(&encode_raw(0x66, b"").unwrap()).await.unwrap();
                    let nan_payload = {
                        let mut p = payload.to_vec();
                        p[20 + 12 * 400 + 36..20 + 12 * 400 + 40].copy_from_slice(&f32::NAN.to_le_bytes());
                        p
                    };
                    dev.send_raw(&encode_raw(kind::FRAME, &nan_payload).unwrap()).await.unwrap();
                    dev.send_raw(&encode_raw(kind::FRAME, &payload[..payload.len() - 24]).unwrap()).await.unwrap();
                }
                dev.send_frame(&s.frame()).await.unwrap();
                sent += 1;
                s.advance();
            }
            r = mode.changed() => {
                if r.is_err() || *mode.borrow() == Mode::Quit {
                    return sent;
                }
                gap_taken = false;
            }
        }
    }
}

/// `lossless`: a byte stream loses nothing, so the dropped count is exact;
/// UDP may lose a datagram when the machine is loaded.
async fn exercise_link(rx: &mut LinkReceiver, mode_tx: &watch::Sender<Mode>, garbage: &[BadReason], lossless: bool) {
    let link: &mut dyn SensorLink = rx;
    assert!(matches!(link.next_frame(SILENCE).await, Err(SensorError::NotStreaming)));
    link.start().await.unwrap();
    let f = link.next_frame(WAIT).await.unwrap();
    assert_eq!(f.marker_count(), 400);
    assert_eq!(f.positions[399], [9.5, 9.5, 0.0]);
    assert!(f.displacements.iter().all(|d| *d == [0.0, 0.0, -0.2f32 as f64]));

    // A gap of 4 frames with every kind of malformed message around it.
    let before = link.stats().dropped;
    mode_tx.send(Mode::Gap(4)).unwrap();
    until_stats(link, "gap and bad messages counted", |s| {
        s.dropped >= before + 4 && garbage.iter().all(|r| s.bad_count(*r) >= 1)
    })
    .await;
    mode_tx.send(Mode::Stream).unwrap();
    let g = link.next_frame(WAIT).await.unwrap();
    assert_eq!(g.marker_count(), 400);

    // Tare is acknowledged after the device re-zeroed, so frames read zero soon.
    link.tare().await.unwrap();
    let z = first_zeroed(link, 2000, f64::from(-0.2f32)).await;
    assert!(z.index > g.index);

    // Dropout: silence gives Timeout, then the stream resumes.
    mode_tx.send(Mode::Pause).unwrap();
    let e = drain_until_silent(link).await;
    assert!(matches!(e, SensorError::Timeout { .. }), "{e}");
    mode_tx.send(Mode::Stream).unwrap();
    for _ in 0..40 {
        link.next_frame(WAIT).await.unwrap();
    }
    let s = link.stats();
    assert!((s.rate_hz - 30.0).abs() < 1e-6, "sensor-time rate {}", s.rate_hz);
    if lossless {
        assert_eq!(s.dropped, 4, "{s:?}");
        assert_eq!(s.bad_total(), garbage.len() as u64, "{s:?}");
    } else {
        assert!(s.dropped >= 4, "{s:?}");
    }
    assert!(s.frames >= 42);

    // STOP is acknowledged; afterwards no frames are delivered.
    link.stop().await.unwrap();
    assert!(matches!(link.next_frame(SILENCE).await, Err(SensorError::NotStreaming)));
}

const LINK_BAD: [BadReason; 6] = [
    BadReason::Garbage,
    BadReason::Checksum,
    BadReason::Version,
    BadReason::UnknownKind,
    BadReason::NotFinite,
    BadReason::Length,
];

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn link_protocol_over_a_pseudo_terminal() {
    let (host, device) = tokio_serial::SerialStream::pair().expect("pty pair");
    let mut rx = LinkReceiver::new(host, LinkConfig { queue_capacity: 1024, ..LinkConfig::default() });
    let (mode_tx, mode_rx) = watch::channel(Mode::Stream);
    let dev = tokio::spawn(link_device(LinkDevice::new(device), mode_rx));
    exercise_link(&mut rx, &mode_tx, &LINK_BAD, true).await;
    mode_tx.send(Mode::Quit).unwrap();
    let sent = tokio::time::timeout(WAIT, dev).await.unwrap().unwrap();
    assert!(sent >= rx.stats().frames);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn link_protocol_over_udp() {
    let dev = LinkDevice::udp(lo(), None).await.unwrap();
    let dev_addr = dev.local_addr().unwrap();
    let mut rx =
        LinkReceiver::udp(lo(), dev_addr, LinkConfig { queue_capacity: 1024, ..LinkConfig::default() }).await.unwrap();
    let (mode_tx, mode_rx) = watch::channel(Mode::Stream);
    let task = tokio::spawn(link_device(dev, mode_rx));
    // Over UDP the noise datagram, too short for a message, is a length error
    // like the cut-short frame.
    exercise_link(&mut rx, &mode_tx, &LINK_BAD[1..], false).await;
    assert_eq!(rx.stats().bad_count(BadReason::Length), 2);
    mode_tx.send(Mode::Quit).unwrap();
    tokio::time::timeout(WAIT, task).await.unwrap().unwrap();
}

#[tokio::test]
async fn a_silent_device_gives_no_ack_after_the_retries() {
    let (host, _device) = tokio::io::duplex(4096);
    let cfg = LinkConfig { queue_capacity: 4, ack_timeout: Duration::from_millis(10), attempts: 2 };
    let mut rx = LinkReceiver::new(host, cfg);
    let e = rx.start().await.unwrap_err();
    assert!(matches!(e, SensorError::NoAck { command: "START", .. }), "{e}");
    // A failed start leaves the link stopped.
    assert!(matches!(rx.next_frame(SILENCE).await, Err(SensorError::NotStreaming)));
}

#[tokio::test]
async fn the_device_going_away_closes_the_link() {
    let (host, device) = tokio::io::duplex(4096);
    let mut rx = LinkReceiver::new(host, LinkConfig::default());
    let mut dev = LinkDevice::new(device);
    let (r, c) = tokio::join!(rx.start(), async {
        let c = dev.next_command().await.unwrap();
        dev.ack(c).await.unwrap();
        c
    });
    r.unwrap();
    assert_eq!(c, LinkCommand::Start);
    drop(dev);
    let e = rx.next_frame(WAIT).await.unwrap_err();
    assert!(matches!(e, SensorError::Closed { .. }), "{e}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn link_receiver_opens_a_serial_device_by_path() {
    use tokio_serial::SerialPort;
    // A pty stands in for the USB serial port: the device holds the master,
    // the host opens the slave by its path as it would /dev/ttyACM0. The
    // pair's own slave handle holds an exclusive lock (as our open does), so
    // it is closed first; nothing is read from the master until we reopen.
    let (device, slave) = tokio_serial::SerialStream::pair().expect("pty pair");
    let path = slave.name().expect("pty slave path");
    drop(slave);
    let mut rx = LinkReceiver::open_serial(&path, 921_600, LinkConfig::default()).unwrap();
    let mut dev = LinkDevice::new(device);
    let sent = Emulated::new(9).frame();
    let (r, ()) = tokio::join!(rx.start(), async {
        assert_eq!(dev.next_command().await.unwrap(), LinkCommand::Start);
        dev.ack(LinkCommand::Start).await.unwrap();
        dev.send_frame(&sent).await.unwrap();
    });
    r.unwrap();
    let f = rx.next_frame(WAIT).await.unwrap();
    assert_eq!((f.index, f.marker_count()), (9, 400));
    assert_eq!(f.displacements[0], [0.0, 0.0, f64::from(-0.2f32)]);
}

/// A second run on the same rig opens the sensor's port right after the first
/// run let it go; the port is held exclusively, so the first link must really
/// have closed it. `close` waits for the receive task (which owns the read
/// half); the reopen is immediate, with no yield to the runtime in between.
#[tokio::test(flavor = "current_thread")]
async fn a_closed_link_frees_its_serial_port_at_once() {
    use tokio_serial::SerialPort;
    let (_device, slave) = tokio_serial::SerialStream::pair().expect("pty pair");
    let path = slave.name().expect("pty slave path");
    drop(slave);
    for round in 0..5 {
        let mut rx = LinkReceiver::open_serial(&path, 921_600, LinkConfig::default())
            .unwrap_or_else(|e| panic!("open #{round} of {path}: {e}"));
        // Let the receive task start reading, as it does during a run.
        tokio::task::yield_now().await;
        rx.close().await;
        drop(rx);
    }
}

/// Issue 11's reproducer: one 24 KB datagram of 12,000 nested brackets used to
/// overflow the stack of the receive task. Now it is a bad frame, counted, and
/// the link keeps delivering the sensor's frames.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_deeply_nested_header_is_a_bad_frame_not_a_crash() {
    let cfg = Tac3dReceiverConfig { bind: lo(), reassembly_timeout: Duration::from_millis(100), ..Default::default() };
    let mut rx = Tac3dReceiver::bind(cfg).await.unwrap();
    let to = rx.local_addr().unwrap();
    let sock = tokio::net::UdpSocket::bind(lo()).await.unwrap();
    let d = 12_000;
    let mut dgram = Vec::new();
    dgram.extend_from_slice(&5u32.to_le_bytes());
    dgram.extend_from_slice(&0u16.to_le_bytes());
    dgram.extend_from_slice(&0u16.to_le_bytes());
    dgram.extend_from_slice(b"index: 1\nSN: x\ntimestamp: 0.5\ndata: ");
    dgram.extend(std::iter::repeat_n(b'[', d));
    dgram.extend(std::iter::repeat_n(b']', d));
    dgram.push(b'\n');
    sock.send_to(&dgram, to).await.unwrap();
    // A good frame after it still arrives.
    let link: &mut dyn SensorLink = &mut rx;
    link.start().await.unwrap();
    let good = Tac3dFrame::from_sensor_frame(&Emulated::new(1).frame(), "SN-OK");
    for d in encode_frame(&good, 1400).unwrap() {
        sock.send_to(&d, to).await.unwrap();
    }
    let f = link.next_frame(Duration::from_secs(5)).await.unwrap();
    assert_eq!(f.index, 1);
    let stats = link.stats();
    assert!(stats.bad_total() >= 1, "{stats:?}");
}

/// Only the configured sensor address is heard; other senders are counted.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn datagrams_from_another_address_are_dropped_and_counted() {
    let cfg = Tac3dReceiverConfig {
        bind: lo(),
        reassembly_timeout: Duration::from_millis(100),
        source: Some("127.0.0.2".parse().unwrap()),
        ..Default::default()
    };
    let mut rx = Tac3dReceiver::bind(cfg).await.unwrap();
    let to = rx.local_addr().unwrap();
    let stranger = tokio::net::UdpSocket::bind(lo()).await.unwrap();
    let good = Tac3dFrame::from_sensor_frame(&Emulated::new(1).frame(), "SN-OK");
    let link: &mut dyn SensorLink = &mut rx;
    link.start().await.unwrap();
    for d in encode_frame(&good, 1400).unwrap() {
        stranger.send_to(&d, to).await.unwrap();
    }
    assert!(link.next_frame(Duration::from_millis(300)).await.is_err());
    assert!(link.stats().bad_total() >= 1);
    // The configured address is heard.
    let sensor = tokio::net::UdpSocket::bind("127.0.0.2:0").await.unwrap();
    for d in encode_frame(&good, 1400).unwrap() {
        sensor.send_to(&d, to).await.unwrap();
    }
    assert_eq!(link.next_frame(Duration::from_secs(5)).await.unwrap().index, 1);
}

#[test]
fn the_default_receiver_listens_on_loopback_only() {
    assert!(Tac3dReceiverConfig::default().bind.ip().is_loopback());
}
