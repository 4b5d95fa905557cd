//! Sensing pipeline benchmark: per-stage time per frame and sustained 60 fps
//! CPU use, on one thread, with the real ONNX Runtime.
//!
//! ```text
//! taskset -c 1 cargo bench -p telextiles-sensing --bench pipeline
//! TELEXTILES_BENCH_MODEL=models/encoder.onnx taskset -c 1 cargo bench -p telextiles-sensing --bench pipeline
//! ```
//! Prints a markdown table (copied into docs/benchmarks.md).

use std::path::PathBuf;
use std::time::{Duration, Instant};

use rand::{Rng, SeedableRng};
use telextiles_recording::resample::FrameMap;
use telextiles_sensing::contact::ContactConfig;
use telextiles_sensing::decide::FlatIndex;
use telextiles_sensing::encoder::{Encoder, EncoderOptions};
use telextiles_sensing::frame::Frame;
use telextiles_sensing::pipeline::{Pipeline, PipelineConfig, StageStats, StageTimes};
use telextiles_sensing::source::yuv::{decode_buffer, encode_yuyv, PixelFormat};
use telextiles_sim::{PressSpec, Simulator};

/// Process CPU time (user + system) from /proc/self/stat, in seconds.
fn cpu_seconds() -> f64 {
    let s = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    let after = s.rsplit_once(')').map(|x| x.1).unwrap_or("");
    let f: Vec<&str> = after.split_whitespace().collect();
    // Fields 14 and 15 of the full line are 12 and 13 after the command name.
    let ticks: f64 = f.get(11).and_then(|v| v.parse::<f64>().ok()).unwrap_or(0.0)
        + f.get(12).and_then(|v| v.parse::<f64>().ok()).unwrap_or(0.0);
    ticks / 100.0
}

/// Back from the 240x320 portrait frame to the 320x240 sensor image.
fn to_sensor(frame: &image::RgbImage) -> Vec<u8> {
    let mut out = vec![0u8; 320 * 240 * 3];
    for y in 0..240usize {
        for x in 0..320usize {
            // out(x', y') = in(319 - y', x')  =>  in(X, Y) = out(Y, 319 - X)
            let p = frame.get_pixel(y as u32, (319 - x) as u32).0;
            out[(y * 320 + x) * 3..][..3].copy_from_slice(&p);
        }
    }
    out
}

/// One captured YUYV 320x240 buffer decoded into the frame, as the DIGIT
/// source does.
fn decode_into(frame: &mut Frame, buf: &[u8], map: &mut FrameMap, scratch: &mut Vec<u8>) {
    frame
        .write(|img| decode_buffer(buf, PixelFormat::Yuyv, map, scratch, img))
        .unwrap();
}

