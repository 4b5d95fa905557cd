//! A simulated press seen by another sensor profile or mode: the simulator
//! renders 240x320 frames at the frame's scale (0.08 mm per pixel, a
//! DIGIT's QVGA); [`as_camera`] gives the same press the geometry and frame
//! rate of another camera — a DIGIT's VGA at 30 fps, a GelSight Mini's
//! 320x240 at 25 fps — as that camera would stream it (landscape, its own
//! pixel size), to be written as a press directory of camera images and
//! read back through the profile's mapping.
//!
//! What it shows and what it does not: the geometry (a smaller field, other
//! pixels, other timing) is the camera's; the optics (gel, lighting,
//! colour) stay the simulated DIGIT's, and a finer mode's pixels are
//! interpolated from the rendering, not rendered finer.

use telextiles_recording::profile::{Mode, SensorProfile};
use telextiles_recording::resample::camera_view;

use crate::{Press, SimError};

/// `press` as `profile`'s camera streaming `mode` would give it: each frame
/// seen at the camera's pixel size and orientation, sampled at the mode's
/// frame rate (the latest rendered frame at each of the camera's ticks),
/// with the metadata saying which sensor (its `sensor_profile`, the
/// frame-based indices of its parameters and its no-contact frames moved
/// to the new frames).
pub fn as_camera(press: &Press, profile: &SensorProfile, mode: Mode) -> Result<Press, SimError> {
    let mm = profile.mm_per_px(mode.width).ok_or_else(|| {
        SimError::InvalidSpec(format!(
            "the {} profile has no field of view to render at",
            profile.label
        ))
    })?;
    if !(mode.fps.is_finite() && mode.fps > 0.0) {
        return Err(SimError::InvalidSpec(format!("frame rate {}", mode.fps)));
    }
    let ts = &press.meta.timestamps_us;
    let last = ts.last().copied().unwrap_or(0);
    let period = 1e6 / mode.fps as f64;
    // The rendered frame each camera tick shows.
    let mut picks = Vec::new();
    let mut k = 0u64;
    loop {
        let t = (k as f64 * period).round() as u64;
        if t > last {
            break;
        }
        let i = ts.partition_point(|&x| x <= t).saturating_sub(1);
        picks.push((t, i));
        k += 1;
    }
    // The first new frame showing rendered frame `i` or later.
    let moved = |i: u32| {
        picks
            .iter()
            .position(|&(_, j)| j >= i as usize)
            .unwrap_or(picks.len()) as u32
    };
    let frames = picks
        .iter()
        .map(|&(_, i)| {
            camera_view(
                &press.frames[i],
                mode.width,
                mode.height,
                profile.landscape,
                mm,
            )
        })
        .collect();
    let mut meta = press.meta.clone();
    meta.fps = mode.fps;
    meta.timestamps_us = picks.iter().map(|&(t, _)| t).collect();
    meta.reference_frames = meta.reference_frames.map(moved);
    if let Some(p) = meta.params.as_mut() {
        p.contact_frame = moved(p.contact_frame);
        p.hold_frame = moved(p.hold_frame);
        p.release_frame = p.release_frame.map(moved);
    }
    meta.sensor_profile = telextiles_recording::profile_tag(profile);
    meta.mm_per_px = None;
    Ok(Press { meta, frames })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{PressSpec, Simulator};
    use telextiles_recording::profile::{DIGIT, GELSIGHT_MINI, UVC};

    #[test]
    fn a_press_takes_the_cameras_geometry_and_frame_rate() {
        let sim = Simulator::new().unwrap();
        let press = sim.render_press(&PressSpec::new("T030", 3)).unwrap();
        let gs = as_camera(&press, &GELSIGHT_MINI, GELSIGHT_MINI.modes[0]).unwrap();
        assert_eq!((gs.frames[0].width(), gs.frames[0].height()), (320, 240));
        assert_eq!(gs.meta.fps, 25.0);
        assert_eq!(gs.meta.timestamps_us[1], 40_000);
        // 2.5 s at 60 fps is 2.5 s at 25 fps.
        let n = gs.frames.len();
        assert!((62..=63).contains(&n), "{n}");
        assert_eq!(gs.meta.sensor_profile.as_deref(), Some("gelsight-mini"));
        let p = press.meta.params.as_ref().unwrap();
        let q = gs.meta.params.as_ref().unwrap();
        // Contact starts at the same time, give or take a camera frame.
        let t = |ts: &[u64], i: u32| ts[i as usize] as i64;
        assert!(
            (t(&gs.meta.timestamps_us, q.contact_frame)
                - t(&press.meta.timestamps_us, p.contact_frame))
            .abs()
                <= 40_000
        );
        let vga = as_camera(&press, &DIGIT, DIGIT.modes[2]).unwrap();
        assert_eq!((vga.frames[0].width(), vga.frames[0].height()), (640, 480));
        assert_eq!(vga.meta.fps, 30.0);
        assert!(as_camera(
            &press,
            &UVC,
            Mode {
                width: 640,
                height: 480,
                fps: 30.0
            }
        )
        .is_err());
    }
}
