//! Frame sources: DIGIT discovery on fake sysfs trees, format negotiation,
//! YUYV/MJPG decoding and orientation, LED control values, recorded replay,
//! and the resilient wrapper (missing camera, unplugging, bad frames).

use std::os::unix::fs::symlink;
use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use image::{Rgb, RgbImage};
use proptest::prelude::*;
use telextiles_recording::profile::{Mode, DIGIT, GELSIGHT_MINI, UVC};
use telextiles_recording::resample::FrameMap;
use telextiles_sensing::frame::{Frame, FrameError, FRAME_H, FRAME_W};
use telextiles_sensing::source::digit::{led_control_value, LedIntensity};
use telextiles_sensing::source::recorded::{Pace, RecordedSource};
use telextiles_sensing::source::sysfs::{find_camera, find_digit, find_digits};
use telextiles_sensing::source::yuv::{
    decode_buffer, decode_mjpg, decode_yuyv, encode_yuyv, negotiate, rotate_to_frame,
    OfferedFormat, PixelFormat,
};
use telextiles_sensing::source::{Backoff, FrameSource, Resilient, SourceError};

fn write(p: &Path, s: &str) {
    std::fs::create_dir_all(p.parent().unwrap()).unwrap();
    std::fs::write(p, format!("{s}\n")).unwrap();
}

/// A fake USB camera: /sys/devices/.../<usb>/{idVendor,...} and
/// /sys/class/video4linux/<node>/device -> <usb>/<usb>:1.0
fn fake_camera(root: &Path, usb: &str, nodes: &[(&str, &str)], attrs: &[(&str, &str)]) {
    let dev = root.join("devices/pci0000:00/usb1").join(usb);
    for (k, v) in attrs {
        write(&dev.join(k), v);
    }
    let iface = dev.join(format!("{usb}:1.0"));
    std::fs::create_dir_all(&iface).unwrap();
    for (node, index) in nodes {
        let class = root.join("class/video4linux").join(node);
        std::fs::create_dir_all(&class).unwrap();
        write(&class.join("index"), index);
        // The V4L2 card name, as uvcvideo makes it from the product string.
        let product = attrs
            .iter()
            .find(|(k, _)| *k == "product")
            .map_or("UVC Camera", |a| a.1);
        write(&class.join("name"), &format!("{product}: {product}"));
        symlink(&iface, class.join("device")).unwrap();
    }
}

fn digit_attrs(serial: &str) -> Vec<(&'static str, String)> {
    vec![
        ("idVendor", "2833".into()),
        ("idProduct", "0209".into()),
        ("product", "DIGIT".into()),
        ("manufacturer", "Facebook".into()),
        ("serial", serial.into()),
        ("bcdDevice", "0200".into()),
    ]
}

fn fake_sysfs() -> tempfile::TempDir {
    let t = tempfile::tempdir().unwrap();
    let a1 = digit_attrs("D20118");
    let a1: Vec<(&str, &str)> = a1.iter().map(|(k, v)| (*k, v.as_str())).collect();
    fake_camera(t.path(), "1-1", &[("video0", "0"), ("video1", "1")], &a1);
    let webcam = [
        ("idVendor", "046d"),
        ("idProduct", "0825"),
        ("product", "Webcam C270"),
        ("serial", "ABC"),
    ];
    fake_camera(
        t.path(),
        "1-2",
        &[("video2", "0"), ("video3", "1")],
        &webcam,
    );
    let a2 = digit_attrs("D00045");
    let a2: Vec<(&str, &str)> = a2.iter().map(|(k, v)| (*k, v.as_str())).collect();
    fake_camera(t.path(), "1-3", &[("video10", "0"), ("video11", "1")], &a2);
    t
}

#[test]
fn sysfs_walk_finds_digits_by_usb_id_and_serial() {
    let t = fake_sysfs();
    let dev = Path::new("/dev");
    let all = find_digits(t.path(), dev);
    let names: Vec<_> = all
        .iter()
        .map(|d| (d.name.as_str(), d.serial.as_str()))
        .collect();
    assert_eq!(
        names,
        [("video0", "D20118"), ("video10", "D00045")],
        "capture nodes only, webcam skipped"
    );
    assert_eq!(all[0].node, Path::new("/dev/video0"));
    assert_eq!(all[0].product, "DIGIT");
    assert_eq!(all[0].manufacturer, "Facebook");
    assert_eq!(all[0].revision, 200);
    let d = find_digit(t.path(), dev, Some("D00045")).unwrap();
    assert_eq!(d.node, Path::new("/dev/video10"));
    assert_eq!(find_digit(t.path(), dev, None).unwrap().serial, "D20118");
    match find_digit(t.path(), dev, Some("D99999")) {
        Err(SourceError::Unavailable(m)) => {
            assert!(
                m.contains("D99999") && m.contains("D20118") && m.contains("D00045"),
                "{m}"
            )
        }
        other => panic!("expected Unavailable, got {other:?}"),
    }
}

