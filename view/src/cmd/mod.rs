//! The subcommands of `view`, one module each, with the options they share ([`args`]), the
//! one loader of files, scenes and lights ([`load`]). `--help-advanced` is `mlt_help`'s.

pub mod args;
pub mod compare;
pub mod flat;
pub mod load;
pub mod open;
pub mod probe;
pub mod reference;
pub mod render;
pub mod timings;
