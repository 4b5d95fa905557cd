//! A real GelSight Mini (Taxim's calibration unit: a no-contact frame and
//! presses of a calibration ball, 640x480 landscape at 0.0295 mm per
//! pixel; fixtures/gelsight_mini/README.md) through the profile's mapping
//! and the contact detector: the ball lands where and as large as its
//! millimetres say on the 0.08 mm frame, and the detector sees each press.

use image::RgbImage;
use telextiles_recording::profile::{FRAME_MM_PER_PX, GELSIGHT_MINI};
use telextiles_recording::resample::FrameMap;
use telextiles_sensing::contact::{ContactConfig, ContactDetector};

fn fixture(name: &str) -> RgbImage {
    let p = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures/gelsight_mini")
        .join(name);
    image::open(&p).unwrap().into_rgb8()
}

fn mapped(img: &RgbImage, map: &mut FrameMap) -> RgbImage {
    let mut out = RgbImage::new(240, 320);
    map.map(img.as_raw(), &mut out).unwrap();
    out
}

/// The blob where `a` differs from `b` by more than a third of the
/// largest difference inside `field`: its centroid and equivalent radius.
fn blob(
    a: &RgbImage,
    b: &RgbImage,
    field: telextiles_recording::resample::Rect,
) -> (f64, f64, f64) {
    let diff = |x: u32, y: u32| -> f64 {
        (0..3)
            .map(|c| (a.get_pixel(x, y).0[c] as f64 - b.get_pixel(x, y).0[c] as f64).abs())
            .sum()
    };
    let pts: Vec<(u32, u32)> = (field.y..field.y + field.h)
        .flat_map(|y| (field.x..field.x + field.w).map(move |x| (x, y)))
        .collect();
    let max = pts.iter().map(|&(x, y)| diff(x, y)).fold(0.0, f64::max);
    let inside: Vec<(u32, u32)> = pts
        .into_iter()
        .filter(|&(x, y)| diff(x, y) > max / 3.0)
        .collect();
    let n = inside.len() as f64;
    let cx = inside.iter().map(|p| p.0 as f64).sum::<f64>() / n;
    let cy = inside.iter().map(|p| p.1 as f64).sum::<f64>() / n;
    (cx, cy, (n / std::f64::consts::PI).sqrt())
}

#[test]
fn a_real_gelsight_mini_press_lands_at_its_size_in_millimetres() {
    let bg = fixture("gelsight_mini_background_640x480.png");
    let mut map = FrameMap::for_profile(&GELSIGHT_MINI, 640, 480, None).unwrap();
    assert!((map.mm_per_px() - 0.0295).abs() < 1e-4);
    let bg_frame = mapped(&bg, &mut map);
    let field = map.valid();
    let f = FRAME_MM_PER_PX as f64 / 0.0295;
    let full = |img: &RgbImage| telextiles_recording::resample::Rect {
        x: 0,
        y: 0,
        w: img.width(),
        h: img.height(),
    };
    for (name, (cx, cy, r)) in [
        ("gelsight_mini_ball_08_640x480.png", (350.0, 218.0, 51.0)),
        ("gelsight_mini_ball_16_640x480.png", (324.0, 226.0, 46.0)),
    ] {
        let raw = fixture(name);
        let ball = mapped(&raw, &mut map);
        let (x, y, radius) = blob(&ball, &bg_frame, field);
        let (nx, ny, native) = blob(&raw, &bg, full(&raw));
        // Camera (cx, cy) turned: frame x from the camera's row, frame y
        // from its column counted from the right; both scaled about the
        // field's centre.
        let to_frame = |cx: f64, cy: f64| {
            (
                120.0 + (cy + 0.5 - 240.0) / f - 0.5,
                160.0 + ((639.0 - cx) + 0.5 - 320.0) / f - 0.5,
            )
        };
        // The blob's centre is where the camera's own pixels put it, to a
        // frame pixel; and near the contact centre Taxim marks.
        let (wx, wy) = to_frame(nx, ny);
        assert!(
            (x - wx).abs() < 1.0 && (y - wy).abs() < 1.0,
            "{name}: centre ({x:.1}, {y:.1}), on the camera's pixels ({wx:.1}, {wy:.1})"
        );
        let (tx, ty) = to_frame(cx, cy);
        assert!(
            (x - tx).hypot(y - ty) < r / f / 2.0,
            "{name}: centre ({x:.1}, {y:.1}), Taxim's ({tx:.1}, {ty:.1})"
        );
        // Its size: the same blob measured on the camera's own pixels,
        // in millimetres, is the frame's to 6 %; and no larger than the
        // contact circle Taxim marks (the blob is where the change is
        // strongest, inside the circle).
        let (mm_frame, mm_native) = (radius * FRAME_MM_PER_PX as f64, native * 0.0295);
        assert!(
            (mm_frame / mm_native - 1.0).abs() < 0.06,
            "{name}: {mm_frame:.3} mm on the frame, {mm_native:.3} mm on the camera's pixels"
        );
        assert!(
            radius <= r / f,
            "{name}: radius {radius:.1}, circle {:.1}",
            r / f
        );
    }
}

#[test]
fn the_contact_detector_sees_a_real_gelsight_mini_press() {
    let mut map = FrameMap::for_profile(&GELSIGHT_MINI, 640, 480, None).unwrap();
    let bg = mapped(&fixture("gelsight_mini_background_640x480.png"), &mut map);
    let ball = mapped(&fixture("gelsight_mini_ball_08_640x480.png"), &mut map);
    let mut det = ContactDetector::new(ContactConfig::default());
    let mut t = 0u64;
    let mut step = |img: &RgbImage| {
        t += 40_000; // 25 fps
        det.update(img, t)
    };
    // Resting: the reference is captured, nothing is in contact.
    for _ in 0..40 {
        assert!(!step(&bg).in_contact);
    }
    // Pressed: in contact within the detector's run of frames.
    let pressed: Vec<bool> = (0..6).map(|_| step(&ball).in_contact).collect();
    assert!(pressed[2..].iter().all(|&c| c), "{pressed:?}");
    // A small ball touches a small part of the gel.
    let u = step(&ball);
    assert!(
        u.coverage > 0.0 && u.coverage < 0.5,
        "coverage {}",
        u.coverage
    );
    // Lifted: the press ends.
    let lifted: Vec<bool> = (0..20).map(|_| step(&bg).in_contact).collect();
    assert!(!lifted[lifted.len() - 1], "{lifted:?}");
}
