//! Per-effect tests through the true rig: each effect's limit (the neutral
//! parameter gives the clean model), its documented signature (docs/physics.md 2.x),
//! and the physics numbers the note gives.

use super::*;
use crate::physics::{ContactPair, NormalModel, torsion_at};

fn pair() -> ContactPair {
    crate::defaults::pair()
}

/// Load 0 -> 3 mm in 0.05 mm steps, 1 s per step, and back.
fn sweep() -> Vec<CommandedPose> {
    let mut v: Vec<CommandedPose> =
        (0..=60).map(|i| CommandedPose { t_s: i as f64, stage_mm: i as f64 * 0.05, rot_deg: 0.0 }).collect();
    v.extend((0..60).rev().map(|i| CommandedPose { t_s: 120.0 - i as f64, stage_mm: i as f64 * 0.05, rot_deg: 0.0 }));
    v
}

/// Hold at the clean beta = 0.2 stage and twist 0 -> `amp` -> 0 in `n` steps each way.
fn twist(amp: f64, n: usize) -> Vec<CommandedPose> {
    let stage = NormalModel::new(pair()).unwrap().solve_for_gamma2(1.0).unwrap().delta_mm;
    let mut v: Vec<f64> = (0..=n).map(|i| amp * i as f64 / n as f64).collect();
    v.extend((0..n).rev().map(|i| amp * i as f64 / n as f64));
    v.iter().enumerate().map(|(i, &r)| CommandedPose { t_s: i as f64, stage_mm: stage, rot_deg: r }).collect()
}

fn run(profile: SimProfile, cmds: &[CommandedPose]) -> Vec<Reading> {
    simulate(pair(), &profile, cmds).unwrap()
}

fn clean(cmds: &[CommandedPose]) -> Vec<Reading> {
    run(SimProfile::default(), cmds)
}

fn max_diff(a: &[Reading], b: &[Reading]) -> (f64, f64) {
    a.iter().zip(b).fold((0.0f64, 0.0f64), |(g, t), (x, y)| {
        (g.max((x.gamma1_mm - y.gamma1_mm).abs()), t.max((x.theta1_deg - y.theta1_deg).abs()))
    })
}

fn all_cmds() -> Vec<CommandedPose> {
    let mut v = sweep();
    let n = v.len() as f64;
    v.extend(twist(8.0, 40).into_iter().map(|c| CommandedPose { t_s: c.t_s + n, ..c }));
    v
}

#[test]
fn neutral_parameters_give_the_clean_model() {
    let cmds = all_cmds();
    let c = clean(&cmds);
    // Effects outside the contact: bit for bit.
    let exact = [
        SimProfile { contact_offset: Some(contact_offset::Params { contact_offset_mm: 0.0 }), ..Default::default() },
        SimProfile { stage_backlash: Some(stage_backlash::Params { b_mm: 0.0, engaged: true }), ..Default::default() },
        SimProfile {
            rotation_backlash: Some(rotation_backlash::Params { b_deg: 0.0, engaged: true }),
            ..Default::default()
        },
        SimProfile {
            thermal_drift: Some(thermal_drift::Params { v_mm_per_s: 0.0, vdot_mm_per_s2: 0.0 }),
            ..Default::default()
        },
        SimProfile { sensor_gain: Some(sensor_gain::Params { g: 1.0 }), ..Default::default() },
    ];
    for p in exact {
        let r = run(p.clone(), &cmds);
        assert_eq!(max_diff(&r, &c), (0.0, 0.0), "{:?}", p.enabled());
    }
    // Effects inside the contact take their own solver: equal to round-off.
    let close = [
        SimProfile { frame_compliance: Some(frame_compliance::Params { c_mm_per_n: 0.0 }), ..Default::default() },
        SimProfile { adhesion: Some(adhesion::Params { w_mj_m2: 0.0, eta: 1.0 }), ..Default::default() },
        SimProfile {
            viscoelastic: Some(viscoelastic::Params { rho: 1.0, tau_s: 5.0, memory_n: 0.0 }),
            ..Default::default()
        },
    ];
    for p in close {
        let r = run(p.clone(), &cmds);
        let (g, t) = max_diff(&r, &c);
        assert!(g < 1e-9 && t < 1e-9, "{:?}: {g} mm {t} deg", p.enabled());
    }
    // Layer and friction have their limit at infinity: h -> inf, mu -> inf.
    let thick = run(
        SimProfile { finite_thickness: Some(finite_thickness::Params { h_mm: 1000.0 }), ..Default::default() },
        &cmds,
    );
    // The layer's effect vanishes like a/h: ten times thicker, ten times smaller.
    let (g, t) = max_diff(&thick, &c);
    assert!(g < 5e-3 && t < 2e-3, "{g} {t}");
    let thicker = run(
        SimProfile { finite_thickness: Some(finite_thickness::Params { h_mm: 100.0 }), ..Default::default() },
        &cmds,
    );
    let ratio = max_diff(&thicker, &c).0 / g;
    assert!(ratio > 8.0 && ratio < 11.0, "{ratio}");
    let sticky =
        run(SimProfile { partial_slip: Some(partial_slip::Params { mu: 100.0 }), ..Default::default() }, &cmds);
    let (g, t) = max_diff(&sticky, &c);
    assert!(g == 0.0 && t < 5e-3, "{g} {t}");
}

