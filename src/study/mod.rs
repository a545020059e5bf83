//! The studies: `lfit bench` (methods × strategies × budgets on one energy, [`bench`]), its
//! report with the papers' tables, statistical tests and plots ([`report`], [`stats`],
//! [`plots`]), its fitted poses ([`poses`]), the built-in presets ([`presets`]) and tuned
//! baselines ([`tuned`]), and `lfit ablate` ([`ablate`], with the neural feature).

#[cfg(feature = "neural")]
pub mod ablate;
pub mod bench;
pub mod plots;
pub mod poses;
pub mod presets;
pub mod report;
pub mod stats;
pub mod tuned;