#[test]
fn each_profile_finds_its_sensor_by_ids_names_serial_or_node() {
    let t = fake_sysfs();
    let dev = Path::new("/dev");
    fake_camera(
        t.path(),
        "1-4",
        &[("video20", "0")],
        &[
            ("idVendor", "2bd9"),
            ("idProduct", "0001"),
            ("product", "GelSight Mini R0B 28J3-CWXU"),
            ("serial", "28J3CWXU"),
        ],
    );
    let gs = find_camera(t.path(), dev, &GELSIGHT_MINI, None).unwrap();
    assert_eq!(gs.node, Path::new("/dev/video20"));
    // Selected by serial, node or kernel name.
    let d = find_camera(t.path(), dev, &DIGIT, Some("/dev/video10")).unwrap();
    assert_eq!(d.serial, "D00045");
    assert_eq!(
        find_camera(t.path(), dev, &DIGIT, Some("video10"))
            .unwrap()
            .serial,
        "D00045"
    );
    // A generic camera is any camera; a node names one whatever it is.
    assert_eq!(
        find_camera(t.path(), dev, &UVC, None).unwrap().name,
        "video0"
    );
    let w = find_camera(t.path(), dev, &GELSIGHT_MINI, Some("/dev/video2")).unwrap();
    assert_eq!(w.product, "Webcam C270");
    // Absent: what it looked for and what is there.
    let empty = tempfile::tempdir().unwrap();
    match find_camera(empty.path(), dev, &GELSIGHT_MINI, None) {
        Err(SourceError::Unavailable(m)) => assert!(
            m.contains("no GelSight Mini found")
                && m.contains("named \"GelSight Mini\"")
                && m.contains("telextilesd sensors"),
            "{m}"
        ),
        other => panic!("expected Unavailable, got {other:?}"),
    }
    match find_camera(t.path(), dev, &GELSIGHT_MINI, Some("XYZ")) {
        Err(SourceError::Unavailable(m)) => assert!(m.contains("28J3CWXU (/dev/video20)"), "{m}"),
        other => panic!("expected Unavailable, got {other:?}"),
    }
}

#[test]
fn a_camera_is_identified_by_its_profile_or_told_how_to_describe_it() {
    let t = fake_sysfs();
    let cams = telextiles_sensing::source::sysfs::find_cameras(t.path(), Path::new("/dev"));
    use telextiles_sensing::source::sysfs::identify_camera;
    // The first camera a built-in profile knows (the DIGIT on video0).
    let (p, c) = identify_camera(&cams, None).unwrap();
    assert_eq!((p.name, c.name.as_str()), ("digit", "video0"));
    // The webcam, named: none of the built-in sensors.
    let e = identify_camera(&cams, Some("/dev/video2")).unwrap_err();
    assert!(
        e.contains("Webcam C270") && e.contains("sensor_profile = \"uvc\""),
        "{e}"
    );
    let e = identify_camera(&cams, Some("/dev/video99")).unwrap_err();
    assert!(
        e.contains("no camera /dev/video99") && e.contains("/dev/video10"),
        "{e}"
    );
    assert!(identify_camera(&[], None)
        .unwrap_err()
        .contains("plugged in"));
}

#[test]
fn sysfs_matches_on_product_name_alone_and_reports_absence_clearly() {
    let t = tempfile::tempdir().unwrap();
    // Another firmware's USB id, product string still DIGIT.
    fake_camera(
        t.path(),
        "2-1",
        &[("video4", "0")],
        &[
            ("idVendor", "1234"),
            ("idProduct", "5678"),
            ("product", "DIGIT"),
            ("serial", "D1"),
        ],
    );
    assert_eq!(find_digits(t.path(), Path::new("/dev")).len(), 1);
    let empty = tempfile::tempdir().unwrap();
    match find_digit(empty.path(), Path::new("/dev"), None) {
        Err(SourceError::Unavailable(m)) => {
            assert!(m.contains("2833:0209") && m.contains("plugged in"), "{m}")
        }
        other => panic!("expected Unavailable, got {other:?}"),
    }
}

fn offer(f: &[u8; 4], w: u32, h: u32, fps: &[u32]) -> OfferedFormat {
    OfferedFormat {
        fourcc: *f,
        width: w,
        height: h,
        fps: fps.to_vec(),
    }
}

fn mode(s: &str) -> Mode {
    s.parse().unwrap()
}

#[test]
fn negotiation_prefers_yuyv_qvga60_and_falls_back() {
    let digit = [
        offer(b"YUYV", 320, 240, &[60, 30]),
        offer(b"YUYV", 640, 480, &[30, 15]),
        offer(b"MJPG", 320, 240, &[60, 30]),
    ];
    let n = negotiate(&digit, &DIGIT, None).unwrap();
    assert_eq!((n.format, n.mode), (PixelFormat::Yuyv, mode("320x240@60")));
    assert_eq!(n.note, None);
    let n = negotiate(&digit, &DIGIT, Some(mode("640x480@30"))).unwrap();
    assert_eq!((n.format, n.mode), (PixelFormat::Yuyv, mode("640x480@30")));
    assert_eq!(n.note, None);
    let mjpg_only = [offer(b"MJPG", 320, 240, &[60, 30])];
    assert_eq!(
        negotiate(&mjpg_only, &DIGIT, None).unwrap().format,
        PixelFormat::Mjpg
    );
    let qvga30 = [offer(b"YUYV", 320, 240, &[30])];
    assert_eq!(
        negotiate(&qvga30, &DIGIT, None).unwrap().mode,
        mode("320x240@30")
    );
    let webcam = [
        offer(b"YUYV", 1280, 720, &[10]),
        offer(b"H264", 320, 240, &[60]),
    ];
    let e = negotiate(&webcam, &DIGIT, None).unwrap_err();
    assert!(e.contains("1280x720") && e.contains("H264"), "{e}");
}