#[test]
fn finite_thickness_stiffens_at_depth_and_lowers_h3() {
    let cmds = sweep();
    let c = clean(&cmds);
    let l =
        run(SimProfile { finite_thickness: Some(finite_thickness::Params { h_mm: 5.0 }), ..Default::default() }, &cmds);
    // Relative shortfall of gamma1 grows with depth (chi = a/h grows).
    let rel = |i: usize| 1.0 - l[i].gamma1_mm / c[i].gamma1_mm;
    assert!(rel(5) > 0.0 && rel(20) > rel(5) && rel(60) > rel(20), "{} {} {}", rel(5), rel(20), rel(60));
    // Same on load and unload (no memory).
    assert_eq!(l[30].gamma1_mm, l[90].gamma1_mm);
    // Force at the same indentation is Hertz times Phi(a/h) in the rigid-indenter
    // limit; here the composite stiffens less, but the force at equal stage rises.
    assert!(l[60].force_n > c[60].force_n);
    // Torsion at the same indenter deformation gamma2 = 1 mm (beta = 0.2): the
    // stiffer layer makes a smaller contact, the contact compliances grow against
    // the rod's, and theta2/theta1 = H3 comes out low (the rod route, docs/physics.md 2.1).
    let layer = SimProfile { finite_thickness: Some(finite_thickness::Params { h_mm: 20.0 }), ..Default::default() };
    let stage_for_gamma2 = |p: &SimProfile| {
        let (mut lo, mut hi) = (0.0, 10.0);
        for _ in 0..100 {
            let mid = 0.5 * (lo + hi);
            let r = simulate(pair(), p, &[CommandedPose { t_s: 0.0, stage_mm: mid, rot_deg: 0.0 }]).unwrap();
            if r[0].gamma2_mm < 1.0 { lo = mid } else { hi = mid }
        }
        0.5 * (lo + hi)
    };
    let at = |p: &SimProfile| {
        let st = stage_for_gamma2(p);
        simulate(pair(), p, &[CommandedPose { t_s: 0.0, stage_mm: st, rot_deg: 4.0 }]).unwrap()[0]
    };
    let (lr, cr) = (at(&layer), at(&SimProfile::default()));
    assert!(lr.contact_radius_mm < cr.contact_radius_mm, "{} vs {}", lr.contact_radius_mm, cr.contact_radius_mm);
    let h3 = |r: &Reading| (4.0 - r.theta1_deg) / r.theta1_deg;
    let clean_h3 = crate::physics::h3_from_materials(&pair().elastomer, &pair().indenter, 0.2);
    assert!((h3(&cr) / clean_h3 - 1.0).abs() < 1e-6, "{} vs {clean_h3}", h3(&cr));
    assert!(h3(&lr) < clean_h3 * 0.99, "{} vs {clean_h3}", h3(&lr));
}

