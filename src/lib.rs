//! The command-line programs' shared code.
//!
//! - [`metrics`]: image error against a reference (relMSE, MSE, PSNR).

pub mod metrics;
