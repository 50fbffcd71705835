//! Project automation (matklad's xtask pattern): `cargo xtask <command>`.
//!
//! Every command does its own set-up (the thumbv7em target, rustfmt and clippy) so that
//! it runs on a fresh machine.

use std::path::{Path, PathBuf};
use std::process::{Command, ExitCode};

/// The one owner of the MCU target triple for automation.
const TARGET: &str = "thumbv7em-none-eabihf";
/// Portable crates that must build for the MCU.
const CORE_CRATES: &[&str] = &["mras"];

const HELP: &str = "\
cargo xtask <command>

  ci            everything CI checks: fmt, clippy (host and target), host tests,
                cross-build of the core for thumbv7em-none-eabihf
  test-host     host tests only
  build-cross   release cross-build of the portable core(s) for the MCU
  docs-tables   regenerate the tables of docs/theory.md (prints markdown)
";

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let result = match args.first().map(String::as_str) {
        Some("ci") => ci(),
        Some("test-host") => test_host(),
        Some("build-cross") => setup().and_then(|_| build_cross()),
        Some("docs-tables") => docs_tables(),
        Some("-h" | "--help" | "help") | None => {
            print!("{HELP}");
            Ok(())
        }
        Some(other) => Err(format!("unknown command `{other}`\n\n{HELP}")),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("xtask: {e}");
            ExitCode::FAILURE
        }
    }
}

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("xtask lives one level below the workspace root")
        .to_path_buf()
}

fn cargo() -> Command {
    let mut c = Command::new(std::env::var("CARGO").unwrap_or_else(|_| "cargo".into()));
    c.current_dir(root());
    c
}

/// Run a command, echoing it; error with its exit status.
fn run(mut c: Command) -> Result<(), String> {
    let shown = format!("{c:?}").replace('"', "");
    eprintln!("\n$ {shown}");
    let status = c
        .status()
        .map_err(|e| format!("cannot start {shown}: {e}"))?;
    if status.success() {
        Ok(())
    } else {
        Err(format!("`{shown}` failed ({status})"))
    }
}

fn output_of(program: &str, args: &[&str]) -> Option<String> {
    let out = Command::new(program).args(args).output().ok()?;
    out.status
        .success()
        .then(|| String::from_utf8_lossy(&out.stdout).into_owned())
}

/// Install the MCU target and the lint tools when missing.
fn setup() -> Result<(), String> {
    let installed = output_of("rustup", &["target", "list", "--installed"]).unwrap_or_default();
    if !installed.lines().any(|l| l.trim() == TARGET) {
        let mut c = Command::new("rustup");
        c.args(["target", "add", TARGET]);
        run(c)?;
    }
    for (tool, component) in [("cargo-fmt", "rustfmt"), ("cargo-clippy", "clippy")] {
        if output_of(tool, &["--version"]).is_none() {
            let mut c = Command::new("rustup");
            c.args(["component", "add", component]);
            run(c)?;
        }
    }
    Ok(())
}

fn test_host() -> Result<(), String> {
    let mut c = cargo();
    c.args(["test", "--workspace", "--locked"]);
    run(c)
}

fn build_cross() -> Result<(), String> {
    for krate in CORE_CRATES {
        let mut c = cargo();
        c.args([
            "build",
            "--locked",
            "--release",
            "--target",
            TARGET,
            "-p",
            krate,
        ]);
        run(c)?;
    }
    Ok(())
}

fn ci() -> Result<(), String> {
    setup()?;
    let mut c = cargo();
    c.args(["fmt", "--all", "--", "--check"]);
    run(c)?;
    let mut c = cargo();
    c.args([
        "clippy",
        "--locked",
        "--workspace",
        "--all-targets",
        "--",
        "-D",
        "warnings",
    ]);
    run(c)?;
    for krate in CORE_CRATES {
        let mut c = cargo();
        c.args([
            "clippy", "--locked", "--target", TARGET, "-p", krate, "--", "-D", "warnings",
        ]);
        run(c)?;
    }
    build_cross()?;
    test_host()?;
    eprintln!("\nxtask ci: all checks passed");
    Ok(())
}

fn docs_tables() -> Result<(), String> {
    for sub in ["compare-laws", "gain-sweep"] {
        let mut c = cargo();
        c.args([
            "run",
            "--locked",
            "--release",
            "-q",
            "-p",
            "hil-sim",
            "--",
            sub,
        ]);
        run(c)?;
    }
    Ok(())
}
