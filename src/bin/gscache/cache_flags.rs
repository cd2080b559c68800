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
    /// Whether the command line named any of the denoised cache's settings
    /// (`--cache-min-coverage`, `--cache-max-bias`, `--cache-handoff-frames`): set by
    /// [`CacheFlags::note_named`] from the parsed arguments.
    #[arg(skip)]
    pub termination_named: bool,
}

impl CacheFlags {
    /// Notes whether the command line (`matches`, the subcommand's) named any of error-aware
    /// termination's settings, so that [`CacheFlags::choice`] keeps what the user chose.
    pub fn note_named(&mut self, matches: &clap::ArgMatches) {
        // clap's ids are the settings' field names, as the keys are.
        self.termination_named = CacheConfig::FOR_DENOISER_KEYS.iter().any(|id| {
            matches.try_get_raw(id).is_ok_and(|v| v.is_some())
                && matches.value_source(id) == Some(clap::parser::ValueSource::CommandLine)
        });
    }

    /// The cache these flags ask for; the Gaussian cache starts from `load` when given. An
    /// image that will be `denoised` takes [`CacheConfig::for_denoiser`]'s termination unless
    /// the command line chose it (the plain cache's structured error is what a denoiser keeps).
    pub fn choice(&self, load: Option<PathBuf>, denoised: bool) -> Result<CacheChoice> {
        Ok(if self.nrc {
            self.nrc_settings.validate()?;
            CacheChoice::Neural(self.nrc_settings)
        } else if self.cache {
            let config = if denoised && !self.termination_named {
                let c = self.settings.for_denoiser();
                eprintln!(
                    "note: the image is denoised, so the cache reads a level only where it has \
                     earned trust, and only in an image's first passes (--cache-min-coverage {} \
                     --cache-max-bias {} --cache-handoff-frames {}; \
                     name any of them to choose otherwise)",
                    c.min_coverage, c.max_bias, c.handoff_frames
                );
                c
            } else {
                self.settings
            };
            CacheChoice::Gaussian { config, load }
        } else {
            CacheChoice::None
        })
    }
}
