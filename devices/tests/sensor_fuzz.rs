//! Property tests over both decoders: random bytes and mutated valid frames
//! never panic, never yield a frame that was not sent, and round trips hold.

use std::time::{Duration, Instant};

use devices::sensor::link::{LinkDecoder, LinkMessage, decode_datagram, encode};
use devices::sensor::tac3d::{Tac3dFrame, Tac3dReassembler, decode_frame, encode_frame, encode_parts};
use devices::sensor::{FrameTracker, SensorFrame};
use proptest::prelude::*;

fn arb_frame(max_markers: usize) -> impl Strategy<Value = SensorFrame> {
    (any::<u64>(), -1e6f64..1e6, 0..=max_markers).prop_flat_map(|(index, t_s, n)| {
        let row = prop::array::uniform3(-100.0f64..100.0);
        (prop::collection::vec(row.clone(), n), prop::collection::vec(row, n))
            .prop_map(move |(positions, displacements)| SensorFrame { index, t_s, positions, displacements })
    })
}

/// The frame as the link protocol carries it (floats rounded to f32).
fn as_f32(f: &SensorFrame) -> SensorFrame {
    let r = |v: &Vec<[f64; 3]>| v.iter().map(|a| a.map(|x| f64::from(x as f32))).collect();
    SensorFrame { index: f.index, t_s: f.t_s, positions: r(&f.positions), displacements: r(&f.displacements) }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, ..ProptestConfig::default() })]

    #[test]
    fn link_decoders_survive_random_bytes(bytes in prop::collection::vec(any::<u8>(), 0..2048), chunk in 1usize..64) {
        let _ = decode_datagram(&bytes);
        let mut d = LinkDecoder::new();
        for c in bytes.chunks(chunk) {
            d.push(c);
            while let Some(m) = d.next_message() {
                // A random message passing two CRC-32s is possible but not in 2 kB of noise.
                prop_assert!(!matches!(m, Ok(LinkMessage::Frame(_))), "{m:?}");
            }
        }
    }

    #[test]
    fn link_round_trip(f in arb_frame(64), chunk in 1usize..200) {
        let bytes = encode(&LinkMessage::Frame(f.clone())).unwrap();
        let want = LinkMessage::Frame(as_f32(&f));
        prop_assert_eq!(decode_datagram(&bytes).unwrap(), want.clone());
        let mut d = LinkDecoder::new();
        let mut got = Vec::new();
        for c in bytes.chunks(chunk) {
            d.push(c);
            while let Some(m) = d.next_message() {
                got.push(m.unwrap());
            }
        }
        prop_assert_eq!(got, vec![want]);
    }

    /// CRC-32 detects every error burst up to 32 bits, so no corruption of
    /// 1-4 adjacent bytes is ever accepted; truncation is never accepted.
    #[test]
    fn mutated_link_frames_are_rejected(
        f in arb_frame(16),
        at in any::<prop::sample::Index>(),
        xor in prop::collection::vec(any::<u8>(), 1..=4),
        cut in any::<prop::sample::Index>(),
    ) {
        let good = encode(&LinkMessage::Frame(f.clone())).unwrap();
        let mut bad = good.clone();
        let i = at.index(good.len());
        let mut changed = false;
        for (k, x) in xor.iter().enumerate() {
            if let Some(b) = bad.get_mut(i + k) {
                *b ^= x;
                changed |= *x != 0;
            }
        }
        prop_assume!(changed);
        prop_assert!(decode_datagram(&bad).is_err());
        let mut d = LinkDecoder::new();
        d.push(&bad);
        while let Some(m) = d.next_message() {
            prop_assert!(m.is_err(), "accepted a corrupted frame: {m:?}");
        }
        let short = &good[..cut.index(good.len())];
        prop_assert!(decode_datagram(short).is_err());
        let mut d = LinkDecoder::new();
        d.push(short);
        while let Some(m) = d.next_message() {
            prop_assert!(m.is_err());
        }
    }

    /// After any corruption the stream decoder still finds the next good frame.
    #[test]
    fn link_stream_recovers_after_corruption(
        f in arb_frame(8),
        noise in prop::collection::vec(any::<u8>(), 0..300),
        at in any::<prop::sample::Index>(),
    ) {
        let mut first = encode(&LinkMessage::Frame(f.clone())).unwrap();
        let i = at.index(first.len());
        first[i] ^= 0x5A;
        let next = SensorFrame { index: f.index.wrapping_add(1), ..f.clone() };
        let tail = encode(&LinkMessage::Frame(next.clone())).unwrap();
        let stream = [first, noise, tail].concat();
        let mut d = LinkDecoder::new();
        d.push(&stream);
        let mut frames = Vec::new();
        while let Some(m) = d.next_message() {
            if let Ok(LinkMessage::Frame(g)) = m {
                frames.push(g);
            }
        }
        prop_assert_eq!(frames.last(), Some(&as_f32(&next)));
    }

    #[test]
    fn tac3d_decoders_survive_random_bytes(
        datagrams in prop::collection::vec(prop::collection::vec(any::<u8>(), 0..300), 0..20),
        head in "[ -~\n]{0,400}",
        blob in prop::collection::vec(any::<u8>(), 0..200),
    ) {
        let mut re = Tac3dReassembler::new(Duration::from_secs(1));
        let now = Instant::now();
        for d in &datagrams {
            let _ = re.push(d, now);
        }
        let _ = re.expire(now + Duration::from_secs(2));
        prop_assert_eq!(re.pending(), 0);
        if let Ok(f) = decode_frame(head.as_bytes(), &blob) {
            let _ = f.to_sensor_frame();
        }
    }

    #[test]
    fn tac3d_round_trip_in_any_packet_order(
        f in arb_frame(400),
        max_datagram in 600usize..20000,
        seed in any::<u64>(),
    ) {
        let packets = encode_frame(&Tac3dFrame::from_sensor_frame(&f, "AD2-0065L"), max_datagram).unwrap();
        prop_assert!(packets.iter().all(|p| p.len() <= max_datagram));
        // A deterministic shuffle from the seed.
        let mut order: Vec<usize> = (0..packets.len()).collect();
        let mut s = seed | 1;
        for i in (1..order.len()).rev() {
            s ^= s << 13; s ^= s >> 7; s ^= s << 17;
            order.swap(i, (s % (i as u64 + 1)) as usize);
        }
        let mut re = Tac3dReassembler::new(Duration::from_secs(1));
        let now = Instant::now();
        let mut done = Vec::new();
        for &k in &order {
            if let Some(g) = re.push(&packets[k], now).unwrap() {
                done.push(g);
            }
        }
        prop_assert_eq!(done.len(), 1);
        let g = done[0].to_sensor_frame().unwrap();
        prop_assert_eq!((g.index, g.t_s, &g.displacements), (f.index, f.t_s, &f.displacements));
        // Positions travel as reference + displacement (Tac3D sends current positions).
        for (a, b) in g.positions.iter().flatten().zip(f.positions.iter().flatten()) {
            prop_assert!((a - b).abs() <= 1e-12 * (1.0 + b.abs()), "{} vs {}", a, b);
        }
        prop_assert_eq!(g.positions.len(), f.positions.len());
    }

    /// Mutating the YAML header or the blob of a valid frame, or truncating
    /// either, gives an error or a frame; never a panic.
    #[test]
    fn mutated_tac3d_frames_never_panic(
        f in arb_frame(20),
        at in any::<prop::sample::Index>(),
        byte in any::<u8>(),
        in_head in any::<bool>(),
        cut in any::<prop::sample::Index>(),
    ) {
        let (head, blob) = encode_parts(&Tac3dFrame::from_sensor_frame(&f, "SN")).unwrap();
        let (mut h, mut b) = (head.into_bytes(), blob);
        if in_head { let i = at.index(h.len()); h[i] = byte; } else if !b.is_empty() { let i = at.index(b.len()); b[i] = byte; }
        if let Ok(g) = decode_frame(&h, &b) {
            let _ = g.to_sensor_frame();
        }
        let hc = cut.index(h.len() + 1);
        if let Ok(g) = decode_frame(&h[..hc], &b) {
            let _ = g.to_sensor_frame();
        }
        let bc = cut.index(b.len() + 1);
        if let Ok(g) = decode_frame(&h, &b[..bc]) {
            // With the header intact, a shorter blob decodes only when nothing was cut.
            if !in_head {
                prop_assert_eq!(bc, b.len(), "{:?}", g);
            }
        }
    }

    /// Any printable serial number and status text survive the YAML header
    /// (plain when safe, single-quoted otherwise).
    #[test]
    fn tac3d_header_strings_round_trip(sn in "[ -~]{0,24}", msg in "[ -~]{0,40}") {
        let mut f = Tac3dFrame::from_sensor_frame(&SensorFrame {
            index: 3, t_s: 0.25, positions: vec![[0.0; 3]], displacements: vec![[0.0; 3]],
        }, &sn);
        f.msg = Some(msg.clone());
        let (head, blob) = encode_parts(&f).unwrap();
        let g = decode_frame(head.as_bytes(), &blob).unwrap();
        prop_assert_eq!(g.sn, sn);
        prop_assert_eq!(g.msg, Some(msg));
    }

    /// The tracker's dropped count equals the frames missing between accepted
    /// ones; late frames are never accepted.
    #[test]
    fn tracker_counts_gaps(steps in prop::collection::vec(0u64..5, 1..100)) {
        let mut t = FrameTracker::new();
        let mut idx = 1000u64;
        let mut missing = 0;
        t.frame(idx, 0.0);
        for s in &steps {
            if *s == 0 {
                prop_assert_eq!(t.frame(idx, 0.0), devices::sensor::Verdict::Stale);
                continue;
            }
            missing += s - 1;
            idx += s;
            prop_assert_eq!(t.frame(idx, idx as f64 / 30.0), devices::sensor::Verdict::Accept);
        }
        prop_assert_eq!(t.stats().dropped, missing);
    }
}
