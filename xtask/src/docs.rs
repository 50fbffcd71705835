//! `cargo xtask docs`: every measured figure on a page comes from a generator.
//!
//! A generator is the command that measures (`perf`, `emu-report`, `cycles`, `size`,
//! `bench-accuracy`, hil-sim's figure runs). It writes *figure files* into
//! `docs/figures/`: markdown sections (`<id>.md`) and, for the accuracy benchmark, the
//! page's figures by name (`accuracy.json`, `accuracy-reduced.json`). The pages (README.md,
//! docs/*.md) hold hand-written prose around generated sections, each a copy of one
//! figure file between markers that name the file and its command (see `docgen`);
//! docs/results.md is generated whole from its template and `accuracy.json`.
//!
//! `cargo xtask docs [NAME..]` runs the generators (all by default) and splices their
//! files into the pages; `--render` only splices (after a template or prose edit).
//! `--check` (in `cargo xtask ci`): first the pages against the committed figure files,
//! with no simulation (a hand edit of any figure on any page fails, naming the page and
//! the section); then the generators CI can afford rerun into `target/docs-check/` and
//! their files compared with the committed ones (a figure that a code change moved, or a
//! hand edit of the figure file itself, fails). The expensive generators (the full
//! accuracy benchmark, the ripple scenarios over 25 noise seeds, the QEMU cycle count)
//! are checked only through their committed files; the reduced accuracy benchmark's
//! figures are the first 24 sensors of the full one's, so CI's reduced run checks that
//! the full run's figures are still current for those. `--check-pages` is the first
//! part alone (seconds).

use crate::{hil_sim, root, run};
use anyhow::{anyhow, bail, Context, Result};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// How `cargo xtask docs --check` checks a generator's figure files.
#[derive(Clone, Copy, PartialEq, Eq)]
enum InCi {
    /// Rerun (seconds to a few minutes: CI runs most of it anyway), every file compared.
    Rerun,
    /// The accuracy benchmark's reduced variant rerun, `accuracy-reduced.json` compared.
    Reduced,
    /// Too slow for CI: only the pages against its committed files.
    No,
}

struct Generator {
    name: &'static str,
    /// The command the pages' markers name: what regenerates the section.
    command: &'static str,
    /// Markdown sections it writes (`docs/figures/<id>.md`).
    sections: &'static [&'static str],
    /// Other figure files it writes (data the renderer reads).
    data: &'static [&'static str],
    in_ci: InCi,
}

const GENERATORS: [Generator; 14] = [
    Generator {
        name: "size",
        command: "cargo xtask size",
        sections: &["size"],
        data: &[],
        in_ci: InCi::Rerun,
    },
    Generator {
        name: "perf",
        command: "cargo xtask perf",
        sections: &["perf"],
        data: &[],
        in_ci: InCi::Rerun,
    },
    Generator {
        name: "emu-report",
        command: "cargo xtask emu-report",
        sections: &["emu-report", "emu-scenarios"],
        data: &[],
        in_ci: InCi::Rerun,
    },
    Generator {
        name: "cycles",
        command: "cargo xtask cycles",
        sections: &["cycles"],
        data: &[],
        in_ci: InCi::No,
    },
    Generator {
        name: "bench-accuracy",
        command: "cargo xtask bench-accuracy",
        sections: &["accuracy-summary"],
        data: &["accuracy.json", "accuracy-reduced.json"],
        in_ci: InCi::Reduced,
    },
    Generator {
        name: "scenarios",
        command: "cargo xtask docs scenarios",
        sections: &["scenarios", "scenarios-ci", "scenarios-summary"],
        data: &[],
        in_ci: InCi::Rerun,
    },
    Generator {
        name: "commissioning",
        command: "cargo xtask docs commissioning",
        sections: &["commissioning"],
        data: &[],
        in_ci: InCi::Rerun,
    },
    Generator {
        name: "identification",
        command: "cargo xtask docs identification",
        sections: &["identification", "identification-without"],
        data: &[],
        in_ci: InCi::Rerun,
    },
    Generator {
        name: "laws",
        command: "cargo xtask docs laws",
        sections: &["compare-laws", "gain-sweep", "laws-summary"],
        data: &[],
        in_ci: InCi::Rerun,
    },
    Generator {
        name: "core",
        command: "cargo xtask docs core",
        sections: &["core-accuracy"],
        data: &[],
        in_ci: InCi::Rerun,
    },
    Generator {
        name: "ripple-ci",
        command: "cargo xtask docs ripple-ci",
        sections: &["ripple-ci"],
        data: &[],
        in_ci: InCi::Rerun,
    },
    Generator {
        name: "ripple",
        command: "cargo xtask docs ripple",
        sections: &["ripple"],
        data: &[],
        in_ci: InCi::No,
    },
    Generator {
        name: "identification-seeds",
        command: "cargo xtask docs identification-seeds",
        sections: &["identification-seeds"],
        data: &[],
        in_ci: InCi::No,
    },
    Generator {
        name: "ripple-elf",
        command: "cargo xtask ripple-elf",
        sections: &["ripple-elf"],
        data: &[],
        in_ci: InCi::No,
    },
];

