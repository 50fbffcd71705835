//! Project automation (matklad's xtask pattern): `cargo xtask <command>`.
//!
//! Every command does its own set-up (the thumbv7em target, rustfmt and clippy) so that
//! it runs on a fresh machine.

mod docs;
mod isr;
mod mutants;
mod qemu;
mod regs;

use anyhow::{anyhow, bail, Context, Result};
use std::path::{Path, PathBuf};
use std::process::{Command, ExitCode};

/// The one owner of the MCU target triple for automation.
pub(crate) const TARGET: &str = "thumbv7em-none-eabihf";
/// Portable crates that must build for the MCU (and are tested on the host).
const CORE_CRATES: &[&str] = &["mras", "mras-sim", "drive", "calib-record"];
/// The firmware binary (target only).
pub(crate) const FIRMWARE: &str = "drive-fw";
/// The emulator image of the core (target only, built by `xtask qemu`).
const QEMU_IMAGE: &str = "mras-qemu";
/// The firmware-in-the-loop emulator (GPL-2.0, links Unicorn); its tests run in the
/// host profile ([`HOST_PROFILE`]).
pub(crate) const EMULATOR: &str = "drive-emu";
/// Budgets of the size report: growth is a decision, not an accident. The part has
/// 256 KiB in the bank the code runs from (memory.x); 120 KiB leaves room for the
/// application beside a core that chooses its bank from the data and a drive that
/// identifies its motor (the motor's identification took the firmware past the 96 KiB
/// of the budget before; the N = 1 build's deadlines at 40 kHz past 112 KiB: a new bank
/// built in the adaptation task and swapped in, the survey's end a phase a run; the
/// size today: docs/figures/size.md, `cargo xtask size`).
const FLASH_BUDGET_BYTES: u64 = 120 * 1024;
const RAM_BUDGET_BYTES: u64 = 16 * 1024;

