//! The scene writer (`SceneFile::to_toml`): what it writes reads back to the same tables, for
//! every bundled scene, for a scene that sets every key away from its default, and for the
//! automatic scene. Equal tables build equal scenes (`build_scene` is a function of them and
//! the file's folder), so these are the round trips the viewer's Save, `--save-scene` and
//! `gscache bench large` rely on.

use std::path::{Path, PathBuf};
use volume_pt::auto_scene::{VolumeStats, scene_description};
use volume_pt::scene::SceneFile;
use volume_pt::{Colormap, io::Format};

fn read(path: &Path) -> SceneFile {
    let text = std::fs::read_to_string(path).unwrap();
    toml::from_str(&text).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

fn round_trip(scene: &SceneFile, what: &str) {
    let text = scene.to_toml("a comment\nof two lines").unwrap();
    assert!(text.starts_with("# a comment\n# of two lines\n"), "{text}");
    let back: SceneFile =
        toml::from_str(&text).unwrap_or_else(|e| panic!("{what}: {e}\n--- written:\n{text}"));
    assert_eq!(&back, scene, "{what}: written as\n{text}");
}

#[test]
fn every_bundled_scene_reads_back_as_written() {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../data/scenes");
    let mut scenes = 0;
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "toml") {
            round_trip(&read(&path), &path.display().to_string());
            scenes += 1;
        }
    }
    assert!(scenes >= 7, "{scenes} scenes in {}", dir.display());
}

/// Every key of the format set away from its default, so a key the writer skips or misspells
/// (and the reader then takes as its default) is seen.
const EVERY_KEY: &str = r#"
[volume]
file = "volumes/v.raw"
format = "raw"
dims = [3, 4, 5]
dtype = "u16"
byte_order = "big"
header_bytes = 12
spacing = [0.5, 0.25, 2.0]
units = "µm"
origin = [-1.0, 2.0, 3.5]
filter = "nearest"
macrocell = 4

[transfer]
window = [-3.5, 1200.0]
density_scale = 0.125
preset = "presets/cool.json"
preset_name = "Cool to Warm"
opacity = [[0.0, 0.0], [0.3, 0.7], [1.0, 1.0]]

[[light]]
type = "distant"
direction = [0.0, -1.0, 0.25]
irradiance = [1.5, 2.0, 2.5]

[[light]]
center = [1.0, 2.0, 3.0]
radius = 0.75
radiance = [10.0, 20.0, 30.0]

[environment]
radiance = [0.1, 0.2, 0.3]

[phase]
kind = "henyeygreenstein"
g = -0.4

[camera]
eye = [1.0, 2.0, 3.0]
target = [0.5, 0.0, -1.0]
up = [0.0, 0.0, 1.0]
fov_y = 27.5
width = 33
height = 17

[render]
spp = 7
max_depth = -1
integrator = "uniform"
seed = 99
rr_start_depth = 9
show_lights = false

[output]
exposure = -1.5
tonemap = "aces"

[clip]
box = { min = [-1.0, -2.0, -3.0], max = [1.5, 2.5, 3.5] }

[[clip.plane]]
point = [0.0, 0.5, 0.0]
normal = [1.0, -1.0, 0.25]

[[clip.plane]]
point = [0.25, 0.0, 0.0]
normal = [0.0, 0.0, -1.0]

[[view]]
name = "front"
eye = [0.0, -5.0, 0.0]
target = [0.0, 0.0, 0.0]
up = [0.0, 0.0, 1.0]

[[view]]
name = "a view \"quoted\""
eye = [3.0, 1.0, 2.0]
target = [0.5, 0.5, 0.5]
up = [0.0, 1.0, 0.0]
"#;

#[test]
fn a_scene_with_every_key_set_reads_back_as_written() {
    let scene: SceneFile = toml::from_str(EVERY_KEY).unwrap();
    round_trip(&scene, "every key");
    // And with points rather than a preset, an isotropic phase and a light of each kind.
    let mut points: SceneFile = toml::from_str(EVERY_KEY).unwrap();
    points.transfer.preset = None;
    points.transfer.preset_name = None;
    points.transfer.opacity = None;
    points.transfer.points = Some(vec![
        volume_pt::scene::TfPoint {
            value: 0.0,
            color: [0.1, 0.2, 0.3],
            opacity: 0.0,
        },
        volume_pt::scene::TfPoint {
            value: 0.7,
            color: [0.9, 0.8, 0.7],
            opacity: 1.0 / 3.0,
        },
    ]);
    points.phase = volume_pt::Phase::Isotropic;
    round_trip(&points, "points");
}

#[test]
fn the_automatic_scene_reads_back_as_written() {
    for format in [None, Some(Format::Nifti)] {
        let (scene, comment) = scene_description(
            Path::new("some folder/\"quoted\" volume.nrrd"),
            format,
            glam::Vec3::new(64.0, 80.5, 31.0),
            VolumeStats {
                window: (-1024.0, 3071.0),
                threshold: 0.3173,
            },
            Colormap::Viridis,
        );
        let text = scene.to_toml(&comment).unwrap();
        let back: SceneFile = toml::from_str(&text).unwrap();
        assert_eq!(back, scene, "{text}");
        // Every line of the comment is a comment.
        assert_eq!(text.lines().take_while(|l| l.starts_with('#')).count(), 3);
    }
}