/// The page generated whole, its template and its figure files (the second's names
/// prefixed as the template names them).
const RESULTS_PAGE: &str = "docs/results.md";
const RESULTS_TEMPLATE: &str = "hil-sim/src/accuracy/results.template.md";
const RESULTS_FIGURES: [(&str, &str); 2] =
    [("accuracy.json", ""), ("accuracy-reduced.json", "reduced.")];

fn figures_dir() -> PathBuf {
    root().join(docgen::FIGURES_DIR)
}

fn generator(name: &str) -> Result<&'static Generator> {
    GENERATORS.iter().find(|g| g.name == name).ok_or_else(|| {
        let names: Vec<&str> = GENERATORS.iter().map(|g| g.name).collect();
        anyhow!(
            "no docs generator `{name}` (available: {})",
            names.join(", ")
        )
    })
}

fn owner(id: &str) -> Option<&'static Generator> {
    GENERATORS.iter().find(|g| g.sections.contains(&id))
}

/// `cargo xtask docs [--check | --check-pages | --render] [NAME..]`.
pub fn main(args: &[String]) -> Result<()> {
    let (flags, names): (Vec<&String>, Vec<&String>) =
        args.iter().partition(|a| a.starts_with("--"));
    let names: Vec<&str> = names.iter().map(|s| s.as_str()).collect();
    match flags.iter().map(|s| s.as_str()).collect::<Vec<_>>()[..] {
        [] => generate(&names),
        ["--render"] if names.is_empty() => render_pages(),
        ["--check-pages"] if names.is_empty() => check_pages(),
        ["--check"] => check(&names),
        _ => bail!("usage: cargo xtask docs [--check | --check-pages | --render] [GENERATOR..]"),
    }
}

/// Run the named generators (all when none) into docs/figures, then splice the pages.
pub fn generate(names: &[&str]) -> Result<()> {
    let chosen: Vec<&Generator> = match names {
        [] => GENERATORS.iter().collect(),
        _ => names.iter().map(|n| generator(n)).collect::<Result<_>>()?,
    };
    let dir = figures_dir();
    std::fs::create_dir_all(&dir).with_context(|| dir.display().to_string())?;
    let mut walls = Vec::new();
    for g in chosen {
        let started = std::time::Instant::now();
        run_generator(g, &dir, false, None)
            .with_context(|| format!("docs generator {}", g.name))?;
        walls.push((g.name, started.elapsed().as_secs_f64()));
    }
    render_pages()?;
    for (name, s) in walls {
        eprintln!("xtask docs: {name} took {s:.0} s wall");
    }
    Ok(())
}