#[test]
fn adhesion_hysteresis_near_contact_and_negative_reading_on_unload() {
    let cmds = sweep();
    let c = clean(&cmds);
    let a =
        run(SimProfile { adhesion: Some(adhesion::Params { w_mj_m2: 80.0, eta: 3.0 }), ..Default::default() }, &cmds);
    // Load: contact larger than Hertz and gamma2/gamma1 raised at small depth (punch term has no Yoffe factor).
    assert!(a[2].contact_radius_mm > c[2].contact_radius_mm);
    let ratio = |r: &Reading| r.gamma2_mm / r.gamma1_mm;
    assert!(ratio(&a[2]) > ratio(&c[2]), "{} vs {}", ratio(&a[2]), ratio(&c[2]));
    // The effect fades with depth.
    let d = |i: usize| (a[i].gamma1_mm - c[i].gamma1_mm).abs() / c[i].gamma1_mm;
    assert!(d(60) < 0.2 * d(2), "{} {}", d(60), d(2));
    // Unload below load at small stage (pinned, then receding edge with eta w).
    assert!(a[118].gamma1_mm < a[2].gamma1_mm, "{} vs {}", a[118].gamma1_mm, a[2].gamma1_mm);
    // Back at stage 0: still in contact, surface pulled up (negative depth).
    assert!(a[120].in_contact && a[120].gamma1_mm < 0.0, "{:?}", a[120]);
    // JKR: on an advancing edge the energy release rate equals w.
    let r = a[10];
    let es = pair().composite_modulus_mpa();
    let hertz = 4.0 * es * r.contact_radius_mm.powi(3) / (3.0 * pair().composite_radius_mm());
    let dp = (r.force_n - hertz) / (2.0 * es * r.contact_radius_mm);
    let g = es * dp * dp / (2.0 * std::f64::consts::PI * r.contact_radius_mm);
    assert!((g / 80e-6 - 1.0).abs() < 1e-6, "G = {g}");
}

#[test]
fn viscoelastic_creeps_during_a_hold_and_saturates_at_the_relaxed_model() {
    let stage = 2.0;
    let cmds: Vec<CommandedPose> =
        (0..=400).map(|i| CommandedPose { t_s: i as f64 * 0.25, stage_mm: stage, rot_deg: 0.0 }).collect();
    let v = run(
        SimProfile {
            viscoelastic: Some(viscoelastic::Params { rho: 1.05, tau_s: 5.0, memory_n: 0.0 }),
            ..Default::default()
        },
        &cmds,
    );
    let relaxed = NormalModel::new(pair()).unwrap().solve(stage).unwrap().gamma1_mm;
    // Step load: gamma1 starts low (glassy elastomer) and rises towards the relaxed value.
    assert!(v[0].gamma1_mm < relaxed - 0.005, "{} vs {relaxed}", v[0].gamma1_mm);
    assert!(v[20].gamma1_mm > v[0].gamma1_mm && v[40].gamma1_mm > v[20].gamma1_mm);
    // Exponential approach: after 20 tau it is the relaxed (reported) modulus.
    assert!((v[400].gamma1_mm - relaxed).abs() < 1e-6, "{} vs {relaxed}", v[400].gamma1_mm);
    // About 1/e of the gap remains after one retardation time (force relaxes
    // with tau/rho, so between the two).
    let gap = |i: usize| relaxed - v[i].gamma1_mm;
    let frac = gap(20) / gap(0);
    assert!(frac > 0.25 && frac < 0.45, "{frac}");
    // Torsion hold: a twist step is met by the glassy elastomer (theta1 low), then
    // theta1 creeps up to the relaxed split with the same kernel.
    let st = NormalModel::new(pair()).unwrap().solve_for_gamma2(1.0).unwrap().delta_mm;
    let mut tw: Vec<CommandedPose> =
        (0..=200).map(|i| CommandedPose { t_s: i as f64 * 0.25, stage_mm: st, rot_deg: 0.0 }).collect();
    tw.extend((1..=200).map(|i| CommandedPose { t_s: 50.0 + i as f64 * 0.25, stage_mm: st, rot_deg: 5.0 }));
    let prof = SimProfile {
        viscoelastic: Some(viscoelastic::Params { rho: 1.05, tau_s: 5.0, memory_n: 0.0 }),
        ..Default::default()
    };
    let vt = run(prof, &tw);
    let relaxed_split = run(SimProfile::default(), &tw[400..])[0].theta1_deg;
    assert!(vt[201].theta1_deg < relaxed_split * 0.99, "{} vs {relaxed_split}", vt[201].theta1_deg);
    assert!(vt[240].theta1_deg > vt[201].theta1_deg);
    assert!((vt[400].theta1_deg / relaxed_split - 1.0).abs() < 2e-3, "{} vs {relaxed_split}", vt[400].theta1_deg);
    // Sweep: unload above load.
    let s = run(
        SimProfile {
            viscoelastic: Some(viscoelastic::Params { rho: 1.05, tau_s: 5.0, memory_n: 0.0 }),
            ..Default::default()
        },
        &sweep(),
    );
    assert!(s[90].gamma1_mm > s[30].gamma1_mm + 0.003);
}

