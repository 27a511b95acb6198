//! Rates of the diagnosis over many seeds (issue 6, "Must show"):
//!
//! * each identifiable effect is named in at least 90 % of its concealed seeds
//!   (the corpus case's parameters, `sim::corpus::cases`, with the seed
//!   varied), and its parameters' 95 % intervals cover the truth on the named
//!   seeds — at least 80 % of them, the slack a nominal 95 % interval needs over
//!   ten seeds (P(fewer than 8 of 10 cover) ~ 1 % at the nominal rate);
//! * after correction, on the named seeds where the report calls the effect's
//!   parameters well determined, E1 is within 1 % and nu1 within 3 % of the
//!   truth; where it calls them weakly determined (adhesion at the corpus's
//!   tack, mostly), the corrected E1/nu1 intervals cover the truth instead;
//! * effects the sweeps determine only weakly (a 100 mm layer, a compliant
//!   frame: both look like a depth-gain error) are reported as `ambiguous` with
//!   the truth among the listed explanations (or named), and the corrected E1/nu1
//!   intervals cover the truth;
//! * the report locates the mismatch (non-empty `mismatch`) on >= 90 % of the
//!   named seeds (except contact_offset, which is the baseline's own z0);
//! * clean controls: an effect is named, or a mismatch reported, in at most 5 %
//!   of them (at most 1 of 20).
//!
//! Before/after errors are printed: `cargo test --test diagnose_rates -- --nocapture`.
//! The recordings are simulated here (seeded), not read from files; the seeds
//! of each effect run on two threads.

use easycalib::diagnosis::{DiagnoseOptions, Diagnosis, diagnose};
use sim::corpus::{CorpusCase, cases};
use sim::effects::{Identifiability, SimProfile, info};

/// Seeds per effect and of clean controls.
const SEEDS: u64 = 10;
const CLEAN_SEEDS: u64 = 20;
/// Seeds start here (the corpus itself uses 21 and 22).
const FIRST_SEED: u64 = 1000;

/// One diagnosis and the truth it is judged against.
struct Outcome {
    seed: u64,
    d: Diagnosis,
    e1: f64,
    nu1: f64,
    /// True effect parameters by name (the profile's TOML keys).
    truth: toml::Table,
}

impl Outcome {
    fn named(&self, effect: &str) -> bool {
        self.d.effects.contains(&effect)
    }
    fn listed(&self, effect: &str) -> bool {
        self.d.ambiguous.iter().any(|a| a.effects.contains(&effect))
    }
    fn err_before(&self) -> (f64, f64) {
        ((self.d.baseline.e1_mpa / self.e1 - 1.0) * 100.0, (self.d.baseline.nu1 / self.nu1 - 1.0) * 100.0)
    }
    fn err_after(&self) -> (f64, f64) {
        ((self.d.corrected.e1_mpa / self.e1 - 1.0) * 100.0, (self.d.corrected.nu1 / self.nu1 - 1.0) * 100.0)
    }
    /// Whether every fitted parameter of `effect` has an interval holding the truth.
    fn param_covers(&self, effect: &str) -> bool {
        let Some(e) = self.d.explanation.iter().find(|e| e.effect == effect) else {
            return false;
        };
        e.params.iter().all(|p| {
            let t = self.truth.get(p.name).and_then(|v| v.as_float()).expect("truth of a fitted parameter");
            p.ci95[0].is_none_or(|lo| lo <= t) && p.ci95[1].is_none_or(|hi| t <= hi)
        })
    }
    /// Whether the report calls every parameter of `effect` well determined.
    fn well_determined(&self, effect: &str) -> bool {
        self.d.explanation.iter().filter(|e| e.effect == effect).all(|e| e.params.iter().all(|p| p.well_determined))
    }
    fn e1_nu1_cover(&self) -> bool {
        let c = &self.d.corrected.ci95;
        c.e1_mpa[0] <= self.e1 && self.e1 <= c.e1_mpa[1] && c.nu1[0] <= self.nu1 && self.nu1 <= c.nu1[1]
    }
    fn params_text(&self) -> String {
        self.d
            .explanation
            .iter()
            .flat_map(|e| e.params.iter())
            .map(|p| {
                let f = |v: Option<f64>| v.map_or("open".to_string(), |v| format!("{v:.4e}"));
                format!("{} {:.4e} [{}, {}]", p.name, p.value, f(p.ci95[0]), f(p.ci95[1]))
            })
            .collect::<Vec<_>>()
            .join(", ")
    }
}

fn corpus_case(effect: &str) -> CorpusCase {
    cases().into_iter().find(|c| c.effect == effect).expect("corpus case")
}

