//! A method as the runner measures it: an integrator and the one cache it reads.
//!
//! The experiment file spells a method's cache as a pair of optional tables, `cache` (the
//! Gaussian cache) and `nrc` (the neural radiance cache); [`MethodSpec::new`] is the one place
//! that pair becomes a [`MethodCache`], and every later question (which flags render it, how
//! long it warms up, which session cache it builds) is a method of that enum. Both tables are
//! one generic [`Warmed`] settings type: the library's settings key for key plus the warm-up
//! keys, read and written by one piece of serde glue.

use crate::error::{Error, Result, Within, refuse};
use gs_cache::CacheConfig;
use nrc_cache::NrcConfig;
use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};
use volume_pt::IntegratorKind;

/// A cache's library settings as an experiment file holds them: checked, and spelt as the
/// program's flags.
pub trait CacheSettings: Copy + Default + PartialEq + Serialize + DeserializeOwned {
    /// The experiment file's table and the program's flag (`cache`: `--cache`, `--cache-KEY`).
    const KEY: &'static str;
    /// What a report calls it.
    const LABEL: &'static str;
    /// The library's own check of the settings.
    fn check(&self) -> std::result::Result<(), String>;

    /// `--KEY-NAME VALUE` for every setting that differs from its default (`lr_color` is
    /// `--cache-lr-color`): the experiment file's keys as the program's flags.
    fn changed_flags(&self) -> Vec<String> {
        crate::command::flag_args(Self::KEY, self, &Self::default())
    }
}

impl CacheSettings for CacheConfig {
    const KEY: &'static str = "cache";
    const LABEL: &'static str = "cache";
    fn check(&self) -> std::result::Result<(), String> {
        self.validate().map_err(|e| e.to_string())
    }
}

impl CacheSettings for NrcConfig {
    const KEY: &'static str = "nrc";
    const LABEL: &'static str = "neural cache";
    fn check(&self) -> std::result::Result<(), String> {
        self.validate().map_err(|e| e.to_string())
    }
}

/// A cache's settings in the experiment file: the library's settings, key for key (the same
/// keys as `gscache render --cache-KEY` or `--nrc-KEY`), plus how the cache is warmed up before
/// it is measured.
#[derive(Debug, Clone, Deserialize, Serialize, PartialEq)]
#[serde(
    try_from = "toml::Table",
    into = "toml::Table",
    bound(serialize = "S: CacheSettings", deserialize = "S: CacheSettings")
)]
pub struct Warmed<S> {
    pub settings: S,
    /// Frames (1 spp each) trained along an orbit ending at the camera before measuring: the
    /// cache a user has after moving to this view. Not counted in the image's time.
    pub warmup: u32,
    /// Degrees of that orbit.
    pub warmup_orbit_degrees: f32,
}

/// The Gaussian cache's table (`cache`).
pub type CacheDesc = Warmed<CacheConfig>;
/// The neural radiance cache's table (`nrc`).
pub type NrcDesc = Warmed<NrcConfig>;

/// Warm-up frames when the table does not say.
const DEFAULT_WARMUP: u32 = 40;
/// Degrees of the warm-up's orbit when the table does not say.
const DEFAULT_WARMUP_ORBIT_DEGREES: f32 = 60.0;

impl<S: CacheSettings> Default for Warmed<S> {
    fn default() -> Self {
        Self {
            settings: S::default(),
            warmup: DEFAULT_WARMUP,
            warmup_orbit_degrees: DEFAULT_WARMUP_ORBIT_DEGREES,
        }
    }
}

impl<S: CacheSettings> Warmed<S> {
    /// The library settings, checked.
    pub fn config(&self) -> Result<S> {
        self.settings.check().map_err(Error::Invalid)?;
        Ok(self.settings)
    }

    /// `--KEY --frames N`, the flags of every setting that differs from its default, and the
    /// warm-up's flags: what `gscache render` needs to render `frames` frames of this cache.
    pub fn render_flags(&self, frames: u32) -> Vec<String> {
        let mut args = vec![
            format!("--{}", S::KEY),
            "--frames".into(),
            frames.to_string(),
        ];
        args.extend(self.settings.changed_flags());
        args.extend([
            "--warmup".into(),
            self.warmup.to_string(),
            "--warmup-orbit-degrees".into(),
            self.warmup_orbit_degrees.to_string(),
        ]);
        args
    }
}

