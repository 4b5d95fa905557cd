//! The on-disk press format: bit-exact round trip, PyTouch layout, and clear
//! errors naming the file on bad input.
use rand::{Rng, SeedableRng};
use std::path::{Path, PathBuf};
use telextiles_sim::recording::{
    self, read_frame, read_press, read_pytouch, write_press, RecordingError,
};
use telextiles_sim::{Press, PressSpec, RgbImage, Simulator};

fn small_press(sim: &Simulator) -> Press {
    sim.render_press(&PressSpec {
        frames: 6,
        jig: false,
        person: 2,
        ..PressSpec::new("T050", 5)
    })
    .unwrap()
}

fn msg(e: RecordingError) -> String {
    e.to_string()
}

#[test]
fn round_trip_is_bit_exact_and_atomic() {
    let sim = Simulator::new().unwrap();
    let press = small_press(&sim);
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("nested/press");
    write_press(&dir, &press).unwrap();
    let back = read_press(&dir).unwrap();
    assert_eq!(back, press);
    assert_eq!(back.meta.params, press.meta.params);
    // no temporary directories are left behind
    let left: Vec<_> = std::fs::read_dir(tmp.path().join("nested"))
        .unwrap()
        .collect();
    assert_eq!(left.len(), 1);
    // refuses to overwrite
    let e = write_press(&dir, &press).unwrap_err();
    assert!(msg(e).contains("already exists"));
    // a press with a wrong-size frame is refused before anything is written
    let mut bad = press.clone();
    bad.frames[2] = RgbImage::new(320, 240);
    let e = write_press(&tmp.path().join("bad"), &bad).unwrap_err();
    assert!(msg(e).contains("frame 2"));
    assert!(!tmp.path().join("bad").exists());
}

fn written(tmp: &Path) -> std::path::PathBuf {
    let sim = Simulator::new().unwrap();
    let dir = tmp.join("p");
    write_press(&dir, &small_press(&sim)).unwrap();
    dir
}

#[test]
fn corrupt_png_names_the_file() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = written(tmp.path());
    std::fs::write(dir.join("000003.png"), b"\x89PNG\r\n\x1a\nnot really").unwrap();
    let e = msg(read_press(&dir).unwrap_err());
    assert!(e.contains("000003.png") && e.contains("corrupt PNG"), "{e}");
    // truncated real PNG
    let bytes = std::fs::read(dir.join("000001.png")).unwrap();
    std::fs::write(dir.join("000001.png"), &bytes[..bytes.len() / 2]).unwrap();
    let e = msg(read_press(&dir).unwrap_err());
    assert!(e.contains("000001.png"), "{e}");
}

#[test]
fn wrong_frame_size_names_the_file() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = written(tmp.path());
    RgbImage::new(320, 240)
        .save(dir.join("000004.png"))
        .unwrap();
    let e = msg(read_press(&dir).unwrap_err());
    assert!(e.contains("000004.png") && e.contains("320x240"), "{e}");
}

#[test]
fn missing_or_malformed_metadata_names_the_file() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = written(tmp.path());
    let meta = dir.join("press.json");
    let good = std::fs::read_to_string(&meta).unwrap();
    std::fs::write(&meta, "{ \"format\": ").unwrap();
    let e = msg(read_press(&dir).unwrap_err());
    assert!(e.contains("press.json") && e.contains("malformed"), "{e}");
    std::fs::write(
        &meta,
        good.replace("\"format_version\": 1", "\"format_version\": 99"),
    )
    .unwrap();
    let e = msg(read_press(&dir).unwrap_err());
    assert!(e.contains("press.json") && e.contains("99"), "{e}");
    std::fs::write(&meta, good.replace("\"000002.png\"", "\"../000002.png\"")).unwrap();
    let e = msg(read_press(&dir).unwrap_err());
    assert!(e.contains("plain file name"), "{e}");
    std::fs::write(&meta, good.replace("\"000005.png\"", "\"000009.png\"")).unwrap();
    let e = msg(read_press(&dir).unwrap_err());
    assert!(e.contains("000009.png"), "{e}");
    std::fs::remove_file(&meta).unwrap();
    let e = msg(read_press(&dir).unwrap_err());
    assert!(e.contains("press.json"), "{e}");
}