fn main() {
    let model = std::env::var_os("TELEXTILES_BENCH_MODEL")
        .map(PathBuf::from)
        .unwrap_or_else(|| {
            PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/fixture_encoder.onnx")
        });
    let frames_n: usize = std::env::var("TELEXTILES_BENCH_FRAMES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(3000);
    let sustain_s: u64 = std::env::var("TELEXTILES_BENCH_SECONDS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(10);
    // The contact detector's tile (`ContactConfig::tile`; 0: the whole
    // frame, as shipped).
    let tile: u32 = std::env::var("TELEXTILES_BENCH_CONTACT_TILE")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(0);

    let sim = Simulator::new().expect("simulator");
    let press = sim.render_press(&PressSpec::new("T030", 1)).expect("press");
    // The hold: from the end of the ramp to the release, if the press
    // releases (the frames after it show no contact).
    let params = press.meta.params.as_ref().unwrap();
    let hold = params.hold_frame as usize;
    let end = params
        .release_frame
        .map_or(press.frames.len(), |r| r as usize);
    let frames: Vec<image::RgbImage> = press.frames[hold..end].to_vec();
    let yuyv: Vec<Vec<u8>> = frames
        .iter()
        .map(|f| encode_yuyv(&to_sensor(f), 320, 240))
        .collect();

    let enc = Encoder::open(
        &model,
        &EncoderOptions {
            threads: 1,
            ..Default::default()
        },
    )
    .expect("model");
    let info = enc.info().clone();
    // An index the size of the catalogue (119 textiles); its vectors do not
    // matter for timing.
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
    let textiles: Vec<(String, Vec<Vec<f32>>)> = (0..119)
        .map(|i| {
            (
                format!("T{:03}", i + 1),
                vec![(0..info.dim).map(|_| rng.gen_range(-1.0f32..1.0)).collect()],
            )
        })
        .collect();
    let index = FlatIndex::from_embeddings(&textiles).unwrap();
    let mut pipeline = Pipeline::new(
        enc,
        index,
        PipelineConfig {
            // One endless press of the hold's frames over and over: its
            // score is flat, and after 30 s the detector would rightly take
            // the reference for stale and end it. The benchmark times
            // frames in contact, so that rule is off here.
            contact: ContactConfig {
                stale_after_ms: 0.0,
                tile,
                ..Default::default()
            },
            ..Default::default()
        },
        Some(&telextiles_sensing::front::pixels_of(&sim.background(0))),
    )
    .unwrap();

    let mut frame = Frame::blank();
    let mut scratch = Vec::new();
    let mut map = FrameMap::digit(320, 240).expect("the DIGIT's QVGA");
    let mut stats = StageStats::with_capacity(frames_n);
    // Warm-up.
    for i in 0..60 {
        decode_into(&mut frame, &yuyv[i % yuyv.len()], &mut map, &mut scratch);
        frame.set_time(i as u64 * 16_667, 0);
        pipeline
            .process(&frame, &mut StageTimes::default())
            .unwrap();
    }
    let mut encoded = 0;
    let t_all = Instant::now();
    let cpu0 = cpu_seconds();
    for i in 0..frames_n {
        let t0 = Instant::now();
        decode_into(&mut frame, &yuyv[i % yuyv.len()], &mut map, &mut scratch);
        let mut times = StageTimes {
            decode_ns: t0.elapsed().as_nanos() as u64,
            ..Default::default()
        };
        frame.set_time((60 + i) as u64 * 16_667, 0);
        let out = pipeline.process(&frame, &mut times).unwrap();
        if out.step.is_some() {
            encoded += 1;
        }
        stats.record(&times);
    }
    let wall = t_all.elapsed().as_secs_f64();
    let cpu_fast = cpu_seconds() - cpu0;
    assert_eq!(
        encoded, frames_n,
        "every benchmark frame is in contact and encoded"
    );
    let (per, total) = stats.summary();

    // Sustained: frames delivered at 60 fps for `sustain_s` seconds.
    let n_sustain = (sustain_s * 60) as usize;
    let start = Instant::now();
    let cpu1 = cpu_seconds();
    let mut late = 0;
    let mut sustain_encoded = 0;
    for i in 0..n_sustain {
        let due = start + Duration::from_micros(i as u64 * 16_667);
        let now = Instant::now();
        if due > now {
            std::thread::sleep(due - now);
        } else if now - due > Duration::from_micros(16_667) {
            late += 1;
        }
        decode_into(&mut frame, &yuyv[i % yuyv.len()], &mut map, &mut scratch);
        // Frame time goes on from the loop above: a jump would be a gap in
        // the stream, which ends the press, and the hold frames would then
        // be taken for the new no-contact reference (nothing encoded).
        frame.set_time((60 + frames_n + i) as u64 * 16_667, 0);
        let out = pipeline
            .process(&frame, &mut StageTimes::default())
            .unwrap();
        if out.step.is_some() {
            sustain_encoded += 1;
        }
    }
    let sustain_wall = start.elapsed().as_secs_f64();
    let sustain_cpu = cpu_seconds() - cpu1;
    assert_eq!(
        sustain_encoded, n_sustain,
        "every frame of the sustained run is in contact and encoded"
    );

    println!(
        "model: {} ({}, input {}x{}, crop {}, dim {}), 1 intra-op thread",
        model.display(),
        info.arch,
        info.preprocess.size,
        info.preprocess.size,
        info.preprocess.crop,
        info.dim
    );
    println!("index: 119 textiles (flat centroids); frames: T030 press hold frames as YUYV 320x240 buffers");
    println!(
        "contact detector: {}\n",
        if tile == 0 {
            "the whole frame".to_string()
        } else {
            format!("the most changed tile of {tile} x {tile} blocks")
        }
    );
    println!("| stage | p50 ms | p90 ms | p99 ms |");
    println!("|---|---:|---:|---:|");
    for (name, s) in per {
        println!(
            "| {name} | {:.3} | {:.3} | {:.3} |",
            s.p50_ms, s.p90_ms, s.p99_ms
        );
    }
    println!(
        "| **whole frame** | **{:.3}** | {:.3} | {:.3} |",
        total.p50_ms, total.p90_ms, total.p99_ms
    );
    println!();
    println!(
        "as fast as possible: {frames_n} frames in {wall:.2} s = {:.0} frames/s on one thread (CPU {:.0}% of one core)",
        frames_n as f64 / wall,
        100.0 * cpu_fast / wall
    );
    println!(
        "sustained 60 fps for {sustain_s} s: CPU {:.1}% of one core ({:.2} s CPU over {:.2} s; {late} frames late by more than a period)",
        100.0 * sustain_cpu / sustain_wall,
        sustain_cpu,
        sustain_wall
    );
}