#[test]
fn a_mode_the_camera_refuses_is_said_with_what_streams_instead() {
    // A DIGIT whose firmware streams no VGA: asked for VGA, it streams
    // QVGA and the owner is told why.
    let qvga_only = [offer(b"YUYV", 320, 240, &[60, 30])];
    let n = negotiate(&qvga_only, &DIGIT, Some(mode("640x480@30"))).unwrap();
    assert_eq!(n.mode, mode("320x240@60"));
    let note = n.note.expect("a note");
    assert!(
        note.contains("DIGIT does not offer 640x480 @ 30 fps")
            && note.contains("YUYV 320x240 @ [60, 30] fps")
            && note.contains("streaming 320x240 @ 60 fps instead"),
        "{note}"
    );
}

#[test]
fn each_profile_negotiates_its_own_modes() {
    // A GelSight Mini offering its 25 fps modes among others.
    let gs = [
        offer(b"MJPG", 3280, 2464, &[15]),
        offer(b"YUYV", 640, 480, &[25, 15]),
        offer(b"YUYV", 320, 240, &[25]),
    ];
    let n = negotiate(&gs, &GELSIGHT_MINI, None).unwrap();
    assert_eq!(n.mode, mode("320x240@25"));
    let n = negotiate(&gs, &GELSIGHT_MINI, Some(mode("640x480@25"))).unwrap();
    assert_eq!((n.mode, n.note), (mode("640x480@25"), None));
    // Its own modes missing: an error naming them and what is offered.
    let e = negotiate(&[offer(b"YUYV", 1280, 720, &[30])], &GELSIGHT_MINI, None).unwrap_err();
    assert!(
        e.contains("GelSight Mini modes (320x240 @ 25 fps, 640x480 @ 25 fps")
            && e.contains("1280x720"),
        "{e}"
    );
    // A generic camera: the mode asked for, else the first it offers in a
    // format we decode, at its fastest.
    let cam = [
        offer(b"H264", 1920, 1080, &[30]),
        offer(b"MJPG", 1280, 720, &[30, 60]),
        offer(b"YUYV", 640, 480, &[30]),
    ];
    let n = negotiate(&cam, &UVC, None).unwrap();
    assert_eq!((n.format, n.mode), (PixelFormat::Mjpg, mode("1280x720@60")));
    let n = negotiate(&cam, &UVC, Some(mode("640x480@30"))).unwrap();
    assert_eq!((n.format, n.mode), (PixelFormat::Yuyv, mode("640x480@30")));
}

/// A landscape sensor image with a gradient and a red square at sensor
/// x 300..310, y 10..20.
fn sensor_image(w: u32, h: u32) -> RgbImage {
    RgbImage::from_fn(w, h, |x, y| {
        let (sx, sy) = (x * 320 / w, y * 240 / h);
        if (300..310).contains(&sx) && (10..20).contains(&sy) {
            Rgb([220, 30, 30])
        } else {
            Rgb([(40 + sx / 4) as u8, (60 + sy / 4) as u8, 120])
        }
    })
}

fn close(a: &[u8], b: &[u8], tol: i32) -> bool {
    a.iter()
        .zip(b)
        .all(|(x, y)| (*x as i32 - *y as i32).abs() <= tol)
}

#[test]
fn yuyv_decodes_and_rotates_like_digit_interface() {
    let src = sensor_image(320, 240);
    let yuyv = encode_yuyv(src.as_raw(), 320, 240);
    assert_eq!(yuyv.len(), 320 * 240 * 2);
    let mut scratch = Vec::new();
    let mut out = RgbImage::new(FRAME_W, FRAME_H);
    let mut map = FrameMap::digit(320, 240).unwrap();
    decode_buffer(&yuyv, PixelFormat::Yuyv, &mut map, &mut scratch, &mut out).unwrap();
    assert_eq!((out.width(), out.height()), (240, 320));
    // digit-interface: cv2.transpose then cv2.flip(0): out(x, y) = in(319 - y, x).
    for (x, y) in [(0u32, 0u32), (239, 319), (15, 14), (100, 200), (5, 300)] {
        let want = src.get_pixel(319 - y, x).0;
        let got = out.get_pixel(x, y).0;
        assert!(
            close(&want, &got, 6),
            "({x},{y}): want {want:?} got {got:?}"
        );
    }
    // The red square (sensor x 300..310, y 10..20) lands at x 10..20, y 10..20.
    assert!(out.get_pixel(15, 14).0[0] > 180 && out.get_pixel(15, 14).0[1] < 80);
    assert!(
        out.get_pixel(15, 300).0[0] < 150,
        "not mirrored to the bottom"
    );
}

#[test]
fn vga_is_rotated_and_averaged_to_the_same_frame() {
    let src = sensor_image(640, 480);
    let mut out = RgbImage::new(1, 1);
    rotate_to_frame(src.as_raw(), 640, 480, &mut out).unwrap();
    assert_eq!((out.width(), out.height()), (240, 320));
    assert!(
        out.get_pixel(15, 14).0[0] > 180,
        "red square in the same place as at QVGA"
    );
    assert!(matches!(
        rotate_to_frame(&[0; 30], 5, 2, &mut out),
        Err(FrameError::Decode(_))
    ));
}