#[test]
fn contact_offset_shifts_the_approach() {
    let cmds = sweep();
    let z0 = 0.012;
    let o = run(
        SimProfile { contact_offset: Some(contact_offset::Params { contact_offset_mm: z0 }), ..Default::default() },
        &cmds,
    );
    let m = NormalModel::new(pair()).unwrap();
    for (c, r) in cmds.iter().zip(&o) {
        assert_eq!(r.gamma1_mm, m.solve(c.stage_mm - z0).unwrap().gamma1_mm);
    }
    // Dead band below z0; negative z0: already in contact at stage 0.
    let neg = run(
        SimProfile { contact_offset: Some(contact_offset::Params { contact_offset_mm: -0.01 }), ..Default::default() },
        &cmds[..1],
    );
    assert!(neg[0].gamma1_mm > 0.0);
    assert!(
        run(
            SimProfile {
                contact_offset: Some(contact_offset::Params { contact_offset_mm: 0.06 }),
                ..Default::default()
            },
            &cmds[..2]
        )[1]
        .gamma1_mm
            == 0.0
    );
}

#[test]
fn stage_backlash_steps_at_reversal_and_shifts_the_unload_branch() {
    let b = 0.01;
    let mut cmds = sweep();
    // A half step back just after the turn: inside the play, nothing moves.
    cmds.insert(61, CommandedPose { t_s: 60.5, stage_mm: 3.0 - 0.004, rot_deg: 0.0 });
    let r = run(
        SimProfile { stage_backlash: Some(stage_backlash::Params { b_mm: b, engaged: true }), ..Default::default() },
        &cmds,
    );
    let c = clean(&cmds);
    assert_eq!(r[30].gamma1_mm, c[30].gamma1_mm, "load branch untouched");
    assert_eq!(r[61].gamma1_mm, r[60].gamma1_mm, "dead zone at the turn");
    let m = NormalModel::new(pair()).unwrap();
    for i in 62..cmds.len() - 1 {
        let expect = m.solve(cmds[i].stage_mm + b).unwrap().gamma1_mm;
        assert_eq!(r[i].gamma1_mm, expect, "unload at stage {}", cmds[i].stage_mm);
    }
    // Not engaged: the first b of loading is lost.
    let ne = run(
        SimProfile { stage_backlash: Some(stage_backlash::Params { b_mm: b, engaged: false }), ..Default::default() },
        &cmds,
    );
    assert_eq!(ne[30].gamma1_mm, m.solve(cmds[30].stage_mm - b).unwrap().gamma1_mm);
}

#[test]
fn frame_compliance_removes_c_times_f() {
    let cmds = sweep();
    let c = 0.01;
    let r = run(
        SimProfile { frame_compliance: Some(frame_compliance::Params { c_mm_per_n: c }), ..Default::default() },
        &cmds,
    );
    for (cmd, x) in cmds.iter().zip(&r).skip(1) {
        if cmd.stage_mm > 0.0 {
            let closure = x.gamma1_mm + x.gamma2_mm + c * x.force_n - cmd.stage_mm;
            assert!(closure.abs() < 1e-10, "{closure}");
        }
    }
    // The clean model at the approach that did reach the contact.
    let m = NormalModel::new(pair()).unwrap();
    let s = m.solve(3.0 - c * r[60].force_n).unwrap();
    assert!((s.gamma1_mm - r[60].gamma1_mm).abs() < 1e-9);
    assert!(r[30].gamma1_mm == r[90].gamma1_mm, "no memory");
}