impl<S: CacheSettings> TryFrom<toml::Table> for Warmed<S> {
    type Error = String;
    /// Takes the warm-up keys out and reads every other key as a library setting (unknown keys
    /// are refused by the settings' own deserialiser).
    fn try_from(mut table: toml::Table) -> std::result::Result<Self, String> {
        let warmup = match table.remove("warmup") {
            None => DEFAULT_WARMUP,
            Some(v) => v
                .as_integer()
                .and_then(|n| u32::try_from(n).ok())
                .ok_or_else(|| format!("warmup = {v}: expected a frame count >= 0"))?,
        };
        let warmup_orbit_degrees = match table.remove("warmup_orbit_degrees") {
            None => DEFAULT_WARMUP_ORBIT_DEGREES,
            Some(v) => match v.as_float().or_else(|| v.as_integer().map(|n| n as f64)) {
                Some(x) if x.is_finite() => x as f32,
                _ => {
                    return Err(format!(
                        "warmup_orbit_degrees = {v}: expected a finite angle"
                    ));
                }
            },
        };
        let settings = S::deserialize(toml::Value::Table(table)).map_err(|e| e.to_string())?;
        Ok(Self {
            settings,
            warmup,
            warmup_orbit_degrees,
        })
    }
}

impl<S: CacheSettings> From<Warmed<S>> for toml::Table {
    fn from(d: Warmed<S>) -> toml::Table {
        let mut t =
            toml::Table::try_from(d.settings).expect("cache settings are plain TOML values");
        t.insert("warmup".into(), toml::Value::Integer(d.warmup.into()));
        t.insert(
            "warmup_orbit_degrees".into(),
            toml::Value::Float(d.warmup_orbit_degrees.into()),
        );
        t
    }
}

/// The cache a method reads: none, the Gaussian cache, or the neural radiance cache, each
/// with its warm-up.
#[derive(Debug, Clone, Default, PartialEq)]
pub enum MethodCache {
    #[default]
    None,
    Gaussian(CacheDesc),
    Neural(NrcDesc),
}

impl MethodCache {
    /// The file's `cache` / `nrc` pair as one choice; both at once are refused.
    pub fn from_tables(cache: Option<CacheDesc>, nrc: Option<NrcDesc>) -> Result<Self> {
        Ok(match (cache, nrc) {
            (Some(_), Some(_)) => refuse!("both `cache` and `nrc`: a method reads one cache"),
            (Some(c), None) => MethodCache::Gaussian(c),
            (None, Some(n)) => MethodCache::Neural(n),
            (None, None) => MethodCache::None,
        })
    }

    /// Whether the method reads a cache of either kind.
    pub fn is_some(&self) -> bool {
        !matches!(self, MethodCache::None)
    }

    /// The Gaussian cache's table, if that is the cache.
    pub fn gaussian(&self) -> Option<&CacheDesc> {
        match self {
            MethodCache::Gaussian(c) => Some(c),
            _ => None,
        }
    }

    /// Warm-up frames before the method is measured (0 without a cache).
    pub fn warmup(&self) -> u32 {
        match self {
            MethodCache::None => 0,
            MethodCache::Gaussian(c) => c.warmup,
            MethodCache::Neural(n) => n.warmup,
        }
    }

    /// Degrees of orbit over the warm-up (0 without a cache).
    pub fn warmup_orbit_degrees(&self) -> f32 {
        match self {
            MethodCache::None => 0.0,
            MethodCache::Gaussian(c) => c.warmup_orbit_degrees,
            MethodCache::Neural(n) => n.warmup_orbit_degrees,
        }
    }

    /// The settings checked; `Err` names the table.
    fn check(&self) -> Result<()> {
        match self {
            MethodCache::None => Ok(()),
            MethodCache::Gaussian(c) => c.config().within(|| "cache".into()).map(drop),
            MethodCache::Neural(n) => n.config().within(|| "nrc".into()).map(drop),
        }
    }

    /// The flags that make `gscache render` render `frames` frames of this cache (none
    /// without one).
    pub fn render_flags(&self, frames: u32) -> Vec<String> {
        match self {
            MethodCache::None => Vec::new(),
            MethodCache::Gaussian(c) => c.render_flags(frames),
            MethodCache::Neural(n) => n.render_flags(frames),
        }
    }

    /// `: cache `key = value, ...`` for a report's method list (empty without a cache).
    pub fn report_text(&self) -> String {
        fn text<S: CacheSettings>(d: &Warmed<S>) -> String {
            format!(": {} `{}`", S::LABEL, crate::command::settings_text(d))
        }
        match self {
            MethodCache::None => String::new(),
            MethodCache::Gaussian(c) => text(c),
            MethodCache::Neural(n) => text(n),
        }
    }

    /// The cache a render session builds, its settings checked.
    pub fn session_choice(&self) -> Result<render_session::CacheChoice> {
        use render_session::CacheChoice;
        Ok(match self {
            MethodCache::None => CacheChoice::None,
            MethodCache::Gaussian(c) => CacheChoice::gaussian(c.config()?),
            MethodCache::Neural(n) => CacheChoice::Neural(n.config()?),
        })
    }
}