#[test]
fn truncated_or_odd_yuyv_is_a_decode_error() {
    let mut scratch = Vec::new();
    assert!(
        matches!(decode_yuyv(&[0; 1000], 320, 240, &mut scratch), Err(FrameError::Decode(m)) if m.contains("1000 bytes"))
    );
    assert!(decode_yuyv(&[0; 100], 5, 10, &mut scratch).is_err());
    // A padded buffer (drivers may round up) decodes.
    assert!(decode_yuyv(&vec![128; 320 * 240 * 2 + 64], 320, 240, &mut scratch).is_ok());
}

#[test]
fn mjpg_decodes_and_rejects_garbage_and_wrong_sizes() {
    let src = sensor_image(320, 240);
    let mut jpeg = Vec::new();
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 95)
        .encode_image(&src)
        .unwrap();
    let mut scratch = Vec::new();
    let mut out = RgbImage::new(FRAME_W, FRAME_H);
    let mut map = FrameMap::digit(320, 240).unwrap();
    decode_buffer(&jpeg, PixelFormat::Mjpg, &mut map, &mut scratch, &mut out).unwrap();
    assert!(close(
        &out.get_pixel(100, 200).0,
        &src.get_pixel(119, 100).0,
        12
    ));
    assert!(matches!(
        decode_mjpg(b"not a jpeg", 320, 240, &mut scratch),
        Err(FrameError::Decode(_))
    ));
    let small = sensor_image(160, 120);
    let mut jpeg2 = Vec::new();
    image::codecs::jpeg::JpegEncoder::new(&mut jpeg2)
        .encode_image(&small)
        .unwrap();
    match decode_mjpg(&jpeg2, 320, 240, &mut scratch) {
        Err(FrameError::Decode(m)) => assert!(m.contains("160x120"), "{m}"),
        other => panic!("{other:?}"),
    }
    // Truncated JPEG.
    assert!(decode_mjpg(&jpeg[..jpeg.len() / 3], 320, 240, &mut scratch).is_err());
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]
    #[test]
    fn decoding_random_buffers_never_panics(bytes in proptest::collection::vec(any::<u8>(), 0..4096), mjpg in any::<bool>(), w in 0u32..700, h in 0u32..500) {
        let mut scratch = Vec::new();
        let mut out = RgbImage::new(FRAME_W, FRAME_H);
        let f = if mjpg { PixelFormat::Mjpg } else { PixelFormat::Yuyv };
        if let Ok(mut map) = FrameMap::new(w, h, true, 0.05) {
            let _ = decode_buffer(&bytes, f, &mut map, &mut scratch, &mut out);
        }
        let mut jpegish = vec![0xff, 0xd8, 0xff, 0xe0];
        jpegish.extend_from_slice(&bytes);
        let _ = decode_mjpg(&jpegish, 320, 240, &mut scratch);
    }
}

#[test]
fn led_values_follow_the_digit_firmware() {
    assert_eq!(led_control_value(LedIntensity::MAX, 200), Ok(0xfff));
    assert_eq!(
        led_control_value(LedIntensity { r: 1, g: 2, b: 3 }, 201),
        Ok(0x123)
    );
    assert_eq!(led_control_value(LedIntensity::uniform(0), 200), Ok(0));
    assert_eq!(
        led_control_value(LedIntensity::MAX, 101),
        Ok(255),
        "old firmware: one 0..255 level"
    );
    assert!(led_control_value(LedIntensity { r: 16, g: 0, b: 0 }, 200).is_err());
}

/// A scripted source: yields the given results in order, then Ended.
struct Script(Vec<Result<RgbImage, SourceError>>, u64);
impl FrameSource for Script {
    fn next_frame(&mut self, out: &mut Frame) -> Result<(), SourceError> {
        if self.0.is_empty() {
            return Err(SourceError::Ended);
        }
        let img = self.0.remove(0)?;
        out.set_image(img)?;
        out.set_time(self.1, out.seq());
        self.1 += 16_667;
        Ok(())
    }
    fn describe(&self) -> String {
        "script".into()
    }
}

fn good() -> RgbImage {
    RgbImage::from_pixel(FRAME_W, FRAME_H, Rgb([90, 100, 110]))
}

#[test]
fn missing_camera_is_retried_with_backoff_then_reported() {
    let delays = Arc::new(Mutex::new(Vec::new()));
    let d2 = delays.clone();
    let t = tempfile::tempdir().unwrap();
    let root = t.path().to_path_buf();
    let mut src = Resilient::new(move || {
        find_digit(&root, Path::new("/dev"), Some("D20118"))?;
        unreachable!("no camera in an empty sysfs")
    })
    .with_backoff(Backoff::new(
        Duration::from_millis(100),
        Duration::from_millis(400),
    ))
    .with_max_attempts(5)
    .with_sleeper(move |d| d2.lock().unwrap().push(d));
    let mut f = Frame::blank();
    match src.next_frame(&mut f) {
        Err(SourceError::Unavailable(m)) => {
            assert!(m.contains("gave up after 5") && m.contains("D20118"), "{m}")
        }
        other => panic!("{other:?}"),
    }
    let ms: Vec<u128> = delays
        .lock()
        .unwrap()
        .iter()
        .map(|d| d.as_millis())
        .collect();
    assert_eq!(ms, [100, 200, 400, 400]);
    assert_eq!(src.stats().open_failures, 5);
}

