//! What to run: presets, the matrix of runs in a seeded order, and the memory guard.

pub mod matrix;
pub mod memory;
pub mod preset;
