//! The checkout a command runs in: where its outputs go (`target/...`) and where the
//! release firmware ELF is, found from the current directory at run time, never from a
//! source path fixed when the binary was built (a binary copied or built elsewhere
//! writes into the checkout it is run in).

use std::path::{Path, PathBuf};

/// The workspace root: the nearest directory at or above the current one whose
/// `Cargo.toml` declares `[workspace]`; the current directory outside a checkout.
pub fn root() -> PathBuf {
    let here = std::env::current_dir().unwrap_or_else(|_| PathBuf::from("."));
    workspace_above(&here).unwrap_or(here)
}

fn workspace_above(dir: &Path) -> Option<PathBuf> {
    dir.ancestors()
        .find(|d| {
            std::fs::read_to_string(d.join("Cargo.toml"))
                .is_ok_and(|t| t.lines().any(|l| l.trim() == "[workspace]"))
        })
        .map(Path::to_path_buf)
}

/// `target/` of the checkout: where every command writes what it produces.
pub fn target_dir() -> PathBuf {
    root().join("target")
}

/// The release firmware ELF of the checkout (`cargo xtask build-cross`).
pub fn release_elf() -> PathBuf {
    target_dir().join("thumbv7em-none-eabihf/release/drive-fw")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_workspace_is_found_from_a_directory_below_it() {
        let dir = tempfile::tempdir().unwrap();
        let ws = dir.path();
        std::fs::write(ws.join("Cargo.toml"), "[workspace]\nmembers = []\n").unwrap();
        let below = ws.join("a/b");
        std::fs::create_dir_all(&below).unwrap();
        std::fs::write(ws.join("a/Cargo.toml"), "[package]\nname = \"a\"\n").unwrap();
        assert_eq!(workspace_above(&below).as_deref(), Some(ws));
        assert_eq!(workspace_above(Path::new("/")), None);
    }
}
