//! The material cases the large-strain tables are built over, and running a
//! builder over them on a few threads (fem/examples/large_strain_*.rs).

/// (E2/E1, nu1, nu2) of every case, in the tables' order. Above nu1 = 0.48
/// the neo-Hookean reference does not reach these depths (at 0.499 it stops
/// within the first few steps): the tables end there and the fit extends
/// them polynomially to 0.5 (fem/src/hyper/table.rs).
pub fn grid() -> Vec<(f64, f64, f64)> {
    let mut cases = Vec::new();
    for e_ratio in [1.0, 2.0, 4.0, 8.0] {
        for nu1 in [0.3, 0.4, 0.48] {
            for nu2 in [0.33, 0.4, 0.47] {
                cases.push((e_ratio, nu1, nu2));
            }
        }
    }
    cases
}

/// The cases to build: the whole [`grid`], or those with `E_RATIO=r` (one
/// modulus ratio), or the one `CASE=e,nu1,nu2`.
pub fn selected() -> Vec<(f64, f64, f64)> {
    let num = |v: &str| v.trim().parse::<f64>().ok();
    if let Ok(one) = std::env::var("CASE") {
        let v: Vec<f64> = one.split(',').filter_map(num).collect();
        if let [e, n1, n2] = v[..] {
            return vec![(e, n1, n2)];
        }
    }
    let e_ratio = std::env::var("E_RATIO").ok().and_then(|v| num(&v));
    grid().into_iter().filter(|c| e_ratio.is_none_or(|e| (c.0 - e).abs() < 1e-9)).collect()
}

/// `run` on every case, `THREADS` (default 2) at a time, each case's rows in
/// the cases' order; progress on stderr.
pub fn run_all(cases: &[(f64, f64, f64)], run: impl Fn(f64, f64, f64) -> Vec<String> + Sync) -> Vec<Vec<String>> {
    let threads: usize = std::env::var("THREADS").ok().and_then(|v| v.parse().ok()).unwrap_or(2);
    let next = std::sync::atomic::AtomicUsize::new(0);
    let results = std::sync::Mutex::new(vec![Vec::new(); cases.len()]);
    std::thread::scope(|s| {
        for _ in 0..threads {
            s.spawn(|| {
                loop {
                    let i = next.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
                    let Some(&(e, n1, n2)) = cases.get(i) else { break };
                    let t = std::time::Instant::now();
                    let rows = run(e, n1, n2);
                    eprintln!("E2/E1 {e} nu1 {n1} nu2 {n2}: {} rows in {:.1?}", rows.len(), t.elapsed());
                    if let Ok(mut r) = results.lock() {
                        r[i] = rows;
                    }
                }
            });
        }
    });
    results.into_inner().unwrap_or_default()
}

/// The element the tables are built on: `INTEGRATION=full` for the extension
/// tables (fem/data/large_strain_full*.csv, the fully integrated element that
/// follows the press to the indenter's flank), the selective one otherwise.
pub fn integration() -> fem::Integration {
    match std::env::var("INTEGRATION").as_deref() {
        Ok("full") => fem::Integration::Full,
        _ => fem::Integration::Selective,
    }
}

/// The element size at the contact a table is built with: `FINE_MM`, else `default_mm`.
pub fn fine_mm(default_mm: f64) -> f64 {
    std::env::var("FINE_MM").ok().and_then(|v| v.parse::<f64>().ok()).unwrap_or(default_mm)
}

/// The gel's mesh a table is built on (the layer model's layout with
/// [`fine_mm`] elements at the contact) and the hemisphere's radial segments to match.
pub fn gel_mesh(h: f64, default_fine_mm: f64) -> (fem::Mesh, usize) {
    let fine = fine_mm(default_fine_mm);
    (fem::forward::gel_mesh_at(h, fine).unwrap(), fem::forward::hemisphere_segments(fine))
}
