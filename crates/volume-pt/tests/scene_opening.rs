//! Opening a scene the way the program does (a scene file or a bare volume) and the one set of
//! overrides that `gscache render`, `gscache view` and the Python package apply.

use std::path::PathBuf;
use volume_pt::{Colormap, IntegratorKind, SceneOverrides, open_scene};

fn data(path: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../data")
        .join(path)
}

#[test]
fn a_scene_file_opens_as_written_and_a_volume_with_the_automatic_scene() {
    let file = data("scenes/default.toml");
    let opened = open_scene(&file, Colormap::default()).unwrap();
    assert!(!opened.automatic);
    assert_eq!(opened.file, file);
    assert_eq!(opened.text, std::fs::read_to_string(&file).unwrap());
    assert_eq!(opened.scene.settings.spp, 64);

    let volume = data("volumes/neghip_64x64x64_uint8.raw");
    let opened = open_scene(&volume, Colormap::default()).unwrap();
    assert!(opened.automatic);
    assert_eq!(opened.file, volume.with_extension("auto.toml"));
    assert!(
        opened.text.contains("[[transfer.points]]"),
        "{}",
        opened.text
    );
}

#[test]
fn overrides_change_only_what_they_name() {
    let mut scene = open_scene(&data("scenes/default.toml"), Colormap::default())
        .unwrap()
        .scene;
    let before = scene.clone();
    SceneOverrides::default().apply(&mut scene).unwrap();
    assert_eq!(scene.settings, before.settings);
    assert_eq!(scene.camera, before.camera);

    SceneOverrides {
        spp: Some(3),
        integrator: Some(IntegratorKind::Uniform),
        max_depth: Some(-1),
        seed: Some(77),
        width: Some(40),
        height: None,
        macrocell: Some(4),
        clip_box: Some(volume_pt::ClipBox {
            min: [-10.0, -20.0, -30.0],
            max: [10.0, 20.0, 30.0],
        }),
        clip_plane: vec![],
        view: None,
    }
    .apply(&mut scene)
    .unwrap();
    let clip = scene.media.medium.clipping();
    assert_eq!(clip.bounds.unwrap().max, [10.0, 20.0, 30.0]);
    assert!(clip.planes.is_empty(), "no plane given, none made");
    assert_eq!(scene.settings.spp, 3);
    assert_eq!(scene.settings.path.integrator, IntegratorKind::Uniform);
    assert_eq!(scene.settings.path.max_depth, None);
    assert_eq!(scene.settings.seed, 77);
    assert_eq!((scene.camera.width, scene.camera.height), (40, 512));
    assert_eq!(scene.camera.position, before.camera.position);
    assert_eq!(scene.media.medium.majorants().cell_size(), 4.0);
    assert_eq!(
        scene.settings.path.rr_start_depth,
        before.settings.path.rr_start_depth
    );
}

#[test]
fn a_bad_override_is_refused_by_name() {
    let scene = open_scene(&data("scenes/default.toml"), Colormap::default())
        .unwrap()
        .scene;
    let refused = |o: SceneOverrides, what: &str| {
        let mut s = scene.clone();
        let e = o.apply(&mut s).unwrap_err().to_string();
        assert!(e.contains(what), "{e}");
        // Nothing was changed by the refused overrides' settings.
        assert_eq!(s.settings, scene.settings);
    };
    refused(
        SceneOverrides {
            spp: Some(0),
            ..Default::default()
        },
        "spp = 0",
    );
    refused(
        SceneOverrides {
            max_depth: Some(-2),
            ..Default::default()
        },
        "max_depth -2",
    );
    refused(
        SceneOverrides {
            clip_plane: vec![volume_pt::ClipPlane {
                point: [0.0; 3],
                normal: [0.0; 3],
            }],
            ..Default::default()
        },
        "clip plane 0",
    );
    assert!(
        volume_pt::scene::parse_clip_box("1,2,3")
            .unwrap_err()
            .contains("expected 6 comma-separated numbers")
    );
    assert!(
        volume_pt::scene::parse_clip_plane("0,0,0,1,x,0")
            .unwrap_err()
            .contains("clip plane `0,0,0,1,x,0`")
    );
    refused(
        SceneOverrides {
            view: Some("top".into()),
            ..Default::default()
        },
        "--view \"top\": the scene has no [[view]] tables",
    );
    let mut s = scene.clone();
    let e = SceneOverrides {
        width: Some(0),
        ..Default::default()
    }
    .apply(&mut s)
    .unwrap_err()
    .to_string();
    assert!(e.starts_with("width/height:"), "{e}");
}

/// A scene's `[[view]]` tables are checked by name: a second view of one name, an empty name,
/// and a view whose camera cannot be built (its up along its line of sight) are refused.
#[test]
fn bad_views_are_refused_by_name() {
    use volume_pt::scene::ViewDesc;
    let scene = open_scene(&data("scenes/default.toml"), Colormap::default())
        .unwrap()
        .scene;
    let view = |name: &str, up: [f32; 3]| ViewDesc {
        name: name.into(),
        eye: [0.0, 0.0, 10.0],
        target: [0.0; 3],
        up,
    };
    let check = |views: &[ViewDesc]| ViewDesc::validate_all(views, &scene.camera);
    assert!(check(&[view("a", [0.0, 1.0, 0.0]), view("b", [1.0, 0.0, 0.0])]).is_ok());
    let twice = check(&[view("a", [0.0, 1.0, 0.0]), view("a", [1.0, 0.0, 0.0])]).unwrap_err();
    assert!(twice.contains("a second view named \"a\""), "{twice}");
    assert!(
        check(&[view("", [0.0, 1.0, 0.0])])
            .unwrap_err()
            .contains("view 0: name")
    );
    let along = check(&[view("top", [0.0, 0.0, 1.0])]).unwrap_err();
    assert!(along.starts_with("view \"top\":"), "{along}");
}
