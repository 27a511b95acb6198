//! Writes the concealed-data corpus: `tests/data/<effect>.csv` for every case
//! of `sim::corpus::cases()` and the manifest `tests/data/corpus.toml`.
//! Deterministic: the same seeds give the same files.
//!
//!     cargo run -p sim --example make_corpus [-- OUT_DIR]

use std::path::PathBuf;

use sim::corpus::{CorpusManifest, cases};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let out = std::env::args()
        .nth(1)
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../tests/data"));
    std::fs::create_dir_all(&out)?;
    let cases = cases();
    for c in &cases {
        let rec = c.generate()?;
        rec.write_path(&out.join(&c.file))?;
        println!("{:24} {:4} samples  seed {}", c.file, rec.samples.len(), c.seed);
    }
    let manifest = CorpusManifest { cases };
    let header = "# Concealed-data corpus for `easycalib diagnose` (written by\n\
                  # `cargo run -p sim --example make_corpus`; do not edit by hand).\n\
                  # bias_in: which fit the concealed bias shows in (full / paper / none).\n\n";
    std::fs::write(out.join("corpus.toml"), format!("{header}{}", manifest.to_toml_string()?))?;
    println!("wrote {}", out.join("corpus.toml").display());
    Ok(())
}