#[test]
fn random_metadata_bytes_never_panic() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = written(tmp.path());
    let meta = dir.join("press.json");
    let good = std::fs::read(&meta).unwrap();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
    for _ in 0..300 {
        let mut b = good.clone();
        match rng.gen_range(0..3) {
            0 => {
                for _ in 0..rng.gen_range(1..8) {
                    let i = rng.gen_range(0..b.len());
                    b[i] = rng.gen();
                }
            }
            1 => b.truncate(rng.gen_range(0..b.len())),
            _ => b = (0..rng.gen_range(0..200)).map(|_| rng.gen()).collect(),
        }
        std::fs::write(&meta, &b).unwrap();
        if let Err(e) = read_press(&dir) {
            assert!(!e.to_string().is_empty());
        }
    }
    // random bytes as a frame
    std::fs::write(&meta, &good).unwrap();
    for _ in 0..50 {
        let b: Vec<u8> = (0..rng.gen_range(0..400)).map(|_| rng.gen()).collect();
        std::fs::write(dir.join("000000.png"), &b).unwrap();
        let e = read_press(&dir).unwrap_err();
        assert!(e.to_string().contains("000000.png"));
    }
}

#[test]
fn pytouch_layout_reads_and_names_bad_files() {
    let sim = Simulator::new().unwrap();
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path();
    let p = small_press(&sim);
    for (class, serial) in [
        ("cotton", "D20001"),
        ("cotton", "D20002"),
        ("wool", "D20001"),
    ] {
        let d = root.join(class).join(serial);
        std::fs::create_dir_all(&d).unwrap();
        for (i, f) in p.frames.iter().take(3).enumerate() {
            f.save(d.join(format!("frame_{i}.png"))).unwrap();
        }
        std::fs::write(d.join("notes.txt"), "ignored").unwrap();
    }
    let presses = read_pytouch(root).unwrap();
    assert_eq!(presses.len(), 3);
    assert_eq!(presses[0].meta.textile, "cotton");
    assert_eq!(presses[1].meta.sensor_serial.as_deref(), Some("D20002"));
    assert_eq!(presses[2].meta.textile, "wool");
    assert_eq!(presses[2].frames[1], p.frames[1]);
    assert_eq!(presses[0].meta.timestamps_us.len(), 3);
    std::fs::write(root.join("wool/D20001/frame_1.png"), b"garbage").unwrap();
    let e = read_pytouch(root).unwrap_err().to_string();
    assert!(e.contains("frame_1.png"), "{e}");
    let empty = tempfile::tempdir().unwrap();
    assert!(read_pytouch(empty.path()).is_err());
    assert!(recording::pytouch_index(&root.join("missing")).is_err());

    // The one walk every reader uses: the sequences as recordings, each
    // with its serial's unit (serials in sorted order) and directory;
    // press directories, where there are any, instead.
    std::fs::copy(
        root.join("wool/D20001/frame_0.png"),
        root.join("wool/D20001/frame_1.png"),
    )
    .unwrap();
    let recs = recording::find_recordings(root).unwrap();
    let units: Vec<(PathBuf, u32)> = recs
        .iter()
        .map(|r| match r {
            recording::Recording::Pytouch { unit, .. } => (r.path(), *unit),
            other => panic!("{other:?}"),
        })
        .collect();
    assert_eq!(
        units,
        vec![
            (root.join("cotton/D20001"), 0),
            (root.join("cotton/D20002"), 1),
            (root.join("wool/D20001"), 0),
        ]
    );
    let loaded = recs[1].load().unwrap();
    assert_eq!(loaded.meta.sensor, 1);
    assert_eq!(loaded.meta.reference_frames, None);
    assert_eq!(loaded.meta.source, "pytouch");
    write_press(&root.join("pressed/0001"), &p).unwrap();
    let recs = recording::find_recordings(root).unwrap();
    assert_eq!(
        recs,
        vec![recording::Recording::Press(root.join("pressed/0001"))]
    );
    assert_eq!(recs[0].load().unwrap(), p);
    for (bad, msg) in [
        (empty.path().to_path_buf(), "not a PyTouch layout"),
        (root.join("missing"), "not a directory"),
        (root.join("cotton/D20001/frame_0.png"), "not a directory"),
    ] {
        let e = recording::find_recordings(&bad).unwrap_err().to_string();
        assert!(e.contains(msg), "{}: {e}", bad.display());
    }
}

