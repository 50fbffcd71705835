//! Outputs that appear whole or not at all: written under a temporary name next to the
//! destination and renamed into place on success (replay, rtt-log), one file
//! ([`Pending`]) or a set of files in one directory ([`PendingDir`]).

use anyhow::{Context, Result};
use std::fs::{self, File, OpenOptions};
use std::path::{Path, PathBuf};

/// An output written under a temporary name in its destination's directory and renamed
/// into place by [`Pending::commit`]; dropped uncommitted, it removes itself.
pub(crate) struct Pending {
    tmp: PathBuf,
    dest: PathBuf,
    committed: bool,
}

impl Pending {
    pub(crate) fn create(dest: &Path) -> Result<(Self, File)> {
        let dir = match dest.parent() {
            Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
            _ => PathBuf::from("."),
        };
        let file_name = dest
            .file_name()
            .with_context(|| format!("{}: not a file name", dest.display()))?;
        let tmp = dir.join(format!(
            ".{}.{}.tmp",
            file_name.to_string_lossy(),
            std::process::id()
        ));
        let f = OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&tmp)
            .with_context(|| format!("{}: cannot create {}", dest.display(), tmp.display()))?;
        Ok((
            Self {
                tmp,
                dest: dest.to_path_buf(),
                committed: false,
            },
            f,
        ))
    }

    pub(crate) fn commit(mut self) -> Result<()> {
        fs::rename(&self.tmp, &self.dest)
            .with_context(|| format!("{}: cannot write", self.dest.display()))?;
        self.committed = true;
        Ok(())
    }
}

impl Drop for Pending {
    fn drop(&mut self) {
        if !self.committed {
            let _ = fs::remove_file(&self.tmp);
        }
    }
}

/// Files written into a hidden directory inside their destination directory and
/// renamed into it by [`PendingDir::commit`]; dropped uncommitted, the hidden directory
/// goes with whatever was written there.
pub(crate) struct PendingDir {
    tmp: PathBuf,
    dir: PathBuf,
    files: Vec<String>,
    committed: bool,
}

impl PendingDir {
    /// Creates `dir` if needed and `dir/.<tag>.<pid>.tmp` in it.
    pub(crate) fn create(dir: &Path, tag: &str) -> Result<Self> {
        fs::create_dir_all(dir).with_context(|| format!("{}: cannot create", dir.display()))?;
        let tmp = dir.join(format!(".{tag}.{}.tmp", std::process::id()));
        fs::create_dir(&tmp).with_context(|| format!("{}: cannot create", tmp.display()))?;
        Ok(Self {
            tmp,
            dir: dir.to_path_buf(),
            files: Vec::new(),
            committed: false,
        })
    }

    /// Where to write the files before they are committed.
    pub(crate) fn tmp(&self) -> &Path {
        &self.tmp
    }

    /// Commit `name` (written in [`Self::tmp`]) with the others.
    pub(crate) fn add(&mut self, name: String) {
        self.files.push(name);
    }

    /// Moves every added file into the destination directory; their new paths.
    pub(crate) fn commit(mut self) -> Result<Vec<PathBuf>> {
        let mut out = Vec::new();
        for f in &self.files {
            let dest = self.dir.join(f);
            fs::rename(self.tmp.join(f), &dest)
                .with_context(|| format!("{}: cannot write", dest.display()))?;
            out.push(dest);
        }
        self.committed = true;
        let _ = fs::remove_dir_all(&self.tmp);
        Ok(out)
    }
}

impl Drop for PendingDir {
    fn drop(&mut self) {
        if !self.committed {
            let _ = fs::remove_dir_all(&self.tmp);
        }
    }
}
