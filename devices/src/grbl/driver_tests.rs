//! Byte-exact transaction scripts over an in-memory duplex pipe.
use super::*;
use tokio::io::{AsyncBufReadExt, BufReader, DuplexStream};

fn cfg() -> GrblConfig {
    GrblConfig {
        reply_timeout: Duration::from_millis(500),
        banner_timeout: Duration::from_millis(500),
        poll_interval: Duration::from_millis(1),
        ..GrblConfig::default()
    }
}

/// Read exactly `n` bytes the driver wrote.
async fn expect(dev: &mut DuplexStream, want: &[u8]) {
    let mut got = vec![0u8; want.len()];
    dev.read_exact(&mut got).await.unwrap();
    assert_eq!(String::from_utf8_lossy(&got), String::from_utf8_lossy(want));
}

async fn connected() -> (GrblStage<DuplexStream>, DuplexStream) {
    let (host, mut dev) = tokio::io::duplex(4096);
    let script = async move {
        expect(&mut dev, &[0x18]).await;
        dev.write_all(b"\r\nGrbl 1.1h ['$' for help]\r\n").await.unwrap();
        expect(&mut dev, b"?").await;
        dev.write_all(b"<Idle|MPos:0.000,0.000,1.000|FS:0,0|WCO:0.000,0.000,0.000>\r\n").await.unwrap();
        dev
    };
    let (stage, dev) = tokio::join!(GrblStage::connect(host, cfg()), script);
    (stage.unwrap(), dev)
}

#[tokio::test]
async fn connect_resets_and_reads_banner() {
    let (stage, _dev) = connected().await;
    assert_eq!(stage.version(), Some("1.1h"));
    assert_eq!(stage.alarm(), None);
}

#[tokio::test]
async fn rejected_line_is_device_reported_with_meaning() {
    let (mut stage, mut dev) = connected().await;
    let script = async move {
        expect(&mut dev, b"G90 G1 Z2.0000 F60.0000\n").await;
        dev.write_all(b"error:22\r\n").await.unwrap();
        dev
    };
    let (r, _dev) = tokio::join!(stage.start_move_to(Mm(2.0)), script);
    let e = r.unwrap_err();
    assert_eq!(e.kind(), FaultKind::DeviceReported);
    assert!(matches!(e, GrblError::Rejected { code: ErrorCode(22), .. }));
    assert!(e.to_string().contains("Feed rate has not yet been set"), "{e}");
    assert_eq!(stage.unacknowledged_bytes(), 0);
}

/// The top speed goes out with the next move's feed (`F`, mm/min): 0.1 mm/s
/// is `F6`; setting it sends nothing, returns the speed it replaces, and a
/// speed that is not a positive number is refused with the feed unchanged.
#[tokio::test]
async fn a_top_speed_is_the_next_moves_feed() {
    let (mut stage, mut dev) = connected().await;
    assert_eq!(stage.set_max_speed(0.1).await.unwrap(), Some(1.0));
    for bad in [0.0, -1.0, f64::NAN, f64::INFINITY] {
        let e = stage.set_max_speed(bad).await.unwrap_err();
        assert_eq!(e.kind(), FaultKind::Protocol, "{bad}: {e}");
        assert!(e.to_string().contains("stage top speed"), "{e}");
    }
    let script = async move {
        expect(&mut dev, b"G90 G1 Z2.0000 F6.0000\n").await;
        dev.write_all(b"ok\r\n").await.unwrap();
        dev
    };
    let (r, _dev) = tokio::join!(stage.start_move_to(Mm(2.0)), script);
    r.unwrap();
    assert_eq!(stage.set_max_speed(1.0).await.unwrap(), Some(0.1));
}

#[tokio::test]
async fn out_of_travel_sends_nothing() {
    let (mut stage, mut dev) = connected().await;
    let e = stage.start_move_to(Mm(25.5)).await.unwrap_err();
    assert_eq!(e.kind(), FaultKind::Limit);
    let e = stage.start_move_to(Mm(f64::NAN)).await.unwrap_err();
    assert_eq!(e.kind(), FaultKind::Limit);
    drop(stage);
    let mut rest = Vec::new();
    dev.read_to_end(&mut rest).await.unwrap();
    assert!(rest.is_empty(), "{rest:?}");
}

#[tokio::test]
async fn relative_move_starts_from_reported_position_and_waits() {
    let (mut stage, mut dev) = connected().await;
    let script = async move {
        expect(&mut dev, b"?").await;
        dev.write_all(b"<Idle|MPos:0.000,0.000,1.000|FS:0,0>\r\n").await.unwrap();
        expect(&mut dev, b"G91 G1 Z0.5000 F60.0000\n").await;
        dev.write_all(b"ok\r\n").await.unwrap();
        expect(&mut dev, b"?").await;
        dev.write_all(b"<Run|MPos:0.000,0.000,1.200|FS:60,0>\r\n").await.unwrap();
        expect(&mut dev, b"?").await;
        dev.write_all(b"<Idle|MPos:0.000,0.000,1.500|FS:0,0>\r\n").await.unwrap();
        dev
    };
    let run = async {
        stage.start_move_by(Mm(0.5)).await?;
        stage.wait_until_stopped(Duration::from_secs(2)).await.map(f64::from)
    };
    let (r, _dev) = tokio::join!(run, script);
    assert!((r.unwrap() - 1.5).abs() < 1e-9);
}