/// The image-folder layout `<class>/*.png` (no serial level): one sequence
/// per class from a sensor not named, beside other classes'
/// `<class>/<serial>` sequences. A class directory with both is refused.
#[test]
fn frames_directly_under_a_class_are_one_sequence_of_an_unnamed_sensor() {
    let sim = Simulator::new().unwrap();
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path();
    let p = small_press(&sim);
    for dir in [
        root.join("cotton"),
        root.join("wool"),
        root.join("yak/D20001"),
    ] {
        std::fs::create_dir_all(&dir).unwrap();
        for (i, f) in p.frames.iter().take(2).enumerate() {
            f.save(dir.join(format!("{i}.png"))).unwrap();
        }
    }
    let recs = recording::find_recordings(root).unwrap();
    let got: Vec<(PathBuf, Option<String>, String)> = recs
        .iter()
        .map(|r| {
            let m = r.load().unwrap().meta;
            (r.path(), m.sensor_serial, m.textile)
        })
        .collect();
    assert_eq!(
        got,
        vec![
            (root.join("cotton"), None, "cotton".to_string()),
            (root.join("wool"), None, "wool".to_string()),
            (
                root.join("yak/D20001"),
                Some("D20001".to_string()),
                "yak".to_string()
            ),
        ]
    );
    assert_eq!(recs[0].load().unwrap().frames, p.frames[..2].to_vec());
    // A stray image (a preview, a photo of the fabric) beside a class's
    // sensor directories is not read as one more press of that class: the
    // dataset is refused, naming the class directory, the image and the
    // sensor directories, by every reader.
    p.frames[0].save(root.join("yak/preview.png")).unwrap();
    for e in [
        recording::find_recordings(root).unwrap_err(),
        recording::find_recordings_at(root, Some(30.0)).unwrap_err(),
        recording::pytouch_index(root).unwrap_err(),
        read_pytouch(root).unwrap_err(),
    ] {
        let e = e.to_string();
        assert!(e.contains(&root.join("yak").display().to_string()), "{e}");
        assert!(e.contains("holds both frames (preview.png)"), "{e}");
        assert!(e.contains("(D20001/)"), "{e}");
        assert!(e.contains("not both"), "{e}");
    }
    std::fs::remove_file(root.join("yak/preview.png")).unwrap();
    assert_eq!(recording::find_recordings(root).unwrap(), recs);
    // A class directory holding neither frames nor sequences is no dataset.
    let empty = tempfile::tempdir().unwrap();
    std::fs::create_dir_all(empty.path().join("cotton")).unwrap();
    std::fs::write(empty.path().join("cotton/notes.txt"), "x").unwrap();
    let e = recording::find_recordings(empty.path())
        .unwrap_err()
        .to_string();
    assert!(e.contains("<class>/*.png"), "{e}");
}

/// Many tools number frames without zero padding (`frame_1.png`, …,
/// `frame_12.png`): a sequence's frames are taken with the numbers
/// compared as numbers, not as text (which would put frame 10 after
/// frame 1 and scramble the press).
#[test]
fn unpadded_frame_numbers_keep_the_frames_in_order() {
    use std::cmp::Ordering::*;
    use telextiles_sim::recording::frame_order;
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path().join("silk").join("D20001");
    std::fs::create_dir_all(&d).unwrap();
    // Frame k is a flat grey of level k, so the order can be read back.
    for k in 1..=12u8 {
        RgbImage::from_pixel(240, 320, image::Rgb([k, k, k]))
            .save(d.join(format!("frame_{k}.png")))
            .unwrap();
    }
    let recs = recording::find_recordings(tmp.path()).unwrap();
    let press = recs[0].load().unwrap();
    let levels: Vec<u8> = press.frames.iter().map(|f| f.as_raw()[0]).collect();
    assert_eq!(levels, (1..=12).collect::<Vec<u8>>());

    for (a, b, o) in [
        ("frame_2.png", "frame_10.png", Less),
        ("000009.png", "000010.png", Less),
        ("frame_10.png", "frame_10.png", Equal),
        ("a2b10.png", "a2b9.png", Greater),
        ("frame_007.png", "frame_7.png", Less),
        (
            "frame_99999999999999999999999.png",
            "frame_100000000000000000000000.png",
            Less,
        ),
        ("frame.png", "frame_1.png", Less),
        ("b1.png", "a2.png", Greater),
    ] {
        assert_eq!(frame_order(a, b), o, "{a} vs {b}");
        assert_eq!(frame_order(b, a), o.reverse(), "{b} vs {a}");
    }
}

