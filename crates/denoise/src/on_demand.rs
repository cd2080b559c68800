//! A denoiser loaded the first time it is used, not when a program starts.
//!
//! Loading Open Image Denoise runs its library's initialisers and starts its thread pool: a
//! program that only might denoise (the viewer, whose page has a denoise toggle) should pay
//! neither, nor run any library, until the user asks for a denoised image.

use crate::{Denoiser, Result};

/// A [`Denoiser`] loaded on first use; a failed load is remembered and said again, not
/// retried on every frame.
#[derive(Debug)]
pub struct OnDemand {
    threads: usize,
    /// The library's file, where the caller names it; else it is looked for
    /// ([`crate::library`]).
    library: Option<std::path::PathBuf>,
    state: State,
}

#[derive(Debug)]
enum State {
    NotLoaded,
    Loaded(Box<Denoiser>),
    Missing(String),
    /// Loaded, and handed to a caller that runs it elsewhere ([`OnDemand::take`]).
    Taken,
}

impl OnDemand {
    /// A denoiser that will run on `threads` threads (0: every core) once loaded.
    pub fn new(threads: usize) -> Self {
        Self {
            threads,
            library: None,
            state: State::NotLoaded,
        }
    }

    /// A denoiser from the library at `path`, loaded on first use.
    pub fn from_library(path: impl Into<std::path::PathBuf>, threads: usize) -> Self {
        Self {
            threads,
            library: Some(path.into()),
            state: State::NotLoaded,
        }
    }

    /// A denoiser already loaded (for callers that load it themselves).
    pub fn loaded(denoiser: Denoiser) -> Self {
        Self {
            threads: 0,
            library: None,
            state: State::Loaded(Box::new(denoiser)),
        }
    }

    /// Whether a denoiser may be had: true until a load has failed.
    pub fn offered(&self) -> bool {
        !matches!(self.state, State::Missing(_))
    }

    /// Whether the library has been loaded.
    pub fn is_loaded(&self) -> bool {
        matches!(self.state, State::Loaded(_) | State::Taken)
    }

    /// The denoiser itself, loaded now if need be, for a caller that runs it on a thread of
    /// its own (the viewer's filter thread); later calls say it was taken.
    pub fn take(&mut self) -> std::result::Result<Denoiser, String> {
        self.get()?;
        match std::mem::replace(&mut self.state, State::Taken) {
            State::Loaded(denoiser) => Ok(*denoiser),
            other => {
                self.state = other;
                Err("Open Image Denoise was handed over already".to_string())
            }
        }
    }

    /// The denoiser, loaded now if this is the first call; the load's error as text otherwise.
    pub fn get(&mut self) -> std::result::Result<&mut Denoiser, String> {
        if let State::NotLoaded = self.state {
            let loaded: Result<Denoiser> = match &self.library {
                Some(path) => Denoiser::from_library(path, self.threads),
                None => Denoiser::load(self.threads),
            };
            self.state = match loaded {
                Ok(d) => State::Loaded(Box::new(d)),
                Err(e) => State::Missing(e.to_string()),
            };
        }
        match &mut self.state {
            State::Loaded(denoiser) => Ok(denoiser),
            State::Missing(why) => Err(why.clone()),
            // Not reached: the load above left the state Loaded or Missing.
            State::NotLoaded => Err("Open Image Denoise was not loaded".to_string()),
            State::Taken => Err("Open Image Denoise was handed over already".to_string()),
        }
    }
}
