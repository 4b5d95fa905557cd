//! Find DIGIT sensors by walking sysfs, as `digit-interface` does with pyudev
//! (`subsystem=video4linux, ID_MODEL=DIGIT`, then `ID_SERIAL_SHORT`).
//!
//! For every `/sys/class/video4linux/videoN` we resolve `device` (the USB
//! interface) and read the USB device's attributes one level up: `idVendor`,
//! `idProduct`, `product` (udev's `ID_MODEL`), `manufacturer` (`ID_VENDOR`),
//! `serial` (`ID_SERIAL_SHORT`) and `bcdDevice` (`ID_REVISION`). A node
//! matches when its USB id is 2833:0209 or its product is "DIGIT". Only
//! capture nodes (`index` 0) are returned; a DIGIT also exposes a metadata
//! node with `index` 1. Pure apart from reading the given directory tree, so
//! tests run it on fake trees.

use std::fs;
use std::path::{Path, PathBuf};

use super::SourceError;

/// USB vendor id of the DIGIT.
pub const DIGIT_VENDOR_ID: &str = "2833";
/// USB product id of the DIGIT.
pub const DIGIT_PRODUCT_ID: &str = "0209";
/// USB product string of the DIGIT.
pub const DIGIT_PRODUCT: &str = "DIGIT";

/// A DIGIT found in sysfs.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct DigitDevice {
    /// Device node, e.g. `/dev/video0`.
    pub node: PathBuf,
    /// Kernel name, e.g. `video0`.
    pub name: String,
    /// USB serial (`ID_SERIAL_SHORT`), e.g. `D20118`; empty if the device has none.
    pub serial: String,
    /// USB manufacturer string.
    pub manufacturer: String,
    /// USB product string (`DIGIT`).
    pub model: String,
    /// `bcdDevice` read as decimal digits, as digit-interface does with
    /// `int(ID_REVISION)`: firmware "0200" -> 200. Revisions below 200 have no
    /// per-colour LED control.
    pub revision: u32,
}

fn attr(dir: &Path, name: &str) -> Option<String> {
    fs::read_to_string(dir.join(name))
        .ok()
        .map(|s| s.trim().to_string())
}

/// All DIGIT capture nodes under `sysfs_root` (normally `/sys`), with device
/// nodes under `dev_root` (normally `/dev`), sorted by node name.
pub fn find_digits(sysfs_root: &Path, dev_root: &Path) -> Vec<DigitDevice> {
    let class = sysfs_root.join("class/video4linux");
    let Ok(rd) = fs::read_dir(&class) else {
        return Vec::new();
    };
    let mut out = Vec::new();
    for entry in rd.flatten() {
        let dir = entry.path();
        let name = entry.file_name().to_string_lossy().into_owned();
        if attr(&dir, "index").is_some_and(|i| i != "0") {
            continue;
        }
        // `device` links to the USB interface; its parent is the USB device.
        let Ok(iface) = fs::canonicalize(dir.join("device")) else {
            continue;
        };
        let Some(usb) = iface.parent() else {
            continue;
        };
        let vid = attr(usb, "idVendor").unwrap_or_default();
        let pid = attr(usb, "idProduct").unwrap_or_default();
        let model = attr(usb, "product").unwrap_or_default();
        let is_digit = (vid.eq_ignore_ascii_case(DIGIT_VENDOR_ID)
            && pid.eq_ignore_ascii_case(DIGIT_PRODUCT_ID))
            || model == DIGIT_PRODUCT;
        if !is_digit {
            continue;
        }
        out.push(DigitDevice {
            node: dev_root.join(&name),
            serial: attr(usb, "serial").unwrap_or_default(),
            manufacturer: attr(usb, "manufacturer").unwrap_or_default(),
            revision: attr(usb, "bcdDevice")
                .and_then(|r| r.parse().ok())
                .unwrap_or(0),
            model,
            name,
        });
    }
    out.sort_by_key(|d| natural_key(&d.name));
    out
}

/// A video capture device found in sysfs, whatever it is.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Camera {
    /// Device node, e.g. `/dev/video0`.
    pub node: PathBuf,
    /// Kernel name, e.g. `video0`.
    pub name: String,
    /// The V4L2 card name (`name` in sysfs).
    pub card: String,
    /// USB vendor and product ids (empty for a device not on USB).
    pub vendor_id: String,
    /// USB product id.
    pub product_id: String,
    /// USB product string.
    pub product: String,
    /// USB manufacturer string.
    pub manufacturer: String,
    /// USB serial, empty if it has none.
    pub serial: String,
}

/// Every video4linux capture node (`index` 0) under `sysfs_root`, with
/// its USB attributes where it is a USB device, sorted by node name: what
/// `telextilesd sensors` lists, so that a sensor the daemon does not
/// recognise can still be seen and named.
pub fn find_cameras(sysfs_root: &Path, dev_root: &Path) -> Vec<Camera> {
    let Ok(rd) = fs::read_dir(sysfs_root.join("class/video4linux")) else {
        return Vec::new();
    };
    let mut out = Vec::new();
    for entry in rd.flatten() {
        let dir = entry.path();
        let name = entry.file_name().to_string_lossy().into_owned();
        if attr(&dir, "index").is_some_and(|i| i != "0") {
            continue;
        }
        let usb = fs::canonicalize(dir.join("device"))
            .ok()
            .and_then(|iface| iface.parent().map(Path::to_path_buf));
        let usb_attr = |k: &str| usb.as_deref().and_then(|u| attr(u, k)).unwrap_or_default();
        out.push(Camera {
            node: dev_root.join(&name),
            card: attr(&dir, "name").unwrap_or_default(),
            vendor_id: usb_attr("idVendor"),
            product_id: usb_attr("idProduct"),
            product: usb_attr("product"),
            manufacturer: usb_attr("manufacturer"),
            serial: usb_attr("serial"),
            name,
        });
    }
    out.sort_by_key(|c| natural_key(&c.name));
    out
}

fn natural_key(name: &str) -> (String, u64) {
    let digits = name.trim_start_matches(|c: char| !c.is_ascii_digit());
    let prefix = &name[..name.len() - digits.len()];
    (prefix.to_string(), digits.parse().unwrap_or(u64::MAX))
}

/// The DIGIT with this serial (or the only/first one when `serial` is None).
/// Absent → [`SourceError::Unavailable`] naming what was found.
pub fn find_digit(
    sysfs_root: &Path,
    dev_root: &Path,
    serial: Option<&str>,
) -> Result<DigitDevice, SourceError> {
    let all = find_digits(sysfs_root, dev_root);
    let found = match serial {
        Some(s) => all.iter().find(|d| d.serial == s),
        None => all.first(),
    };
    match found {
        Some(d) => Ok(d.clone()),
        None => {
            let listed: Vec<String> = all
                .iter()
                .map(|d| format!("{} ({})", d.serial, d.node.display()))
                .collect();
            let want = serial.map_or("DIGIT found".to_string(), |s| {
                format!("DIGIT with serial {s}")
            });
            Err(SourceError::Unavailable(if listed.is_empty() {
                format!(
                    "no {want}: no video4linux device with USB id {DIGIT_VENDOR_ID}:{DIGIT_PRODUCT_ID} \
                     under {} (is the sensor plugged in?)",
                    sysfs_root.join("class/video4linux").display()
                )
            } else {
                format!("no {want}; connected DIGITs: {}", listed.join(", "))
            }))
        }
    }
}