#[tokio::test]
async fn relative_move_beyond_travel_is_refused_before_sending() {
    let (mut stage, mut dev) = connected().await;
    let script = async move {
        expect(&mut dev, b"?").await;
        dev.write_all(b"<Idle|MPos:0.000,0.000,24.900|FS:0,0>\r\n").await.unwrap();
        dev
    };
    let (r, mut dev) = tokio::join!(stage.start_move_by(Mm(0.2)), script);
    assert_eq!(r.unwrap_err().kind(), FaultKind::Limit);
    drop(stage);
    let mut rest = Vec::new();
    dev.read_to_end(&mut rest).await.unwrap();
    assert!(rest.is_empty());
}

#[tokio::test]
async fn alarm_during_wait_is_device_reported() {
    let (mut stage, mut dev) = connected().await;
    let script = async move {
        expect(&mut dev, b"G90 G1 Z3.0000 F60.0000\n").await;
        dev.write_all(b"ok\r\n").await.unwrap();
        expect(&mut dev, b"?").await;
        dev.write_all(b"<Run|MPos:0.000,0.000,1.200|FS:60,0>\r\nALARM:1\r\n[MSG:Reset to continue]\r\n").await.unwrap();
        dev
    };
    let run = async {
        stage.start_move_to(Mm(3.0)).await?;
        stage.wait_until_stopped(Duration::from_secs(2)).await
    };
    let (r, _dev) = tokio::join!(run, script);
    let e = r.unwrap_err();
    assert!(matches!(e, GrblError::Alarm { code: AlarmCode(1) }), "{e}");
    assert_eq!(e.kind(), FaultKind::DeviceReported);
    assert!(e.to_string().contains("Hard limit triggered"));
    // Locked: further moves are refused without sending.
    assert!(matches!(stage.start_move_to(Mm(1.0)).await, Err(GrblError::Alarm { .. })));
}

#[tokio::test]
async fn closed_link_is_disconnected_not_timeout() {
    let (mut stage, dev) = connected().await;
    drop(dev);
    let e = stage.position().await.unwrap_err();
    assert_eq!(e.kind(), FaultKind::Disconnected, "{e}");
}

#[tokio::test]
async fn silent_device_times_out() {
    let (mut stage, _dev) = connected().await;
    let e = stage.position().await.unwrap_err();
    assert_eq!(e.kind(), FaultKind::Timeout, "{e}");
}

#[tokio::test]
async fn character_counting_never_exceeds_rx_buffer() {
    // A device that answers `ok` to each line only after a delay lets the
    // driver queue lines; the count of unanswered bytes must stay <= 128.
    let (host, dev) = tokio::io::duplex(4096);
    let (mut rd, mut wr) = tokio::io::split(dev);
    let device = tokio::spawn(async move {
        let mut b = [0u8; 1];
        rd.read_exact(&mut b).await.unwrap();
        assert_eq!(b[0], 0x18);
        wr.write_all(b"Grbl 1.1h ['$' for help]\r\n").await.unwrap();
        rd.read_exact(&mut b).await.unwrap();
        assert_eq!(b[0], b'?');
        wr.write_all(b"<Idle|MPos:0.000,0.000,0.000|FS:0,0>\r\n").await.unwrap();
        let mut reader = BufReader::new(rd);
        let mut in_buffer = 0usize;
        let mut max_seen = 0usize;
        let mut queued = VecDeque::new();
        for _ in 0..20 {
            let mut line = String::new();
            reader.read_line(&mut line).await.unwrap();
            in_buffer += line.len();
            queued.push_back(line.len());
            max_seen = max_seen.max(in_buffer);
            // Answer only when the buffer holds three or more lines.
            while queued.len() >= 3 {
                in_buffer -= queued.pop_front().unwrap();
                wr.write_all(b"ok\r\n").await.unwrap();
            }
        }
        while queued.pop_front().is_some() {
            wr.write_all(b"ok\r\n").await.unwrap();
        }
        max_seen
    });
    let mut stage = GrblStage::connect(host, cfg()).await.unwrap();
    let mut seqs = Vec::new();
    let cmd = GrblCommand::Feed { distance: Distance::Absolute, axis: 'Z', mm: 12.3456, feed_mm_min: 1234.5 };
    for _ in 0..20 {
        seqs.push(stage.send_line(&cmd, "test").await.unwrap());
        assert!(stage.unacknowledged_bytes() <= RX_BUFFER_SIZE);
    }
    for s in seqs {
        stage.wait_answer(s, &cmd, Duration::from_secs(1), "test").await.unwrap();
    }
    let max_seen = device.await.unwrap();
    assert!(max_seen <= RX_BUFFER_SIZE, "{max_seen}");
    // 27-byte lines: the driver really did queue several (4 fit in 128).
    assert!(max_seen > 2 * 25, "{max_seen}");
}

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig::with_cases(64))]
    /// Whatever a device sends before hanging up, connecting ends in a
    /// typed error (or a session, if the bytes happen to hold a banner and
    /// a status report) and never panics.
    #[test]
    fn garbage_from_the_device_never_panics(bytes in proptest::collection::vec(proptest::prelude::any::<u8>(), 0..400)) {
        let rt = tokio::runtime::Builder::new_current_thread().enable_all().build().unwrap();
        rt.block_on(async {
            let (host, mut dev) = tokio::io::duplex(4096);
            dev.write_all(&bytes).await.unwrap();
            drop(dev);
            match GrblStage::connect(host, cfg()).await {
                Ok(_) => {}
                Err(e) => {
                    assert!(matches!(e.kind(), FaultKind::Disconnected | FaultKind::Protocol | FaultKind::Timeout), "{e}");
                }
            }
        });
    }
}
