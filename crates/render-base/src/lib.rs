//! render-base: what every crate of the renderer shares.
//!
//! - [`atomic_file`]: the one way the project writes a file for a user. The file appears whole
//!   or not at all, and no one who can write to the output folder can redirect the write.
//! - [`control`]: cancellation and progress for long work, in one value ([`Control::none()`]
//!   for neither).
//! - [`hash`]: the splitmix64 finaliser every stateless hash is built on.

pub mod atomic_file;
pub mod control;
pub mod hash;

pub use atomic_file::{AtomicWriter, WriteError, check_writable, write_atomically};
pub use control::Control;
