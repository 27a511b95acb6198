//! APT protocol speed: codec encode + decode throughput (messages/s), and the
//! round trip of one status request from the real driver over a
//! pseudo-terminal to the emulator and back.

use std::hint::black_box;
use std::time::{Duration, Instant};

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use devices::Axis;
use devices::apt::codec::{AptDecoder, AptMessage, HOST, HwInfo, StatusPayload, USB_UNIT, encode_into, status};
use devices::apt::{AptConfig, AptStage};
use devices::serial::open_serial_settle;
use sim::clock::VirtualClock;
use sim::emulator::apt::{k10cr1_axis, spawn_apt_rotation, spawn_apt_stage, z8_axis};
use sim::emulator::rig::Rig;

/// A realistic mix: mostly status traffic, some moves, one identify.
fn traffic() -> Vec<AptMessage> {
    let mut v = Vec::new();
    for i in 0..100i32 {
        v.push(AptMessage::MotReqDcStatusUpdate { chan: 1 });
        v.push(AptMessage::MotGetDcStatusUpdate(StatusPayload::dc(1, 42_641 + i, 12, status::HOMED | status::ENABLED)));
        if i % 10 == 0 {
            v.push(AptMessage::MotMoveAbsolute { chan: 1, position: Some(i * 1000) });
            v.push(AptMessage::MotMoveCompleted(StatusPayload::dc(1, i * 1000, 0, status::HOMED)));
        }
    }
    v.push(AptMessage::HwGetInfo(Box::new(HwInfo {
        serial: 27_000_001,
        model: "KDC101".into(),
        hw_type: 16,
        firmware: (3, 0, 10),
        notes: String::new(),
        reserved: [0; 10],
        stage_id: 9,
        hw_version: 1,
        mod_state: 0,
        n_channels: 1,
    })));
    v
}

fn codec(c: &mut Criterion) {
    let msgs = traffic();
    let mut g = c.benchmark_group("apt_codec");
    g.throughput(Throughput::Elements(msgs.len() as u64));
    let mut wire = Vec::with_capacity(8192);
    g.bench_function("encode_decode_mix", |b| {
        b.iter(|| {
            wire.clear();
            for m in &msgs {
                // Both directions decode with the host's addressing: replies are encoded to the host.
                encode_into(black_box(m), HOST, USB_UNIT, &mut wire);
            }
            let mut dec = AptDecoder::for_host();
            dec.feed(&wire);
            let mut n = 0usize;
            while let Some(f) = dec.next_frame() {
                if f.is_ok() {
                    n += 1;
                }
            }
            assert_eq!(n, msgs.len());
            n
        })
    });
    g.finish();
}

fn pty_round_trip(c: &mut Criterion) {
    let rt = tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build().expect("runtime");
    let rig = Rig::new(VirtualClock::new(100.0), z8_axis(25.0), k10cr1_axis());
    let (_stage_emu, mut stage) = rt.block_on(async {
        let h = spawn_apt_stage(rig.clone()).expect("emulator");
        let port = open_serial_settle(h.path(), Duration::ZERO).await.expect("pty");
        let s = AptStage::connect(port, AptConfig::kdc101_z825b()).await.expect("connect");
        (h, s)
    });
    let (_rot_emu, mut rot) = rt.block_on(async {
        let h = spawn_apt_rotation(rig.clone()).expect("emulator");
        let port = open_serial_settle(h.path(), Duration::ZERO).await.expect("pty");
        let r = devices::apt::AptRotation::connect(port, AptConfig::k10cr1()).await.expect("connect");
        (h, r)
    });
    let mut g = c.benchmark_group("apt_pty");
    g.bench_function("kdc101_status_round_trip", |b| {
        b.iter_custom(|iters| {
            rt.block_on(async {
                let t0 = Instant::now();
                for _ in 0..iters {
                    black_box(Axis::status(&mut stage).await.expect("status"));
                }
                t0.elapsed()
            })
        })
    });
    // The K10CR1 is polled with two requests (STATUSBITS + POSCOUNTER).
    g.bench_function("k10cr1_status_two_round_trips", |b| {
        b.iter_custom(|iters| {
            rt.block_on(async {
                let t0 = Instant::now();
                for _ in 0..iters {
                    black_box(Axis::status(&mut rot).await.expect("status"));
                }
                t0.elapsed()
            })
        })
    });
    g.finish();
}

criterion_group!(benches, codec, pty_round_trip);
criterion_main!(benches);
