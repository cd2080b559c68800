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
    /// What the command line changes of the scene.
    #[command(flatten)]
    pub overrides: volume_pt::SceneOverrides,
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
