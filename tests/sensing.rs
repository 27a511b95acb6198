//! Frame processing against fields with a known truth: synthetic Hertz
//! fields (sim::sensor::field) and the simulated sensor on the emulated rig.

use devices::sensor::SensorFrame;
use easycalib::sensing::{SensingConfig, SensingError, Tare, measure};
use sim::clock::VirtualClock;
use sim::emulator::axis::AxisConfig;
use sim::emulator::rig::{Rig, RigPose};
use sim::rng::Rng;
use sim::sensor::field::{ContactState, MarkerGrid, NoiseConfig, no_contact_frame, synth_frame};
use sim::sensor::rig::{RigSensor, SensorSimConfig};

/// A random contact of torsion-phase size with an off-grid centre.
fn random_contact(rng: &mut Rng, a_range: (f64, f64), nu: f64) -> ContactState {
    let a = a_range.0 + (a_range.1 - a_range.0) * rng.uniform();
    let gamma1 = 0.3 + 3.0 * rng.uniform();
    let theta = (rng.uniform() - 0.5) * 10f64.to_radians();
    // Never on a marker or on a grid mid-line (markers sit at +-0.5, +-1.5, ...).
    let centre = [0.137 + 0.6 * (rng.uniform() - 0.5), -0.211 + 0.6 * (rng.uniform() - 0.5)];
    ContactState::new(centre, gamma1, a, theta).with_nu1(nu)
}

struct Errors {
    gamma_um: Vec<f64>,
    theta_deg: Vec<f64>,
}

impl Errors {
    fn max_gamma(&self) -> f64 {
        self.gamma_um.iter().fold(0.0, |m, e| m.max(e.abs()))
    }
    fn max_theta(&self) -> f64 {
        self.theta_deg.iter().fold(0.0, |m, e| m.max(e.abs()))
    }
    fn frac_within(&self, g_um: f64, t_deg: f64) -> f64 {
        let ok = self.gamma_um.iter().zip(&self.theta_deg).filter(|(g, t)| g.abs() <= g_um && t.abs() <= t_deg).count();
        ok as f64 / self.gamma_um.len() as f64
    }
}

fn run(cases: usize, seed: u64, a_range: (f64, f64), noise: NoiseConfig) -> Errors {
    let grid = MarkerGrid::tac3d();
    let cfg = SensingConfig::default();
    let mut rng = Rng::seed_from(seed);
    let mut e = Errors { gamma_um: Vec::new(), theta_deg: Vec::new() };
    for k in 0..cases {
        let nu = if k % 2 == 0 { 0.5 } else { 0.39 };
        let state = random_contact(&mut rng, a_range, nu);
        let frame = synth_frame(&state, &grid, &noise, &mut rng, k as u64, 0.0);
        let m = measure(&frame, &cfg).unwrap_or_else(|err| panic!("case {k} {state:?}: {err}"));
        e.gamma_um.push((m.gamma1_mm - state.gamma1_mm) * 1e3);
        e.theta_deg.push(m.theta1_deg - state.theta1_rad.to_degrees());
    }
    e
}

#[test]
fn noise_free_field_gives_exact_gamma1_and_theta1() {
    let e = run(60, 1, (2.0, 5.0), NoiseConfig::NONE);
    println!("noise-free: max |gamma1 err| {:.2e} um, max |theta1 err| {:.2e} deg", e.max_gamma(), e.max_theta());
    assert!(e.max_gamma() < 1.0, "{}", e.max_gamma());
    assert!(e.max_theta() < 0.005, "{}", e.max_theta());
}

#[test]
fn small_contacts_still_give_gamma1_through_the_hertz_fit() {
    // Contacts of 0.9-2 mm: the quadratic window reaches outside the contact
    // and the Hertz-field fit takes over.
    let e = run(40, 2, (0.9, 2.0), NoiseConfig::NONE);
    println!("small contacts: max |gamma1 err| {:.2e} um", e.max_gamma());
    assert!(e.max_gamma() < 1.0, "{}", e.max_gamma());
}

#[test]
fn five_percent_outliers_are_rejected() {
    let e = run(100, 3, (2.0, 5.0), NoiseConfig::NONE.with_outliers(0.05));
    let within = e.frac_within(1.0, 0.005);
    let mut g = e.gamma_um.clone();
    g.sort_by(|a, b| a.abs().total_cmp(&b.abs()));
    println!(
        "5% outliers: {:.0}% of frames within 1 um / 0.005 deg; median |gamma1 err| {:.2e} um, max {:.1} um, max theta {:.3} deg",
        within * 100.0,
        g[g.len() / 2].abs(),
        e.max_gamma(),
        e.max_theta()
    );
    // Known weakness: when two or three outliers land in the ~12-marker
    // window of a small contact, one can mask the other.
    assert!(within >= 0.9, "{within}");
}

