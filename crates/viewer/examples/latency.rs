//! The viewer's responsiveness, measured from a client over a real socket (BENCHMARKS.md):
//! - edit to first updated frame: a transfer-function edit on a still 640x360 view, until the
//!   first frame rendered after it arrives (the median of 20);
//! - frames a second while dragging a 1280x720 view: camera messages at 60 a second for 3 s.
//!
//! `cargo run --release -p viewer --example latency`

use futures_util::{SinkExt, StreamExt};
use std::path::PathBuf;
use std::time::{Duration, Instant};
use tokio_tungstenite::tungstenite::Message;

fn start(width: u32, height: u32) -> viewer::Viewer {
    let file = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../data/scenes/default.toml");
    let text = std::fs::read_to_string(&file).unwrap();
    let mut scene = volume_pt::load_scene(&file).unwrap();
    scene.camera = scene.camera.with_size(width, height).unwrap();
    viewer::serve(
        scene,
        text,
        file,
        viewer::ServeOptions {
            port: 0,
            output: std::env::temp_dir().join("gscache-view-latency"),
            ..Default::default()
        },
    )
    .unwrap()
}

async fn connect(
    v: &viewer::Viewer,
) -> tokio_tungstenite::WebSocketStream<tokio_tungstenite::MaybeTlsStream<tokio::net::TcpStream>> {
    let token = v.url().split("token=").nth(1).unwrap();
    let url = format!("ws://127.0.0.1:{}/ws?token={token}", v.address().port());
    tokio_tungstenite::connect_async(url).await.unwrap().0
}

fn stats(m: &Message) -> Option<serde_json::Value> {
    match m {
        Message::Text(t) => {
            let v: serde_json::Value = serde_json::from_str(t.as_str()).ok()?;
            (v["type"] == "stats").then_some(v)
        }
        _ => None,
    }
}

#[tokio::main(flavor = "current_thread")]
async fn main() {
    let v = start(640, 360);
    let mut s = connect(&v).await;
    let mut latencies = Vec::new();
    for k in 0..21 {
        // Let the view settle a little, then edit.
        tokio::time::sleep(Duration::from_millis(300)).await;
        while let Ok(Some(_)) = tokio::time::timeout(Duration::from_millis(1), s.next()).await {}
        let scale = if k % 2 == 0 { 1.2 } else { 0.6 };
        let edit = format!(
            r#"{{"type":"transfer","colormap":"scene","window":[0,255],"density_scale":{scale},"opacity":[[0,0],[0.25,0.35],[1,1]]}}"#
        );
        let sent = Instant::now();
        s.send(Message::Text(edit.into())).await.unwrap();
        loop {
            let m = s.next().await.unwrap().unwrap();
            if let Some(st) = stats(&m)
                && st["spp"] == 1
            {
                break;
            }
        }
        if k > 0 {
            latencies.push(sent.elapsed().as_secs_f64() * 1e3);
        }
    }
    latencies.sort_by(f64::total_cmp);
    println!(
        "edit to first updated frame, 640x360, NEE: median {:.1} ms (min {:.1}, max {:.1}, {} edits)",
        latencies[latencies.len() / 2],
        latencies[0],
        latencies[latencies.len() - 1],
        latencies.len()
    );
    drop(s);
    v.stop();

    let v = start(1280, 720);
    let mut s = connect(&v).await;
    let (eye, start) = ([60.0f32, 45.0, 95.0], Instant::now());
    let mut frames = 0u32;
    let mut sizes = Vec::new();
    let mut tick = tokio::time::interval(Duration::from_millis(16));
    while start.elapsed() < Duration::from_secs(3) {
        tokio::select! {
            _ = tick.tick() => {
                let a = start.elapsed().as_secs_f32();
                let m = format!(
                    r#"{{"type":"camera","eye":[{},{},{}],"target":[0,0,0],"up":[0,1,0],"moving":true}}"#,
                    eye[0] * a.cos() - eye[2] * a.sin(), eye[1], eye[0] * a.sin() + eye[2] * a.cos()
                );
                s.send(Message::Text(m.into())).await.unwrap();
            }
            m = s.next() => {
                if let Some(st) = stats(&m.unwrap().unwrap()) {
                    frames += 1;
                    sizes.push(format!("{}x{}", st["width"], st["height"]));
                }
            }
        }
    }
    sizes.dedup();
    println!(
        "dragging a 1280x720 view, NEE: {:.1} frames/s over 3 s (shown at {})",
        frames as f64 / 3.0,
        sizes.join(", ")
    );
    v.stop();
}
