//! The output folder of a run (`track`, `eval`, `demo`): checked before any work is done (a
//! folder, or one that can be made; writable; not inside the input dataset), locked for the
//! run (a second run into it is refused while the first one writes), outputs of an earlier
//! run refused unless asked to replace them (then removed first, so that runs never mix), and
//! the folders made for a run that wrote nothing removed again.

use std::path::{Component, Path, PathBuf};

/// Why an output folder cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum OutFolderError {
    /// The path exists and is not a folder.
    #[error("output folder {0}: exists and is not a directory")]
    NotADirectory(PathBuf),
    /// The folder could not be made.
    #[error("output folder {path}: cannot be created: {source}")]
    Create {
        /// Folder.
        path: PathBuf,
        /// Cause.
        #[source]
        source: std::io::Error,
    },
    /// Nothing can be written into it.
    #[error("output folder {path}: not writable: {source}")]
    NotWritable {
        /// Folder.
        path: PathBuf,
        /// Cause.
        #[source]
        source: std::io::Error,
    },
    /// It lies inside the input dataset, whose files it could overwrite.
    #[error("output folder {out} is inside the dataset {input}: choose a folder outside it")]
    InsideInput {
        /// Output folder.
        out: PathBuf,
        /// Dataset folder.
        input: PathBuf,
    },
    /// It holds the outputs of an earlier run.
    #[error(
        "output folder {path} already holds {} from an earlier run; choose another folder or pass --overwrite",
        found.join(", ")
    )]
    Exists {
        /// Folder.
        path: PathBuf,
        /// The outputs found.
        found: Vec<String>,
    },
    /// Another run is writing into it.
    #[error(
        "output folder {0}: another run is writing into it (it holds the lock {LOCK_FILE}); wait for that run or choose another folder"
    )]
    Busy(PathBuf),
    /// An earlier output could not be removed.
    #[error("{path}: cannot remove the earlier output: {source}")]
    Remove {
        /// File or folder.
        path: PathBuf,
        /// Cause.
        #[source]
        source: std::io::Error,
    },
}

/// The lock file a run holds in its output folder (an advisory lock on it, released when the
/// process ends, however it ends; the file is removed when the run is done).
pub const LOCK_FILE: &str = ".host-vision.lock";

/// A checked output folder, locked for the run. Dropped, it releases the lock and removes its
/// file; without [`OutFolder::keep`], it also removes the folders it made (only while they are
/// empty), so that a run that failed early leaves nothing behind.
#[derive(Debug)]
pub struct OutFolder {
    path: PathBuf,
    /// Folders made, outermost first.
    created: Vec<PathBuf>,
    /// The lock held, once taken.
    lock: Option<std::fs::File>,
    keep: bool,
}

impl OutFolder {
    /// Checks `path` and makes it. `owned` are the names a run writes into it (`dir/prefix*suffix`
    /// for the files of a folder it shares with the user's): present, they are refused, or
    /// removed with `overwrite`. `input` is the dataset, which must not hold
    /// the folder.
    pub fn prepare(
        path: &Path,
        owned: &[String],
        input: Option<&Path>,
        overwrite: bool,
    ) -> Result<Self, OutFolderError> {
        if path.exists() && !path.is_dir() {
            return Err(OutFolderError::NotADirectory(path.to_owned()));
        }
        if let Some(input) = input
            && let (Some(out), Ok(input_abs)) = (resolve(path), input.canonicalize())
            && out.starts_with(&input_abs)
        {
            return Err(OutFolderError::InsideInput {
                out: path.to_owned(),
                input: input.to_owned(),
            });
        }
        let mut missing = Vec::new();
        let mut p = path.to_path_buf();
        while !p.as_os_str().is_empty() && !p.exists() {
            missing.push(p.clone());
            if !p.pop() {
                break;
            }
        }
        missing.reverse();
        let mut folder = OutFolder {
            path: path.to_owned(),
            created: Vec::new(),
            lock: None,
            keep: false,
        };
        for dir in missing {
            match std::fs::create_dir(&dir) {
                Ok(()) => folder.created.push(dir),
                Err(e) if dir.is_dir() => drop(e),
                Err(source) => {
                    return Err(OutFolderError::Create {
                        path: path.to_owned(),
                        source,
                    });
                }
            }
        }
        // The lock, before anything in the folder is looked at or removed; making its file
        // also shows that the folder is writable, now rather than after the work.
        let not_writable = |source| OutFolderError::NotWritable {
            path: path.to_owned(),
            source,
        };
        let lock = std::fs::OpenOptions::new()
            .create(true)
            .truncate(false)
            .write(true)
            .open(path.join(LOCK_FILE))
            .map_err(not_writable)?;
        match lock.try_lock() {
            Ok(()) => folder.lock = Some(lock),
            Err(std::fs::TryLockError::WouldBlock) => {
                return Err(OutFolderError::Busy(path.to_owned()));
            }
            Err(std::fs::TryLockError::Error(e)) => return Err(not_writable(e)),
        }
        let found: Vec<(&String, Vec<PathBuf>)> = owned
            .iter()
            .map(|n| (n, matching(path, n)))
            .filter(|(_, files)| !files.is_empty())
            .collect();
        if !found.is_empty() {
            if !overwrite {
                return Err(OutFolderError::Exists {
                    path: path.to_owned(),
                    found: found.into_iter().map(|(n, _)| n.clone()).collect(),
                });
            }
            for (_, files) in found {
                for p in files {
                    let removed = if p.is_dir() {
                        std::fs::remove_dir_all(&p)
                    } else {
                        std::fs::remove_file(&p)
                    };
                    removed.map_err(|source| OutFolderError::Remove { path: p, source })?;
                }
            }
            // A folder of outputs left empty goes too; one that holds the user's files stays.
            for name in owned {
                if let Some((dir, _)) = name.split_once('/') {
                    let _ = std::fs::remove_dir(path.join(dir));
                }
            }
        }
        Ok(folder)
    }

