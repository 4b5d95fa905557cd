use super::*;
use crate::profile::{DIGIT, GELSIGHT_MINI, UVC};
use image::{Rgb, RgbImage};

/// A smooth, coloured, asymmetric test image.
fn smooth(w: u32, h: u32) -> RgbImage {
    RgbImage::from_fn(w, h, |x, y| {
        let (fx, fy) = (x as f32 / w as f32, y as f32 / h as f32);
        Rgb([
            (40.0 + 150.0 * fx) as u8,
            (60.0 + 120.0 * fy) as u8,
            (100.0 + 60.0 * (fx * fy)) as u8,
        ])
    })
}

#[test]
fn the_digit_modes_are_a_turn_and_a_two_by_two_mean() {
    let cam = smooth(320, 240);
    let mut m = FrameMap::digit(320, 240).unwrap();
    assert_eq!(m.valid(), Rect::FULL);
    let mut out = RgbImage::new(1, 1);
    m.map(cam.as_raw(), &mut out).unwrap();
    for (x, y) in [(0, 0), (239, 0), (0, 319), (100, 200)] {
        // digit-interface: frame (x, y) = camera (W-1-y, x).
        assert_eq!(out.get_pixel(x, y), cam.get_pixel(319 - y, x));
    }
    let vga = smooth(640, 480);
    let mut m = FrameMap::digit(640, 480).unwrap();
    m.map(vga.as_raw(), &mut out).unwrap();
    for (x, y) in [(0u32, 0u32), (239, 0), (17, 301)] {
        let px = |cx: u32, cy: u32| vga.get_pixel(cx, cy).0;
        let quad = [
            px(639 - 2 * y, 2 * x),
            px(639 - 2 * y - 1, 2 * x),
            px(639 - 2 * y, 2 * x + 1),
            px(639 - 2 * y - 1, 2 * x + 1),
        ];
        let want: [u8; 3] = std::array::from_fn(|c| {
            ((quad.iter().map(|p| p[c] as u32).sum::<u32>() + 2) / 4) as u8
        });
        assert_eq!(out.get_pixel(x, y).0, want);
    }
    assert!(FrameMap::digit(300, 200)
        .unwrap_err()
        .contains("cannot map a 300x200"));
}

#[test]
fn a_gelsight_mini_fills_the_middle_of_the_frame_and_mirrors_around_it() {
    // 18.88 mm over 320 px: 0.059 mm per pixel, 236 x 177 frame pixels.
    let mut m = FrameMap::for_profile(&GELSIGHT_MINI, 320, 240, None).unwrap();
    assert!(m.turns());
    let v = m.valid();
    assert!(
        (176..=178).contains(&v.w) && (235..=237).contains(&v.h),
        "{v:?}"
    );
    // Centred.
    assert!((v.x as i32 - (240 - v.w as i32) / 2).abs() <= 1, "{v:?}");
    assert!((v.y as i32 - (320 - v.h as i32) / 2).abs() <= 1, "{v:?}");
    let cam = smooth(320, 240);
    let mut out = RgbImage::new(240, 320);
    m.map(cam.as_raw(), &mut out).unwrap();
    // Mirrored at the edges of the field: columns x-1-i and x+i agree.
    for i in 0..5 {
        for y in [v.y + 10, v.y + 100] {
            assert_eq!(out.get_pixel(v.x - 1 - i, y), out.get_pixel(v.x + i, y));
            let r = v.x + v.w;
            assert_eq!(out.get_pixel(r + i, y), out.get_pixel(r - 1 - i, y));
        }
    }
    assert_eq!(out.get_pixel(120, 0), out.get_pixel(120, 2 * v.y - 1));
}

#[test]
fn every_scale_keeps_a_flat_image_flat() {
    let cam = RgbImage::from_pixel(333, 250, Rgb([17, 128, 250]));
    for mm in [0.02f32, 0.0295, 0.059, 0.08, 0.1, 0.16] {
        let mut m = FrameMap::new(333, 250, true, mm).unwrap();
        let mut out = RgbImage::new(240, 320);
        m.map(cam.as_raw(), &mut out).unwrap();
        assert!(out.pixels().all(|p| p.0 == [17, 128, 250]), "{mm}");
    }
}

/// Frame pixels per period of a pattern along the frame's x axis (by the
/// mean spacing of its upward crossings of the row's mean).
fn period_px(img: &RgbImage, y: u32, x0: u32, x1: u32) -> f32 {
    let row: Vec<f32> = (x0..x1).map(|x| img.get_pixel(x, y).0[0] as f32).collect();
    let mean = row.iter().sum::<f32>() / row.len() as f32;
    let ups: Vec<usize> = (1..row.len())
        .filter(|&i| row[i - 1] < mean && row[i] >= mean)
        .collect();
    (ups[ups.len() - 1] - ups[0]) as f32 / (ups.len() - 1) as f32
}

