//! Decoder throughput of the two sensor transports for one 20 x 20 frame
//! (criterion reports frames/s as elements/s). A real sensor streams 30-100
//! frames/s, so these are headroom figures.

use std::hint::black_box;
use std::time::{Duration, Instant};

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use devices::sensor::SensorFrame;
use devices::sensor::link::{LinkDecoder, LinkMessage, crc32, decode_datagram, encode};
use devices::sensor::tac3d::{
    DEFAULT_MAX_DATAGRAM, Tac3dFrame, Tac3dReassembler, decode_frame, encode_frame, encode_parts,
};

/// A pressed 20 x 20 frame with non-trivial values in every marker.
fn frame() -> SensorFrame {
    let positions = (0..400)
        .map(|i| {
            let (x, y) = ((i % 20) as f64 - 9.5, (i / 20) as f64 - 9.5);
            [x, y, -(x * x + y * y) / 66.0]
        })
        .collect();
    let displacements = (0..400)
        .map(|i| {
            let r2 = (((i % 20) as f64 - 9.5).powi(2) + ((i / 20) as f64 - 9.5).powi(2)) / 9.0;
            [1e-3 * i as f64, -2e-3 * i as f64, -1.2 * (-r2).exp()]
        })
        .collect();
    SensorFrame { index: 123_456, t_s: 4115.2, positions, displacements }
}

fn tac3d(c: &mut Criterion) {
    let f = Tac3dFrame::from_sensor_frame(&frame(), "AD2-0065L");
    let (head, blob) = encode_parts(&f).unwrap();
    let packets = encode_frame(&f, DEFAULT_MAX_DATAGRAM).unwrap();
    let mut g = c.benchmark_group("tac3d_20x20");
    g.throughput(Throughput::Elements(1));
    g.bench_function("decode_frame", |b| {
        b.iter(|| decode_frame(black_box(head.as_bytes()), black_box(&blob)).unwrap().to_sensor_frame().unwrap())
    });
    g.bench_function(format!("reassemble_{}_datagrams_and_decode", packets.len()), |b| {
        let mut re = Tac3dReassembler::new(Duration::from_secs(1));
        let now = Instant::now();
        b.iter(|| {
            let mut out = None;
            for p in &packets {
                if let Some(fr) = re.push(black_box(p), now).unwrap() {
                    out = Some(fr.to_sensor_frame().unwrap());
                }
            }
            out.unwrap()
        })
    });
    g.bench_function("encode_frame", |b| b.iter(|| encode_frame(black_box(&f), DEFAULT_MAX_DATAGRAM).unwrap()));
    g.finish();
}

fn link(c: &mut Criterion) {
    let bytes = encode(&LinkMessage::Frame(frame())).unwrap();
    let mut g = c.benchmark_group("link_20x20");
    g.throughput(Throughput::Elements(1));
    g.bench_function("decode_datagram", |b| b.iter(|| decode_datagram(black_box(&bytes)).unwrap()));
    // The checksum's share of a decode.
    g.bench_function("crc32_whole_message", |b| b.iter(|| crc32(black_box(&bytes))));
    g.bench_function("stream_decode_1k_chunks", |b| {
        let mut d = LinkDecoder::new();
        b.iter(|| {
            let mut out = None;
            for c in bytes.chunks(1024) {
                d.push(black_box(c));
                while let Some(m) = d.next_message() {
                    out = Some(m.unwrap());
                }
            }
            out.unwrap()
        })
    });
    g.finish();
}

criterion_group!(benches, tac3d, link);
criterion_main!(benches);