const HELP: &str = "\
cargo xtask <command>

  ci            everything CI checks: fmt, clippy (host and target), host tests,
                cross-build of the portable crates and the firmware, size report,
                the emulator tests, `mutants`, and `docs --check` (which runs
                `perf`)
  test-host     host tests only
  build-cross   release cross-build of the portable crates and the firmware, size report
  size          size report of the firmware (flash and static RAM against budgets);
                regenerates docs/figures/size.md and the pages that show it
  isr-check     the release firmware's control interrupt and adaptation task reach no
                f64 soft-float routine, no panic path, no PC write the scan cannot
                follow and nothing that is not code (disassembly scan; perf scans
                each of its builds the same way)
  flash         build and flash the release firmware with probe-rs's flash algorithm
                (`hil-sim probe flash`: a probe attached; `--probe SERIAL` among
                several); the calibration pages are left as they are
  attach        attach to the running drive without reset (`hil-sim probe attach`:
                checks the flash holds this ELF, halts the core briefly) and record
                its RTT stream until Ctrl-C or `--duration-s`: raw capture, CSV,
                events and plots in target/bench
  bench         the main job, the bench workflow through probe-rs: flash the release
                ELF, reset, record the commissioning power-up, flash it again (the
                calibration survives), record the reboot that loads it. Without
                `--probe` on the emulated STM32G474 (hil-sim/emu, Unicorn; its
                virtual probe, the simulated drive, what the drive did measured at
                the plant; installs Debian cmake and libclang-dev if missing); with
                `--probe [SERIAL]` on the real board. Captures, CSV and plots in
                target/bench
  qemu          the core on an emulated Cortex-M4F: bit-exact against the host
  cycles        instructions and estimated cycles per core step (QEMU's instruction
                trace; installs Debian qemu-system-arm if missing); regenerates
                docs/figures/cycles.md and the pages that show it
  docs [GEN..]  every generated figure of the docs: runs the generators (all, or
                those named: size perf emu-report cycles bench-accuracy scenarios
                commissioning identification laws core ripple-ci ripple
                identification-seeds ripple-elf; minutes for all) into
                docs/figures/, then splices them into README.md and docs/*.md
  docs --render splice the pages from the committed figure files only (after a
                template or prose edit; seconds)
  docs --check  what CI checks: the pages against docs/figures/ (a figure edited by
                hand fails, naming the page and the section), then the generators CI
                can afford rerun into target/docs-check/ and compared with the
                committed figure files
  docs --check-pages  the first half of --check alone (seconds)
  bench-accuracy  the accuracy benchmark against offline calibrations (500 sensors,
                release): regenerates docs/results.md, docs/results/ and the
                benchmark's figure files; further arguments go to `hil-sim
                bench-accuracy` (--sensors, --seed, --reduced)
  emu           the same as `bench` without `--probe`
  emu-report    every firmware-in-the-loop scenario; regenerates
                docs/figures/emu-report.md and emu-scenarios.md and the pages that
                show them
  perf          the control interrupt by stage at 20 and 40 kHz, and at 20 kHz with
                an N = 1 sensor and the bank from the data: cross-builds the three
                (target/perf/drive-fw-20k, -40k, -n1), commissions each to Run on
                the emulator (the last with an N = 1 sensor), measures 0.5 s of Run
                (instructions and estimated Cortex-M4 cycles per stage); regenerates
                docs/figures/perf.md and the pages that show it; fails if a build
                fails isr-check (each is scanned before it runs) or the gate of
                hil-sim/emu/src/budget.rs (a HardFault, a broken rule, a missed
                period, an interrupt, masked stretch or adaptation-task run over
                budget)
  ripple-elf    the torque-ripple learner on the release firmware: cross-builds the
                N = 1 sensor build with Run at 1 rev/s and 5 rev/s (features
                sensor-n1, slow-run or run-5rev) with and without the learner
                (learn-ripple) into target/ripple-elf/,
                commissions each on the emulator on ripple-1rev's rig and sensor and
                scores its Run at the plant (θ̂ against the rotor by harmonic, the
                rotor's motion); regenerates docs/figures/ripple-elf.md and the pages
                that show it (minutes; not in CI)
  mutants       deliberately broken firmware (the `mutant-*` features of drive-fw:
                the correction's sign, the electrical offset, a control interrupt of
                1.5 periods, a starved update queue), each run on the emulator test
                meant to catch it: fails unless every one is caught for its reason
  regs          regenerate the emulator's STM32G474 register table (hil-sim/emu/src/
                regs_g474.rs) from the stm32g4 PAC's sources
  regs --check  fail if the committed register table differs from what the PAC generates
";

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let result = match args.first().map(String::as_str) {
        Some("ci") => ci(),
        Some("test-host") => test_host(),
        Some("build-cross") => setup().and_then(|_| build_cross()).map(drop),
        Some("size") => docs::generate(&["size"]),
        Some("isr-check") => setup()
            .and_then(|_| build_cross())
            .and_then(|_| isr::check(&release_elf())),
        Some("flash") => probe_tool("flash", &args[1..]),
        Some("attach") => probe_tool("attach", &args[1..]),
        Some("bench") => bench(&args[1..]),
        Some("docs") => docs::main(&args[1..]),
        Some("bench-accuracy") => bench_accuracy(&args[1..]).and_then(|_| docs::render_pages()),
        Some("qemu") => setup().and_then(|_| qemu::bit_exact()),
        Some("cycles") => docs::generate(&["cycles"]),
        Some("regs") => regs::main(&args[1..]),
        Some("emu") => bench(&[]),
        Some("mutants") => setup()
            .and_then(|_| emu_setup())
            .and_then(|_| mutants::check()),
        Some("emu-report") => docs::generate(&["emu-report"]),
        Some("perf") => docs::generate(&["perf"]),
        Some("ripple-elf") => docs::generate(&["ripple-elf"]),
        Some("-h" | "--help" | "help") | None => {
            print!("{HELP}");
            Ok(())
        }
        Some(other) => Err(anyhow!("unknown command `{other}`\n\n{HELP}")),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            // The whole chain: what failed, then why.
            eprintln!("xtask: {e:#}");
            ExitCode::FAILURE
        }
    }
}

/// The workspace root of the checkout the command runs in, found at run time: `cargo
/// xtask` is `cargo run -p xtask`, which sets `CARGO_MANIFEST_DIR` to this checkout's
/// xtask/ for the run; started otherwise, `cargo locate-project` from the current
/// directory. Never the source path the binary was built from.
pub(crate) fn root() -> PathBuf {
    static ROOT: std::sync::OnceLock<PathBuf> = std::sync::OnceLock::new();
    ROOT.get_or_init(|| {
        let from_cargo = std::env::var_os("CARGO_MANIFEST_DIR")
            .and_then(|d| Path::new(&d).parent().map(Path::to_path_buf));
        from_cargo
            .or_else(|| {
                let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
                let manifest = output_of(
                    &cargo,
                    &["locate-project", "--workspace", "--message-format", "plain"],
                )?;
                Path::new(manifest.trim()).parent().map(Path::to_path_buf)
            })
            .unwrap_or_else(|| PathBuf::from("."))
    })
    .clone()
}

/// The cargo profile of every host build `cargo xtask` makes (Cargo.toml): one build
/// serves the host tests, the simulator and the emulator.
pub(crate) const HOST_PROFILE: &str = "host";

/// The release firmware ELF the cross build writes (and `cargo xtask flash` flashes).
pub(crate) fn release_elf() -> PathBuf {
    root()
        .join("target")
        .join(TARGET)
        .join("release")
        .join(FIRMWARE)
}

pub(crate) fn cargo() -> Command {
    let mut c = Command::new(std::env::var("CARGO").unwrap_or_else(|_| "cargo".into()));
    c.current_dir(root());
    c
}

/// Run a command, echoing it; error with its exit status.
pub(crate) fn run(mut c: Command) -> Result<()> {
    let shown = format!("{c:?}").replace('"', "");
    eprintln!("\n$ {shown}");
    let status = c
        .status()
        .with_context(|| format!("cannot start {shown}"))?;
    if status.success() {
        Ok(())
    } else {
        Err(anyhow!("`{shown}` failed ({status})"))
    }
}

pub(crate) fn output_of(program: &str, args: &[&str]) -> Option<String> {
    let out = Command::new(program).args(args).output().ok()?;
    out.status
        .success()
        .then(|| String::from_utf8_lossy(&out.stdout).into_owned())
}

/// Install the MCU target and the lint tools when missing.
fn setup() -> Result<()> {
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

fn test_host() -> Result<()> {
    let mut c = cargo();
    c.args([
        "test",
        "--profile",
        HOST_PROFILE,
        "--workspace",
        "--exclude",
        FIRMWARE,
        "--exclude",
        QEMU_IMAGE,
        "--exclude",
        EMULATOR,
        "--locked",
    ]);
    run(c)
}

/// `cargo build --locked --release --target thumbv7em-none-eabihf -p <krate>`: the
/// firmware's profile, for the firmware and every image of the core.
pub(crate) fn cross_build(krate: &str) -> Command {
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
    c
}

/// The cross builds and the firmware's size report (its docs section).
fn build_cross() -> Result<String> {
    for krate in CORE_CRATES.iter().chain([&FIRMWARE]) {
        run(cross_build(krate))?;
    }
    size_report()
}

/// Flash (ROM) and static RAM of the firmware ELF, from its allocated sections: printed,
/// and as the section of docs/figures/size.md.
fn size_report() -> Result<String> {
    use object::{Object, ObjectSection, SectionFlags, SectionKind};
    const SHF_ALLOC: u64 = 0x2;
    let elf = release_elf();
    let data = std::fs::read(&elf).with_context(|| elf.display().to_string())?;
    let file = object::File::parse(&*data).with_context(|| elf.display().to_string())?;
    let (mut flash, mut ram) = (0u64, 0u64);
    eprintln!("\nsize of {FIRMWARE} ({}):", elf.display());
    for s in file.sections() {
        let SectionFlags::Elf { sh_flags } = s.flags() else {
            continue;
        };
        if sh_flags & SHF_ALLOC == 0 || s.size() == 0 {
            continue;
        }
        let name = s.name().unwrap_or("?");
        let in_ram = (0x2000_0000..0x2002_0000).contains(&s.address());
        let nobits = s.kind() == SectionKind::UninitializedData;
        if in_ram {
            ram += s.size();
            // .data occupies RAM and, as its initial image, flash too.
            if !nobits && !name.starts_with(".uninit") {
                flash += s.size();
            }
        } else {
            flash += s.size();
        }
        eprintln!(
            "  {name:<16} {:>8} bytes at {:#010x}",
            s.size(),
            s.address()
        );
    }
    eprintln!(
        "  flash {flash} bytes of {FLASH_BUDGET_BYTES} ({:.0} %), static RAM {ram} bytes of {RAM_BUDGET_BYTES} ({:.0} %)",
        100.0 * flash as f64 / FLASH_BUDGET_BYTES as f64,
        100.0 * ram as f64 / RAM_BUDGET_BYTES as f64
    );
    if flash > FLASH_BUDGET_BYTES || ram > RAM_BUDGET_BYTES {
        bail!("firmware over its size budget");
    }
    let row = |what: &str, used: u64, budget: u64| {
        format!(
            "| {what} | {used} | {budget} ({} KiB) | {:.0} % |\n",
            budget / 1024,
            100.0 * used as f64 / budget as f64
        )
    };
    Ok(format!(
        "The release `{FIRMWARE}` ELF (20 kHz, default features), from its allocated sections:\n\n\
         | | bytes | budget | of the budget |\n|---|---:|---:|---:|\n{}{}",
        row(
            "flash (code, read-only data, the image of .data)",
            flash,
            FLASH_BUDGET_BYTES
        ),
        row("static RAM (.data, .bss, .uninit)", ram, RAM_BUDGET_BYTES)
    ))
}

/// The bench tool (`hil-sim probe`, on the probe-rs library) on the release ELF with a
/// real probe: `flash`, `attach` or `power-up`; further arguments (`--probe SERIAL`,
/// `--duration-s`, ...) go to it.
fn probe_tool(cmd: &str, extra: &[String]) -> Result<()> {
    setup()?;
    build_cross()?;
    let elf = release_elf();
    let mut args = vec!["probe", cmd, "--elf", elf.to_str().context("ELF path")?];
    args.extend(extra.iter().map(String::as_str));
    run(hil_sim(&args))
}

/// The main job, the bench workflow: probe-rs flashes the release ELF, records the
/// commissioning power-up over RTT, flashes it again and records the reboot that loads
/// the calibration. With `--probe [SERIAL]` on the board a real probe reaches; without,
/// on the emulated STM32G474 through the emulator's virtual probe.
fn bench(extra: &[String]) -> Result<()> {
    let Some(i) = extra.iter().position(|a| a == "--probe") else {
        return emu(&["bench"], extra);
    };
    let mut rest: Vec<String> = extra.to_vec();
    // `--probe` alone: the one probe attached (the tool refuses a choice among several).
    if rest.get(i + 1).is_none_or(|v| v.starts_with("--")) {
        rest.remove(i);
    }
    probe_tool("power-up", &rest)
}

/// What the emulator crate's build needs: Unicorn's C code (cmake) and bindgen
/// (libclang).
fn emu_setup() -> Result<()> {
    qemu::ensure("cmake", "cmake")?;
    qemu::ensure_package("libclang-dev")
}

/// The emulator (drive-emu) on the release firmware.
fn emu(args: &[&str], extra: &[String]) -> Result<()> {
    setup()?;
    emu_setup()?;
    run(cross_build(FIRMWARE))?;
    let mut c = emulator("run");
    c.arg("--");
    c.args(args);
    c.args(extra);
    run(c)
}

/// `cargo <subcommand> --profile host --locked -p drive-emu`: the emulator as CI builds
/// it.
pub(crate) fn emulator(subcommand: &str) -> Command {
    let mut c = cargo();
    c.args([
        subcommand,
        "--profile",
        HOST_PROFILE,
        "--locked",
        "-p",
        EMULATOR,
    ]);
    c
}

/// The `fast-run` build (Run near the voltage limit) at `target/fast-run/`, where the
/// emulator's high-modulation test finds it; the default build rebuilt after it.
pub(crate) fn fast_run_aside() -> Result<PathBuf> {
    let out = build_aside(&["--features", "fast-run"], "fast-run", "drive-fw-fast-run")?;
    run(cross_build(FIRMWARE))?;
    Ok(out)
}

/// The 40 kHz and N = 1 builds at `target/perf/` (where `perf` puts them too), for the
/// probe-rs tests that flash them over a commissioned drive: the first keeps its record
/// (another control rate), the second refuses it (another core configuration). The
/// default build rebuilt after them.
pub(crate) fn other_configs_aside() -> Result<()> {
    build_aside(&["--features", "pwm-40khz"], "perf", "drive-fw-40k")?;
    build_aside(&["--features", "sensor-n1"], "perf", "drive-fw-n1")?;
    run(cross_build(FIRMWARE))
}

/// The firmware builds `perf` measures: (label, cargo features, ELF name, the
/// `drive-emu perf` option that names the board it runs on: `--n1-build` for the
/// N = 1 sensor).
const PERF_BUILDS: [(&str, &[&str], &str, &str); 4] = [
    ("20 kHz", &[], "drive-fw-20k", "--build"),
    (
        "40 kHz",
        &["--features", "pwm-40khz"],
        "drive-fw-40k",
        "--build",
    ),
    (
        "20 kHz, N = 1 sensor, bank from the data",
        &["--features", "sensor-n1"],
        "drive-fw-n1",
        "--n1-build",
    ),
    (
        "40 kHz, N = 1 sensor, bank from the data",
        &["--features", "sensor-n1,pwm-40khz"],
        "drive-fw-n1-40k",
        "--n1-build",
    ),
];

/// The release firmware built with `cargo` arguments `features` and copied aside to
/// `target/<dir>/<name>` (every build links to the same path), then scanned by
/// `isr-check`: every build CI makes is, before anything runs it. Callers rebuild the
/// default build last, so that the release ELF other commands use stays that one.
pub(crate) fn build_aside(features: &[&str], dir: &str, name: &str) -> Result<PathBuf> {
    let mut c = cross_build(FIRMWARE);
    c.args(features);
    run(c)?;
    let dir = root().join("target").join(dir);
    std::fs::create_dir_all(&dir).with_context(|| dir.display().to_string())?;
    let out = dir.join(name);
    std::fs::copy(release_elf(), &out).with_context(|| out.display().to_string())?;
    isr::check(&out)?;
    Ok(out)
}

/// Every build cross-built (each copied aside: they link to the same path) and scanned
/// by `isr-check`, then each commissioned to Run on the emulator and measured by stage;
/// `report` regenerates that document's section. The default build is rebuilt last, so
/// the release ELF other commands use stays the 20 kHz one.
fn perf(report: Option<&Path>) -> Result<()> {
    setup()?;
    emu_setup()?;
    let mut builds = Vec::new();
    for (label, features, name, board) in PERF_BUILDS.iter().rev() {
        let out = build_aside(features, "perf", name)?;
        builds.push((*board, format!("{label}={}", out.display())));
    }
    builds.reverse();
    let mut c = emulator("run");
    c.args(["--", "perf"]);
    for (board, b) in &builds {
        c.arg(board).arg(b);
    }
    if let Some(r) = report {
        c.arg("--report").arg(r);
    }
    run(c)
}

/// The builds `ripple-elf` measures: (label, cargo features, ELF name). All with an
/// N = 1 sensor, Run at 1 rev/s and at 5 rev/s (where the release observer shows the
/// learner's harmonics), each without and with the torque-ripple learner.
const RIPPLE_ELF_BUILDS: [(&str, &[&str], &str); 4] = [
    (
        "`sensor-n1`, `slow-run`",
        &["--features", "sensor-n1,slow-run"],
        "drive-fw-n1-slow",
    ),
    (
        "`sensor-n1`, `slow-run`, `learn-ripple`",
        &["--features", "sensor-n1,slow-run,learn-ripple"],
        "drive-fw-n1-slow-learn",
    ),
    (
        "`sensor-n1`, `run-5rev`",
        &["--features", "sensor-n1,run-5rev"],
        "drive-fw-n1-5rev",
    ),
    (
        "`sensor-n1`, `run-5rev`, `learn-ripple`",
        &["--features", "sensor-n1,run-5rev,learn-ripple"],
        "drive-fw-n1-5rev-learn",
    ),
];

/// Both builds cross-built aside (and scanned by `isr-check`), the default build
/// rebuilt after them, then each measured on the emulator's ripple board; `report`
/// regenerates that document's section.
fn ripple_elf(report: Option<&Path>) -> Result<()> {
    setup()?;
    emu_setup()?;
    let mut c = emulator("run");
    c.args(["--", "ripple"]);
    for (label, features, name) in RIPPLE_ELF_BUILDS {
        let out = build_aside(features, "ripple-elf", name)?;
        c.arg("--build").arg(format!("{label}={}", out.display()));
    }
    run(cross_build(FIRMWARE))?;
    if let Some(r) = report {
        c.arg("--report").arg(r);
    }
    run(c)
}

fn ci() -> Result<()> {
    setup()?;
    emu_setup()?;
    regs::main(&["--check".to_string()])?;
    let mut c = cargo();
    c.args(["fmt", "--all", "--", "--check"]);
    run(c)?;
    let mut c = cargo();
    c.args([
        "clippy",
        "--locked",
        "--workspace",
        "--exclude",
        FIRMWARE,
        "--exclude",
        QEMU_IMAGE,
        "--all-targets",
        "--",
        "-D",
        "warnings",
    ]);
    run(c)?;
    let mut c = cargo();
    c.args(["clippy", "--locked", "--target", TARGET]);
    for krate in CORE_CRATES.iter().chain([&FIRMWARE, &QEMU_IMAGE]) {
        c.args(["-p", krate]);
    }
    c.args(["--", "-D", "warnings"]);
    run(c)?;
    build_cross()?;
    isr::check(&release_elf())?;
    qemu::bit_exact()?;
    test_host()?;
    // The release firmware on the emulated board: the scenarios and the rule models;
    // the high-modulation test also runs the `fast-run` build (set aside, then the
    // default rebuilt so the release ELF stays the default build).
    fast_run_aside()?;
    // The probe-rs tests flash builds of another control rate and another core
    // configuration over a commissioned drive (the second's boot refuses the record:
    // ConfigMismatch).
    other_configs_aside()?;
    // The scenarios the tests run are the report's: they leave their rows and sections
    // behind, and the docs check below assembles the report from them (same ELFs).
    let pieces = root().join("target").join("emu-pieces");
    if pieces.exists() {
        std::fs::remove_dir_all(&pieces).with_context(|| pieces.display().to_string())?;
    }
    let mut c = emulator("test");
    // drive_emu::scenarios::pieces::ENV (xtask does not link the GPL emulator).
    c.env("DRIVE_EMU_PIECES", &pieces);
    run(c)?;
    // The same tests fail on firmware broken on purpose: the checks can fail.
    mutants::check()?;
    // Every generated figure of the docs: the pages against the committed figure
    // files, then the generators CI can afford rerun and compared, `perf` among them
    // (every build commissions to Run without a missed control period).
    docs::check_reusing(&[], Some(&pieces))?;
    eprintln!("\nxtask ci: all checks passed");
    Ok(())
}

/// The reduced variant runs in `ci` as `hil-sim/tests/accuracy.rs` (host tests).
fn bench_accuracy(extra: &[String]) -> Result<()> {
    let mut args = vec!["bench-accuracy"];
    args.extend(extra.iter().map(String::as_str));
    run(hil_sim(&args))
}

/// `cargo run --profile host -p hil-sim -- <args>`.
pub(crate) fn hil_sim(args: &[&str]) -> Command {
    let mut c = cargo();
    c.args([
        "run",
        "--locked",
        "--profile",
        HOST_PROFILE,
        "-q",
        "-p",
        "hil-sim",
        "--",
    ]);
    c.args(args);
    c
}
