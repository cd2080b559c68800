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
//!   albedo, or with the albedo and the normal ([`Aux`]), at a [`Quality`].

pub mod filter;
pub mod library;

pub use filter::{Aux, Denoiser, Options, Quality};
pub use library::{ENV_VAR, INSTALL_HINT};

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
}

pub type Result<T, E = DenoiseError> = std::result::Result<T, E>;

/// The variable that makes a missing library an error for [`load_or_skip`] (CI sets it to 1).
pub const REQUIRE_VAR: &str = "GSCACHE_REQUIRE_OIDN";

/// For steps that run only where the library is installed (the denoising tests): the denoiser
/// on `threads` threads, or `None` with a line on stderr saying the step was skipped. Where
/// `GSCACHE_REQUIRE_OIDN=1` a missing library is the error instead, so a run that must denoise
/// cannot pass by skipping.
pub fn load_or_skip(threads: usize) -> Result<Option<Denoiser>> {
    match Denoiser::load(threads) {
        Ok(d) => Ok(Some(d)),
        Err(e) if std::env::var(REQUIRE_VAR).as_deref() != Ok("1") => {
            eprintln!("SKIPPED: Open Image Denoise is not installed here ({e})");
            Ok(None)
        }
        Err(e) => Err(e),
    }
}