#[test]
fn unplug_replug_and_bad_frames_are_survived_and_counted() {
    let opens = Arc::new(Mutex::new(0u32));
    let o2 = opens.clone();
    let mut src = Resilient::new(move || {
        let mut n = o2.lock().unwrap();
        *n += 1;
        match *n {
            1 => Ok(Box::new(Script(
                vec![
                    Ok(good()),
                    Ok(RgbImage::new(320, 240)), // landscape: wrong size
                    Err(SourceError::BadFrame(FrameError::Decode("corrupt".into()))),
                    Ok(good()),
                    Err(SourceError::Unavailable("unplugged".into())),
                ],
                0,
            )) as Box<dyn FrameSource>),
            2 => Err(SourceError::Unavailable("not back yet".into())),
            _ => Ok(Box::new(Script(vec![Ok(good())], 1_000_000))),
        }
    })
    .with_sleeper(|_| {});
    let mut f = Frame::blank();
    let mut got = 0;
    loop {
        match src.next_frame(&mut f) {
            Ok(()) => {
                assert_eq!((f.image().width(), f.image().height()), (FRAME_W, FRAME_H));
                got += 1
            }
            Err(SourceError::Ended) => break,
            Err(e) => panic!("{e}"),
        }
    }
    assert_eq!(got, 3);
    let s = src.stats();
    assert_eq!(
        (s.frames, s.bad_frames, s.reopens, s.open_failures),
        (3, 2, 1, 1)
    );
}

#[test]
fn endless_bad_frames_trigger_a_reopen() {
    let opens = Arc::new(Mutex::new(0u32));
    let o2 = opens.clone();
    let mut src = Resilient::new(move || {
        *o2.lock().unwrap() += 1;
        Ok(Box::new(Script(
            (0..10).map(|_| Ok(RgbImage::new(2, 2))).collect(),
            0,
        )) as Box<dyn FrameSource>)
    })
    .with_max_consecutive_bad(4)
    .with_max_attempts(3)
    .with_sleeper(|_| {});
    let mut f = Frame::blank();
    match src.next_frame(&mut f) {
        Err(SourceError::Unavailable(m)) => assert!(
            m.contains("4 bad frames in a row") && m.contains("gave up after 3"),
            "{m}"
        ),
        other => panic!("{other:?}"),
    }
    assert_eq!(
        *opens.lock().unwrap(),
        3,
        "reopened after every 4 bad frames in a row"
    );
    assert_eq!(src.stats().bad_frames, 12);
}

#[test]
fn recorded_replay_fast_real_time_and_errors() {
    let sim = telextiles_sim::Simulator::new().unwrap();
    let spec = telextiles_sim::PressSpec {
        frames: 12,
        ..telextiles_sim::PressSpec::new("T030", 3)
    };
    let press = sim.render_press(&spec).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let pdir = dir.path().join("p");
    telextiles_sim::recording::write_press(&pdir, &press).unwrap();
    let mut src = RecordedSource::open(&pdir, Pace::AsFastAsPossible).unwrap();
    let mut f = Frame::blank();
    let mut ts = Vec::new();
    while src.next_frame(&mut f).is_ok() {
        ts.push(f.timestamp_us());
        assert_eq!(f.image(), &press.frames[ts.len() - 1]);
    }
    assert_eq!(ts, press.meta.timestamps_us);
    // Real time: 12 frames at 60 fps take about 183 ms (11 periods).
    let mut src = RecordedSource::open(&pdir, Pace::RealTime).unwrap();
    let t0 = std::time::Instant::now();
    while src.next_frame(&mut f).is_ok() {}
    assert!(
        t0.elapsed() >= Duration::from_millis(180),
        "{:?}",
        t0.elapsed()
    );
    // Looping keeps timestamps increasing.
    let mut src =
        RecordedSource::from_press(press.clone(), Pace::AsFastAsPossible, "x").looping(true);
    let mut last = None;
    for _ in 0..30 {
        src.next_frame(&mut f).unwrap();
        assert!(last.is_none_or(|l| f.timestamp_us() > l));
        last = Some(f.timestamp_us());
    }
    // A frame of the wrong size in a recording is a counted bad frame.
    let mut bad = press.clone();
    bad.frames[2] = RgbImage::new(320, 240);
    let mut src = Resilient::new({
        let mut once = Some(bad);
        move || {
            let p = once.take().ok_or(SourceError::Ended)?;
            Ok(
                Box::new(RecordedSource::from_press(p, Pace::AsFastAsPossible, "bad"))
                    as Box<dyn FrameSource>,
            )
        }
    });
    let mut n = 0;
    while src.next_frame(&mut f).is_ok() {
        n += 1;
    }
    assert_eq!((n, src.stats().bad_frames), (11, 1));
    // A missing recording is a clear error.
    match RecordedSource::open(&dir.path().join("nope"), Pace::AsFastAsPossible) {
        Err(SourceError::Fatal(m)) => assert!(m.contains("nope"), "{m}"),
        Err(e) => panic!("{e}"),
        Ok(_) => panic!("opened a missing recording"),
    }
}

