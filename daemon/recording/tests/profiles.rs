//! Recordings of every sensor profile: a camera's own images stored with
//! its profile are read back as 240x320 frames at the frame's scale.

use image::{Rgb, RgbImage};
use telextiles_recording::profile::{GELSIGHT_MINI, UVC};
use telextiles_recording::recording::{
    self, find_recordings, read_meta, read_press, write_press, Recording, Sensor,
};
use telextiles_recording::resample::{camera_view, FrameMap};
use telextiles_recording::{Press, PressMeta};

fn meta(n: usize, fps: f32, profile: Option<&str>, mm: Option<f32>) -> PressMeta {
    PressMeta {
        textile: "T001".into(),
        person: 0,
        sensor: 0,
        jig: false,
        fps,
        timestamps_us: (0..n as u64)
            .map(|i| i * (1e6 / fps as f64) as u64)
            .collect(),
        seed: None,
        source: "test".into(),
        sensor_serial: None,
        params: None,
        reference_frames: Some(1),
        sensor_profile: profile.map(str::to_string),
        mm_per_px: mm,
    }
}

fn textured() -> RgbImage {
    RgbImage::from_fn(240, 320, |x, y| {
        Rgb([
            (128.0 + 60.0 * (x as f32 * 0.3).sin()) as u8,
            (128.0 + 60.0 * (y as f32 * 0.2).cos()) as u8,
            ((x + y) % 200) as u8,
        ])
    })
}

#[test]
fn a_gelsight_mini_press_is_stored_as_the_camera_gives_it_and_read_as_frames() {
    let frame = textured();
    let cam = camera_view(
        &frame,
        320,
        240,
        true,
        GELSIGHT_MINI.mm_per_px(320).unwrap(),
    );
    let press = Press {
        meta: meta(3, 25.0, Some("gelsight-mini"), None),
        frames: vec![cam.clone(); 3],
    };
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("p");
    write_press(&dir, &press).unwrap();
    let json = std::fs::read_to_string(dir.join("press.json")).unwrap();
    assert!(
        json.contains("\"width\": 320") && json.contains("gelsight-mini"),
        "{json}"
    );
    let back = read_press(&dir).unwrap();
    assert_eq!(back.frames.len(), 3);
    let mut want = RgbImage::new(240, 320);
    FrameMap::for_profile(&GELSIGHT_MINI, 320, 240, None)
        .unwrap()
        .map(cam.as_raw(), &mut want)
        .unwrap();
    assert_eq!(back.frames[0], want);
    assert_eq!(back.meta.profile().unwrap().name, "gelsight-mini");
    // Given as another sensor, it says what its press.json says.
    let mut r = find_recordings(tmp.path()).unwrap();
    let digit = Sensor {
        profile: &telextiles_recording::profile::DIGIT,
        mm_per_px: None,
    };
    let e = r[0].assume_sensor(digit).unwrap_err().to_string();
    assert!(
        e.contains("GelSight Mini") && e.contains("DIGIT given"),
        "{e}"
    );
    let gs = Sensor {
        profile: &GELSIGHT_MINI,
        mm_per_px: None,
    };
    r[0].assume_sensor(gs).unwrap();
}

#[test]
fn a_press_its_profile_cannot_map_is_refused_whole() {
    let tmp = tempfile::tempdir().unwrap();
    // A generic camera with no scale: not written (nothing left behind).
    let press = Press {
        meta: meta(2, 30.0, Some("uvc"), None),
        frames: vec![RgbImage::new(320, 240); 2],
    };
    let e = write_press(&tmp.path().join("a"), &press)
        .unwrap_err()
        .to_string();
    assert!(e.contains("mm_per_px"), "{e}");
    assert_eq!(std::fs::read_dir(tmp.path()).unwrap().count(), 0);
    // With its scale it is.
    let press = Press {
        meta: meta(2, 30.0, Some("uvc"), Some(0.05)),
        frames: vec![RgbImage::new(320, 240); 2],
    };
    write_press(&tmp.path().join("b"), &press).unwrap();
    assert_eq!(
        read_press(&tmp.path().join("b")).unwrap().frames[0].width(),
        240
    );
    // An unknown profile in press.json is an error naming the ones built in.
    let p = tmp.path().join("b/press.json");
    let s = std::fs::read_to_string(&p)
        .unwrap()
        .replace("\"uvc\"", "\"gelsite\"");
    std::fs::write(&p, s).unwrap();
    let e = read_meta(&tmp.path().join("b")).unwrap_err().to_string();
    assert!(
        e.contains("gelsite") && e.contains("digit, gelsight-mini, uvc"),
        "{e}"
    );
    // A DIGIT press of a size no DIGIT streams.
    let press = Press {
        meta: meta(1, 30.0, None, None),
        frames: vec![RgbImage::new(300, 200)],
    };
    let e = write_press(&tmp.path().join("c"), &press)
        .unwrap_err()
        .to_string();
    assert!(e.contains("300x200"), "{e}");
    let _ = UVC;
}

#[test]
fn a_pytouch_sequence_of_another_sensor_is_mapped_and_timed_by_its_profile() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = tmp.path().join("denim/GS0001");
    std::fs::create_dir_all(&seq).unwrap();
    let cam = camera_view(&textured(), 320, 240, true, 0.059);
    for i in 0..4 {
        cam.save(seq.join(format!("{i:03}.png"))).unwrap();
    }
    let mut r = find_recordings(tmp.path()).unwrap();
    recording::assume_sensor(
        &mut r,
        Some(Sensor {
            profile: &GELSIGHT_MINI,
            mm_per_px: None,
        }),
    )
    .unwrap();
    assert!(matches!(r[0], Recording::Pytouch { .. }));
    let p = r[0].load().unwrap();
    assert_eq!(p.meta.fps, 25.0);
    assert_eq!(p.meta.timestamps_us[1], 40_000);
    assert_eq!(p.meta.sensor_profile.as_deref(), Some("gelsight-mini"));
    assert_eq!((p.frames[0].width(), p.frames[0].height()), (240, 320));
    // As a DIGIT (no sensor given) the same 320x240 images are a DIGIT's
    // QVGA at 60 fps: turned, not scaled.
    let r = find_recordings(tmp.path()).unwrap();
    let p = r[0].load().unwrap();
    assert_eq!(p.meta.fps, 60.0);
    assert_eq!(p.meta.sensor_profile, None);
}
