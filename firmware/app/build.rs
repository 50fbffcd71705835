//! Link with the workspace's `memory.x` (the one owner of the memory map) and defmt.
use std::{env, fs, path::PathBuf};

fn main() {
    let out = PathBuf::from(env::var("OUT_DIR").unwrap());
    let memory_x = PathBuf::from(env::var("CARGO_MANIFEST_DIR").unwrap()).join("../../memory.x");
    fs::copy(&memory_x, out.join("memory.x")).expect("workspace memory.x");
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rerun-if-changed={}", memory_x.display());
    println!("cargo:rustc-link-arg-bins=-Tdefmt.x");
}
