//! Errors in an input file (a TOML configuration or scenario, a recorded CSV) that say
//! where: the file, the line and the field, so the user can go straight to the fix.

/// A problem at a place in an input file: `file:line: field `key`: problem`, with the
/// line and the field left out when they are not known.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{file}{}: {problem}", located(.line, .field))]
pub struct InputError {
    /// The file as the user named it.
    pub file: String,
    /// 1-based line.
    pub line: Option<u64>,
    /// The field (CSV column or dotted TOML key).
    pub field: Option<String>,
    pub problem: String,
}

impl InputError {
    /// A problem with the file as a whole.
    pub fn new(file: impl Into<String>, problem: impl Into<String>) -> Self {
        Self {
            file: file.into(),
            line: None,
            field: None,
            problem: problem.into(),
        }
    }

    /// A problem on `line`.
    pub fn at(file: impl Into<String>, line: u64, problem: impl Into<String>) -> Self {
        Self {
            line: Some(line),
            ..Self::new(file, problem)
        }
    }

    /// A problem with `field` on `line`.
    pub fn field(
        file: impl Into<String>,
        line: u64,
        field: impl Into<String>,
        problem: impl Into<String>,
    ) -> Self {
        Self {
            field: Some(field.into()),
            ..Self::at(file, line, problem)
        }
    }
}

/// `:line` and `: field `key`` as they follow the file name.
fn located(line: &Option<u64>, field: &Option<String>) -> String {
    match (line, field) {
        (Some(l), Some(f)) => format!(":{l}: field `{f}`"),
        (Some(l), None) => format!(":{l}"),
        (None, Some(f)) => format!(": field `{f}`"),
        (None, None) => String::new(),
    }
}

/// A simulation parameter the model refuses, named as the scenario file spells it
/// (`motor.r_ohm`), with the rule it breaks.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum InvalidParam {
    /// One parameter outside its range: `name` = value: rule.
    #[error("`{name}` = {value}: {rule}")]
    OutOfRange {
        name: &'static str,
        value: f64,
        rule: &'static str,
    },
    /// A rule that involves several parameters or no single value to show.
    #[error("{0}")]
    Rule(&'static str),
    /// The noise distribution refused its deviation.
    #[error(transparent)]
    Noise(#[from] rand_distr::NormalError),
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn messages_name_what_is_known() {
        assert_eq!(
            InputError::new("a.csv", "empty").to_string(),
            "a.csv: empty"
        );
        assert_eq!(
            InputError::at("a.csv", 3, "short").to_string(),
            "a.csv:3: short"
        );
        assert_eq!(
            InputError::field("a.csv", 3, "x", "not a number").to_string(),
            "a.csv:3: field `x`: not a number"
        );
    }
}
