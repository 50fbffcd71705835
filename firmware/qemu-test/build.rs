//! Embed the input vector named by `MRAS_QEMU_VECTOR` (written by `hil-sim qemu-vector`,
//! driven by `cargo xtask qemu`); without it the image runs an empty vector.
use std::{env, fs, path::PathBuf};

fn main() {
    let out = PathBuf::from(env::var("OUT_DIR").unwrap()).join("vector.bin");
    println!("cargo:rerun-if-env-changed=MRAS_QEMU_VECTOR");
    // MRAS_QEMU_MODE=cycles: run the three path configurations with step markers for
    // the instruction trace instead of the bit-exactness trace.
    println!("cargo:rerun-if-env-changed=MRAS_QEMU_MODE");
    println!("cargo::rustc-check-cfg=cfg(cycles_mode)");
    if env::var("MRAS_QEMU_MODE").as_deref() == Ok("cycles") {
        println!("cargo:rustc-cfg=cycles_mode");
    }
    match env::var("MRAS_QEMU_VECTOR") {
        Ok(p) => {
            println!("cargo:rerun-if-changed={p}");
            fs::copy(&p, &out).unwrap_or_else(|e| panic!("MRAS_QEMU_VECTOR={p}: {e}"));
        }
        Err(_) => fs::write(&out, []).unwrap(),
    }
}