/// Run `g` with its figure files written into `out`; `check`: the variant CI runs;
/// `pieces`: where the emulator's tests left the scenarios they ran (`emu-report`
/// takes those of the same ELFs instead of running them again).
fn run_generator(g: &Generator, out: &Path, check: bool, pieces: Option<&Path>) -> Result<()> {
    let file = |name: &str| out.join(name);
    match g.name {
        "size" => {
            crate::setup()?;
            let text = crate::build_cross()?;
            write(&file("size.md"), &text)
        }
        "perf" => crate::perf(Some(&file("perf.md"))),
        "ripple-elf" => crate::ripple_elf(Some(&file("ripple-elf.md"))),
        "emu-report" => {
            let (report, details) = (file("emu-report.md"), file("emu-scenarios.md"));
            let report = report.to_str().context("a non-UTF-8 path")?;
            let details = details.to_str().context("a non-UTF-8 path")?;
            let fast = crate::fast_run_aside()?;
            let fast = fast.to_str().context("a non-UTF-8 path")?;
            let mut reuse = Vec::new();
            if let Some(dir) = pieces {
                reuse.push("--reuse".to_string());
                reuse.push(dir.to_str().context("a non-UTF-8 path")?.to_string());
            }
            crate::emu(
                &[
                    "scenarios",
                    "--report",
                    report,
                    "--details",
                    details,
                    "--fast-elf",
                    fast,
                ],
                &reuse,
            )
        }
        "cycles" => {
            crate::setup()?;
            let text = crate::qemu::cycles()?;
            write(&file("cycles.md"), &text)
        }
        "bench-accuracy" => {
            let figures = out.to_str().context("a non-UTF-8 path")?;
            if check {
                let page = file("results.md");
                let page = page.to_str().context("a non-UTF-8 path")?;
                run(hil_sim(&[
                    "bench-accuracy",
                    "--reduced",
                    "--out",
                    page,
                    "--figures",
                    figures,
                ]))
            } else {
                run(hil_sim(&["bench-accuracy", "--figures", figures]))
            }
        }
        name => {
            let dir = out.to_str().context("a non-UTF-8 path")?;
            run(hil_sim(&["figures", name, "--out", dir]))
        }
    }
}

fn write(path: &Path, text: &str) -> Result<()> {
    std::fs::write(path, docgen::normalised(text)).with_context(|| path.display().to_string())
}

fn read(path: &Path) -> Result<String> {
    std::fs::read_to_string(path).with_context(|| path.display().to_string())
}

/// README.md and docs/*.md but the page generated whole.
fn pages() -> Result<Vec<PathBuf>> {
    let mut pages = vec![root().join("README.md")];
    let docs = root().join("docs");
    for e in std::fs::read_dir(&docs).with_context(|| docs.display().to_string())? {
        let p = e?.path();
        if p.extension().is_some_and(|x| x == "md") && !p.ends_with(RESULTS_PAGE) {
            pages.push(p);
        }
    }
    pages.sort();
    Ok(pages)
}

fn shown(p: &Path) -> String {
    p.strip_prefix(root()).unwrap_or(p).display().to_string()
}

/// docs/results.md from its template and figure files.
fn results_page() -> Result<String> {
    let mut values = BTreeMap::new();
    for (file, prefix) in RESULTS_FIGURES {
        let path = figures_dir().join(file);
        let v: BTreeMap<String, String> = serde_json::from_str(&read(&path)?)
            .with_context(|| format!("{}: not a map of figures", shown(&path)))?;
        values.extend(v.into_iter().map(|(k, v)| (format!("{prefix}{k}"), v)));
    }
    let template = read(&root().join(RESULTS_TEMPLATE))?;
    docgen::render(&template, &values).map_err(|e| anyhow!("{RESULTS_TEMPLATE}: {e}"))
}

