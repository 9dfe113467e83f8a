//! The light model the relighting evaluates (`E = I max(0, cos) / d^2 V` inside a spot's
//! cone): [`mlt_format::light_model`], shared with the bake's estimates.

pub use mlt_format::light_model::{Cone, Light, LightError};