#[test]
fn a_yarn_spacing_in_millimetres_is_the_same_number_of_frame_pixels_at_every_scale() {
    // Stripes 1.2 mm apart across the frame's x axis, which is the
    // landscape camera's y axis.
    for (w, h, mm) in [
        (320u32, 240u32, 0.059f32),
        (640, 480, 0.0295),
        (1280, 960, 0.02),
    ] {
        let cam = RgbImage::from_fn(w, h, |_, y| {
            let v = 128.0 + 100.0 * (2.0 * std::f32::consts::PI * y as f32 * mm / 1.2).sin();
            Rgb([v as u8, 0, 0])
        });
        let mut m = FrameMap::new(w, h, true, mm).unwrap();
        let mut out = RgbImage::new(240, 320);
        m.map(cam.as_raw(), &mut out).unwrap();
        let v = m.valid();
        let p = period_px(&out, 160, v.x, v.x + v.w);
        assert!((p - 1.2 / FRAME_MM_PER_PX).abs() < 0.3, "{w}x{h}: {p}");
    }
}

#[test]
fn a_camera_view_maps_back_to_the_frame_it_was_taken_from() {
    let frame = smooth(240, 320);
    for (profile, w, h) in [
        (&GELSIGHT_MINI, 320, 240),
        (&DIGIT, 640, 480),
        (&DIGIT, 320, 240),
    ] {
        let mm = profile.mm_per_px(w).unwrap();
        let cam = camera_view(&frame, w, h, true, mm);
        let mut m = FrameMap::for_profile(profile, w, h, None).unwrap();
        let mut back = RgbImage::new(240, 320);
        m.map(cam.as_raw(), &mut back).unwrap();
        let v = m.valid();
        let mut worst = 0i32;
        for y in v.y + 1..v.y + v.h - 1 {
            for x in v.x + 1..v.x + v.w - 1 {
                for c in 0..3 {
                    let d = back.get_pixel(x, y).0[c] as i32 - frame.get_pixel(x, y).0[c] as i32;
                    worst = worst.max(d.abs());
                }
            }
        }
        assert!(worst <= 2, "{} {w}x{h}: off by {worst}", profile.name);
    }
}

#[test]
fn bad_sizes_shapes_and_scales_are_refused_by_name() {
    let e = FrameMap::for_profile(&GELSIGHT_MINI, 320, 200, None).unwrap_err();
    assert!(
        e.contains("not the shape") && e.contains("320x240 @ 25 fps"),
        "{e}"
    );
    let e = FrameMap::for_profile(&UVC, 320, 240, None).unwrap_err();
    assert!(e.contains("sensor.mm_per_px"), "{e}");
    assert!(FrameMap::for_profile(&UVC, 300, 200, Some(0.05)).is_ok());
    assert!(FrameMap::new(320, 240, true, 0.0)
        .unwrap_err()
        .contains("not a scale"));
    assert!(FrameMap::new(0, 240, true, 0.1).is_err());
    let mut m = FrameMap::digit(320, 240).unwrap();
    let e = m.map(&[0; 30], &mut RgbImage::new(240, 320)).unwrap_err();
    assert!(e.contains("30 bytes"), "{e}");
}

#[test]
fn a_portrait_image_maps_as_its_landscape_original_turned() {
    // The same camera image saved landscape (turned by the map) and
    // portrait (turned by the tool that saved it): one frame, at every
    // scale, through both passes' orders.
    for (w, h, mm) in [
        (640u32, 480u32, 0.04f32),
        (320, 240, 0.059),
        (400, 300, 0.1),
    ] {
        let land = smooth(w, h);
        let portrait = RgbImage::from_fn(h, w, |x, y| *land.get_pixel(w - 1 - y, x));
        let mut a = RgbImage::new(240, 320);
        let mut b = RgbImage::new(240, 320);
        let mut ml = FrameMap::new(w, h, true, mm).unwrap();
        let mut mp = FrameMap::new(h, w, false, mm).unwrap();
        ml.map(land.as_raw(), &mut a).unwrap();
        mp.map(portrait.as_raw(), &mut b).unwrap();
        assert_eq!(ml.valid(), mp.valid(), "{w}x{h}");
        assert_eq!(a, b, "{w}x{h}");
    }
}

#[test]
fn a_field_much_smaller_than_the_frame_is_mirrored_again_and_again() {
    // 40 x 30 camera pixels at the frame's scale: 30 x 40 frame pixels,
    // margins wider than the field itself.
    let cam = smooth(40, 30);
    let mut m = FrameMap::new(40, 30, true, FRAME_MM_PER_PX).unwrap();
    let v = m.valid();
    assert_eq!((v.w, v.h), (30, 40));
    let mut out = RgbImage::new(240, 320);
    m.map(cam.as_raw(), &mut out).unwrap();
    // Reflected at each edge of the field, then at each edge of the
    // reflection: period 2 x 30 columns.
    let y = v.y + 7;
    for x in 0..240u32 {
        let inside =
            v.x as i64 + mirror(x as i64, v.x as i64, (v.x + v.w) as i64) as i64 - v.x as i64;
        assert_eq!(out.get_pixel(x, y), out.get_pixel(inside as u32, y), "{x}");
    }
    // Every pixel is one of the field's.
    let field: std::collections::HashSet<[u8; 3]> = (v.y..v.y + v.h)
        .flat_map(|y| (v.x..v.x + v.w).map(move |x| (x, y)))
        .map(|(x, y)| out.get_pixel(x, y).0)
        .collect();
    assert!(out.pixels().all(|p| field.contains(&p.0)));
}