/// A recording whose timestamps go backwards is refused with a clear error,
/// on disk and in memory, instead of panicking the sensing thread.
#[test]
fn a_recording_whose_timestamps_go_backwards_is_refused_not_a_panic() {
    let sim = telextiles_sim::Simulator::new().unwrap();
    let spec = telextiles_sim::PressSpec {
        frames: 6,
        ..telextiles_sim::PressSpec::new("T030", 3)
    };
    let mut press = sim.render_press(&spec).unwrap();
    press.meta.timestamps_us[3] = 0;
    // In memory (a replay built by a program): frames up to the bad one,
    // then a fatal error naming it.
    let mut src = RecordedSource::from_press(press.clone(), Pace::AsFastAsPossible, "backwards");
    let mut f = Frame::blank();
    for _ in 0..3 {
        src.next_frame(&mut f).unwrap();
    }
    match src.next_frame(&mut f) {
        Err(SourceError::Fatal(m)) => assert!(m.contains("backwards at frame 3"), "{m}"),
        other => panic!("{other:?}"),
    }
    // The first timestamp after later ones (no underflow either).
    let mut first = press.clone();
    first.meta.timestamps_us = vec![500_000, 1, 2, 3, 4, 5];
    let mut src = RecordedSource::from_press(first, Pace::AsFastAsPossible, "first");
    src.next_frame(&mut f).unwrap();
    assert!(matches!(src.next_frame(&mut f), Err(SourceError::Fatal(_))));
    // On disk: refused when read.
    let dir = tempfile::tempdir().unwrap();
    let pdir = dir.path().join("p");
    telextiles_sim::recording::write_press(&pdir, &press).unwrap();
    match RecordedSource::open(&pdir, Pace::AsFastAsPossible) {
        Err(SourceError::Fatal(m)) => assert!(m.contains("timestamps go backwards"), "{m}"),
        Err(e) => panic!("{e}"),
        Ok(_) => panic!("opened a recording whose timestamps go backwards"),
    }
}

/// `replay:<dir>`: every recording under a directory, one after another
/// in sorted order, each first frame announcing its recording with the
/// recording's own reference; one stream whose timestamps keep increasing;
/// an unreadable recording skipped by name; looping; and a clear end when
/// nothing can be read.
#[test]
fn a_directory_of_recordings_replays_one_after_another_each_with_its_reference() {
    use telextiles_sensing::front::{recording_reference, References};
    use telextiles_sensing::source::recorded::RecordingsSource;
    let sim = telextiles_sim::Simulator::new().unwrap();
    let render = |t: &str, seed: u64, frames: usize| {
        let spec = telextiles_sim::PressSpec {
            frames,
            ..telextiles_sim::PressSpec::new(t, seed)
        };
        sim.render_press(&spec).unwrap()
    };
    let (a, b) = (render("T030", 3, 12), render("T045", 4, 10));
    assert_ne!(recording_reference(&a), recording_reference(&b));
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join("recordings");
    telextiles_sim::recording::write_press(&root.join("T030/0001"), &a).unwrap();
    telextiles_sim::recording::write_press(&root.join("T045/0001"), &b).unwrap();
    // A third recording whose metadata is corrupt: skipped, by name.
    telextiles_sim::recording::write_press(&root.join("T099/0001"), &a).unwrap();
    std::fs::write(root.join("T099/0001/press.json"), "{ not json").unwrap();

    let mut src = RecordingsSource::open(&root, Pace::AsFastAsPossible, References::none())
        .unwrap()
        .looping(true);
    assert_eq!(src.recordings().len(), 3);
    assert!(
        src.describe().contains("3 recordings"),
        "{}",
        src.describe()
    );
    let mut f = Frame::blank();
    let mut last_t: Option<u64> = None;
    // Two rounds: a, b, (the corrupt one), a, b.
    for round in 0..2 {
        for (press, name) in [(&a, "T030/0001"), (&b, "T045/0001")] {
            for (i, want) in press.frames.iter().enumerate() {
                src.next_frame(&mut f).unwrap();
                assert_eq!(f.image(), want, "round {round}, {name}, frame {i}");
                let t = f.timestamp_us();
                match (i, last_t) {
                    // Within a recording, its own spacing.
                    (1.., Some(l)) => assert_eq!(
                        t - l,
                        press.meta.timestamps_us[i] - press.meta.timestamps_us[i - 1]
                    ),
                    // Between recordings one frame period (60 fps).
                    (0, Some(l)) => assert_eq!(t - l, 16_667, "{name}"),
                    (_, None) => assert_eq!(t, 0),
                }
                last_t = Some(t);
                let announced = src.new_recording();
                if i == 0 {
                    let r = announced.unwrap_or_else(|| panic!("{name} not announced"));
                    assert!(r.name.ends_with(name), "{}", r.name);
                    assert_eq!(r.reference, recording_reference(press));
                    assert!(r.reference.is_some());
                } else {
                    assert_eq!(announced, None, "{name} frame {i}");
                }
            }
        }
        match src.next_frame(&mut f) {
            Err(SourceError::Skipped(m)) => assert!(m.contains("T099/0001"), "{m}"),
            other => panic!("{other:?}"),
        }
        assert_eq!(src.new_recording(), None);
    }

    // Without looping: the end after one round.
    let mut once = RecordingsSource::open(
        &root.join("T045"),
        Pace::AsFastAsPossible,
        References::none(),
    )
    .unwrap();
    let mut n = 0;
    while once.next_frame(&mut f).is_ok() {
        n += 1;
    }
    assert_eq!(n, b.frames.len());
    assert!(matches!(once.next_frame(&mut f), Err(SourceError::Ended)));

    // A press directory itself is one recording.
    let one = RecordingsSource::open(
        &root.join("T030/0001"),
        Pace::AsFastAsPossible,
        References::none(),
    )
    .unwrap();
    assert_eq!(one.recordings().len(), 1);

    // Real time: 22 frames of two recordings take 21 periods (350 ms).
    let mut paced = RecordingsSource::open(&root, Pace::RealTime, References::none()).unwrap();
    let t0 = std::time::Instant::now();
    for _ in 0..a.frames.len() + b.frames.len() {
        paced.next_frame(&mut f).unwrap();
    }
    assert!(
        t0.elapsed() >= Duration::from_millis(345),
        "{:?}",
        t0.elapsed()
    );

    // Nothing readable: each skipped, then a fatal error naming the directory.
    let bad = dir.path().join("bad");
    for k in ["x/0001", "y/0001"] {
        telextiles_sim::recording::write_press(&bad.join(k), &a).unwrap();
        std::fs::write(bad.join(k).join("press.json"), "[]").unwrap();
    }
    let mut src = RecordingsSource::open(&bad, Pace::AsFastAsPossible, References::none())
        .unwrap()
        .looping(true);
    for k in ["x/0001", "y/0001"] {
        match src.next_frame(&mut f) {
            Err(SourceError::Skipped(m)) => assert!(m.contains(k), "{m}"),
            other => panic!("{other:?}"),
        }
    }
    match src.next_frame(&mut f) {
        Err(SourceError::Fatal(m)) => {
            assert!(m.contains("none of its 2 recordings"), "{m}");
            assert!(m.contains("bad"), "{m}");
        }
        other => panic!("{other:?}"),
    }
    // A directory that does not exist.
    match RecordingsSource::open(
        &dir.path().join("nope"),
        Pace::AsFastAsPossible,
        References::none(),
    ) {
        Err(SourceError::Fatal(m)) => assert!(m.contains("nope"), "{m}"),
        Err(e) => panic!("{e}"),
        Ok(_) => panic!("opened a missing directory"),
    }
}

