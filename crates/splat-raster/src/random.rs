//! Stateless integer hashing for per-fragment random decisions (render-base's, re-exported: one
//! definition for every crate).

pub use render_base::hash::{hash32, unit_f32};