/// Others' datasets often store DIGIT frames as JPEG: a PyTouch sequence
/// may be PNG or JPEG frames (the content decides, not the name), read to
/// within JPEG's loss; a press directory stays PNG only, read bit-exact.
#[test]
fn pytouch_frames_may_be_jpeg() {
    let sim = Simulator::new().unwrap();
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path();
    let p = small_press(&sim);
    let d = root.join("denim").join("D20001");
    std::fs::create_dir_all(&d).unwrap();
    for (i, f) in p.frames.iter().take(3).enumerate() {
        f.save(d.join(format!("frame_{i}.JPG"))).unwrap();
    }
    let recs = recording::find_recordings(root).unwrap();
    assert_eq!(recs.len(), 1);
    let loaded = recs[0].load().unwrap();
    assert_eq!(loaded.frames.len(), 3);
    for (got, want) in loaded.frames.iter().zip(&p.frames) {
        let n = got.as_raw().len() as f64;
        let mad: f64 = got
            .as_raw()
            .iter()
            .zip(want.as_raw())
            .map(|(&a, &b)| (a as f64 - b as f64).abs())
            .sum::<f64>()
            / n;
        assert!(mad < 6.0, "mean absolute difference {mad} DN (quality 75)");
    }
    // A JPEG named .png is read as what it is.
    std::fs::copy(d.join("frame_0.JPG"), root.join("named.png")).unwrap();
    let img = recording::read_image(&root.join("named.png")).unwrap();
    assert_eq!(img, loaded.frames[0]);
    // ...but a press directory's frames must be PNG.
    let e = read_frame(&root.join("named.png")).unwrap_err().to_string();
    assert!(e.contains("corrupt PNG"), "{e}");
    // Neither PNG nor JPEG; a grey JPEG; a landscape JPEG.
    std::fs::write(root.join("text.jpg"), "frame").unwrap();
    let e = recording::read_image(&root.join("text.jpg"))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("text.jpg") && e.contains("neither a PNG nor a JPEG"),
        "{e}"
    );
    image::GrayImage::new(240, 320)
        .save(root.join("grey.jpg"))
        .unwrap();
    let e = recording::read_image(&root.join("grey.jpg"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("expected 8-bit RGB"), "{e}");
    RgbImage::new(300, 200).save(root.join("odd.jpg")).unwrap();
    let e = recording::read_image(&root.join("odd.jpg"))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("odd.jpg") && e.contains("cannot map a 300x200 image"),
        "{e}"
    );
}