/// A PyTouch-style dataset replays as well; its sequences carry no
/// reference, so each is announced with the one given for its sensor (or
/// None: captured from its first frames, as from a camera).
#[test]
fn a_pytouch_dataset_replays_with_the_references_given_for_its_sensors() {
    use telextiles_sensing::front::{pixels_of, References};
    use telextiles_sensing::source::recorded::RecordingsSource;
    let sim = telextiles_sim::Simulator::new().unwrap();
    let spec = telextiles_sim::PressSpec {
        frames: 6,
        ..telextiles_sim::PressSpec::new("T030", 3)
    };
    let press = sim.render_press(&spec).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join("data");
    for (class, serial) in [("cotton", "D00001"), ("wool", "D00002")] {
        let d = root.join(class).join(serial);
        std::fs::create_dir_all(&d).unwrap();
        for (i, fr) in press.frames.iter().enumerate() {
            fr.save(d.join(format!("{i:04}.png"))).unwrap();
        }
    }
    let ref_png = dir.path().join("ref.png");
    let blank = RgbImage::from_pixel(FRAME_W, FRAME_H, Rgb([40, 60, 80]));
    blank.save(&ref_png).unwrap();
    let refs = References::from_args(&[format!("D00002={}", ref_png.display())]).unwrap();
    let mut src = RecordingsSource::open(&root, Pace::AsFastAsPossible, refs).unwrap();
    let mut f = Frame::blank();
    let mut announced = Vec::new();
    while src.next_frame(&mut f).is_ok() {
        if let Some(r) = src.new_recording() {
            announced.push(r);
        }
    }
    assert_eq!(announced.len(), 2);
    assert!(
        announced[0].name.ends_with("cotton/D00001"),
        "{}",
        announced[0].name
    );
    assert_eq!(announced[0].reference, None);
    assert!(
        announced[1].name.ends_with("wool/D00002"),
        "{}",
        announced[1].name
    );
    assert_eq!(announced[1].reference, Some(pixels_of(&blank)));

    // The frames' times: 60 fps for these 240x320 frames, unless a rate is
    // given (`replay_fps`); the second recording follows the first a
    // frame period after its last frame.
    let times = |fps: Option<f32>| -> Vec<u64> {
        let mut src = RecordingsSource::open(&root, Pace::AsFastAsPossible, References::none())
            .unwrap()
            .assume_fps(fps)
            .unwrap();
        let mut f = Frame::blank();
        let mut t = Vec::new();
        while src.next_frame(&mut f).is_ok() {
            t.push(f.timestamp_us());
        }
        t
    };
    let at_60: Vec<u64> = (0..12)
        .map(|i| (i as f64 * 1e6 / 60.0).round() as u64)
        .collect();
    assert_eq!(times(None), at_60);
    assert_eq!(
        times(Some(20.0)),
        (0..12).map(|i| i * 50_000).collect::<Vec<u64>>()
    );
    // Press directories carry their own times: a rate for them is refused.
    let presses = dir.path().join("presses");
    telextiles_sim::recording::write_press(&presses.join("T030/0001"), &press).unwrap();
    match RecordingsSource::open(&presses, Pace::AsFastAsPossible, References::none())
        .unwrap()
        .assume_fps(Some(30.0))
    {
        Err(SourceError::Fatal(m)) => {
            assert!(
                m.contains("T030/0001") && m.contains("press.json gives its timestamps"),
                "{m}"
            )
        }
        Err(e) => panic!("{e}"),
        Ok(_) => panic!("a rate was taken for press directories"),
    }
}

