//! Files a run writes for people and other tools: PLY splats and points.
pub mod ply;
