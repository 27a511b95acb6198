//! Fuzzing every parser of outside input (issue 11; docs/hardening.md): random
//! bytes and structured mutations of valid inputs — flipped, inserted, deleted
//! and repeated bytes, deep brackets, huge numbers — into recordings, scripts,
//! rig files, sim profiles, Tac3D headers and datagram streams, link-protocol
//! streams, APT frames and GRBL lines. A target passes when nothing panics,
//! nothing hangs, and what is accepted is self-consistent.
//!
//! CI runs each target for a bounded number of cases. For a long run:
//! `EASYCALIB_FUZZ_SECS=600 cargo test --release --test fuzz TARGET -- --nocapture`
//! keeps drawing fresh batches (a new seed each) until the time is spent.

use std::time::{Duration, Instant};

use devices::apt::codec::{Addressing, decode_frame as apt_decode};
use devices::grbl::codec::{LineSplitter, parse_line_bytes};
use devices::sensor::link::LinkDecoder;
use devices::sensor::tac3d::{Tac3dReassembler, decode_frame as tac3d_decode};
use easycalib::rig::RigConfig;
use easycalib::run::Script;
use proptest::prelude::*;
use proptest::test_runner::{Config, RngAlgorithm, TestCaseError, TestRng, TestRunner};
use sim::effects::SimProfile;
use sim::recording::Recording;

const BATCH: u32 = 128;

/// Run `check` on `strategy`: one batch in CI, batches until EASYCALIB_FUZZ_SECS
/// have passed when that is set. Prints the number of cases.
fn fuzz<S: Strategy>(name: &str, strategy: S, check: impl Fn(S::Value) -> Result<(), TestCaseError>) {
    let budget = std::env::var("EASYCALIB_FUZZ_SECS").ok().and_then(|s| s.parse::<f64>().ok());
    let deadline = budget.map(|s| Instant::now() + Duration::from_secs_f64(s));
    let mut cases = 0u64;
    for batch in 0u64.. {
        let mut seed = [0u8; 32];
        seed[..8].copy_from_slice(&batch.to_le_bytes());
        seed[8..16].copy_from_slice(&name.len().to_le_bytes());
        let rng = TestRng::from_seed(RngAlgorithm::ChaCha, &seed);
        let mut runner =
            TestRunner::new_with_rng(Config { cases: BATCH, failure_persistence: None, ..Config::default() }, rng);
        if let Err(e) = runner.run(&strategy, &check) {
            panic!("fuzz target {name}, batch {batch}: {e}");
        }
        cases += u64::from(BATCH);
        if deadline.is_none_or(|d| Instant::now() >= d) {
            break;
        }
    }
    eprintln!("fuzz {name}: {cases} cases, no failure");
}

/// One edit of a byte string.
#[derive(Debug, Clone)]
enum Edit {
    Flip(usize, u8),
    Insert(usize, Vec<u8>),
    Delete(usize, usize),
    Repeat(usize, usize, usize),
}

fn edit() -> impl Strategy<Value = Edit> {
    let special = prop_oneof![
        prop::collection::vec(any::<u8>(), 1..16),
        Just(b"[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[".to_vec()),
        Just(b"1e308".to_vec()),
        Just(b"-0".to_vec()),
        Just(b"NaN".to_vec()),
        Just(b"\n# key: value\n".to_vec()),
        Just(b",,,,".to_vec()),
        Just(b"\"".to_vec()),
        Just(vec![0xff, 0xfe]),
    ];
    prop_oneof![
        (any::<usize>(), any::<u8>()).prop_map(|(i, b)| Edit::Flip(i, b)),
        (any::<usize>(), special).prop_map(|(i, v)| Edit::Insert(i, v)),
        (any::<usize>(), 1usize..64).prop_map(|(i, n)| Edit::Delete(i, n)),
        (any::<usize>(), 1usize..64, 1usize..50).prop_map(|(i, n, k)| Edit::Repeat(i, n, k)),
    ]
}

fn apply(seed: &[u8], edits: &[Edit]) -> Vec<u8> {
    let mut v = seed.to_vec();
    for e in edits {
        let at = |i: usize, len: usize| if len == 0 { 0 } else { i % (len + 1) };
        match e {
            Edit::Flip(i, b) if !v.is_empty() => {
                let n = v.len();
                v[i % n] ^= b | 1;
            }
            Edit::Flip(..) => {}
            Edit::Insert(i, bytes) => {
                let p = at(*i, v.len());
                v.splice(p..p, bytes.iter().copied());
            }
            Edit::Delete(i, n) => {
                let p = at(*i, v.len());
                let end = (p + n).min(v.len());
                v.drain(p..end);
            }
            Edit::Repeat(i, n, k) => {
                let p = at(*i, v.len());
                let end = (p + n).min(v.len());
                let piece = v[p..end].to_vec();
                for _ in 0..*k {
                    v.splice(end..end, piece.iter().copied());
                }
            }
        }
    }
    v
}

