//! The frame every source delivers: 240 wide x 320 tall RGB, as
//! `digit-interface` returns DIGIT frames, with a capture timestamp.

use image::RgbImage;

/// Frame width in pixels (portrait orientation).
pub const FRAME_W: u32 = 240;
/// Frame height in pixels (portrait orientation).
pub const FRAME_H: u32 = 320;
/// Bytes in one RGB frame.
pub const FRAME_BYTES: usize = (FRAME_W * FRAME_H * 3) as usize;

/// One RGB frame, 240 wide x 320 tall, with its capture time. Valid by
/// construction: every way to make one or to change its pixels checks the
/// size, so nothing downstream checks it again.
#[derive(Clone, Debug, PartialEq)]
pub struct Frame {
    /// Pixels, row-major RGB u8, always 240x320.
    image: RgbImage,
    /// Capture time in microseconds on the source's clock (monotonic within a
    /// source; sources restart it at 0 where they have no clock of their own).
    timestamp_us: u64,
    /// Sequence number assigned by the source (counts delivered frames).
    seq: u64,
}

impl Default for Frame {
    fn default() -> Self {
        Frame::blank()
    }
}

impl Frame {
    /// A black frame of the right size.
    pub fn blank() -> Frame {
        Frame {
            image: RgbImage::new(FRAME_W, FRAME_H),
            timestamp_us: 0,
            seq: 0,
        }
    }

    /// Wrap an image after checking its size.
    pub fn new(image: RgbImage, timestamp_us: u64, seq: u64) -> Result<Frame, FrameError> {
        check_dims(image.width(), image.height())?;
        Ok(Frame {
            image,
            timestamp_us,
            seq,
        })
    }

    /// The pixels (always 240x320).
    pub fn image(&self) -> &RgbImage {
        &self.image
    }

    /// The capture time, µs on the source's clock.
    pub fn timestamp_us(&self) -> u64 {
        self.timestamp_us
    }

    /// The source's sequence number.
    pub fn seq(&self) -> u64 {
        self.seq
    }

    /// The pixels, taken out of the frame.
    pub fn into_image(self) -> RgbImage {
        self.image
    }

    /// Set the capture time and sequence number.
    pub fn set_time(&mut self, timestamp_us: u64, seq: u64) {
        self.timestamp_us = timestamp_us;
        self.seq = seq;
    }

    /// Replace the pixels with `image`, checked; on error the frame is
    /// left as it was.
    pub fn set_image(&mut self, image: RgbImage) -> Result<(), FrameError> {
        check_dims(image.width(), image.height())?;
        self.image = image;
        Ok(())
    }

    /// Copy `image`'s pixels in (no allocation), checked; on error the
    /// frame is left as it was.
    pub fn copy_image(&mut self, image: &RgbImage) -> Result<(), FrameError> {
        check_dims(image.width(), image.height())?;
        self.image.copy_from_slice(image.as_raw());
        Ok(())
    }

    /// Write the pixels in place with `f` (a decoder), then check the
    /// size: a writer that left another size gets an error and a black
    /// frame, never an invalid one.
    pub fn write<E>(&mut self, f: impl FnOnce(&mut RgbImage) -> Result<(), E>) -> Result<(), E>
    where
        E: From<FrameError>,
    {
        let r = f(&mut self.image);
        if let Err(e) = check_dims(self.image.width(), self.image.height()) {
            self.image = RgbImage::new(FRAME_W, FRAME_H);
            return Err(e.into());
        }
        r
    }
}

fn check_dims(w: u32, h: u32) -> Result<(), FrameError> {
    if (w, h) != (FRAME_W, FRAME_H) {
        return Err(FrameError::WrongSize {
            width: w,
            height: h,
        });
    }
    Ok(())
}

/// Why a frame was rejected.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum FrameError {
    /// Not 240 x 320.
    #[error("frame is {width}x{height}, expected {FRAME_W} wide x {FRAME_H} tall")]
    WrongSize {
        /// Width received.
        width: u32,
        /// Height received.
        height: u32,
    },
    /// Pixel buffer length does not match the size.
    #[error("frame buffer holds {got} bytes, expected {FRAME_BYTES}")]
    BadLength {
        /// Bytes received.
        got: usize,
    },
    /// A captured buffer could not be decoded.
    #[error("cannot decode captured buffer: {0}")]
    Decode(String),
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_frame_cannot_be_made_or_changed_into_another_size() {
        let small = RgbImage::new(320, 240);
        assert_eq!(
            Frame::new(small.clone(), 5, 1),
            Err(FrameError::WrongSize {
                width: 320,
                height: 240
            })
        );
        let mut f = Frame::new(
            RgbImage::from_pixel(FRAME_W, FRAME_H, image::Rgb([7, 8, 9])),
            5,
            1,
        )
        .expect("240x320");
        let before = f.clone();
        // Refused replacements leave the frame as it was.
        assert!(f.set_image(small.clone()).is_err());
        assert!(f.copy_image(&small).is_err());
        assert_eq!(f, before);
        // A writer that leaves another size: an error and a black frame of
        // the right size, never an invalid one.
        let r: Result<(), FrameError> = f.write(|img| {
            *img = RgbImage::new(10, 10);
            Ok(())
        });
        assert!(matches!(
            r,
            Err(FrameError::WrongSize {
                width: 10,
                height: 10
            })
        ));
        assert_eq!((f.image().width(), f.image().height()), (FRAME_W, FRAME_H));
        assert!(f.image().as_raw().iter().all(|&v| v == 0));
        // What it says it holds.
        f.set_time(42, 3);
        assert_eq!((f.timestamp_us(), f.seq()), (42, 3));
        let fresh = RgbImage::from_pixel(FRAME_W, FRAME_H, image::Rgb([1, 2, 3]));
        f.copy_image(&fresh).expect("same size");
        assert_eq!(f.image(), &fresh);
        assert_eq!(f.into_image(), fresh);
    }
}