/// Others' frames at the other sizes a DIGIT gives (the camera's landscape
/// QVGA and VGA, portrait VGA) are mapped to the portrait frame as the
/// live source maps the camera's stream; a press directory's frames must
/// be the frame itself.
#[test]
fn others_frames_are_mapped_to_the_portrait_frame_as_the_camera_stream_is() {
    let sim = Simulator::new().unwrap();
    let frame = small_press(&sim).frames[0].clone();
    // The camera's landscape view: camera pixel (319 - y, x) is frame
    // pixel (x, y) (digit-interface turns it 90 degrees counter-clockwise).
    let mut land = RgbImage::new(320, 240);
    for y in 0..320 {
        for x in 0..240 {
            land.put_pixel(319 - y, x, *frame.get_pixel(x, y));
        }
    }
    let land_vga = RgbImage::from_fn(640, 480, |x, y| *land.get_pixel(x / 2, y / 2));
    let portrait_vga = RgbImage::from_fn(480, 640, |x, y| *frame.get_pixel(x / 2, y / 2));
    let tmp = tempfile::tempdir().unwrap();
    for (name, img) in [
        ("qvga-landscape.png", &land),
        ("vga-landscape.png", &land_vga),
        ("vga-portrait.png", &portrait_vga),
        ("frame.png", &frame),
    ] {
        let path = tmp.path().join(name);
        img.save(&path).unwrap();
        assert_eq!(recording::read_image(&path).unwrap(), frame, "{name}");
    }
    // VGA is averaged over 2x2 blocks, rounded.
    let mut out = RgbImage::new(1, 1);
    let mut vga = vec![0u8; 480 * 640 * 3];
    vga[..3].copy_from_slice(&[10, 20, 30]);
    vga[3..6].copy_from_slice(&[11, 20, 31]);
    recording::to_frame(&vga, 480, 640, &mut out).unwrap();
    assert_eq!((out.width(), out.height()), (240, 320));
    assert_eq!(out.get_pixel(0, 0).0, [5, 10, 15]);
    let e = recording::to_frame(&vga[..30], 480, 640, &mut out).unwrap_err();
    assert!(e.contains("30 bytes"), "{e}");
    // A press directory's frame is read as it is, or refused.
    let e = read_frame(&tmp.path().join("qvga-landscape.png"))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("frame is 320x240, expected 240x320") && e.contains("counter-clockwise"),
        "{e}"
    );
}

/// A sequence saved without timestamps is spaced at the DIGIT's stream
/// rate for the size it was saved at (QVGA 60 fps, VGA 30 fps), or at the
/// rate given for it; press directories keep their own timestamps and
/// refuse a rate given for them.
#[test]
fn frames_without_timestamps_take_the_streams_rate_or_the_one_given() {
    let sim = Simulator::new().unwrap();
    let p = small_press(&sim);
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path().join("data");
    for (serial, vga) in [("D1", false), ("D2", true)] {
        let d = root.join("cotton").join(serial);
        std::fs::create_dir_all(&d).unwrap();
        for (i, f) in p.frames.iter().take(4).enumerate() {
            let img = if vga {
                RgbImage::from_fn(480, 640, |x, y| *f.get_pixel(x / 2, y / 2))
            } else {
                f.clone()
            };
            img.save(d.join(format!("{i}.png"))).unwrap();
        }
    }
    let rates = |recs: &[recording::Recording]| -> Vec<(f32, Vec<u64>)> {
        recs.iter()
            .map(|r| {
                let m = r.load().unwrap().meta;
                (m.fps, m.timestamps_us)
            })
            .collect()
    };
    let recs = recording::find_recordings_at(&root, None).unwrap();
    assert_eq!(recs, recording::find_recordings(&root).unwrap());
    assert_eq!(
        rates(&recs),
        vec![
            (60.0, vec![0, 16_667, 33_333, 50_000]),
            (30.0, vec![0, 33_333, 66_667, 100_000]),
        ]
    );
    let given = recording::find_recordings_at(&root, Some(25.0)).unwrap();
    assert_eq!(
        rates(&given),
        vec![(25.0, vec![0, 40_000, 80_000, 120_000]); 2]
    );
    // The frames are the same whatever the rate.
    assert_eq!(
        given[1].load().unwrap().frames,
        recs[1].load().unwrap().frames
    );

    // Press directories carry timestamps: a rate given for them is refused.
    write_press(&tmp.path().join("presses/0001"), &p).unwrap();
    let e =
        msg(recording::find_recordings_at(&tmp.path().join("presses"), Some(30.0)).unwrap_err());
    assert!(
        e.contains("0001") && e.contains("press.json gives its timestamps"),
        "{e}"
    );
    assert_eq!(
        recording::find_recordings_at(&tmp.path().join("presses"), None)
            .unwrap()
            .len(),
        1
    );

    // The flag's parser.
    assert_eq!(recording::parse_fps("30").unwrap(), 30.0);
    assert_eq!(recording::parse_fps(" 29.97 ").unwrap(), 29.97);
    for bad in ["0", "-5", "nan", "inf", "1001", "fast", ""] {
        assert!(recording::parse_fps(bad).is_err(), "{bad}");
    }
    assert!(recording::parse_fps("fast")
        .unwrap_err()
        .contains("not a frame rate"));
    assert!(recording::parse_fps("0")
        .unwrap_err()
        .contains("out of range"));
}

