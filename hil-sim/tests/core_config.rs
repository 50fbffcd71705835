//! The core configuration file (`replay --config`, a scenario's `[core]` table): every
//! field arrives, and every refusal names its line and dotted key.

use hil_sim::core_config::CoreConfigFile;
use hil_sim::front_end::FrontEnd;
use mras::{AdaptationLaw, Config, PathKind};
const FULL: &str = include_str!("data/core_config_full.toml");

fn parse(text: &str) -> CoreConfigFile {
    CoreConfigFile::parse(text, "cfg.toml").unwrap()
}

fn parse_error(text: &str) -> String {
    CoreConfigFile::parse(text, "cfg.toml")
        .unwrap_err()
        .to_string()
}

fn config_error(text: &str) -> String {
    parse(text).to_config(50.0e-6).unwrap_err().to_string()
}

#[test]
fn full_file_parses_and_every_field_arrives() {
    let t = parse(FULL);
    assert!(t.input_given() && t.sets("sensor_periods"));
    let c = t.to_config(100.0e-6).unwrap();
    assert_eq!(c.sample_period_s, 100.0e-6);
    assert_eq!(c.sensor_periods, 4);
    assert_eq!(t.input.offset_x, 2048.0);
    assert_eq!(t.input.gain_y, 1.0 / 1000.0);
    assert_eq!(t.input.raw_limit, 4095.0);
    assert_eq!(c.observer.eigenvalues_hz, [200.0, 20.0, 2.0]);
    assert_eq!(c.observer.inertia_kg_m2, 2.0e-4);
    assert_eq!(
        c.paths(),
        &[
            PathKind::Offset,
            PathKind::AmplitudeQuadrature,
            PathKind::Harmonic(4),
            PathKind::Harmonic(5),
            PathKind::Harmonic(-4),
        ]
    );
    assert!(c.paths_from_data);
    assert_eq!(
        c.law,
        AdaptationLaw::Compensated {
            gain_per_rad: 0.1,
            offset_gain_per_mech_rad: 0.2,
            proportional: 0.05,
            h_floor: 0.1
        }
    );
    assert_eq!(c.gates.max_disturbance_nm, f32::INFINITY);
    assert_eq!(c.gates.max_accel_rad_s2, 5000.0);
    assert_eq!(c.health.coefficient_limit, 0.5);
    assert_eq!(c.convergence.min_revs, 3);
}

#[test]
fn empty_file_is_the_core_default() {
    let t = parse("");
    assert!(!t.input_given() && !t.sets("sensor_periods"));
    assert_eq!(t.to_config(50.0e-6).unwrap(), Config::default());
    assert_eq!(t.input, FrontEnd::default());
}

#[test]
fn a_partial_table_keeps_the_other_defaults() {
    let t = parse("[gates]\nmin_h = 0.01\n[input]\nraw_limit = 4095\n");
    let (c, d) = (t.config, Config::default());
    assert_eq!(c.gates.min_h, 0.01);
    assert_eq!(c.gates.min_speed_rad_s, d.gates.min_speed_rad_s);
    assert_eq!(t.input.raw_limit, 4095.0);
    assert_eq!(t.input.gain_x, FrontEnd::default().gain_x);
    assert!(!parse("[input]\nraw_limit = 4095\n").input_given());
}

#[test]
fn input_table_errors_name_their_line() {
    let e = parse_error("sensor_periods = 2\n[input]\ngain_x = 0.5\nofset_x = 1\n");
    assert!(
        e.starts_with("cfg.toml:4: ") && e.contains("`input.ofset_x`"),
        "{e}"
    );
    let e = parse_error("sensor_periods = 2\ninput = 3\n");
    assert!(
        e.starts_with("cfg.toml:2: ") && e.contains("must be a table"),
        "{e}"
    );
}

#[test]
fn paper_literal_law_and_integer_values() {
    let t = parse("[law]\nkind = \"paper-literal\"\nk1_per_s = 20\n");
    assert_eq!(
        t.to_config(50.0e-6).unwrap().law,
        AdaptationLaw::PaperLiteral {
            k1_per_s: 20.0,
            k2: 0.1
        }
    );
}