/// Diagnose `n` seeds of `case` (parameters fixed, seed varied), two threads.
fn run_seeds(case: &CorpusCase, n: u64) -> Vec<Outcome> {
    let truth: toml::Table = match toml::Value::try_from(&case.profile).expect("profile serialises") {
        toml::Value::Table(t) => t.get(case.effect.as_str()).and_then(|v| v.as_table()).cloned().unwrap_or_default(),
        _ => toml::Table::new(),
    };
    let seeds: Vec<u64> = (FIRST_SEED..FIRST_SEED + n).collect();
    let one = |seed: u64| {
        let mut c = case.clone();
        c.seed = seed;
        let rec = c.generate().expect("corpus case generates");
        let d = diagnose(&rec, &DiagnoseOptions::default()).expect("diagnosis runs");
        Outcome { seed, d, e1: case.e1_mpa, nu1: case.nu1, truth: truth.clone() }
    };
    let mut out: Vec<Outcome> = std::thread::scope(|s| {
        let (a, b): (Vec<u64>, Vec<u64>) = seeds.iter().partition(|s| *s % 2 == 0);
        let h = s.spawn(|| a.into_iter().map(one).collect::<Vec<_>>());
        let mut v: Vec<Outcome> = b.into_iter().map(one).collect();
        v.extend(h.join().expect("worker thread"));
        v
    });
    out.sort_by_key(|o| o.seed);
    for o in &out {
        let (eb, nb) = o.err_before();
        let (ea, na) = o.err_after();
        println!(
            "{:<18} seed {}: named {:?} ambiguous {:?} unexplained {} | E1 err {eb:+.2}% -> {ea:+.2}% | nu1 err {nb:+.2}% -> {na:+.2}% | {}",
            case.effect,
            o.seed,
            o.d.effects,
            o.d.ambiguous.iter().map(|a| a.effects.join("+")).collect::<Vec<_>>(),
            o.d.unexplained,
            o.params_text()
        );
    }
    out
}

/// Mean of |x| over a set.
fn mean_abs(v: impl Iterator<Item = f64>) -> f64 {
    let (s, n) = v.fold((0.0, 0usize), |(s, n), x| (s + x.abs(), n + 1));
    if n == 0 { f64::NAN } else { s / n as f64 }
}

fn summary_line(effect: &str, out: &[Outcome], named: &[&Outcome], covered: usize) {
    let all = || out.iter();
    println!(
        "RATE {effect}: named {}/{} | param interval covers {covered}/{} named | mean |E1 err| {:.2}% -> {:.2}% | mean |nu1 err| {:.2}% -> {:.2}% (all seeds)",
        named.len(),
        out.len(),
        named.len(),
        mean_abs(all().map(|o| o.err_before().0)),
        mean_abs(all().map(|o| o.err_after().0)),
        mean_abs(all().map(|o| o.err_before().1)),
        mean_abs(all().map(|o| o.err_after().1)),
    );
}

/// An identifiable effect: named in >= 90 % of the seeds, its parameters
/// covered on >= 80 % of the named seeds, E1 within 1 % and nu1 within 3 % on
/// every named seed, nothing unexplained.
fn identifiable(effect: &str) {
    let case = corpus_case(effect);
    let out = run_seeds(&case, SEEDS);
    let named: Vec<&Outcome> = out.iter().filter(|o| o.named(effect)).collect();
    let covered = named.iter().filter(|o| o.param_covers(effect)).count();
    summary_line(effect, &out, &named, covered);
    for o in &out {
        assert!(!o.d.unexplained, "{effect} seed {}: {}", o.seed, o.d.verdict);
    }
    assert!(10 * named.len() >= 9 * out.len(), "{effect}: named in {}/{} seeds", named.len(), out.len());
    assert!(10 * covered >= 8 * named.len(), "{effect}: interval covers the truth in {covered}/{} named", named.len());
    // "Where the data determine the effect well": every fitted parameter's
    // interval closed and narrower than its value. Elsewhere the report must say
    // the effect is weakly determined, and the corrected E1/nu1 intervals cover
    // the truth in >= 80 % of those seeds.
    let (well, weak): (Vec<&Outcome>, Vec<&Outcome>) = named.iter().partition(|o| o.well_determined(effect));
    for o in &well {
        let (ea, na) = o.err_after();
        assert!(ea.abs() < 1.0 && na.abs() < 3.0, "{effect} seed {}: E1 {ea:+.2}%, nu1 {na:+.2}%", o.seed);
    }
    for o in &weak {
        assert!(o.d.verdict.contains("weakly determined"), "{effect} seed {}: {}", o.seed, o.d.verdict);
    }
    // The report says where the mismatch is (contact_offset is the baseline's
    // own z0: there is nothing left to locate).
    let located = named.iter().filter(|o| !o.d.mismatch.is_empty()).count();
    println!("RATE {effect}: mismatch located on {located}/{} named", named.len());
    if effect != "contact_offset" {
        assert!(10 * located >= 9 * named.len(), "{effect}: mismatch located on {located}/{}", named.len());
    }
    let weak_cover = weak.iter().filter(|o| o.e1_nu1_cover()).count();
    println!(
        "RATE {effect}: well determined {}/{} named (E1 within 1 %, nu1 within 3 %) | weakly determined {} (E1/nu1 intervals cover {weak_cover})",
        well.len(),
        named.len(),
        weak.len()
    );
    assert!(10 * weak_cover >= 8 * weak.len(), "{effect}: weakly determined, E1/nu1 cover {weak_cover}/{}", weak.len());
}

