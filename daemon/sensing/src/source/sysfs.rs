//! Find cameras, and the sensor of a profile among them, by walking sysfs
//! (for a DIGIT as `digit-interface` does with pyudev:
//! `subsystem=video4linux, ID_MODEL=DIGIT`, then `ID_SERIAL_SHORT`).
//!
//! For every `/sys/class/video4linux/videoN` we resolve `device` (the USB
//! interface) and read the USB device's attributes one level up: `idVendor`,
//! `idProduct`, `product` (udev's `ID_MODEL`), `manufacturer` (`ID_VENDOR`),
//! `serial` (`ID_SERIAL_SHORT`) and `bcdDevice` (`ID_REVISION`). A node
//! is a profile's sensor when its USB ids or names match the profile's
//! ([`SensorProfile::matches`]; a DIGIT: 2833:0209 or "DIGIT"). Only
//! capture nodes (`index` 0) are returned; a DIGIT also exposes a metadata
//! node with `index` 1. Pure apart from reading the given directory tree, so
//! tests run it on fake trees.

use std::fs;
use std::path::{Path, PathBuf};

use telextiles_recording::profile::{SensorProfile, DIGIT};

use super::SourceError;

fn attr(dir: &Path, name: &str) -> Option<String> {
    fs::read_to_string(dir.join(name))
        .ok()
        .map(|s| s.trim().to_string())
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
    /// USB product string (`DIGIT`).
    pub product: String,
    /// USB manufacturer string.
    pub manufacturer: String,
    /// USB serial (`ID_SERIAL_SHORT`), e.g. `D20118`; empty if it has none.
    pub serial: String,
    /// `bcdDevice` read as decimal digits, as digit-interface does with
    /// `int(ID_REVISION)`: firmware "0200" -> 200 (0 if absent). DIGIT
    /// revisions below 200 have no per-colour LED control.
    pub revision: u32,
}

impl Camera {
    /// Whether it is `profile`'s sensor (any camera is a generic one).
    pub fn is(&self, profile: &SensorProfile) -> bool {
        (profile.usb_ids.is_empty() && profile.names.is_empty())
            || profile.matches(&self.vendor_id, &self.product_id, &self.product, &self.card)
    }
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
        // A DIGIT also exposes a metadata node, index 1.
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
            revision: usb_attr("bcdDevice").parse().unwrap_or(0),
            name,
        });
    }
    out.sort_by_key(|c| natural_key(&c.name));
    out
}

/// Sort key: `video2` before `video10`.
fn natural_key(name: &str) -> (String, u64) {
    let digits = name.trim_start_matches(|c: char| !c.is_ascii_digit());
    let prefix = &name[..name.len() - digits.len()];
    (prefix.to_string(), digits.parse().unwrap_or(u64::MAX))
}

/// All DIGIT capture nodes under `sysfs_root` (normally `/sys`), with device
/// nodes under `dev_root` (normally `/dev`), sorted by node name.
pub fn find_digits(sysfs_root: &Path, dev_root: &Path) -> Vec<Camera> {
    find_cameras(sysfs_root, dev_root)
        .into_iter()
        .filter(|c| c.is(&DIGIT))
        .collect()
}

/// The DIGIT with this serial (or the first one when `serial` is None).
/// Absent → [`SourceError::Unavailable`] naming what was found.
pub fn find_digit(
    sysfs_root: &Path,
    dev_root: &Path,
    serial: Option<&str>,
) -> Result<Camera, SourceError> {
    find_camera(sysfs_root, dev_root, &DIGIT, serial)
}

/// `profile`'s sensor: the one `select` names (its serial, its device node
/// such as `/dev/video2`, or its kernel name `video2`), else the first
/// found. A generic profile takes any camera. Absent →
/// [`SourceError::Unavailable`] naming what it looked for and what is
/// connected.
pub fn find_camera(
    sysfs_root: &Path,
    dev_root: &Path,
    profile: &SensorProfile,
    select: Option<&str>,
) -> Result<Camera, SourceError> {
    let all = find_cameras(sysfs_root, dev_root);
    let named = |c: &Camera, s: &str| c.serial == s || c.name == s || c.node == Path::new(s);
    let found = match select {
        // A device named by its node is taken whatever it looks like.
        Some(s) => all
            .iter()
            .find(|c| c.is(profile) && named(c, s))
            .or_else(|| all.iter().find(|c| c.node == Path::new(s) || c.name == s)),
        None => all.iter().find(|c| c.is(profile)),
    };
    if let Some(c) = found {
        return Ok(c.clone());
    }
    let mine: Vec<String> = all
        .iter()
        .filter(|c| c.is(profile))
        .map(|c| format!("{} ({})", c.serial, c.node.display()))
        .collect();
    let want = select.map_or(format!("{} found", profile.label), |s| {
        format!("{} {s}", profile.label)
    });
    let how = {
        let mut how: Vec<String> = profile
            .usb_ids
            .iter()
            .map(|(v, p)| format!("USB id {v}:{p}"))
            .collect();
        how.extend(profile.names.iter().map(|n| format!("named {n:?}")));
        if how.is_empty() {
            "no video capture device".to_string()
        } else {
            format!("no video4linux device with {}", how.join(" or "))
        }
    };
    Err(SourceError::Unavailable(if mine.is_empty() {
        format!(
            "no {want}: {how} under {} (is the sensor plugged in? `telextilesd sensors` lists what is)",
            sysfs_root.join("class/video4linux").display()
        )
    } else {
        format!("no {want}; connected: {}", mine.join(", "))
    }))
}

/// The built-in profile of the camera `select` names (serial, node or
/// kernel name), else of the first camera that has one: what `sensor =
/// camera` streams when no `sensor_profile` is given. A camera no
/// built-in profile knows is an error saying how to describe it.
pub fn identify_camera(
    cameras: &[Camera],
    select: Option<&str>,
) -> Result<(&'static SensorProfile, Camera), String> {
    let profile_of = |c: &Camera| {
        telextiles_recording::profile::identify(&c.vendor_id, &c.product_id, &c.product, &c.card)
    };
    let chosen = match select {
        Some(s) => cameras
            .iter()
            .find(|c| c.serial == s || c.name == s || c.node == Path::new(s)),
        None => cameras
            .iter()
            .find(|c| !profile_of(c).modes.is_empty())
            .or(cameras.first()),
    };
    let Some(c) = chosen else {
        return Err(match select {
            Some(s) => format!(
                "no camera {s}; connected: {}",
                if cameras.is_empty() {
                    "none".to_string()
                } else {
                    cameras
                        .iter()
                        .map(|c| c.node.display().to_string())
                        .collect::<Vec<_>>()
                        .join(", ")
                }
            ),
            None => {
                "no camera found (is the sensor plugged in? `telextilesd sensors` lists what is)"
                    .to_string()
            }
        });
    };
    let p = profile_of(c);
    if p.field_mm.is_none() {
        return Err(format!(
            "the camera on {} ({}) is none of the built-in sensors: set sensor_profile = \"uvc\" and its sensor_mm_per_px (docs/sensors.md)",
            c.node.display(),
            if c.product.is_empty() { &c.card } else { &c.product }
        ));
    }
    Ok((p, c.clone()))
}