    /// The folder.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Keeps the folder: something was written.
    pub fn keep(&mut self) {
        self.keep = true;
    }
}

impl Drop for OutFolder {
    fn drop(&mut self) {
        // The file first (another run that opened it before still finds it locked), then the
        // lock with the handle.
        if let Some(lock) = self.lock.take() {
            let _ = std::fs::remove_file(self.path.join(LOCK_FILE));
            drop(lock);
        }
        if !self.keep {
            // `remove_dir` only removes empty folders: nothing of the user's is lost.
            for dir in self.created.iter().rev() {
                if std::fs::remove_dir(dir).is_err() {
                    break;
                }
            }
        }
    }
}

/// What of `owned` lies in the folder `path`: the file or folder of that name, or, for a name
/// `dir/prefix*suffix`, the files in `dir` whose names match (a run's plots or overlays,
/// beside which the user's own files stay).
fn matching(path: &Path, owned: &str) -> Vec<PathBuf> {
    let Some((dir, pattern)) = owned.split_once('/') else {
        let p = path.join(owned);
        return if p.exists() { vec![p] } else { Vec::new() };
    };
    let (prefix, suffix) = pattern.split_once('*').unwrap_or((pattern, ""));
    let Ok(entries) = std::fs::read_dir(path.join(dir)) else {
        return Vec::new();
    };
    let mut files: Vec<PathBuf> = entries
        .filter_map(Result::ok)
        .filter(|e| {
            let name = e.file_name();
            let name = name.to_string_lossy();
            e.path().is_file()
                && name.len() >= prefix.len() + suffix.len()
                && name.starts_with(prefix)
                && name.ends_with(suffix)
        })
        .map(|e| e.path())
        .collect();
    files.sort();
    files
}

