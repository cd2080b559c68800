//! Which radiance cache a render reads (`--cache`, `--nrc` and their `--cache-KEY` /
//! `--nrc-KEY` settings): shared by `render` and `movie`, so the flags mean one thing.

use anyhow::Result;
use gs_cache::CacheConfig;
use nrc_cache::NrcConfig;
use render_session::CacheChoice;
use std::path::PathBuf;

/// The GSCache radiance cache (Bauer et al., 2025): read where paths stop, trained between
/// frames. Its settings are `--cache-KEY`, the keys of an experiment file's `cache` table.
#[derive(clap::Args, Debug)]
pub struct CacheFlags {
    /// Read and train the radiance cache.
    #[arg(long, conflicts_with = "nrc")]
    pub cache: bool,
    /// Read and train the neural radiance cache (Müller et al., 2021: a hash grid and an MLP)
    /// instead: the baseline the GSCache paper compares with.
    #[arg(long)]
    pub nrc: bool,
    /// The Gaussian cache's settings: `--cache-KEY VALUE`, the keys of an experiment file's
    /// `cache` table.
    #[command(flatten)]
    pub settings: CacheConfig,
    /// The neural cache's settings: `--nrc-KEY VALUE`, the keys of an experiment file's `nrc`
    /// table.
    #[command(flatten)]
    pub nrc_settings: NrcConfig,
}

impl CacheFlags {
    /// The cache these flags ask for; the Gaussian cache starts from `load` when given.
    pub fn choice(&self, load: Option<PathBuf>) -> Result<CacheChoice> {
        Ok(if self.nrc {
            self.nrc_settings.validate()?;
            CacheChoice::Neural(self.nrc_settings)
        } else if self.cache {
            CacheChoice::Gaussian {
                config: self.settings,
                load,
            }
        } else {
            CacheChoice::None
        })
    }
}