#[test]
fn partial_slip_is_sublinear_at_large_twist_with_a_masing_return() {
    let tw = twist(8.0, 40);
    let c = clean(&tw);
    let s = run(SimProfile { partial_slip: Some(partial_slip::Params { mu: 0.5 }), ..Default::default() }, &tw);
    // Small twist: stick, the clean slope.
    assert!((s[1].theta1_deg / c[1].theta1_deg - 1.0).abs() < 0.01);
    // Sublinear: the secant falls with twist, and more with less friction.
    let sec = |i: usize| s[i].theta1_deg / tw[i].rot_deg;
    assert!(sec(20) < sec(5) && sec(30) < sec(20) && sec(40) < sec(30), "{} {} {}", sec(5), sec(20), sec(40));
    assert!(s[40].theta1_deg < 0.995 * c[40].theta1_deg, "{} vs {}", s[40].theta1_deg, c[40].theta1_deg);
    let more = run(SimProfile { partial_slip: Some(partial_slip::Params { mu: 0.35 }), ..Default::default() }, &tw);
    assert!(more[40].theta1_deg < s[40].theta1_deg);
    // The return does not retrace the outgoing branch.
    assert!((s[60].theta1_deg - s[20].theta1_deg).abs() > 1e-3);
    // Normal readings untouched.
    assert_eq!(s[10].gamma1_mm, c[10].gamma1_mm);
    // Low friction: the torque saturates towards Lubkin's M_max = 3 pi mu F a / 16,
    // so theta1 flattens; the twist needed for full gross slip diverges
    // (logarithmically), and past the tabulated range it is a typed error.
    let low =
        run(SimProfile { partial_slip: Some(partial_slip::Params { mu: 0.05 }), ..Default::default() }, &twist(8.0, 4));
    let inc: Vec<f64> = (1..=4).map(|i| low[i].theta1_deg - low[i - 1].theta1_deg).collect();
    assert!(inc.windows(2).all(|w| w[1] < w[0]) && inc[3] < 0.4 * inc[0], "{inc:?}");
    let err = simulate(
        pair(),
        &SimProfile { partial_slip: Some(partial_slip::Params { mu: 0.05 }), ..Default::default() },
        &twist(90.0, 2),
    );
    assert!(matches!(err, Err(EffectError::GrossSlip { .. })), "{err:?}");
}

#[test]
fn thermal_drift_grows_with_time_at_any_load() {
    let cmds: Vec<CommandedPose> =
        (0..=100).map(|i| CommandedPose { t_s: i as f64, stage_mm: 1.0, rot_deg: 0.0 }).collect();
    let c = clean(&cmds);
    let d = run(
        SimProfile {
            thermal_drift: Some(thermal_drift::Params { v_mm_per_s: 2e-4, vdot_mm_per_s2: 1e-6 }),
            ..Default::default()
        },
        &cmds,
    );
    // The frame brings the indenter closer by v t + vdot t^2 / 2: the contact is
    // the clean one at that approach, gel and indenter sharing the extra depth.
    let m = crate::physics::NormalModel::new(pair()).unwrap();
    let mut last = 0.0;
    for (i, (x, y)) in d.iter().zip(&c).enumerate() {
        let t = i as f64;
        let extra = 2e-4 * t + 0.5e-6 * t * t;
        let want = m.solve(1.0 + extra).unwrap();
        assert!((x.gamma1_mm - want.gamma1_mm).abs() < 1e-12 && (x.gamma2_mm - want.gamma2_mm).abs() < 1e-12);
        let rise = x.gamma1_mm - y.gamma1_mm;
        assert!(rise >= last && rise < extra + 1e-15, "{i}: {rise} vs {extra}");
        last = rise;
    }
    assert!(d[100].gamma2_mm > c[100].gamma2_mm + 1e-3);
}

#[test]
fn sensor_gain_maps_h1_without_changing_the_shape() {
    // gamma2_read = stage - g gamma1 = gamma2 + (1 - g) gamma1: to first order
    // H1 -> (H1 + 1 - g) / g (docs/physics.md 2.10), at small depth exactly.
    let g = 1.01;
    let cmds: Vec<CommandedPose> =
        [1e-6, 2e-6].iter().map(|&s| CommandedPose { t_s: 0.0, stage_mm: s, rot_deg: 0.0 }).collect();
    let r = run(SimProfile { sensor_gain: Some(sensor_gain::Params { g }), ..Default::default() }, &cmds);
    let c = clean(&cmds);
    let slope = |r: &[Reading], c: &[CommandedPose]| {
        let g2 = |i: usize| c[i].stage_mm - r[i].gamma1_mm;
        (g2(1) - g2(0)) / (r[1].gamma1_mm - r[0].gamma1_mm)
    };
    let h1 = slope(&c, &cmds);
    let h1g = slope(&r, &cmds);
    assert!((h1g - (h1 + 1.0 - g) / g).abs() < 1e-6, "{h1g} vs {}", (h1 + 1.0 - g) / g);
    // theta1 untouched.
    let tw = twist(4.0, 4);
    let rt = run(SimProfile { sensor_gain: Some(sensor_gain::Params { g }), ..Default::default() }, &tw);
    assert_eq!(rt[4].theta1_deg, clean(&tw)[4].theta1_deg);
    let _ = torsion_at;
}

