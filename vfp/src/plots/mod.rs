//! SVG figures of the commands.

pub mod diag;
pub mod identify;