/// What a page should be: each section's content replaced by its figure file. The
/// problems found on the way (sections no generator owns, commands that are not the
/// owner's, missing figure files) are returned with it.
fn rendered(page: &Path, text: &str, seen: &mut Vec<String>) -> (String, Vec<String>) {
    let name = shown(page);
    let mut problems = Vec::new();
    let found = match docgen::sections(text) {
        Ok(f) => f,
        Err(e) => return (text.into(), vec![format!("{name}: {e}")]),
    };
    let mut out = text.to_string();
    for f in found {
        let Some(g) = owner(&f.id) else {
            problems.push(format!(
                "{name} line {}: section `{}` is written by no generator",
                f.line, f.id
            ));
            continue;
        };
        if f.command != g.command {
            problems.push(format!(
                "{name} line {}: section `{}` names `{}`; its generator is `{}`",
                f.line, f.id, f.command, g.command
            ));
        }
        let path = figures_dir().join(format!("{}.md", f.id));
        let Ok(figure) = std::fs::read_to_string(&path) else {
            problems.push(format!(
                "{name} line {}: section `{}` has no figure file {} (run `{}`)",
                f.line,
                f.id,
                shown(&path),
                g.command
            ));
            continue;
        };
        seen.push(f.id.clone());
        match docgen::splice(&out, &f.id, &figure) {
            Ok(s) => out = s,
            Err(e) => problems.push(format!("{name}: {e}")),
        }
    }
    (out, problems)
}

/// Every page as its figure files make it: (page, what it is, what it should be), and
/// the problems that are not a difference of content.
type Rendering = (Vec<(PathBuf, String, String)>, Vec<String>);

fn render_all() -> Result<Rendering> {
    let mut out = Vec::new();
    let mut problems = Vec::new();
    let mut seen = Vec::new();
    for page in pages()? {
        let text = read(&page)?;
        let (want, p) = rendered(&page, &text, &mut seen);
        problems.extend(p);
        out.push((page, text, want));
    }
    let results = root().join(RESULTS_PAGE);
    match results_page() {
        Ok(want) => out.push((results.clone(), read(&results)?, want)),
        Err(e) => problems.push(format!("{}: {e:#}", shown(&results))),
    }
    // Every figure file is some generator's, and every section is on some page.
    let mut owned: Vec<String> = GENERATORS
        .iter()
        .flat_map(|g| g.sections.iter().map(|s| format!("{s}.md")))
        .chain(
            GENERATORS
                .iter()
                .flat_map(|g| g.data.iter().map(|d| d.to_string())),
        )
        .collect();
    owned.sort();
    let dir = figures_dir();
    if let Ok(entries) = std::fs::read_dir(&dir) {
        for e in entries.flatten() {
            let name = e.file_name().to_string_lossy().into_owned();
            if !owned.contains(&name) {
                problems.push(format!(
                    "{}/{name}: written by no generator (remove it, or register its generator in xtask/src/docs.rs)",
                    docgen::FIGURES_DIR
                ));
            }
        }
    }
    for g in &GENERATORS {
        for id in g.sections {
            if !seen.iter().any(|s| s == id) {
                problems.push(format!(
                    "{}/{id}.md (`{}`) is on no page",
                    docgen::FIGURES_DIR,
                    g.command
                ));
            }
        }
    }
    Ok((out, problems))
}

/// Splice every page from the committed figure files.
pub fn render_pages() -> Result<()> {
    let (pages, problems) = render_all()?;
    for (page, is, want) in pages {
        if is != want {
            std::fs::write(&page, &want).with_context(|| page.display().to_string())?;
            eprintln!("xtask docs: rendered {}", shown(&page));
        }
    }
    if !problems.is_empty() {
        bail!("the docs' generated sections:\n  {}", problems.join("\n  "));
    }
    Ok(())
}

/// The pages against the committed figure files: every difference named by page,
/// section and line.
pub fn check_pages() -> Result<()> {
    let (pages, mut problems) = render_all()?;
    for (page, is, want) in &pages {
        if is == want {
            continue;
        }
        problems.push(difference(page, is, want));
    }
    if !problems.is_empty() {
        bail!(
            "the docs differ from what their generators wrote (a figure on a page is \
             regenerated, never edited by hand: rerun the section's command, or edit the \
             prose outside the markers, or the template):\n  {}",
            problems.join("\n  ")
        );
    }
    eprintln!(
        "xtask docs: {} pages agree with their figure files",
        pages.len()
    );
    Ok(())
}