/// A weakly determined effect (it and its look-alikes fit the sweeps equally
/// well): the report never names another effect in its place nor calls it
/// unexplained; in >= 90 % of the seeds it names the effect or lists it among
/// the explanations it cannot rank (and then names none and says so); under
/// the true explanation, the E1/nu1 intervals cover the truth in >= 80 % of
/// those seeds; when it is named, its parameter interval covers the truth.
fn weakly_determined(effect: &str) {
    let case = corpus_case(effect);
    let out = run_seeds(&case, SEEDS);
    let named: Vec<&Outcome> = out.iter().filter(|o| o.named(effect)).collect();
    let covered = named.iter().filter(|o| o.param_covers(effect)).count();
    summary_line(effect, &out, &named, covered);
    let found: Vec<&Outcome> = out.iter().filter(|o| o.named(effect) || o.listed(effect)).collect();
    // E1/nu1 intervals of the true explanation (the corrected fit when named).
    let truth_covers = |o: &Outcome| {
        if o.named(effect) {
            return o.e1_nu1_cover();
        }
        o.d.ambiguous.iter().filter(|a| a.effects == [effect]).any(|a| {
            let c = &a.ci95;
            c.e1_mpa[0] <= o.e1 && o.e1 <= c.e1_mpa[1] && c.nu1[0] <= o.nu1 && o.nu1 <= c.nu1[1]
        })
    };
    let e1_nu1 = found.iter().filter(|o| truth_covers(o)).count();
    let (n, f) = (out.len(), found.len());
    println!(
        "RATE {effect}: named or listed as ambiguous {f}/{n} | E1 and nu1 intervals of the true explanation cover {e1_nu1}/{f}"
    );
    for o in &out {
        assert!(!o.d.unexplained, "{effect} seed {}: {}", o.seed, o.d.verdict);
        assert!(o.d.effects.iter().all(|e| *e == effect || *e == "contact_offset"), "{}", o.d.verdict);
        if o.listed(effect) {
            assert!(o.d.effects.is_empty() && o.d.verdict.contains("AMBIGUOUS"), "{}", o.d.verdict);
        }
    }
    assert!(10 * f >= 9 * n, "{effect}: named or listed in {f}/{n} seeds");
    assert!(10 * e1_nu1 >= 8 * f, "{effect}: E1/nu1 intervals cover the truth in {e1_nu1}/{f}");
    assert_eq!(covered, named.len(), "{effect}: a named seed's interval misses the truth");
}

#[test]
fn the_library_declares_what_is_tested_here() {
    // Good effects are tested as identifiable or (two of them) as weakly determined;
    // adhesion is Weak in the library, but at the corpus's tack it is named reliably.
    for name in
        ["contact_offset", "stage_backlash", "partial_slip", "rotation_backlash", "thermal_drift", "viscoelastic"]
    {
        assert_eq!(info(name).unwrap().identifiability, Identifiability::Good, "{name}");
    }
    assert_eq!(info("adhesion").unwrap().identifiability, Identifiability::Weak);
    assert_eq!(info("sensor_gain").unwrap().identifiability, Identifiability::NotIdentifiable);
}

#[test]
fn rate_contact_offset() {
    identifiable("contact_offset");
}

#[test]
fn rate_stage_backlash() {
    identifiable("stage_backlash");
}

#[test]
fn rate_partial_slip() {
    identifiable("partial_slip");
}

#[test]
fn rate_rotation_backlash() {
    identifiable("rotation_backlash");
}

#[test]
fn rate_thermal_drift() {
    identifiable("thermal_drift");
}

#[test]
fn rate_viscoelastic() {
    identifiable("viscoelastic");
}

#[test]
fn rate_adhesion() {
    identifiable("adhesion");
}

#[test]
fn rate_finite_thickness_weak() {
    weakly_determined("finite_thickness");
}

#[test]
fn rate_frame_compliance_weak() {
    weakly_determined("frame_compliance");
}

#[test]
fn clean_false_alarms() {
    let mut case = corpus_case("clean");
    case.profile = SimProfile::default();
    let out = run_seeds(&case, CLEAN_SEEDS);
    let named = out.iter().filter(|o| !o.d.effects.is_empty()).count();
    let ambiguous = out.iter().filter(|o| !o.d.ambiguous.is_empty()).count();
    let unexplained = out.iter().filter(|o| o.d.unexplained).count();
    let mismatch = out.iter().filter(|o| !o.d.mismatch.is_empty()).count();
    println!(
        "RATE clean: named {named}/{} | ambiguous {ambiguous} | unexplained {unexplained} | mismatch reported {mismatch} | mean |E1 err| {:.2}% | mean |nu1 err| {:.2}%",
        out.len(),
        mean_abs(out.iter().map(|o| o.err_after().0)),
        mean_abs(out.iter().map(|o| o.err_after().1)),
    );
    assert!(out.len() >= 20);
    assert!(20 * named <= out.len(), "an effect is named in {named}/{} clean controls", out.len());
    assert!(20 * unexplained <= out.len(), "unexplained in {unexplained}/{} clean controls", out.len());
    assert!(20 * mismatch <= out.len(), "a mismatch reported in {mismatch}/{} clean controls", out.len());
}