/// Hidden entries are never recordings: a notebook's
/// `.ipynb_checkpoints` would read as one more sensor, the `._frame.png`
/// files a Mac leaves beside copied frames are not PNGs, and a `.git`
/// directory may hold anything, a press directory included.
#[test]
fn hidden_files_and_directories_are_not_recordings() {
    let sim = Simulator::new().unwrap();
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path();
    let p = small_press(&sim);
    for serial in ["D20001", ".ipynb_checkpoints"] {
        let d = root.join("cotton").join(serial);
        std::fs::create_dir_all(&d).unwrap();
        for (i, f) in p.frames.iter().take(3).enumerate() {
            f.save(d.join(format!("frame_{i}.png"))).unwrap();
            std::fs::write(d.join(format!("._frame_{i}.png")), b"\0\x05\x16\x07").unwrap();
        }
    }
    std::fs::create_dir_all(root.join(".trash/D20001")).unwrap();
    p.frames[0]
        .save(root.join(".trash/D20001/frame_0.png"))
        .unwrap();
    let recs = recording::find_recordings(root).unwrap();
    assert_eq!(recs.len(), 1, "{recs:?}");
    let loaded = recs[0].load().unwrap();
    assert_eq!(loaded.frames.len(), 3);
    assert_eq!(loaded.meta.sensor_serial.as_deref(), Some("D20001"));
    assert_eq!(read_pytouch(root).unwrap().len(), 1);

    // Press directories: one under .git is not searched.
    write_press(&root.join("presses/0001"), &p).unwrap();
    write_press(&root.join("presses/.git/0002"), &p).unwrap();
    let recs = recording::find_recordings(root).unwrap();
    assert_eq!(
        recs,
        vec![recording::Recording::Press(root.join("presses/0001"))]
    );
    // The root itself may be hidden.
    let hidden_root = root.join("presses/.git");
    assert_eq!(recording::find_recordings(&hidden_root).unwrap().len(), 1);
}

/// `find_presses`: recursive, sorted, follows symlinked directories (a
/// user's split of recordings into index and query sets), skips unfinished
/// writes, and survives a link loop.
#[test]
fn find_presses_follows_links_and_skips_unfinished_writes() {
    use telextiles_sim::recording::{find_presses, write_press};
    let sim = telextiles_sim::Simulator::new().unwrap();
    let press = sim
        .render_press(&telextiles_sim::PressSpec {
            frames: 3,
            ..telextiles_sim::PressSpec::new("T030", 1)
        })
        .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("rec");
    for p in ["T030/0002", "T030/0001", "T110/0001"] {
        write_press(&rec.join(p), &press).unwrap();
    }
    std::fs::create_dir_all(rec.join("T030/0003.tmp-1-0")).unwrap();
    std::fs::write(rec.join("T030/0003.tmp-1-0/press.json"), "{}").unwrap();
    let split = dir.path().join("split/T030");
    std::fs::create_dir_all(&split).unwrap();
    std::os::unix::fs::symlink(rec.join("T030/0001"), split.join("a")).unwrap();
    std::os::unix::fs::symlink(dir.path().join("split"), split.join("loop")).unwrap();
    let found = find_presses(&rec).unwrap();
    let rel: Vec<_> = found
        .iter()
        .map(|p| p.strip_prefix(&rec).unwrap().to_path_buf())
        .collect();
    assert_eq!(
        rel,
        ["T030/0001", "T030/0002", "T110/0001"].map(std::path::PathBuf::from)
    );
    let linked = find_presses(&dir.path().join("split")).unwrap();
    assert_eq!(linked.len(), 1, "{linked:?}");
    assert!(linked[0].ends_with("T030/a"), "{linked:?}");
    assert!(find_presses(&dir.path().join("nope")).is_err());
}