/// A method ready to run.
#[derive(Debug, Clone)]
pub struct MethodSpec {
    pub name: String,
    pub integrator: IntegratorKind,
    pub cache: MethodCache,
    /// For a denoised twin: the guides its denoiser took (its image is the method's, denoised).
    pub denoised: Option<denoise::Guides>,
}

impl MethodSpec {
    /// A method, checked: a cache's settings are valid, and a cache reads NEE paths.
    pub fn new(name: String, integrator: IntegratorKind, cache: MethodCache) -> Result<Self> {
        let within = || format!("method `{name}`");
        if cache.is_some() && integrator != IntegratorKind::Nee {
            let why = match cache {
                MethodCache::Neural(_) => {
                    "the neural cache needs `integrator = \"nee\"` (its training paths are NEE paths)"
                }
                _ => "a cache needs `integrator = \"nee\"` (the GSCache paper caches NEE paths)",
            };
            return Err(Error::Invalid(why.into())).within(within);
        }
        cache.check().within(within)?;
        Ok(MethodSpec {
            name,
            integrator,
            cache,
            denoised: None,
        })
    }

    /// This method's twin measured after the denoiser with `guides`.
    pub fn denoised_twin(&self, guides: denoise::Guides) -> MethodSpec {
        let suffix = match guides {
            denoise::Guides::None => String::new(),
            g => format!(" ({g})"),
        };
        MethodSpec {
            name: format!("{} + OIDN{suffix}", self.name),
            denoised: Some(guides),
            ..self.clone()
        }
    }

    /// Whether the method reads a cache of either kind.
    pub fn has_cache(&self) -> bool {
        self.cache.is_some()
    }

    /// The cache a render session builds for this method, its settings checked.
    pub fn cache_choice(&self) -> Result<render_session::CacheChoice> {
        self.cache.session_choice()
    }
}

/// Written as the experiment file spells a method (`cache` and `nrc` tables, either `null`),
/// plus the twin's guides: the results file's form, and the bytes the units' identities hash.
impl Serialize for MethodSpec {
    fn serialize<Z: serde::Serializer>(&self, to: Z) -> std::result::Result<Z::Ok, Z::Error> {
        #[derive(Serialize)]
        struct Written<'a> {
            name: &'a str,
            integrator: IntegratorKind,
            cache: Option<&'a CacheDesc>,
            nrc: Option<&'a NrcDesc>,
            #[serde(skip_serializing_if = "Option::is_none")]
            denoised: Option<denoise::Guides>,
        }
        let (cache, nrc) = match &self.cache {
            MethodCache::None => (None, None),
            MethodCache::Gaussian(c) => (Some(c), None),
            MethodCache::Neural(n) => (None, Some(n)),
        };
        Written {
            name: &self.name,
            integrator: self.integrator,
            cache,
            nrc,
            denoised: self.denoised,
        }
        .serialize(to)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_method_is_written_as_the_file_spells_it() {
        let m = MethodSpec::new(
            "n".into(),
            IntegratorKind::Nee,
            MethodCache::Neural(NrcDesc::default()),
        )
        .unwrap();
        let json = serde_json::to_value(&m).unwrap();
        assert!(json["cache"].is_null(), "{json}");
        assert_eq!(json["nrc"]["warmup"], 40, "{json}");
        assert!(json.get("denoised").is_none(), "{json}");
        let plain = MethodSpec::new("p".into(), IntegratorKind::Nee, MethodCache::None).unwrap();
        let text = serde_json::to_string(&plain).unwrap();
        assert_eq!(
            text,
            r#"{"name":"p","integrator":"nee","cache":null,"nrc":null}"#
        );
    }

    #[test]
    fn both_tables_are_refused_and_a_cache_needs_nee() {
        let e = MethodCache::from_tables(Some(CacheDesc::default()), Some(NrcDesc::default()))
            .unwrap_err()
            .to_string();
        assert!(e.contains("both `cache` and `nrc`"), "{e}");
        let e = MethodSpec::new(
            "m".into(),
            IntegratorKind::Uniform,
            MethodCache::Gaussian(CacheDesc::default()),
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("method `m`") && e.contains("integrator"), "{e}");
    }

    #[test]
    fn warm_up_keys_read_back_as_written() {
        let d = NrcDesc {
            warmup: 7,
            warmup_orbit_degrees: 12.5,
            ..Default::default()
        };
        let t = toml::Table::from(d.clone());
        assert_eq!(NrcDesc::try_from(t).unwrap(), d);
    }
}
