//! The frame every source delivers: 240 wide x 320 tall RGB, as
//! `digit-interface` returns DIGIT frames, with a capture timestamp.

use image::RgbImage;

/// Frame width in pixels (portrait orientation).
pub const FRAME_W: u32 = 240;
/// Frame height in pixels (portrait orientation).
pub const FRAME_H: u32 = 320;
/// Bytes in one RGB frame.
pub const FRAME_BYTES: usize = (FRAME_W * FRAME_H * 3) as usize;

/// One RGB frame, 240 wide x 320 tall, with its capture time.
#[derive(Clone, Debug, PartialEq)]
pub struct Frame {
    /// Pixels, row-major RGB u8.
    pub image: RgbImage,
    /// Capture time in microseconds on the source's clock (monotonic within a
    /// source; sources restart it at 0 where they have no clock of their own).
    pub timestamp_us: u64,
    /// Sequence number assigned by the source (counts delivered frames).
    pub seq: u64,
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

    /// Whether the frame has the size the pipeline expects.
    pub fn check(&self) -> Result<(), FrameError> {
        check_dims(self.image.width(), self.image.height())?;
        if self.image.as_raw().len() != FRAME_BYTES {
            return Err(FrameError::BadLength {
                got: self.image.as_raw().len(),
            });
        }
        Ok(())
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
