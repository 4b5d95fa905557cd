//! `telextilesd sensors`: the optical tactile sensors plugged in — every
//! video capture device, the profile it matches
//! (`telextiles_recording::profile`, `docs/sensors.md`), the modes that
//! profile streams and the millimetres per pixel of each. A camera no
//! profile knows is listed too, as a generic UVC camera, so that a sensor
//! the OS names differently can still be seen and named.

use std::io::Write;
use std::path::PathBuf;

use anyhow::Result;
use serde_json::json;
use telextiles_recording::profile::{self, SensorProfile};
use telextiles_sensing::source::sysfs::{find_cameras, Camera};

/// `telextilesd sensors`
#[derive(clap::Args, Debug)]
pub struct Args {
    /// One JSON object per camera (one per line) instead of text.
    #[arg(long)]
    pub json: bool,
    /// Where sysfs is (tests use a tree of their own).
    #[arg(long, default_value = "/sys", hide = true)]
    pub sysfs: PathBuf,
    /// Where the device nodes are.
    #[arg(long, default_value = "/dev", hide = true)]
    pub dev: PathBuf,
}

/// Run the command, printing to stdout.
pub fn run(a: Args) -> Result<()> {
    run_to(&a, &mut crate::out::stdout())
}

/// Run the command, printing to `out`.
pub fn run_to(a: &Args, out: &mut dyn Write) -> Result<()> {
    let cameras = find_cameras(&a.sysfs, &a.dev);
    if cameras.is_empty() && !a.json {
        writeln!(
            out,
            "no video capture device under {} (is the sensor plugged in? docs/sensors.md)",
            a.sysfs.join("class/video4linux").display()
        )?;
    }
    for c in &cameras {
        let p = profile::identify(&c.vendor_id, &c.product_id, &c.product, &c.card);
        if a.json {
            writeln!(out, "{}", json_line(c, p))?;
        } else {
            write_text(out, c, p)?;
        }
    }
    Ok(())
}

fn modes(p: &SensorProfile) -> Vec<String> {
    p.modes
        .iter()
        .map(|m| {
            let scale = p
                .mm_per_px(m.width)
                .map(|s| format!(", {s:.4} mm/px"))
                .unwrap_or_default();
            format!("{}{scale}", m.text())
        })
        .collect()
}

fn write_text(out: &mut dyn Write, c: &Camera, p: &SensorProfile) -> std::io::Result<()> {
    let usb = if c.vendor_id.is_empty() {
        "not USB".to_string()
    } else {
        format!("USB {}:{}", c.vendor_id, c.product_id)
    };
    let serial = if c.serial.is_empty() {
        String::new()
    } else {
        format!(", serial {}", c.serial)
    };
    writeln!(
        out,
        "{}: {} (profile {}), {usb}{serial}, card {:?}",
        c.node.display(),
        p.label,
        p.name,
        c.card
    )?;
    if p.modes.is_empty() {
        writeln!(
            out,
            "  no built-in profile knows this camera; the daemon reads DIGIT-shaped streams (320x240 or 640x480) today (docs/sensors.md)"
        )?;
    } else {
        writeln!(out, "  modes: {}", modes(p).join("; "))?;
        writeln!(
            out,
            "  LEDs: {}",
            if p.leds {
                "R/G/B, set with `telextilesd ctl sensor led`"
            } else {
                "none the daemon sets"
            }
        )?;
    }
    Ok(())
}