#[test]
fn unknown_field_names_it_its_table_and_line() {
    let e = parse_error("sensor_periods = 2\n\n[gates]\nmin_speed_rad_s = 1.0\nmin_speeed = 2.0\n");
    assert!(e.starts_with("cfg.toml:5: "), "{e}");
    assert!(e.contains("`gates.min_speeed`"), "{e}");
    assert!(e.contains("unknown field"), "{e}");
}

#[test]
fn wrong_type_names_the_field() {
    let e = parse_error("[law]\ngain_per_rad = \"fast\"\n");
    assert!(e.starts_with("cfg.toml:2: field `law.gain_per_rad`"), "{e}");
}

#[test]
fn path_names_as_the_csv_columns_spell_them_are_accepted() {
    let t = parse("paths = [\"offset\", \"amplitude_quadrature\", \"h4\"]\n");
    let want = [
        PathKind::Offset,
        PathKind::AmplitudeQuadrature,
        PathKind::Harmonic(4),
    ];
    assert_eq!(t.config.paths(), &want);
}

#[test]
fn bad_path_string_is_refused_with_its_line() {
    for (bad, why) in [
        ("\"h3\"", "h must be > 3 or < 0"),
        ("\"h16\"", "|h| <= 15"),
        ("\"hx\"", "unknown path"),
    ] {
        let e = parse_error(&format!(
            "sensor_periods = 2\npaths = [\"offset\", {bad}]\n"
        ));
        assert!(e.starts_with("cfg.toml:2: field `paths`"), "{e}");
        assert!(e.contains(why), "{e}");
    }
}

#[test]
fn too_many_paths_point_at_paths() {
    // 17 valid kinds, one more than a bank holds.
    let names: Vec<String> = ["offset", "amplitude-quadrature", "h-2", "h-4", "h-5"]
        .into_iter()
        .map(String::from)
        .chain((4..=15).map(|h| format!("h{h}")))
        .map(|n| format!("{n:?}"))
        .collect();
    assert_eq!(names.len(), mras::MAX_PATHS + 1);
    let e = parse_error(&format!(
        "sensor_periods = 2\npaths = [{}]\n",
        names.join(", ")
    ));
    assert!(
        e.starts_with("cfg.toml:2: invalid configuration `paths`: at most 16 paths"),
        "{e}"
    );
}

#[test]
fn out_of_range_value_names_the_core_field_and_line() {
    let e = config_error("[observer]\ninertia_kg_m2 = 1e-4\n\n[law]\ngain_per_rad = 0.5\n");
    assert!(
        e.starts_with("cfg.toml:5: invalid configuration `law.gain_per_rad`"),
        "{e}"
    );
    // Dotted keys and inline tables are the same keys.
    for text in ["law.gain_per_rad = 0.5\n", "law = { gain_per_rad = 0.5 }\n"] {
        let e = config_error(text);
        assert!(
            e.starts_with("cfg.toml:1: invalid configuration `law.gain_per_rad`"),
            "{e}"
        );
    }
}

#[test]
fn paths_sharing_an_error_harmonic_point_at_paths() {
    let e = config_error("# m = 3 twice\npaths = [\"h4\", \"h-2\"]\n");
    assert!(
        e.starts_with("cfg.toml:2: invalid configuration `paths`"),
        "{e}"
    );
}

#[test]
fn key_of_the_other_law_is_refused() {
    for (text, line, key) in [
        ("[law]\nkind = \"compensated\"\nk2 = 0.1\n", 3, "law.k2"),
        ("[law]\nk1_per_s = 20.0\n", 2, "law.k1_per_s"),
        (
            "[law]\nh_floor = 0.1\nkind = \"paper-literal\"\n",
            2,
            "law.h_floor",
        ),
    ] {
        let e = parse_error(text);
        let want = format!("cfg.toml:{line}: invalid configuration `{key}`: belongs to");
        assert!(e.starts_with(&want), "{e}");
    }
}

#[test]
fn eigenvalue_too_fast_for_the_period_is_refused() {
    let e = parse("").to_config(1.0e-3).unwrap_err().to_string();
    assert!(e.contains("`observer.eigenvalues_hz`"), "{e}");
}
