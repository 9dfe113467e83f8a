//! Shared code of the plot binaries (`plot_sweep`, `plot_scaling`).

pub mod axes;
pub mod table;
