//! `gscache view`: the render session in a browser (the viewer crate). A thin front: it loads
//! the scene (or chooses one for a volume file, as `render` does), starts the viewer, prints its
//! URL and serves until Ctrl-C.

use crate::common::{Global, cancellation};
use anyhow::Result;
use std::net::IpAddr;
use std::path::PathBuf;
use std::sync::atomic::Ordering;

#[derive(clap::Args, Debug)]
pub struct ViewArgs {
    /// Scene file (TOML), or a volume file (NIfTI, NRRD, VTK/VTI, raw) to view with a scene
    /// chosen for it.
    pub scene: PathBuf,
    /// Port to listen on (0: any free one).
    #[arg(long, default_value_t = 8765)]
    pub port: u16,
    /// Address to listen on. Anything but a loopback address exposes the viewer to the network
    /// (the token still guards it).
    #[arg(long, default_value = "127.0.0.1")]
    pub bind: IpAddr,
    /// Where Save writes the image, the scene and the cache.
    #[arg(long, default_value = "out/view")]
    pub output: PathBuf,
    /// Pages connected at once.
    #[arg(long, default_value_t = 4, value_parser = clap::value_parser!(u16).range(1..=64))]
    pub max_clients: u16,
    /// The resolution scale: the view renders at the page's view area in device pixels times
    /// this (0.1 to 2; the page can change it). Until a page says its size, the scene's size.
    #[arg(long, default_value_t = viewer::Resolution::default().scale, value_parser = parse_scale)]
    pub scale: f32,
    /// The largest size the view renders at, WIDTHxHEIGHT (a larger view area is rendered at
    /// this size, its aspect kept, and stretched by the page).
    #[arg(long, default_value = "1920x1080", value_parser = parse_size)]
    pub max_size: (u32, u32),
    /// Denoising from the start (Open Image Denoise; the page's toggle changes it): `auto` is
    /// on where the library loads and off without a word where it does not. With it on, every
    /// frame of a drag is denoised, and a still view until `--denoise-until` samples a pixel.
    #[arg(long, value_enum, default_value = "auto")]
    pub denoise: DenoiseStart,
    /// The samples a pixel from which a still view shows its raw image rather than the
    /// denoised one (0: denoised to the last). The denoised image is ahead in FLIP at every
    /// sample count on smooth data (hydrogen, the embryo) but behind from 8 on data with fine
    /// texture (neghip), which it smooths away: 8 suits such data (BENCHMARKS.md, "The viewer
    /// on screen").
    #[arg(long, default_value_t = viewer::Denoising::default().until_spp)]
    pub denoise_until: u32,
    /// What the command line changes of the scene.
    #[command(flatten)]
    pub overrides: volume_pt::SceneOverrides,
}

/// `--denoise`: whether denoising is on from the start.
#[derive(clap::ValueEnum, Clone, Copy, Debug)]
pub enum DenoiseStart {
    Off,
    Auto,
    On,
}

fn parse_scale(text: &str) -> Result<f32, String> {
    let scale: f32 = text
        .parse()
        .map_err(|_| format!("`{text}`: expected a number"))?;
    // Written so that NaN is refused.
    if !viewer::protocol::SCALES.contains(&scale) {
        return Err(format!(
            "{scale}: expected {} to {}",
            viewer::protocol::SCALES.start(),
            viewer::protocol::SCALES.end()
        ));
    }
    Ok(scale)
}

fn parse_size(text: &str) -> Result<(u32, u32), String> {
    let bad = || format!("`{text}`: expected WIDTHxHEIGHT, each 16 to 16384 pixels, as 1920x1080");
    let (w, h) = text.split_once(['x', 'X']).ok_or_else(bad)?;
    let (w, h): (u32, u32) = (
        w.trim().parse().map_err(|_| bad())?,
        h.trim().parse().map_err(|_| bad())?,
    );
    if !(16..=16384).contains(&w) || !(16..=16384).contains(&h) {
        return Err(bad());
    }
    Ok((w, h))
}

pub fn run(args: ViewArgs, global: &Global) -> Result<i32> {
    let opened = volume_pt::open_scene(&args.scene, Default::default())?;
    let (mut scene, text, file) = (opened.scene, opened.text, opened.file);
    args.overrides.apply(&mut scene)?;
    if !args.bind.is_loopback() {
        eprintln!(
            "warning: listening on {}: anyone who can reach this machine and has the URL's token can use the viewer",
            args.bind
        );
    }
    // Loaded when the page first turns denoising on, not now: loading runs the library's code.
    let denoiser = denoise::OnDemand::new(global.threads.map_or(0, usize::from));
    let cancel = cancellation()?;
    let viewer = viewer::serve(
        scene,
        text,
        file,
        viewer::ServeOptions {
            bind: args.bind,
            port: args.port,
            output: args.output,
            max_clients: args.max_clients as usize,
            denoiser,
            limits: viewer::Limits::default(),
            resolution: viewer::Resolution {
                scale: args.scale,
                max_size: args.max_size,
            },
            denoising: viewer::Denoising {
                start: match args.denoise {
                    DenoiseStart::Off => viewer::DenoiseStart::Off,
                    DenoiseStart::Auto => viewer::DenoiseStart::Auto,
                    DenoiseStart::On => viewer::DenoiseStart::On,
                },
                until_spp: args.denoise_until,
            },
        },
    )?;
    println!("{}", viewer.url());
    eprintln!("gscache view: open the URL above; Ctrl-C stops the viewer");
    while !cancel.load(Ordering::SeqCst) {
        std::thread::sleep(std::time::Duration::from_millis(100));
    }
    viewer.stop();
    if !global.quiet {
        eprintln!("gscache view: stopped");
    }
    Ok(0)
}