/// A DIGIT's LED control as the tests need it: it keeps what is written
/// (or, `ignores`, keeps its first value, as a control that silently fails
/// does), and can fail on write or read.
struct FakeLeds {
    value: i64,
    ignores: bool,
    write_fails: bool,
    read_fails: bool,
    writes: u32,
}

impl FakeLeds {
    fn new() -> FakeLeds {
        FakeLeds {
            value: 0,
            ignores: false,
            write_fails: false,
            read_fails: false,
            writes: 0,
        }
    }
}

impl telextiles_sensing::source::digit::LedControl for FakeLeds {
    fn write(&mut self, value: i64) -> std::io::Result<()> {
        self.writes += 1;
        if self.write_fails {
            return Err(std::io::Error::other("EIO"));
        }
        if !self.ignores {
            self.value = value;
        }
        Ok(())
    }
    fn read(&mut self) -> std::io::Result<i64> {
        if self.read_fails {
            return Err(std::io::Error::other("EINVAL"));
        }
        Ok(self.value)
    }
}

#[test]
fn led_settings_are_read_back_and_a_setting_that_did_not_take_is_an_error() {
    use telextiles_sensing::source::digit::set_led_checked;
    let led = LedIntensity { r: 15, g: 4, b: 0 };
    // Taken: read back equal.
    let mut ok = FakeLeds::new();
    set_led_checked(&mut ok, led, 200).unwrap();
    assert_eq!(ok.value, (15 << 8) | (4 << 4));
    // Old firmware: one level, 17 times the brightest colour.
    let mut old = FakeLeds::new();
    set_led_checked(&mut old, led, 100).unwrap();
    assert_eq!(old.value, 255);
    // Silently ignored: an error naming what was written and what reads back.
    let mut deaf = FakeLeds {
        value: 7,
        ignores: true,
        ..FakeLeds::new()
    };
    let e = set_led_checked(&mut deaf, led, 200)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("did not take") && e.contains("wrote 3904") && e.contains("reads back 7"),
        "{e}"
    );
    // A control that cannot be written or read back says which.
    let mut broken = FakeLeds {
        write_fails: true,
        ..FakeLeds::new()
    };
    assert!(set_led_checked(&mut broken, led, 200)
        .unwrap_err()
        .to_string()
        .contains("cannot set the LEDs"));
    let mut blind = FakeLeds {
        read_fails: true,
        ..FakeLeds::new()
    };
    assert!(set_led_checked(&mut blind, led, 200)
        .unwrap_err()
        .to_string()
        .contains("cannot read the control back"));
    // A level out of range is refused before anything is written.
    let mut untouched = FakeLeds::new();
    assert!(set_led_checked(&mut untouched, LedIntensity { r: 16, g: 0, b: 0 }, 200).is_err());
    assert_eq!(untouched.writes, 0);
}

/// A camera that streams at `fps` frames per second of its own clock while
/// its mode promises `asked`, watched as the DIGIT source watches itself.
struct SlowCamera {
    watch: telextiles_sensing::source::fps::FpsWatch,
    fps: f64,
    k: u64,
    notice: Option<String>,
}

impl FrameSource for SlowCamera {
    fn next_frame(&mut self, out: &mut Frame) -> Result<(), SourceError> {
        let t = (self.k as f64 * 1e6 / self.fps) as u64;
        out.set_time(t, self.k);
        self.k += 1;
        if let Some(m) = self.watch.push(t) {
            self.notice = Some(m);
        }
        Ok(())
    }
    fn describe(&self) -> String {
        "slow camera".into()
    }
    fn take_notice(&mut self) -> Option<String> {
        self.notice.take()
    }
}

#[test]
fn a_camera_below_its_rate_is_reported_through_the_resilient_source_once() {
    let mut src = Resilient::new(|| {
        Ok(Box::new(SlowCamera {
            watch: telextiles_sensing::source::fps::FpsWatch::new(25.0),
            fps: 16.0,
            k: 0,
            notice: None,
        }) as Box<dyn FrameSource>)
    });
    let mut f = Frame::blank();
    let mut notices = Vec::new();
    for _ in 0..16 * 10 {
        src.next_frame(&mut f).unwrap();
        notices.extend(src.take_notice());
    }
    assert_eq!(notices.len(), 1, "{notices:?}");
    assert!(
        notices[0].contains("16.0 fps of the 25 asked"),
        "{}",
        notices[0]
    );
    // Its frames keep their own times: nothing resampled.
    assert_eq!(f.timestamp_us(), (159.0 * 1e6 / 16.0) as u64);
}
