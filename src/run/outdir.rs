//! The run's output folder (docs/run.md, "Output folder"): an existing folder
//! with files in it is refused unless the operator says `--overwrite`, and no file
//! is ever opened through a symbolic link easycalib did not make — a planted
//! `recording.csv -> ~/.bashrc` fails the open instead of clobbering its target.

use std::fs::{File, OpenOptions};
use std::io;
use std::os::unix::fs::OpenOptionsExt;
use std::path::Path;

/// Why the output folder cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum OutDirError {
    #[error("{path} already holds files (a previous run?); choose another --out or pass --overwrite")]
    NotEmpty { path: String },
    #[error("{path} is a symbolic link; give the real folder")]
    Symlink { path: String },
    #[error("{path}: {source}")]
    Io { path: String, source: io::Error },
}

/// Check (and create) the output folder before anything moves. With
/// `overwrite`, symbolic links among its entries are removed (the links, never
/// their targets) so the run writes fresh files.
pub fn prepare(dir: &Path, overwrite: bool) -> Result<(), OutDirError> {
    let shown = || dir.display().to_string();
    match std::fs::symlink_metadata(dir) {
        Ok(m) if m.file_type().is_symlink() => Err(OutDirError::Symlink { path: shown() }),
        Ok(_) => {
            let entries = std::fs::read_dir(dir).map_err(|source| OutDirError::Io { path: shown(), source })?;
            for e in entries {
                let e = e.map_err(|source| OutDirError::Io { path: shown(), source })?;
                if !overwrite {
                    return Err(OutDirError::NotEmpty { path: shown() });
                }
                let is_link = e.file_type().is_ok_and(|t| t.is_symlink());
                if is_link {
                    std::fs::remove_file(e.path())
                        .map_err(|source| OutDirError::Io { path: e.path().display().to_string(), source })?;
                }
            }
            Ok(())
        }
        Err(e) if e.kind() == io::ErrorKind::NotFound => {
            std::fs::create_dir_all(dir).map_err(|source| OutDirError::Io { path: shown(), source })
        }
        Err(source) => Err(OutDirError::Io { path: shown(), source }),
    }
}

/// Create (or truncate) a file for writing without following a symbolic link
/// at its name (O_NOFOLLOW: the open fails instead).
pub fn create_nofollow(path: &Path) -> io::Result<File> {
    OpenOptions::new().write(true).create(true).truncate(true).custom_flags(libc::O_NOFOLLOW).open(path)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn existing_folders_need_overwrite_and_planted_links_are_not_followed() {
        let tmp = tempfile::tempdir().unwrap();
        let out = tmp.path().join("run");
        prepare(&out, false).unwrap();
        assert!(out.is_dir());
        // Empty: fine again.
        prepare(&out, false).unwrap();
        std::fs::write(out.join("recording.csv"), "old").unwrap();
        assert!(matches!(prepare(&out, false), Err(OutDirError::NotEmpty { .. })));
        prepare(&out, true).unwrap();
        // A planted link: its target stays untouched.
        let target = tmp.path().join("precious.txt");
        std::fs::write(&target, "keep me").unwrap();
        std::fs::remove_file(out.join("recording.csv")).unwrap();
        std::os::unix::fs::symlink(&target, out.join("recording.csv")).unwrap();
        assert!(create_nofollow(&out.join("recording.csv")).is_err());
        prepare(&out, true).unwrap();
        let mut f = create_nofollow(&out.join("recording.csv")).unwrap();
        io::Write::write_all(&mut f, b"new").unwrap();
        assert_eq!(std::fs::read_to_string(&target).unwrap(), "keep me");
        // The folder itself as a link is refused.
        let link = tmp.path().join("linked");
        std::os::unix::fs::symlink(&out, &link).unwrap();
        assert!(matches!(prepare(&link, true), Err(OutDirError::Symlink { .. })));
    }
}