#[test]
fn rotation_backlash_flat_step_and_parallel_return() {
    let tw = twist(8.0, 40);
    let b = 0.3;
    let r = run(
        SimProfile {
            rotation_backlash: Some(rotation_backlash::Params { b_deg: b, engaged: true }),
            ..Default::default()
        },
        &tw,
    );
    let c = clean(&tw);
    assert_eq!(r[40].theta1_deg, c[40].theta1_deg);
    // Return: the mount lags by b; 0.2 deg steps, so the first return step is flat.
    assert_eq!(r[41].theta1_deg, r[40].theta1_deg);
    let k = c[40].theta1_deg / 8.0;
    for i in 43..80 {
        assert!((r[i].theta1_deg - (c[i].theta1_deg + b * k)).abs() < 1e-9, "{i}");
    }
    // Not engaged: the first b of the outgoing twist is lost.
    let ne = run(
        SimProfile {
            rotation_backlash: Some(rotation_backlash::Params { b_deg: b, engaged: false }),
            ..Default::default()
        },
        &tw,
    );
    assert_eq!(ne[1].theta1_deg, 0.0);
    assert!((ne[20].theta1_deg - (c[20].theta1_deg - b * k)).abs() < 1e-9);
}

#[test]
fn profile_errors_name_the_effect_and_parameter() {
    let e = SimProfile::from_toml_str("[no_such_effect]\nx = 1\n").unwrap_err().to_string();
    assert!(e.contains("no_such_effect"), "{e}");
    let e = SimProfile::from_toml_str("[adhesion]\nw_mJ_m2 = 50.0\neta = 0.5\n").unwrap_err().to_string();
    assert!(e.contains("adhesion.eta"), "{e}");
    let e = SimProfile::from_toml_str("[partial_slip]\nmu = 1.0\nnu = 2.0\n").unwrap_err().to_string();
    assert!(e.contains("nu"), "{e}");
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("p.toml");
    let p = SimProfile {
        material: Some(Material { e1_mpa: 0.3, nu1: 0.4 }),
        viscoelastic: Some(viscoelastic::Params { rho: 1.03, tau_s: 4.0, memory_n: 0.0 }),
        thermal_drift: Some(thermal_drift::Params { v_mm_per_s: 1e-4, vdot_mm_per_s2: 0.0 }),
        ..Default::default()
    };
    p.save(&path).unwrap();
    assert_eq!(SimProfile::load(&path).unwrap(), p);
    let e = SimProfile::load(&dir.path().join("missing.toml")).unwrap_err().to_string();
    assert!(e.contains("missing.toml"), "{e}");
}

#[test]
fn catalogue_parameter_names_are_the_toml_keys() {
    // Every effect switched on (serialisation does not validate the combination).
    let p = SimProfile {
        finite_thickness: Some(finite_thickness::Params { h_mm: 5.0 }),
        adhesion: Some(adhesion::Params { w_mj_m2: 50.0, eta: 2.0 }),
        viscoelastic: Some(viscoelastic::Params { rho: 1.02, tau_s: 5.0, memory_n: 0.0 }),
        contact_offset: Some(contact_offset::Params { contact_offset_mm: 0.003 }),
        stage_backlash: Some(stage_backlash::Params { b_mm: 0.005, engaged: true }),
        frame_compliance: Some(frame_compliance::Params { c_mm_per_n: 0.003 }),
        partial_slip: Some(partial_slip::Params { mu: 1.0 }),
        rotation_backlash: Some(rotation_backlash::Params { b_deg: 0.1, engaged: true }),
        thermal_drift: Some(thermal_drift::Params { v_mm_per_s: 1e-5, vdot_mm_per_s2: 0.0 }),
        sensor_gain: Some(sensor_gain::Params { g: 1.01 }),
        material: None,
    };
    let v: toml::Table = toml::from_str(&p.to_toml_string().unwrap()).unwrap();
    for info in ALL {
        let sec = v[info.name].as_table().unwrap_or_else(|| panic!("{}", info.name));
        for par in info.params {
            assert!(sec.contains_key(par.name), "{}.{}", info.name, par.name);
            assert!(par.min < par.max);
        }
    }
    assert_eq!(p.enabled().len(), 10);
    assert!(matches!(p.validate(), Err(EffectError::Unsupported(_))));
}