/// The absolute form of `path`, which need not exist yet: `..` and `.` resolved by name, then
/// its nearest existing ancestor canonicalised (symlinks resolved), the rest appended.
fn resolve(path: &Path) -> Option<PathBuf> {
    let abs = if path.is_absolute() {
        path.to_owned()
    } else {
        std::env::current_dir().ok()?.join(path)
    };
    let mut clean = PathBuf::new();
    for c in abs.components() {
        match c {
            Component::ParentDir => {
                clean.pop();
            }
            Component::CurDir => {}
            other => clean.push(other),
        }
    }
    let mut existing = clean.clone();
    let mut rest = Vec::new();
    while !existing.exists() {
        rest.push(existing.file_name()?.to_owned());
        existing.pop();
    }
    let mut out = existing.canonicalize().ok()?;
    out.extend(rest.iter().rev());
    Some(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn names(n: &[&str]) -> Vec<String> {
        n.iter().map(|s| s.to_string()).collect()
    }

    #[test]
    fn earlier_outputs_are_refused_or_replaced_and_other_files_kept() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("out");
        std::fs::create_dir_all(out.join("overlays")).unwrap();
        std::fs::write(out.join("summary.json"), "{}").unwrap();
        std::fs::write(out.join("notes.txt"), "mine").unwrap();
        let owned = names(&["summary.json", "overlays", "frames.csv"]);
        let err = OutFolder::prepare(&out, &owned, None, false).unwrap_err();
        assert!(
            err.to_string()
                .contains("already holds summary.json, overlays"),
            "{err}"
        );
        OutFolder::prepare(&out, &owned, None, true).unwrap();
        assert!(!out.join("summary.json").exists() && !out.join("overlays").exists());
        assert_eq!(
            std::fs::read_to_string(out.join("notes.txt")).unwrap(),
            "mine"
        );
    }

    /// Issue 54, point 8: `--overwrite` removed a whole `plots/` with the user's notes in it,
    /// and a `plots/` holding only the user's files was refused as an earlier run's.
    #[test]
    fn a_shared_folder_loses_only_the_runs_files() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("out");
        std::fs::create_dir_all(out.join("plots")).unwrap();
        std::fs::write(out.join("plots/my_notes.txt"), "mine").unwrap();
        let owned = names(&["summary.json", "plots/*_error.svg", "overlays/frame_*.png"]);
        drop(OutFolder::prepare(&out, &owned, None, false).expect("the user's files only"));
        std::fs::write(out.join("plots/prediction_error.svg"), "<svg/>").unwrap();
        let err = OutFolder::prepare(&out, &owned, None, false).unwrap_err();
        assert!(
            err.to_string().contains("already holds plots/*_error.svg"),
            "{err}"
        );
        drop(OutFolder::prepare(&out, &owned, None, true).unwrap());
        assert!(!out.join("plots/prediction_error.svg").exists());
        assert_eq!(
            std::fs::read_to_string(out.join("plots/my_notes.txt")).unwrap(),
            "mine"
        );
        // A folder of outputs alone goes with them.
        std::fs::create_dir_all(out.join("overlays")).unwrap();
        std::fs::write(out.join("overlays/frame_000001.png"), "png").unwrap();
        drop(OutFolder::prepare(&out, &owned, None, true).unwrap());
        assert!(!out.join("overlays").exists());
    }

    /// Issue 33, point 7: two runs could write into one folder at once. The second is
    /// refused while the first holds the folder, by name; the lock's file goes with the first.
    #[test]
    fn a_second_run_into_a_held_folder_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("out");
        let first = OutFolder::prepare(&out, &[], None, false).unwrap();
        assert!(out.join(LOCK_FILE).exists());
        for overwrite in [false, true] {
            let err = OutFolder::prepare(&out, &[], None, overwrite).unwrap_err();
            assert!(matches!(err, OutFolderError::Busy(_)), "{err}");
            assert!(
                err.to_string().contains("another run is writing into it"),
                "{err}"
            );
        }
        drop(first);
        assert!(!out.join(LOCK_FILE).exists());
        let mut again = OutFolder::prepare(&out, &[], None, false).unwrap();
        again.keep();
        drop(again);
        assert_eq!(
            std::fs::read_dir(&out).unwrap().count(),
            0,
            "nothing left behind"
        );
    }

    #[test]
    fn a_folder_made_for_nothing_is_removed_and_one_kept_stays() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("a/b");
        drop(OutFolder::prepare(&out, &[], None, false).unwrap());
        assert!(!dir.path().join("a").exists());
        let mut kept = OutFolder::prepare(&out, &[], None, false).unwrap();
        kept.keep();
        drop(kept);
        assert!(out.is_dir());
    }

    #[test]
    fn a_folder_inside_the_input_or_a_file_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let input = dir.path().join("ds");
        std::fs::create_dir_all(&input).unwrap();
        for out in [input.clone(), input.join("results"), input.join("x/../y")] {
            let err = OutFolder::prepare(&out, &[], Some(&input), true).unwrap_err();
            assert!(matches!(err, OutFolderError::InsideInput { .. }), "{err}");
        }
        assert!(!input.join("results").exists());
        OutFolder::prepare(&dir.path().join("ds-out"), &[], Some(&input), false).unwrap();
        let file = dir.path().join("file");
        std::fs::write(&file, "").unwrap();
        let err = OutFolder::prepare(&file, &[], None, false).unwrap_err();
        assert!(err.to_string().contains("not a directory"), "{err}");
    }
}
