//! A render session with the Gaussian radiance cache, as a renderer that links the crates
//! would drive it: load a scene, choose the cache, warm it up along an orbit (training only),
//! then render frames that read and train it, and write the image.
//!
//! ```sh
//! cargo run --release -p render-session --example cached_session -- data/scenes/default.toml out/cached.png
//! ```

use render_session::{CacheChoice, Control, Session};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let scene_file = args
        .next()
        .unwrap_or_else(|| "data/scenes/default.toml".into());
    let png = args.next().unwrap_or_else(|| "out/cached.png".into());

    let mut scene = volume_pt::load_scene(std::path::Path::new(&scene_file))?;
    // A small view and one sample per pixel a frame: an interactive budget.
    scene.camera = scene.camera.with_size(320, 180)?;
    scene.settings.spp = 1;
    let (exposure, tonemap) = (scene.output.exposure, scene.output.tonemap);

    // The cache's defaults are the GSCache paper's (gs-cache's CacheConfig documents each).
    let choice = CacheChoice::gaussian(gs_cache::CacheConfig::default());
    let mut session = Session::new(scene, choice)?;
    let control = Control::none();

    // Warm-up frames train the cache without entering the image; the camera orbits 30 degrees
    // about the volume's centre and arrives at the scene's camera.
    let warm = session.warm_up(16, 30.0, &control)?;
    println!("warm-up: {} frames", warm.len());

    // Each frame traces paths that stop into the cache where it is trusted, then trains it.
    for _ in 0..8 {
        let r = session.next_frame(&control)?;
        println!(
            "frame {}: trace {:.1} ms, lookup {:.1} ms, training {:.1} ms",
            r.frame,
            r.trace_seconds * 1e3,
            r.lookup_seconds * 1e3,
            r.train_seconds * 1e3
        );
    }

    if let Some(folder) = std::path::Path::new(&png).parent() {
        std::fs::create_dir_all(folder)?;
    }
    session
        .image()
        .write_png(std::path::Path::new(&png), exposure, tonemap)?;
    println!(
        "wrote {png} ({} frames in the image)",
        session.frames_in_image()
    );
    Ok(())
}