/// Random bytes, or a valid input with a few edits (most of the cases).
fn inputs(seed: Vec<u8>) -> impl Strategy<Value = Vec<u8>> {
    prop_oneof![
        1 => prop::collection::vec(any::<u8>(), 0..4096),
        4 => prop::collection::vec(edit(), 1..6).prop_map(move |e| apply(&seed, &e)),
    ]
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

fn valid_recording() -> Vec<u8> {
    let cfg = sim::generator::GeneratorConfig { seed: 3, ..Default::default() };
    sim::generator::generate(&cfg).unwrap().to_csv_string().into_bytes()
}

#[test]
fn recording() {
    fuzz("recording", inputs(valid_recording()), |b| {
        if let Ok(r) = Recording::parse(&text(&b)) {
            // Whatever is accepted writes back and reads back to the same samples.
            let again = Recording::parse(&r.to_csv_string()).map_err(|e| TestCaseError::fail(e.to_string()))?;
            prop_assert_eq!(again.samples.len(), r.samples.len());
            // The fit's plausibility gate never panics on an accepted recording.
            let _ = easycalib::fit::plausible::check(&r);
        }
        Ok(())
    });
}

#[test]
fn script() {
    let seed = easycalib::run::DEFAULT_SCRIPT_TOML.as_bytes().to_vec();
    fuzz("script", inputs(seed), |b| {
        if let Ok(s) = Script::from_toml(&text(&b)) {
            // An accepted script has bounded durations and step counts.
            prop_assert!(
                s.read_timeout() <= Duration::from_secs(3600) && s.move_timeout() <= Duration::from_secs(3600)
            );
            prop_assert!(s.twist_angles().len() <= 20_001);
        }
        Ok(())
    });
}

#[test]
fn rig_file() {
    let seed = std::fs::read(concat!(env!("CARGO_MANIFEST_DIR"), "/examples/rig-thorlabs.toml")).unwrap();
    fuzz("rig_file", inputs(seed), |b| {
        if let Ok(c) = RigConfig::from_toml(&text(&b)) {
            prop_assert!(c.to_spec().is_ok());
        }
        Ok(())
    });
}

#[test]
fn profile() {
    let seed = b"[frame_compliance]\nc_mm_per_n = 0.004\n[viscoelastic]\nrho = 1.05\ntau_s = 5.0\n".to_vec();
    fuzz("profile", inputs(seed), |b| {
        if let Ok(p) = SimProfile::from_toml_str(&text(&b)) {
            prop_assert!(p.validate().is_ok());
        }
        Ok(())
    });
}

fn valid_tac3d_header() -> Vec<u8> {
    b"index: 7\nSN: EC1-0001\ntimestamp: 1.5\nmsg: ok\ndata:\n  - name: 3D_Positions\n    type: mat\n    width: 3\n    height: 2\n    offset: 0\n    length: 48\n".to_vec()
}

#[test]
fn tac3d_header() {
    fuzz("tac3d_header", (inputs(valid_tac3d_header()), prop::collection::vec(any::<u8>(), 0..256)), |(h, blob)| {
        let _ = tac3d_decode(&h, &blob);
        Ok(())
    });
}

#[test]
fn tac3d_datagrams() {
    let datagram = prop::collection::vec(any::<u8>(), 0..1500);
    fuzz("tac3d_datagrams", prop::collection::vec(datagram, 0..40), |ds| {
        let mut re = Tac3dReassembler::new(Duration::from_secs(1));
        let now = Instant::now();
        for d in &ds {
            let _ = re.push(d, now);
            prop_assert!(re.bytes_in_flight() <= devices::sensor::tac3d::MAX_BYTES_IN_FLIGHT);
        }
        Ok(())
    });
}

#[test]
fn link_stream() {
    fuzz("link_stream", (prop::collection::vec(any::<u8>(), 0..4096), 1usize..128), |(bytes, chunk)| {
        let mut d = LinkDecoder::new();
        for c in bytes.chunks(chunk) {
            d.push(c);
            while d.next_message().is_some() {}
        }
        Ok(())
    });
}

#[test]
fn apt_reply() {
    fuzz("apt_reply", prop::collection::vec(any::<u8>(), 0..600), |bytes| {
        let mut rest = &bytes[..];
        // Walk the stream as the driver does: decode, or drop a byte and resync.
        while !rest.is_empty() {
            match apt_decode(rest, &Addressing::host()) {
                Ok((_, used)) => {
                    prop_assert!(used > 0 && used <= rest.len());
                    rest = &rest[used..];
                }
                Err(_) => rest = &rest[1..],
            }
        }
        Ok(())
    });
}

#[test]
fn grbl_line() {
    fuzz("grbl_line", prop::collection::vec(any::<u8>(), 0..2048), |bytes| {
        let mut s = LineSplitter::new();
        let mut out = Vec::new();
        s.push(&bytes, &mut out);
        for line in out.into_iter().flatten() {
            prop_assert!(line.len() <= devices::grbl::codec::MAX_RESPONSE_LINE);
            let _ = parse_line_bytes(&line);
        }
        Ok(())
    });
}
