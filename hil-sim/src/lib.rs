//! `hil-sim` as a library: the simulated drive, scenarios, replay and plots, used by
//! the `hil-sim` command and by the tests.

pub mod accuracy;
pub mod baselines;
pub mod checkout;
pub mod cli;
pub mod commission;
pub mod core_config;
pub mod exact;
pub(crate) mod figure;
pub mod figures;
pub mod front_end;
pub mod identification;
pub mod input_error;
pub(crate) mod pending;
pub mod plant;
pub mod plant_truth;
pub mod plots;
pub mod power_up;
pub mod probe_bench;
pub mod replay;
pub mod replay_checks;
pub mod report;
pub mod rig;
pub mod rtt_log;
pub mod scenario;
pub mod sensor;
pub mod stream;
pub mod study;
pub mod survey;
pub mod truth_spectrum;
pub mod vector;

use clap::ValueEnum;
use mras::{AdaptationLaw, Config};

/// Which adaptation law to run.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum Law {
    /// Compensated by H(j m N ω̂), integrated over angle (default).
    Ours,
    /// The paper: sign(ω̂), K1 = 50, K2 = 0.1 in time.
    Paper,
}

impl Law {
    pub fn config(self) -> Config {
        Config {
            law: match self {
                Law::Ours => AdaptationLaw::DEFAULT_COMPENSATED,
                Law::Paper => AdaptationLaw::PAPER_FIG8,
            },
            ..Config::default()
        }
    }
}
