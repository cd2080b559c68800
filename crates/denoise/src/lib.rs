//! denoise: Intel Open Image Denoise (OIDN) 2.x for the project's images, loaded at run time.
//!
//! Why at run time: OIDN is a 60 MB C++ library with its own thread pool (TBB). Linking it
//! (the `oidn` crate) would make every build need it, and the README's two commands and CI's
//! default build need nothing but Rust. Loaded with `dlopen`, it is found where a user already
//! has it: a system install, or the copy PyPI's `pyoidn` wheel ships (`pip install pyoidn`).
//! Where it is missing, [`Denoiser::load`] says so and how to install it; nothing else in the
//! project changes. The cost of loading is paid once per process (about 0.1 s, measured in
//! BENCHMARKS.md); a filter is built once per image size and reused.
//!
//! Read it in this order:
//! - [`library`]: where the library is looked for, and the part of its C API used here.
//! - [`filter`]: [`Denoiser`], one device and its `RT` filters: colour alone, or with the
//!   albedo, or with the albedo and the normal ([`Guides`]), at a [`Quality`].
//! - [`on_demand`]: [`OnDemand`], a denoiser loaded the first time it is used.

pub mod filter;
pub mod library;
pub mod on_demand;

pub use filter::{Denoiser, Guides, Options, Quality};
pub use library::{ENV_VAR, INSTALL_HINT};
pub use on_demand::OnDemand;

/// What went wrong, with what to do about it.
#[derive(Debug, thiserror::Error)]
pub enum DenoiseError {
    #[error(
        "Intel Open Image Denoise 2.x was not found, so nothing can be denoised. {INSTALL_HINT} \
         Looked for: {}",
        searched.join("; ")
    )]
    NotFound { searched: Vec<String> },
    #[error("{path}: cannot use it as Intel Open Image Denoise: {message}. {INSTALL_HINT}")]
    Load { path: String, message: String },
    #[error("Open Image Denoise: {0}")]
    Oidn(String),
    #[error("{what}: {message}")]
    Input { what: String, message: String },
    /// The run was abandoned through [`Denoiser::abort_handle`].
    #[error("the denoising run was abandoned")]
    Cancelled,
}

pub type Result<T, E = DenoiseError> = std::result::Result<T, E>;