fn rms(v: &[f64]) -> f64 {
    (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt()
}

#[test]
fn four_um_noise_gives_gamma1_within_5um_and_theta1_within_0_02deg() {
    // Torsion-phase contact sizes (the default rig reaches a ~ 4.9 mm at
    // beta 0.2), 4 um noise on dz (docs/hardware.md C.1) and, conservatively, on
    // dx and dy too, over 6 seeds x 20 frames.
    let mut all = Errors { gamma_um: Vec::new(), theta_deg: Vec::new() };
    for seed in 10..16 {
        let e = run(20, seed, (4.0, 5.0), NoiseConfig::gaussian(0.004));
        all.gamma_um.extend(e.gamma_um);
        all.theta_deg.extend(e.theta_deg);
    }
    let within = all.frac_within(5.0, 0.02);
    println!(
        "4 um noise: gamma1 rms {:.2} um max {:.2} um; theta1 rms {:.4} deg max {:.4} deg; {:.1}% within 5 um / 0.02 deg",
        rms(&all.gamma_um),
        all.max_gamma(),
        rms(&all.theta_deg),
        all.max_theta(),
        within * 100.0
    );
    assert!(all.max_gamma() < 5.0, "{}", all.max_gamma());
    // With 4 um in-plane noise the stuck disc (~60 markers, sum r^2 ~ 700
    // mm^2) bounds any estimator to ~0.0085 deg rms: 0.02 deg is ~2.3 sigma,
    // so a few frames in a hundred exceed it whatever the method.
    assert!(rms(&all.theta_deg) < 0.0105, "{}", rms(&all.theta_deg));
    assert!(within >= 0.95, "{within}");
    // With the in-plane noise at 2 um every frame is within 0.02 deg.
    let mut xy2 = NoiseConfig::gaussian(0.004);
    xy2.sigma_xy_mm = 0.002;
    let e = run(60, 20, (4.0, 5.0), xy2);
    println!("4 um dz / 2 um dx,dy: theta1 max {:.4} deg, gamma1 max {:.2} um", e.max_theta(), e.max_gamma());
    assert!(e.max_theta() < 0.02 && e.max_gamma() < 5.0);
}

fn axis() -> AxisConfig {
    AxisConfig {
        max_velocity: 1.0,
        acceleration: 1.0,
        min_position: -10.0,
        max_position: 10.0,
        resolution: 0.0,
        backlash: 0.0,
        home_velocity: 1.0,
        power_on_position: 0.0,
    }
}

#[test]
fn simulated_sensor_reproduces_the_physics_over_both_sweeps() {
    let rig = Rig::new(VirtualClock::new(1.0), axis(), axis());
    let mut sensor = RigSensor::new(rig, SensorSimConfig::default()).unwrap();
    let cfg = SensingConfig::for_contact(5.0, 33.0);
    let pose = |stage_mm, rot_deg| RigPose { t_s: 0.0, stage_mm, rot_deg };
    // Normal sweep from first touch to beta = 0.2.
    let mut stage = 0.0;
    let mut worst_small = 0.0f64;
    let mut worst = 0.0f64;
    let mut n = 0;
    let mut torsion_stage = None;
    while stage < 8.0 {
        stage += 0.05;
        let p = pose(stage, 0.0);
        let truth = sensor.truth(&p).unwrap();
        let frame = sensor.frame_at_pose(&p);
        let m = measure(&frame, &cfg).unwrap();
        let err = (m.gamma1_mm - truth.normal.gamma1_mm).abs() * 1e3;
        // Contacts under ~1 marker pitch are ill-determined by a 1 mm grid.
        if truth.normal.contact_radius_mm < 1.2 {
            worst_small = worst_small.max(err);
        } else {
            worst = worst.max(err);
            n += 1;
        }
        if truth.beta >= 0.2 {
            torsion_stage = Some(stage);
            break;
        }
    }
    println!(
        "normal sweep: {n} frames with a >= 1.2 mm, max |gamma1 err| {worst:.2} um; smaller contacts {worst_small:.1} um"
    );
    assert!(n > 50);
    assert!(worst < 8.0, "{worst}");
    let stage = torsion_stage.expect("sweep reached beta 0.2");
    // Torsion sweep out to 8 degrees of mount and back.
    let mut errs = Vec::new();
    let angles: Vec<f64> = (0..=40).map(|k| k as f64 * 0.2).chain((0..40).rev().map(|k| k as f64 * 0.2)).collect();
    for rot in angles {
        let p = pose(stage, rot);
        let truth = sensor.truth(&p).unwrap();
        let frame = sensor.frame_at_pose(&p);
        let m = measure(&frame, &cfg).unwrap();
        assert!(truth.theta1_rad.to_degrees() <= 5.1);
        errs.push(m.theta1_deg - truth.theta1_rad.to_degrees());
    }
    let worst_t = errs.iter().fold(0.0f64, |m, e| m.max(e.abs()));
    println!("torsion sweep: theta1 err rms {:.4} deg, max {worst_t:.4} deg over {} frames", rms(&errs), errs.len());
    // Noise-limited (see the 4 um test): rms near the Cramér-Rao ~0.008 deg.
    assert!(rms(&errs) < 0.0105 && worst_t < 0.03, "{} {worst_t}", rms(&errs));
}

#[test]
fn bad_frames_are_typed_errors() {
    let cfg = SensingConfig::default();
    let grid = MarkerGrid::tac3d();
    let empty = SensorFrame { index: 7, t_s: 0.0, positions: vec![], displacements: vec![] };
    assert_eq!(measure(&empty, &cfg), Err(SensingError::Empty { index: 7 }));
    let zero = no_contact_frame(&grid, 8, 0.0);
    assert_eq!(measure(&zero, &cfg), Err(SensingError::NoContact { index: 8, depth_mm: 0.0 }));
    let mut rng = Rng::seed_from(1);
    let state = ContactState::new([0.1, 0.2], 1.0, 3.0, 0.01);
    let mut nan = synth_frame(&state, &grid, &NoiseConfig::NONE, &mut rng, 9, 0.0);
    nan.displacements[17][1] = f64::NAN;
    assert_eq!(measure(&nan, &cfg), Err(SensingError::NotFinite { index: 9, marker: 17, what: "displacement" }));
    let mut short = synth_frame(&state, &grid, &NoiseConfig::NONE, &mut rng, 10, 0.0);
    short.displacements.pop();
    assert!(matches!(
        measure(&short, &cfg),
        Err(SensingError::LengthMismatch { positions: 400, displacements: 399, .. })
    ));
    // A frame pulled outward is no press.
    let mut pulled = synth_frame(&state, &grid, &NoiseConfig::NONE, &mut rng, 11, 0.0);
    pulled.displacements.iter_mut().for_each(|d| d[2] = -d[2]);
    assert!(matches!(measure(&pulled, &cfg), Err(SensingError::NoContact { .. })));
}

#[test]
fn tare_removes_a_standing_offset_and_keeps_the_dead_band() {
    let grid = MarkerGrid::tac3d();
    let mut rng = Rng::seed_from(4);
    let state = ContactState::new([0.1, 0.2], 1.0, 3.0, 0.02);
    let mut offset = no_contact_frame(&grid, 0, 0.0);
    offset.displacements.iter_mut().enumerate().for_each(|(i, d)| *d = [0.001 * (i % 7) as f64, -0.002, 0.03]);
    let tare = Tare::from_frame(&offset).unwrap();
    let mut frame = synth_frame(&state, &grid, &NoiseConfig::NONE, &mut rng, 1, 0.0);
    for (d, o) in frame.displacements.iter_mut().zip(&offset.displacements) {
        for k in 0..3 {
            d[k] += o[k];
        }
    }
    let m = measure(&tare.apply(&frame).unwrap(), &SensingConfig::default()).unwrap();
    assert!((m.gamma1_mm - 1.0).abs() < 1e-9 && (m.theta1_deg - 0.02f64.to_degrees()).abs() < 1e-6);
    let zero = tare.apply(&no_contact_frame(&grid, 2, 0.0)).unwrap();
    assert!(zero.displacements.iter().all(|d| *d == [0.0; 3]));
}

/// Frames to a UDP address in the Tac3D main program's format.
struct Tac3dUdpSink {
    socket: tokio::net::UdpSocket,
    to: std::net::SocketAddr,
}

impl sim::sensor::stream::FrameSink for Tac3dUdpSink {
    async fn send(&mut self, frame: &SensorFrame) -> Result<(), sim::sensor::stream::SinkError> {
        use devices::sensor::tac3d::{Tac3dFrame, encode_frame};
        let tf = Tac3dFrame::from_sensor_frame(frame, "SIM-0001");
        let datagrams = encode_frame(&tf, 8192).map_err(|e| sim::sensor::stream::SinkError::Other(e.to_string()))?;
        for d in datagrams {
            self.socket.send_to(&d, self.to).await?;
        }
        Ok(())
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn end_to_end_stage_move_reaches_gamma1_over_loopback_tac3d() {
    use devices::sensor::SensorLink;
    use devices::sensor::tac3d::{Tac3dReceiver, Tac3dReceiverConfig};
    use sim::physics::NormalModel;
    use std::time::Duration;

    let fast = AxisConfig { max_velocity: 20.0, acceleration: 200.0, ..axis() };
    let rig = Rig::new(VirtualClock::new(20.0), fast, fast);
    let mut rx = Tac3dReceiver::bind(Tac3dReceiverConfig {
        bind: "127.0.0.1:0".parse().unwrap(),
        queue_capacity: 64,
        ..Tac3dReceiverConfig::default()
    })
    .await
    .unwrap();
    rx.start().await.unwrap();
    let socket = tokio::net::UdpSocket::bind("127.0.0.1:0").await.unwrap();
    let sink = Tac3dUdpSink { socket, to: rx.local_addr().unwrap() };
    let cfg = SensorSimConfig::default();
    let model = NormalModel::new(*cfg.setup.pair()).unwrap();
    let stream = sim::sensor::stream::spawn_sensor_stream(rig.clone(), cfg, sink).unwrap();
    let scfg = SensingConfig::for_contact(5.0, 33.0);

    let f = rx.next_frame(Duration::from_secs(2)).await.unwrap();
    assert!(matches!(measure(&f, &scfg), Err(SensingError::NoContact { .. })));

    rig.with_stage(|ax, t| ax.command_move_to(t, 2.0));
    while rig.with_stage(|ax, _| ax.is_moving()) {
        tokio::time::sleep(Duration::from_millis(1)).await;
    }
    let settled = rig.clock().now_s();
    let truth = model.solve(2.0).unwrap().gamma1_mm;
    let mut got = Vec::new();
    while got.len() < 5 {
        let f = rx.next_frame(Duration::from_secs(2)).await.unwrap();
        if f.t_s > settled {
            got.push(measure(&f, &scfg).unwrap().gamma1_mm);
        }
    }
    let mean = got.iter().sum::<f64>() / got.len() as f64;
    println!("end to end: gamma1 {mean:.4} mm vs model {truth:.4} mm");
    assert!((mean - truth).abs() < 0.005, "{mean} vs {truth}");
    assert_eq!(rx.sensor_serial().as_deref(), Some("SIM-0001"));
    // A link dropout: the sensor keeps counting while nothing is sent, so the
    // receiver reports the lost frames once the stream resumes.
    assert_eq!(rx.stats().dropped, 0);
    stream.set_silenced(true);
    let before = stream.frames_generated();
    while stream.frames_generated() < before + 5 {
        tokio::time::sleep(Duration::from_millis(1)).await;
    }
    stream.set_silenced(false);
    let mut waited = 0;
    while rx.stats().dropped < 4 && waited < 2000 {
        let _ = rx.next_frame(Duration::from_millis(100)).await;
        waited += 1;
    }
    assert!(rx.stats().dropped >= 4, "{:?}", rx.stats());
    assert!(matches!(stream.stop().await, sim::sensor::stream::StreamEnd::Stopped { .. }));
}

/// gamma1 against the truth over the contact sizes the normal sweep visits,
/// from first contact (a well under the 1 mm marker pitch) to 3 mm, through the
/// estimator a run uses (docs/sensing.md, "Small contacts"): it first sees
/// the approach's resolved contacts, as a run does, and learns the field's
/// curvature and the contact's place from them. The contacts are the default
/// rig's (Hertz–Tatara state of E1 0.33 MPa, nu1 0.39 under the 5 mm
/// indenter), with the Tac3D's 4 µm marker noise, centred between four
/// markers (the worst place) and on one. Per contact radius: the mean error of
/// 200 frames (the bias) and the error of a sample as a run records it (the
/// mean of four frames), against the standard error the estimator reports.
#[test]
fn gamma1_is_unbiased_from_first_contact_to_torsion_sizes() {
    use easycalib::sensing::FrameEstimator;
    use sim::physics::{Body, ContactPair, NormalModel};
    let pair = ContactPair { elastomer: Body::new(0.33, 0.39, 33.0), indenter: Body::new(1.1, 0.39, 5.0) };
    let model = NormalModel::new(pair).unwrap();
    // The approach depth whose contact radius is `a` (bisection: a grows with depth).
    let state_at = |a: f64| {
        let (mut lo, mut hi) = (1e-6, 4.0);
        for _ in 0..60 {
            let mid = 0.5 * (lo + hi);
            if model.solve(mid).unwrap().contact_radius_mm < a { lo = mid } else { hi = mid }
        }
        model.solve(0.5 * (lo + hi)).unwrap()
    };
    let grid = MarkerGrid::tac3d();
    let noise = NoiseConfig::gaussian(0.004);
    let mut rng = Rng::seed_from(77);
    let mut sample_errors = Vec::new();
    println!(
        "centre      a mm  gamma1 um   bias um   frame sd um  reported sd um   sample rms um  (200 frames, 4 um noise)"
    );
    for centre in [[0.0, 0.0], [0.5, 0.5]] {
        let mut estimator = FrameEstimator::new(SensingConfig::for_contact(5.0, 33.0));
        let mut index = 0;
        let mut frame_of = |a: f64, rng: &mut Rng| {
            let st = state_at(a);
            index += 1;
            let state = ContactState::new(centre, st.gamma1_mm, st.contact_radius_mm, 0.0)
                .with_nu1(0.39)
                .with_spheres(5.0, 33.0);
            (st.gamma1_mm, synth_frame(&state, &grid, &noise, rng, index, 0.0))
        };
        // The approach: settled frames at contacts of 1.5-1.8 mm.
        for k in 0..40 {
            let (_, f) = frame_of(1.5 + 0.3 * (k as f64 / 40.0), &mut rng);
            let _ = estimator.measure(&f);
        }
        assert!(estimator.curvature().is_some() && estimator.centre().is_some(), "nothing learnt on the approach");
        for a in [0.3, 0.4, 0.5, 0.6, 0.75, 1.0, 1.25, 1.5, 2.0, 2.5, 3.0] {
            let (mut errs, mut sds) = (Vec::new(), Vec::new());
            for _ in 0..200 {
                let (truth, f) = frame_of(a, &mut rng);
                // A contact too faint to see reads as none (zero), as the gauge records it.
                match estimator.measure(&f) {
                    Ok(m) => {
                        errs.push((m.gamma1_mm - truth) * 1e3);
                        sds.push(m.gamma1_sd_mm * 1e3);
                    }
                    Err(SensingError::NoContact { .. }) => errs.push(-truth * 1e3),
                    Err(e) => panic!("a {a}: {e}"),
                }
            }
            let n = errs.len() as f64;
            let bias = errs.iter().sum::<f64>() / n;
            let sd = (errs.iter().map(|e| (e - bias).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
            let reported = (sds.iter().map(|s| s * s).sum::<f64>() / sds.len() as f64).sqrt();
            let samples: Vec<f64> = errs.chunks(4).map(|c| c.iter().sum::<f64>() / c.len() as f64).collect();
            let sample_rms = (samples.iter().map(|e| e * e).sum::<f64>() / samples.len() as f64).sqrt();
            println!(
                "{centre:?}  {a:5.2}  {:9.1}   {bias:+7.2}   {sd:9.2}   {reported:12.2}   {sample_rms:12.2}",
                state_at(a).gamma1_mm * 1e3
            );
            // No trend with the contact's size: the bias is within three of
            // its own standard errors and a micrometre everywhere (the
            // curvature learnt at 1.5-1.8 mm is a percent off at 1 mm).
            assert!(bias.abs() <= 3.0 * sd / n.sqrt() + 1.0, "a {a}: bias {bias:+.2} um (frame sd {sd:.2} um)");
            // The reported error is the error: within a factor 1.3 either way.
            assert!(reported / sd < 1.3 && sd / reported < 1.3, "a {a}: scatter {sd:.2} um, reported {reported:.2} um");
            sample_errors.extend(samples);
        }
    }
    let rms = (sample_errors.iter().map(|e| e * e).sum::<f64>() / sample_errors.len() as f64).sqrt();
    println!("gamma1 error of a recorded sample over a = 0.3-3 mm: {rms:.2} um rms");
    assert!(rms <= 2.0, "{rms} um");
}

/// Contact onset as a Tac3D streams it: frames of the simulated sensor at
/// 30 Hz while the stage presses on at 6 µm/s, each one encoded as the vendor's
/// main program sends it (YAML head and binary blob over UDP datagrams of the
/// Ethernet MTU), reassembled from datagrams that arrive out of order, decoded
/// and measured by the run's estimator. No recording of a real Tac3D is in the
/// repository, so the frames are the simulated marker field's: what this holds
/// is the codec and the estimator together, against a known truth. The
/// estimator has first seen one press to gamma1 = 0.5 mm and back, as a run's
/// approach gives it. Every decoded frame must equal the one sent, and gamma1
/// must rise with the truth without a step: each half-second mean within four
/// of its standard errors and 1.5 µm of the truth, from before the contact
/// until gamma1 = 50 µm.
#[test]
fn tac3d_frames_through_contact_onset_decode_and_give_a_smooth_gamma1() {
    use devices::sensor::tac3d::{Tac3dFrame, Tac3dReassembler, encode_frame};
    use easycalib::sensing::FrameEstimator;
    let rig = Rig::new(VirtualClock::new(1.0), axis(), axis());
    let mut sensor = RigSensor::new(rig, SensorSimConfig::default()).unwrap();
    let mut estimator = FrameEstimator::new(SensingConfig::for_contact(5.0, 33.0));
    let pose = |stage_mm: f64| RigPose { t_s: 0.0, stage_mm, rot_deg: 0.0 };
    let mut reassembler = Tac3dReassembler::new(std::time::Duration::from_secs(1));
    let mut replay = |frame: &SensorFrame| -> SensorFrame {
        let mut packets = encode_frame(&Tac3dFrame::from_sensor_frame(frame, "HDL1-SIM0001"), 1472).unwrap();
        packets.reverse();
        let now = std::time::Instant::now();
        let mut out = None;
        for p in &packets {
            if let Some(f) = reassembler.push(p, now).unwrap() {
                out = Some(f.to_sensor_frame().unwrap());
            }
        }
        let got = out.expect("every datagram of the frame arrived");
        assert_eq!((got.index, got.positions.len()), (frame.index, frame.positions.len()));
        assert!(got.displacements.iter().zip(&frame.displacements).all(|(a, b)| a == b), "frame {}", frame.index);
        got
    };
    // The approach's first pass: in to gamma1 = 0.5 mm in 50 µm steps, six frames each, and out.
    let steps: Vec<f64> = (0..=14).map(|k| 0.05 * k as f64).collect();
    for &s in steps.iter().chain(steps.iter().rev()) {
        for _ in 0..6 {
            let f = replay(&sensor.frame_at_pose(&pose(s)));
            let _ = estimator.measure(&f);
        }
    }
    assert!(estimator.curvature().is_some(), "the press taught the estimator the contact");
    // Onset: from 20 µm above the contact to 70 µm in, 6 µm/s at 30 frames/s.
    let (mut window, mut worst) = (Vec::new(), 0.0f64);
    println!("stage um  truth um  mean um  sd um");
    for k in 0..=450 {
        let stage = -0.02 + 0.0002 * k as f64;
        let truth = sensor.truth(&pose(stage)).map_or(0.0, |t| t.normal.gamma1_mm);
        let f = replay(&sensor.frame_at_pose(&pose(stage)));
        let m = match estimator.measure(&f) {
            Ok(m) => (m.gamma1_mm, m.gamma1_sd_mm),
            Err(SensingError::NoContact { .. }) => (0.0, f64::NAN),
            Err(e) => panic!("frame {}: {e}", f.index),
        };
        window.push((truth, m));
        if window.len() == 15 {
            let n = window.len() as f64;
            let truth = window.iter().map(|w| w.0).sum::<f64>() / n;
            let mean = window.iter().map(|w| w.1.0).sum::<f64>() / n;
            // Frames that saw no contact are as uncertain as those that did.
            let sds: Vec<f64> = window.iter().map(|w| w.1.1).filter(|s| s.is_finite()).collect();
            let typical =
                if sds.is_empty() { 0.004 } else { (sds.iter().map(|s| s * s).sum::<f64>() / sds.len() as f64).sqrt() };
            let sd = typical / n.sqrt();
            println!("{:8.1}  {:8.2}  {:7.2}  {:5.2}", stage * 1e3, truth * 1e3, mean * 1e3, sd * 1e3);
            let err = (mean - truth).abs();
            worst = worst.max(err * 1e3);
            if truth <= 0.05 {
                assert!(
                    err <= 4.0 * sd + 0.0015,
                    "stage {stage:.4} mm: gamma1 {mean:.5} mm, truth {truth:.5} mm, sd {sd:.5}"
                );
            }
            window.clear();
        }
    }
    println!("largest half-second error through onset: {worst:.2} um");
}

/// theta1's reported error is its error at torsion sizes: over 1500 frames of
/// a twisted Hertz contact with 4 µm marker noise (the noise known, as the
/// run's estimator pools it), the mean square of error / reported error is
/// 1 within its sampling scatter. The markers' radial contraction (nu1 < 0.5)
/// makes the angle noisier than sigma / sqrt(sum r^2) by 3-7 %; without it
/// this came out 1.06-1.15.
#[test]
fn theta1_errors_are_what_the_rotation_fit_reports() {
    let grid = MarkerGrid::tac3d();
    let mut rng = Rng::seed_from(9);
    for (a, gamma1, theta, centre) in
        [(2.7, 1.2, 0.05, [0.0, 0.0]), (2.7, 1.2, 0.05, [0.13, -0.21]), (2.0, 0.7, 0.03, [0.0, 0.0])]
    {
        let state = ContactState::new(centre, gamma1, a, theta).with_nu1(0.39).with_spheres(5.0, 33.0);
        let cfg = SensingConfig { marker_noise_mm: Some((0.004, 0.004)), ..SensingConfig::for_contact(5.0, 33.0) };
        let n = 1500;
        let z2 = (0..n)
            .map(|k| {
                let f = synth_frame(&state, &grid, &NoiseConfig::gaussian(0.004), &mut rng, k, 0.0);
                let m = measure(&f, &cfg).unwrap();
                ((m.theta1_deg - theta.to_degrees()) / m.theta1_std_deg).powi(2)
            })
            .sum::<f64>()
            / n as f64;
        println!("a {a} mm, centre {centre:?}: mean square of error / reported {z2:.3}");
        // chi2 of 1500 degrees of freedom over 1500: 1 +- 0.037.
        assert!((0.9..=1.11).contains(&z2), "a {a} centre {centre:?}: {z2}");
    }
}

/// An adhesive (JKR) contact is Hertz's field for its radius plus a flat
/// punch's (docs/sensing.md, "Adhesive contacts"): the same inside the
/// contact, steeper outside. Small ones (under ~2 pitches), fitted with the
/// curvature learnt on resolved contacts, read their depth without the
/// punch's bias: the estimator tries the punch on a tied fit that leaves
/// more than chance in its residuals, and once ten frames have shown it,
/// takes the gel as tacky and reads every small contact with it.
#[test]
fn an_adhesive_contact_reads_its_depth() {
    use easycalib::sensing::FrameEstimator;
    let grid = MarkerGrid::tac3d();
    let noise = NoiseConfig::gaussian(0.004);
    let mut rng = Rng::seed_from(12);
    // The default pair's curvature inside the contact, gamma1 / a^2.
    let c = 0.1744;
    let centre = [0.0, 0.0];
    let mut estimator = FrameEstimator::new(SensingConfig::for_contact(5.0, 33.0));
    let mut index = 0;
    let mut frame = |a: f64, punch: f64, rng: &mut Rng| {
        index += 1;
        let state = ContactState::new(centre, c * a * a + punch, a, 0.0)
            .with_nu1(0.39)
            .with_punch(punch)
            .with_spheres(5.0, 33.0);
        (state.gamma1_mm, synth_frame(&state, &grid, &noise, rng, index, 0.0))
    };
    // Resolved contacts teach the curvature and centre (the deep loading branch).
    for k in 0..120 {
        let (_, f) = frame(3.0 - 1.4 * (k as f64 / 120.0), 0.0, &mut rng);
        let _ = estimator.measure(&f);
    }
    assert!(estimator.curvature().is_some() && estimator.centre().is_some(), "nothing learnt");
    println!("    a mm  punch um   bias um (100 frames, 4 um noise)");
    // The unloading branch of 500 mJ/m^2 on the default pair (punches of
    // -0.15 to -0.19 mm at contacts of 1.2-1.8 mm), Hertz (no punch), and
    // the loading branch's smaller punches (-0.075 to -0.094 mm).
    let cases = [
        (1.8, -0.186, 1.0),
        (1.6, -0.175, 1.0),
        (1.4, -0.16, 1.0),
        (1.2, -0.15, 1.0),
        (1.6, 0.0, 1.0),
        (1.2, 0.0, 1.0),
        // One frame cannot tell these from Hertz beyond chance (they read
        // 3.3-3.5 um low that way); the frames above have shown the gel
        // tacky, so the punch is now the model (docs/sensing.md).
        (1.4, -0.094, 2.0),
        (1.25, -0.088, 2.0),
        (1.05, -0.08, 2.0),
    ];
    for (a, punch, bar) in cases {
        let errs: Vec<f64> = (0..100)
            .map(|_| {
                let (truth, f) = frame(a, punch, &mut rng);
                (estimator.measure(&f).expect("a contact").gamma1_mm - truth) * 1e3
            })
            .collect();
        let bias = errs.iter().sum::<f64>() / errs.len() as f64;
        println!("{a:8.2}  {:8.0}   {bias:+7.2}", punch * 1e3);
        // Without the punch term these read 4-30 um low.
        assert!(bias.abs() <= bar, "a {a}, punch {punch}: bias {bias:+.2} um");
    }
}

/// The surface of a 5 mm gel bonded to its window under the 5 mm hemisphere
/// (exact spheres), from the project's finite-element reference (`fem`):
/// each body's surface compliance at every gel surface node under the
/// contact's nodal forces, and the stuck twist of that contact. The
/// Tac3D-like pair of the test data: gel E1 0.33 MPa; indenter 1.1 MPa,
/// 0.39; the gel's Poisson's ratio as asked. A field our sensor model did
/// not draw.
struct FeLayer {
    radii: Vec<f64>,
    press: fem::elastic::SurfaceCompliance,
    /// Gel twist compliance over all surface nodes, and the indenter's on
    /// the contact nodes (both divided by their shear moduli).
    twist_gel: Vec<Vec<f64>>,
    twist_indenter: Vec<Vec<f64>>,
    model: fem::forward::Model,
}

/// One surface state of [`FeLayer`] at every gel surface node: depression
/// (mm, into the gel), outward and twist displacements (mm), and the
/// contact's radius.
struct FeSurface {
    w: Vec<f64>,
    u_r: Vec<f64>,
    u_theta: Vec<f64>,
    a: f64,
}

impl FeLayer {
    fn new(nu1: f64) -> Self {
        let (e1, e2, nu2, r2, h) = (0.33, 1.1, 0.39, 5.0, 5.0);
        let mesh = fem::forward::gel_mesh(h).unwrap();
        let radii = mesh.surface_radii();
        let contact: Vec<f64> = radii.iter().copied().filter(|&r| r < 0.97 * r2).collect();
        let hemisphere = fem::Mesh::hemisphere(r2, &contact, 30).unwrap();
        let (g1, g2) = (e1 / (2.0 * (1.0 + nu1)), e2 / (2.0 * (1.0 + nu2)));
        let scaled = |c: Vec<Vec<f64>>, g: f64| -> Vec<Vec<f64>> {
            c.into_iter().map(|col| col.into_iter().map(|v| v / g).collect()).collect()
        };
        let twist_gel = scaled(fem::torsion::TorsionBody::new(&mesh).unwrap().surface_compliance(&mesh.surface), g1);
        let twist_indenter =
            scaled(fem::torsion::TorsionBody::new(&hemisphere).unwrap().surface_compliance(&hemisphere.surface), g2);
        let press =
            fem::Body::new(mesh, fem::Material { e_mpa: e1, nu: nu1 }).unwrap().surface_compliance_rz(usize::MAX);
        let model = fem::forward::Forward::new(h, e2, nu2, r2).unwrap().model(e1, nu1);
        Self { radii, press, twist_gel, twist_indenter, model }
    }

    /// The frictionless press at approach `delta`, the contact then twisted
    /// by `twist_rad` with its whole contact stuck.
    fn surface(&self, delta: f64, twist_rad: f64) -> FeSurface {
        let st = self.model.normal(delta).unwrap();
        let n = self.radii.len();
        let (mut w, mut u_r) = (vec![0.0; n], vec![0.0; n]);
        for (j, &p) in st.nodal_force.iter().enumerate().filter(|(_, p)| **p != 0.0) {
            for i in 0..n {
                w[i] += self.press.zz[j][i] * p;
                u_r[i] -= self.press.rz[j][i] * p;
            }
        }
        // Stuck twist: the nodes in contact off the axis turn with the
        // platform, sum_j (C_gel + C_ind)[j][i] t_j = twist r_i.
        let last = st.nodal_force.iter().rposition(|&p| p > 0.0).unwrap_or(0);
        let stuck: Vec<usize> = (1..=last).collect();
        let mut u_theta = vec![0.0; n];
        if twist_rad != 0.0 && !stuck.is_empty() {
            let mut a: Vec<Vec<f64>> = stuck
                .iter()
                .map(|&i| stuck.iter().map(|&j| self.twist_gel[j][i] + self.twist_indenter[j][i]).collect())
                .collect();
            let mut t: Vec<f64> = stuck.iter().map(|&i| twist_rad * self.radii[i]).collect();
            // Gaussian elimination (symmetric positive definite, tens of nodes).
            let m = t.len();
            for c in 0..m {
                let pivot = a[c].clone();
                for r in c + 1..m {
                    let f = a[r][c] / pivot[c];
                    a[r][c..].iter_mut().zip(&pivot[c..]).for_each(|(x, p)| *x -= f * p);
                    t[r] -= f * t[c];
                }
            }
            for r in (0..m).rev() {
                let s: f64 = (r + 1..m).map(|k| a[r][k] * t[k]).sum();
                t[r] = (t[r] - s) / a[r][r];
            }
            for (i, u) in u_theta.iter_mut().enumerate() {
                *u = stuck.iter().zip(&t).map(|(&j, tj)| self.twist_gel[j][i] * tj).sum();
            }
        }
        FeSurface { w, u_r, u_theta, a: st.contact_radius_mm[0] }
    }

    /// The approach whose contact reaches radius `a`.
    fn approach_for(&self, a: f64) -> f64 {
        let (mut lo, mut hi) = (1e-4, 4.5);
        for _ in 0..40 {
            let mid = 0.5 * (lo + hi);
            if self.model.normal(mid).unwrap().contact_radius_mm[0] < a { lo = mid } else { hi = mid }
        }
        hi
    }

    /// `v` (at the surface nodes) at radius `r`, linear between nodes.
    fn at(&self, v: &[f64], r: f64) -> f64 {
        let k = self.radii.partition_point(|&x| x <= r).clamp(1, self.radii.len() - 1);
        let t = ((r - self.radii[k - 1]) / (self.radii[k] - self.radii[k - 1])).min(1.0);
        v[k - 1] + t * (v[k] - v[k - 1])
    }

    /// A Tac3D frame of `surface` centred at `centre`, with 4 µm of noise.
    fn frame(&self, surface: &FeSurface, centre: [f64; 2], rng: &mut Rng, index: u64) -> SensorFrame {
        let grid = MarkerGrid::tac3d();
        let sigma = 0.004;
        let displacements = grid
            .positions
            .iter()
            .map(|p| {
                let (dx, dy) = (p[0] - centre[0], p[1] - centre[1]);
                let r = dx.hypot(dy);
                let (ex, ey) = if r > 0.0 { (dx / r, dy / r) } else { (0.0, 0.0) };
                let (w, u, v) = (self.at(&surface.w, r), self.at(&surface.u_r, r), self.at(&surface.u_theta, r));
                [
                    u * ex - v * ey + sigma * rng.normal(),
                    u * ey + v * ex + sigma * rng.normal(),
                    -w + sigma * rng.normal(),
                ]
            })
            .collect();
        SensorFrame { index, t_s: 0.0, positions: grid.positions, displacements }
    }
}

/// The estimator on the finite-element layer's own surface ([`FeLayer`]),
/// Tac3D grid and 4 µm noise, with the 5 mm bonded layer declared. As in a
/// run, an approach to a 2.2 mm contact teaches the contact's centre and
/// curvature and where the gel lies between the layer's two tabulated gels
/// (nu1 0.35 and 0.49); then contacts of 0.4-4 mm must read within 3 µm each
/// and 2 µm rms over the sizes (mean of 60 frames each; measured within 1.2
/// µm), on gels of nu1 0.39 and 0.48 (neither is tabulated), the gel must
/// not be taken as tacky, and the wetter gel must learn the higher weight.
/// The estimator that takes the gel as a half-space is printed beside it:
/// it read the same contacts up to 12 µm shallow and took both gels as tacky
/// (docs/sensing.md, "On a layer").
#[test]
fn a_bonded_gels_own_field_reads_its_depth_at_every_contact_size() {
    use easycalib::sensing::{FrameEstimator, LayerSurface};
    let declared = LayerSurface::declared(sim::physics::Layer::bonded(5.0), sim::physics::Body::new(1.1, 0.39, 5.0))
        .expect("the layer model");
    let radii = [0.4, 0.6, 0.8, 1.0, 1.25, 1.5, 1.75, 2.0, 2.5, 3.0, 4.0];
    let mut weights = Vec::new();
    for (nu1, centre) in [(0.39, [0.0, 0.0]), (0.48, [0.5, 0.5])] {
        let layer = FeLayer::new(nu1);
        let surfaces: Vec<FeSurface> = radii.iter().map(|&a| layer.surface(layer.approach_for(a), 0.0)).collect();
        let learn = layer.surface(layer.approach_for(2.2), 0.0);
        let mut biases = Vec::new();
        for declare in [true, false] {
            let mut cfg = SensingConfig::for_contact(5.0, f64::INFINITY);
            cfg.layer = declare.then(|| declared.clone());
            let mut estimator = FrameEstimator::new(cfg);
            let mut rng = Rng::seed_from(31);
            for k in 0..20 {
                let _ = estimator.measure(&layer.frame(&learn, centre, &mut rng, k));
            }
            let bias: Vec<f64> = surfaces
                .iter()
                .map(|surface| {
                    let errs: Vec<f64> = (0..60)
                        .filter_map(|k| estimator.measure(&layer.frame(surface, centre, &mut rng, 100 + k)).ok())
                        .map(|m| (m.gamma1_mm - surface.w[0]) * 1e3)
                        .collect();
                    assert!(errs.len() >= 55, "nu1 {nu1}, a {:.2} mm: {} of 60 frames read", surface.a, errs.len());
                    errs.iter().sum::<f64>() / errs.len() as f64
                })
                .collect();
            if declare {
                weights.push(estimator.layer_weight().expect("a weight learnt on the approach"));
                assert!(!estimator.is_tacky(), "nu1 {nu1}: a clean layer taken as tacky");
            } else {
                println!("nu1 {nu1}, read as a half-space: tacky {}", estimator.is_tacky());
            }
            biases.push(bias);
        }
        println!(
            "nu1 {nu1} (weight learnt {:.3})\n  a mm   gamma1 um   bias um: layer declared / half-space",
            weights[weights.len() - 1]
        );
        for (k, surface) in surfaces.iter().enumerate() {
            println!("  {:5.2}  {:9.1}   {:+6.2} / {:+6.2}", surface.a, surface.w[0] * 1e3, biases[0][k], biases[1][k]);
        }
        let rms = (biases[0].iter().map(|b| b * b).sum::<f64>() / biases[0].len() as f64).sqrt();
        println!("  rms {rms:.2} um");
        assert!(rms <= 2.0, "nu1 {nu1}: rms bias {rms:.2} um over the sizes");
        for (b, surface) in biases[0].iter().zip(&surfaces) {
            assert!(b.abs() <= 3.0, "nu1 {nu1}, a {:.2} mm: bias {b:+.2} um", surface.a);
        }
    }
    assert!(weights[0] < weights[1], "weights {weights:?}: the wetter gel must lie nearer nu1 0.49");
}

/// theta1 from the finite-element layer's own stuck twist ([`FeLayer`]):
/// on a layer the gel's surface does not turn rigidly inside the contact
/// (its twist u_theta / r varies by a few percent across it), so what the
/// sensor reports must be what the fit's model computes, the area-weighted
/// least-squares twist over the contact disc (`fem::forward`,
/// `contact_twist`). The estimator's rotation fit over the markers inside
/// 0.95 of the contact radius must come within 0.5 % of it at the torsion
/// depth (a = 4.4 mm; mean of 90 frames over three contact centres, 4 µm
/// noise); shallower contacts are printed.
#[test]
fn a_bonded_gels_own_twist_reads_as_the_model_takes_it() {
    let layer = FeLayer::new(0.39);
    let twist = 0.05;
    println!("a mm   area-weighted theta1/twist   estimator's error (90 frames)");
    for (stage, held) in [(2.0, false), (3.0, false), (3.8, true)] {
        let surface = layer.surface(stage, twist);
        // The area-weighted twist over the contact disc, on a fine quadrature.
        let n = 4000;
        let (num, den) = (0..n).fold((0.0, 0.0), |(num, den), k| {
            let r = surface.a * (k as f64 + 0.5) / n as f64;
            (num + layer.at(&surface.u_theta, r) * r * r, den + r * r * r)
        });
        let truth = num / den;
        let mut rng = Rng::seed_from(5);
        let cfg = SensingConfig::for_contact(5.0, f64::INFINITY);
        let mut errs = Vec::new();
        for centre in [[0.0, 0.0], [0.5, 0.5], [0.2, -0.3]] {
            for k in 0..30 {
                let m = measure(&layer.frame(&surface, centre, &mut rng, k), &cfg).unwrap();
                errs.push((m.theta1_deg.to_radians() / truth - 1.0) * 100.0);
            }
        }
        let mean = errs.iter().sum::<f64>() / errs.len() as f64;
        println!("{:5.2}  {:.4}   {mean:+.2} %", surface.a, truth / twist);
        assert!(!held || mean.abs() <= 0.5, "a {:.2} mm: theta1 {mean:+.2} % off the model's", surface.a);
    }
}

/// A run's approach presses the gel once, to about half a millimetre, before
/// any frame has taught the contact's curvature, and the probe for a flat
/// punch needs that curvature. Those frames are kept and probed once it is
/// known, so a tacky gel is found tacky before the sweep: the sweep's first
/// contacts (under a pitch) cannot show a punch frame by frame, and read
/// 5-9 µm low as Hertz (the emulated rig at 500 mJ/m², docs/sensing.md,
/// "Adhesive contacts"). A clean gel pressed the same way is not.
#[test]
fn the_approachs_frames_decide_whether_the_gel_is_tacky() {
    use easycalib::sensing::FrameEstimator;
    let grid = MarkerGrid::tac3d();
    let noise = NoiseConfig::gaussian(0.004);
    // The default pair's curvature inside the contact, gamma1 / a^2.
    let c = 0.1744;
    // The gel's share of JKR's punch on an advancing edge (G = w, 500
    // mJ/m², sim::effects::adhesion): -sqrt(2 pi w a / E*) with the default
    // pair's E* = 0.2993 MPa, times the gel's share of the compliance, 0.769.
    let loading_punch = |a: f64| -0.769 * (2.0 * std::f64::consts::PI * 500e-6 * a / 0.2993).sqrt();
    for (tacky, seed) in [(true, 31), (true, 32), (false, 33), (false, 34)] {
        let mut rng = Rng::seed_from(seed);
        let mut estimator = FrameEstimator::new(SensingConfig::for_contact(5.0, 33.0));
        let mut index = 0;
        let mut frame = |a: f64, punch: f64, rng: &mut Rng| {
            index += 1;
            let punch = if tacky { punch } else { 0.0 };
            let state = ContactState::new([0.0, 0.0], c * a * a + punch, a, 0.0)
                .with_nu1(0.39)
                .with_punch(punch)
                .with_spheres(5.0, 33.0);
            (state.gamma1_mm, synth_frame(&state, &grid, &noise, rng, index, 0.0))
        };
        // The approach: a search step into the gel, then the refining press,
        // as the emulated rig's (8 and 6 frames).
        for (a, n) in [(1.55, 8), (1.85, 6)] {
            for _ in 0..n {
                let (_, f) = frame(a, loading_punch(a), &mut rng);
                estimator.measure(&f).expect("a resolved contact");
            }
        }
        // The sweep's first contacts, under a pitch.
        let mut errs = Vec::new();
        for _ in 0..12 {
            let (truth, f) = frame(1.05, loading_punch(1.05), &mut rng);
            let m = estimator.measure(&f).expect("a contact");
            errs.push((m.gamma1_mm - truth) * 1e3);
        }
        let bias = errs.iter().sum::<f64>() / errs.len() as f64;
        println!("tacky gel {tacky}: taken as tacky {}, a 1.05 mm contact reads {bias:+.2} µm", estimator.is_tacky());
        assert_eq!(estimator.is_tacky(), tacky, "seed {seed}");
        assert!(bias.abs() <= 2.0, "seed {seed}: the sweep's first contacts read {bias:+.2} µm off");
    }
}

/// A JKR contact under a pitch pulls by more than it presses: at a = 0.85 mm
/// on the default pair at 500 mJ/m² the gel's punch is -73 µm against a
/// depth of 53 µm. The tied punch fit must reach that valley from the tied
/// Hertz fit's depth; started from small punches only, a noise-free frame
/// read 21 µm low at 0.85 mm and 12 µm low at 0.9 mm. Under about 0.8 mm the
/// markers see a few micrometres of the field at most, and the frame reads
/// as no contact (docs/sensing.md, "Adhesive contacts").
#[test]
fn a_tacky_gels_contact_under_a_pitch_reads_its_depth() {
    use easycalib::sensing::FrameEstimator;
    let grid = MarkerGrid::tac3d();
    let c = 0.1744;
    // The gel's share of JKR's punch on an advancing edge (as in
    // `the_approachs_frames_decide_whether_the_gel_is_tacky`).
    let loading_punch = |a: f64| -0.769 * (2.0 * std::f64::consts::PI * 500e-6 * a / 0.2993).sqrt();
    let mut rng = Rng::seed_from(41);
    let mut estimator = FrameEstimator::new(SensingConfig::for_contact(5.0, 33.0));
    let mut index = 0;
    let mut frame = |a: f64, punch: f64, sigma: f64, rng: &mut Rng| {
        index += 1;
        let state = ContactState::new([0.0, 0.0], c * a * a + punch, a, 0.0)
            .with_nu1(0.39)
            .with_punch(punch)
            .with_spheres(5.0, 33.0);
        (state.gamma1_mm, synth_frame(&state, &grid, &NoiseConfig::gaussian(sigma), rng, index, 0.0))
    };
    // The run has learnt the curvature and found the gel tacky.
    for (a, n) in [(1.55, 8), (1.85, 6), (1.6, 30)] {
        for _ in 0..n {
            let (_, f) = frame(a, loading_punch(a), 0.004, &mut rng);
            estimator.measure(&f).expect("a resolved contact");
        }
    }
    assert!(estimator.is_tacky(), "the gel is not taken as tacky");
    for a in [0.85, 0.9, 0.95] {
        let (truth, f) = frame(a, loading_punch(a), 1e-7, &mut rng);
        let read = estimator.measure(&f).expect("a contact").gamma1_mm;
        println!("a {a} mm, punch {:.1} µm: noise-free {:+.3} µm off", loading_punch(a) * 1e3, (read - truth) * 1e3);
        // (within the learnt curvature's error)
        assert!((read - truth).abs() < 5e-4, "a {a}: noise-free frame reads {:+.2} µm off", (read - truth) * 1e3);
    }
    // With the sensor's noise the 0.9 mm contact reads without a lean.
    let errs: Vec<f64> = (0..60)
        .map(|_| {
            let (truth, f) = frame(0.9, loading_punch(0.9), 0.004, &mut rng);
            (estimator.measure(&f).expect("a contact").gamma1_mm - truth) * 1e3
        })
        .collect();
    let bias = errs.iter().sum::<f64>() / errs.len() as f64;
    println!("a 0.9 mm, 4 µm noise: bias {bias:+.2} µm over 60 frames");
    assert!(bias.abs() <= 1.0, "a 0.9 mm contact leans {bias:+.2} µm");
}

/// The field the layer's sensing reads is the finite-element layer's
/// ([`FeLayer`]; `sensing::LayerSurface` tabulates the same model). Checked
/// here against physics it did not make: the analytical layer (sim's
/// `LayeredNormal`, exact spheres), whose surface outside the contact is the
/// Hankel transform of its contact pressure through the bonded layer's
/// kernel. Outside contacts of 0.5-2.5 mm on the 5 mm bonded gel, the two
/// surfaces, each over its own axis deflection, must agree to 2.5 % of it
/// where Hertz's shape is off by up to 25 % (measured: within 1.8 %, the
/// largest at 0.5-1 mm contacts, of either sign from one contact size to
/// the next, the FE's nodes touching down; 0.3-0.8 % at 1.5-2.5 mm). The two
/// also differ in the indenter (the FE's hemisphere against a half-space with
/// a sphere's profile) and the gel's width (the FE's 15 mm radius against an
/// unbounded layer).
#[test]
fn the_layers_field_outside_the_contact_is_the_analytical_layers() {
    use sim::physics::{Body, ContactPair, Layer, LayeredNormal, Profile};
    for nu1 in [0.39, 0.48] {
        let fe = FeLayer::new(nu1);
        let pair = ContactPair { elastomer: Body::new(0.33, nu1, f64::INFINITY), indenter: Body::new(1.1, 0.39, 5.0) };
        let exact = LayeredNormal::with_profile(&pair, &Layer::bonded(5.0), 4.9, Profile::Sphere).unwrap();
        let mut worst: (f64, f64, f64) = (0.0, 0.0, 0.0);
        let mut off_hertz: f64 = 0.0;
        for a_target in [0.5, 1.0, 1.5, 2.0, 2.5] {
            let s = fe.surface(fe.approach_for(a_target), 0.0);
            let w0 = fe.at(&s.w, 0.0);
            let rho = [1.25, 1.5, 2.0, 2.5, 3.0];
            let r: Vec<f64> = rho.iter().map(|x| x * s.a).collect();
            let (axis, w) = exact.surface_deflection_mm(s.a, &r).expect("in contact");
            for ((x, r), w) in rho.iter().zip(&r).zip(&w) {
                let (fe_shape, an_shape) = (fe.at(&s.w, *r) / w0, w / axis);
                let hertz = easycalib::sensing::fit::hertz_shape(*x);
                println!("nu1 {nu1} a {:.3} r/a {x}: FE {fe_shape:.4} analytical {an_shape:.4} Hertz {hertz:.4}", s.a);
                if (fe_shape - an_shape).abs() > worst.0.abs() {
                    worst = (fe_shape - an_shape, s.a, *x);
                }
                off_hertz = off_hertz.max((an_shape - hertz).abs());
            }
        }
        println!(
            "nu1 {nu1}: worst FE - analytical {:+.4} of the axis deflection (a {:.2} mm, r/a {}); Hertz off by up to {off_hertz:.3}",
            worst.0, worst.1, worst.2
        );
        assert!(
            worst.0.abs() < 0.025,
            "nu1 {nu1}: the FE layer's field is {:+.4} off the analytical (a {:.2}, r/a {})",
            worst.0,
            worst.1,
            worst.2
        );
        assert!(off_hertz > 0.05, "the check must see the layer: Hertz's shape is only {off_hertz} off");
    }
}

/// On a declared layer the quadratic window's paraboloid is turned into
/// gamma1 through the layer's own field, and inside a deep contact that
/// field is not a paraboloid: the translation must be the paraboloid the
/// window fits at its own markers (1 mm apart, a few dozen), not over a
/// continuous disc. Noise-free frames of the field the emulated rig draws
/// (Hertz's plus the layer's departure, the layer known exactly: the FE
/// layer model's at the gel's own E1 and nu1), on either base, after an
/// approach that teaches the contact's centre and curvature as a run's does,
/// must read contacts from 2 mm to past 0.9 R2 within 0.25 µm, with the
/// centre between markers (measured within 0.01 µm) and off them (0.12 µm).
/// Read over a disc they read up to 1.75 µm shallow (docs/sensing.md, "The
/// deepest contacts").
#[test]
fn a_layers_own_field_reads_exactly_through_the_window_at_any_depth() {
    use easycalib::sensing::{FrameEstimator, LayerSurface};
    use sim::physics::{Body, Layer, LayerBase};
    use sim::sensor::field::synth_frame_on;
    let indenter = Body::new(1.1, 0.39, 5.0);
    for base in [LayerBase::Bonded, LayerBase::Sliding] {
        let layer = Layer { thickness_mm: 5.0, base, thickness_tol_mm: None };
        let law = easycalib::fit::fe_law::frictional_truth(layer, indenter, 0.33, 0.39, sim::defaults::GEL_FRICTION)
            .expect("the layer model");
        let shape = law.surface().expect("the layer's field");
        let surface = LayerSurface::of_gel(layer, indenter, 0.33, 0.39).expect("the layer's tables");
        let grid = MarkerGrid::tac3d();
        let mut rng = Rng::seed_from(3);
        for centre in [[0.0, 0.0], [0.31, -0.22]] {
            let frame = |delta: f64, rng: &mut Rng, k: u64| {
                let st = law.normal(delta).unwrap();
                let state = ContactState::new(centre, st.gamma1_mm, st.contact_radius_mm, 0.0)
                    .with_nu1(0.39)
                    .with_spheres(5.0, f64::INFINITY);
                (synth_frame_on(&state, Some(&shape), &grid, &NoiseConfig::NONE, rng, k, 0.0), st)
            };
            let mut cfg = SensingConfig::for_contact(5.0, f64::INFINITY);
            cfg.layer = Some(surface.clone());
            let mut estimator = FrameEstimator::new(cfg);
            // The approach, to a contact of about 2.2 mm.
            for k in 1..=30 {
                let _ = estimator.measure(&frame(0.8 * k as f64 / 30.0, &mut rng, k).0);
            }
            let mut worst: f64 = 0.0;
            for (k, delta) in [1.0, 1.5, 2.4, 3.0, 3.5, 4.0, 4.46].into_iter().enumerate() {
                let (f, st) = frame(delta, &mut rng, 100 + k as u64);
                let m = estimator.measure(&f).expect("a frame in contact");
                let err_um = (m.gamma1_mm - st.gamma1_mm) * 1e3;
                println!(
                    "{base:?}, centre {centre:?}: a {:.3} mm, gamma1 {:.1} um: read {err_um:+.3} um",
                    st.contact_radius_mm,
                    st.gamma1_mm * 1e3
                );
                worst = worst.max(err_um.abs());
            }
            assert!(worst <= 0.25, "{base:?}, centre {centre:?}: a contact read {worst:.3} um off its depth");
        }
    }
}