/// Which section of `page` differs, and its first differing line.
fn difference(page: &Path, is: &str, want: &str) -> String {
    let name = shown(page);
    let Some((n, a, b)) = docgen::first_difference(is, want) else {
        return format!("{name}: differs");
    };
    let (section, command) = docgen::sections(is)
        .ok()
        .and_then(|found| {
            // The section around the line (1-based) that differs.
            let at = is
                .split_inclusive('\n')
                .take(n - 1)
                .map(str::len)
                .sum::<usize>();
            found
                .into_iter()
                .find(|f| f.content.start <= at && at <= f.content.end)
                .map(|f| (format!("section `{}`", f.id), f.command))
        })
        .unwrap_or_else(|| match page.ends_with(RESULTS_PAGE) {
            true => (
                format!("the page generated from {RESULTS_TEMPLATE}"),
                "cargo xtask bench-accuracy".into(),
            ),
            false => (
                "outside any section".into(),
                "cargo xtask docs --render".into(),
            ),
        });
    format!(
        "{name}: {section}, line {n}:\n      page:      {a}\n      generated: {b}\n    (regenerate: `{command}`)"
    )
}

/// The CI check: the pages, then every generator CI can afford rerun and compared
/// (`names`: only those).
pub fn check(names: &[&str]) -> Result<()> {
    check_reusing(names, None)
}

/// [`check`], with the scenarios the emulator's tests ran on the same ELFs taken from
/// `pieces` (`cargo xtask ci`, which has just run them).
pub fn check_reusing(names: &[&str], pieces: Option<&Path>) -> Result<()> {
    let pages = check_pages();
    let chosen: Vec<&Generator> = match names {
        [] => GENERATORS.iter().filter(|g| g.in_ci != InCi::No).collect(),
        _ => names.iter().map(|n| generator(n)).collect::<Result<_>>()?,
    };
    let mut problems = Vec::new();
    for g in chosen {
        let dir = root().join("target").join("docs-check").join(g.name);
        if dir.exists() {
            std::fs::remove_dir_all(&dir).with_context(|| dir.display().to_string())?;
        }
        std::fs::create_dir_all(&dir).with_context(|| dir.display().to_string())?;
        let started = std::time::Instant::now();
        run_generator(g, &dir, true, pieces)
            .with_context(|| format!("docs generator {}", g.name))?;
        eprintln!(
            "xtask docs: {} regenerated in {:.0} s wall",
            g.name,
            started.elapsed().as_secs_f64()
        );
        let files: Vec<String> = match g.in_ci {
            InCi::Reduced => vec!["accuracy-reduced.json".into()],
            _ => g
                .sections
                .iter()
                .map(|s| format!("{s}.md"))
                .chain(g.data.iter().map(|d| d.to_string()))
                .collect(),
        };
        for f in files {
            let (new, committed) = (dir.join(&f), figures_dir().join(&f));
            let new_text = read(&new)?;
            let old = std::fs::read_to_string(&committed).unwrap_or_default();
            if docgen::normalised(&new_text) != docgen::normalised(&old) {
                let (n, a, b) = docgen::first_difference(&old, &new_text).unwrap_or((0, "", ""));
                problems.push(format!(
                    "{}/{f}: `{}` now measures otherwise, line {n}:\n      committed:   {a}\n      regenerated: {b}\n    (the whole file: {}; rerun `{}` and commit)",
                    docgen::FIGURES_DIR,
                    g.command,
                    shown(&new),
                    g.command
                ));
            }
        }
    }
    let mut failed = Vec::new();
    if let Err(e) = pages {
        failed.push(format!("{e:#}"));
    }
    if !problems.is_empty() {
        failed.push(format!(
            "figure files out of date:\n  {}",
            problems.join("\n  ")
        ));
    }
    if !failed.is_empty() {
        bail!("{}", failed.join("\n"));
    }
    eprintln!("xtask docs: every page and every figure CI regenerates agree");
    Ok(())
}