fn json_line(c: &Camera, p: &SensorProfile) -> serde_json::Value {
    json!({
        "node": c.node.display().to_string(),
        "card": c.card,
        "usb": (!c.vendor_id.is_empty()).then(|| format!("{}:{}", c.vendor_id, c.product_id)),
        "product": c.product,
        "manufacturer": c.manufacturer,
        "serial": (!c.serial.is_empty()).then(|| c.serial.clone()),
        "profile": p.name,
        "leds": p.leds,
        "modes": p.modes.iter().map(|m| json!({
            "width": m.width, "height": m.height, "fps": m.fps,
            "mm_per_px": p.mm_per_px(m.width),
        })).collect::<Vec<_>>(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::os::unix::fs::symlink;
    use std::path::Path;

    fn write(p: &Path, v: &str) {
        std::fs::create_dir_all(p.parent().unwrap()).unwrap();
        std::fs::write(p, v).unwrap();
    }

    /// A USB camera in a fake sysfs tree: its capture node (index 0) and
    /// metadata node (index 1), the interface they link to, the USB
    /// device's attributes one level up.
    fn camera(root: &Path, usb: &str, node: u32, card: &str, attrs: &[(&str, &str)]) {
        let dev = root.join("devices/pci0000:00/usb1").join(usb);
        for (k, v) in attrs {
            write(&dev.join(k), v);
        }
        let iface = dev.join(format!("{usb}:1.0"));
        std::fs::create_dir_all(&iface).unwrap();
        for (k, index) in [(node, "0"), (node + 1, "1")] {
            let class = root.join("class/video4linux").join(format!("video{k}"));
            write(&class.join("index"), index);
            write(&class.join("name"), card);
            symlink(&iface, class.join("device")).unwrap();
        }
    }

    fn listing(root: &Path, json: bool) -> String {
        let a = Args {
            json,
            sysfs: root.to_path_buf(),
            dev: PathBuf::from("/dev"),
        };
        let mut out = Vec::new();
        run_to(&a, &mut out).unwrap();
        String::from_utf8(out).unwrap()
    }

    #[test]
    fn every_camera_is_listed_with_its_profile_modes_and_scale() {
        let t = tempfile::tempdir().unwrap();
        camera(
            t.path(),
            "1-1",
            0,
            "DIGIT: DIGIT",
            &[
                ("idVendor", "2833"),
                ("idProduct", "0209"),
                ("product", "DIGIT"),
                ("serial", "D20118"),
            ],
        );
        camera(
            t.path(),
            "1-2",
            2,
            "GelSight Mini R0B 2BG8-LLT0: Ge",
            &[
                ("idVendor", "1234"),
                ("idProduct", "5678"),
                ("product", "GelSight Mini R0B 2BG8-LLT0"),
            ],
        );
        camera(
            t.path(),
            "1-3",
            10,
            "UVC Camera (046d:0825)",
            &[
                ("idVendor", "046d"),
                ("idProduct", "0825"),
                ("product", "Webcam C270"),
            ],
        );
        let text = listing(t.path(), false);
        let lines: Vec<&str> = text.lines().collect();
        // In node order, metadata nodes left out.
        assert!(
            lines[0]
                .starts_with("/dev/video0: DIGIT (profile digit), USB 2833:0209, serial D20118"),
            "{text}"
        );
        assert!(
            lines[1].contains("320x240 @ 60 fps, 0.0800 mm/px")
                && lines[1].contains("640x480 @ 15 fps, 0.0400 mm/px"),
            "{text}"
        );
        assert!(lines[2].contains("R/G/B"), "{text}");
        assert!(
            lines[3]
                .starts_with("/dev/video2: GelSight Mini (profile gelsight-mini), USB 1234:5678"),
            "{text}"
        );
        assert!(
            lines[4].contains("320x240 @ 25 fps, 0.0590 mm/px"),
            "{text}"
        );
        assert!(
            lines[6].starts_with("/dev/video10: UVC camera (profile uvc)"),
            "{text}"
        );
        assert!(lines[7].contains("no built-in profile"), "{text}");
        assert_eq!(lines.len(), 8, "{text}");
        assert!(
            !text.contains("video1:") && !text.contains("video3:"),
            "{text}"
        );
        // The same as JSON, one object per camera.
        let json: Vec<serde_json::Value> = listing(t.path(), true)
            .lines()
            .map(|l| serde_json::from_str(l).unwrap())
            .collect();
        assert_eq!(json.len(), 3);
        assert_eq!(json[0]["profile"], "digit");
        assert_eq!(json[0]["serial"], "D20118");
        assert_eq!(json[1]["modes"][0]["fps"], 25.0);
        assert!(json[2]["modes"].as_array().unwrap().is_empty());
    }

    #[test]
    fn nothing_plugged_in_says_where_it_looked() {
        let t = tempfile::tempdir().unwrap();
        let text = listing(t.path(), false);
        assert!(text.starts_with("no video capture device under "), "{text}");
        assert!(text.contains("class/video4linux"), "{text}");
        assert_eq!(listing(t.path(), true), "");
    }
}
