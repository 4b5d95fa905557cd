//! Camera pixels to the frame at one physical scale: [`FrameMap`] maps an
//! RGB image as a sensor streams it (any profile, any mode) to the 240x320
//! portrait frame at [`FRAME_MM_PER_PX`], the scale the encoder reads.
//!
//! - **Orientation**: a landscape camera's image is turned 90 degrees
//!   counter-clockwise, as digit-interface turns DIGIT frames
//!   (`cv2.transpose` then `cv2.flip(frame, 0)`): frame pixel (x, y) =
//!   camera pixel (W-1-y, x). An image already portrait is taken as it is.
//! - **Scale**: each frame pixel is the area average of the camera pixels
//!   it covers (a box filter the size of a frame pixel, so a 2x finer
//!   camera is averaged over exact 2x2 blocks); a coarser camera is
//!   sampled bilinearly. Centres are aligned: the camera's field sits in
//!   the middle of the frame.
//! - **A field smaller than the frame** (a GelSight Mini's 14.2 x 18.9 mm
//!   against the frame's 19.2 x 25.6 mm) fills [`FrameMap::valid`], and
//!   the rest of the frame is its mirror image (reflected at the field's
//!   edges): the contact detector and the encoder see texture all over,
//!   no hard edge, no constant band that an exposure change would light
//!   up; the coverage a press reaches is then that of the field, mirrored.
//!   A larger field is cropped to the frame's centre.
//!
//! The DIGIT's own modes take fast paths: QVGA is a turn (a copy), VGA a
//! turn and a 2x2 mean (rounded half up), bit for bit as before profiles
//! existed. Any other scale is two separable passes in integers (weights
//! in 1/256, each pass rounded to a level, so within a level of the exact
//! mean): whole image rows are summed (which vectorises), the result
//! transposed, and its rows summed again. Every table and buffer is made
//! once, in [`FrameMap::new`]; mapping a frame allocates nothing. Its cost
//! per profile and mode: `cargo bench -p telextiles-recording --bench
//! resample`.

use crate::profile::{Mode, SensorProfile, FRAME_MM_PER_PX};
use crate::{HEIGHT, WIDTH};

/// A rectangle of the frame, in pixels.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct Rect {
    /// Left column.
    pub x: u32,
    /// Top row.
    pub y: u32,
    /// Width.
    pub w: u32,
    /// Height.
    pub h: u32,
}

impl Rect {
    /// The whole 240x320 frame.
    pub const FULL: Rect = Rect {
        x: 0,
        y: 0,
        w: WIDTH,
        h: HEIGHT,
    };
}

/// The camera taps of every output coordinate along one axis (`k` per
/// output, unused ones with weight 0).
#[derive(Clone, Debug)]
struct Axis {
    k: usize,
    idx: Vec<u32>,
    w: Vec<f32>,
}

impl Axis {
    /// Taps mapping `n_src` camera pixels to `n_out` frame pixels, `f`
    /// camera pixels per frame pixel, centres aligned; and the range of
    /// outputs the camera's field covers. Outputs outside it take the
    /// taps of their mirror image inside it.
    fn new(n_src: u32, n_out: u32, f: f64) -> Result<(Axis, std::ops::Range<u32>), String> {
        let k = if f > 1.0 { f.ceil() as usize + 1 } else { 2 };
        let (cs, cf) = (n_src as f64 / 2.0, n_out as f64 / 2.0);
        let mut taps: Vec<Option<Vec<(u32, f32)>>> = Vec::with_capacity(n_out as usize);
        for o in 0..n_out {
            let o = o as f64;
            if f >= 1.0 {
                // The frame pixel's interval in camera pixels, within the field.
                let a = (cs + (o - cf) * f).max(0.0);
                let b = (cs + (o + 1.0 - cf) * f).min(n_src as f64);
                if b - a < 0.5 * f {
                    taps.push(None);
                    continue;
                }
                let mut t = Vec::with_capacity(k);
                let mut i = a.floor();
                while i < b {
                    let overlap = b.min(i + 1.0) - a.max(i);
                    if overlap > 1e-9 {
                        t.push((i as u32, (overlap / (b - a)) as f32));
                    }
                    i += 1.0;
                }
                taps.push(Some(t));
            } else {
                // Bilinear at the frame pixel's centre.
                let c = cs + (o + 0.5 - cf) * f;
                if !(0.0..=n_src as f64).contains(&c) {
                    taps.push(None);
                    continue;
                }
                let u = (c - 0.5).clamp(0.0, (n_src - 1) as f64);
                let i0 = u.floor();
                let w = (u - i0) as f32;
                let i1 = (i0 as u32 + 1).min(n_src - 1);
                taps.push(Some(vec![(i0 as u32, 1.0 - w), (i1, w)]));
            }
        }
        let first = taps.iter().position(Option::is_some);
        let last = taps.iter().rposition(Option::is_some);
        let (Some(first), Some(last)) = (first, last) else {
            return Err(format!(
                "{n_src} camera pixels cover no pixel of the frame at this scale"
            ));
        };
        let valid = first as u32..last as u32 + 1;
        let k = taps
            .iter()
            .flatten()
            .map(Vec::len)
            .max()
            .unwrap_or(1)
            .clamp(1, k);
        let mut idx = vec![0u32; n_out as usize * k];
        let mut w = vec![0f32; n_out as usize * k];
        for o in 0..n_out as usize {
            let src = mirror(o as i64, first as i64, last as i64 + 1);
            if let Some(t) = &taps[src] {
                for (j, &(i, wt)) in t.iter().take(k).enumerate() {
                    idx[o * k + j] = i;
                    w[o * k + j] = wt;
                }
                // Unused taps point at the first one, weight 0.
                for j in t.len().min(k)..k {
                    idx[o * k + j] = t[0].0;
                }
            }
        }
        Ok((Axis { k, idx, w }, valid))
    }
}

/// `o` reflected into `[a, b)` (a-1 → a, b → b-1, ...).
fn mirror(mut o: i64, a: i64, b: i64) -> usize {
    while o < a || o >= b {
        if o < a {
            o = 2 * a - 1 - o;
        }
        if o >= b {
            o = 2 * b - 1 - o;
        }
        if b - a == 1 {
            o = a;
        }
    }
    o as usize
}

#[derive(Clone, Debug)]
enum Path {
    /// Same scale and size: a copy (turned or not).
    Copy,
    /// Exactly half the size (the DIGIT's VGA): the 2x2 mean, rounded
    /// half up, exact; `a` holds the sums of row pairs.
    Half { a: Vec<u16> },
    /// Anything else: the separable resampling.
    General(Box<General>),
}

/// The separable resampling, in the image's own rows (R) and columns
/// (C): pass A combines image rows (a weighted sum of whole rows, which
/// vectorises), the result is transposed, pass B combines what were
/// columns the same way. Turned, R is the frame's x and C its y
/// (reversed), so pass B writes frame rows; not turned, R is y and C is x
/// and a last transpose gives the frame.
#[derive(Clone, Debug)]
struct General {
    /// Taps over image rows for the outputs along R's frame axis.
    r_axis: Axis,
    r_w: Vec<u16>,
    r_valid: std::ops::Range<u32>,
    /// Taps over image columns (already in C) for the outputs along C's
    /// frame axis.
    c_axis: Axis,
    c_w: Vec<u16>,
    c_valid: std::ops::Range<u32>,
    /// Pass A's rows (R outputs x image columns x RGB).
    a: Vec<u8>,
    /// The same transposed (image columns x R outputs x RGB).
    t: Vec<u8>,
    /// One row being summed, in 1/256 of a level.
    acc: Vec<u16>,
    /// Not turned: pass B's output (x-major), transposed into the frame.
    o: Vec<u8>,
}

/// Weights in 1/256: every output's sum to exactly 256, so a sum of
/// weighted levels fits 16 bits and the passes vectorise as integers.
fn fixed(axis: &Axis) -> Vec<u16> {
    let mut out = vec![0u16; axis.w.len()];
    for (w, o) in axis.w.chunks(axis.k).zip(out.chunks_mut(axis.k)) {
        for (x, &d) in o.iter_mut().zip(w) {
            *x = (d * 256.0).round() as u16;
        }
        let sum: i32 = o.iter().map(|&x| x as i32).sum();
        if sum > 0 {
            // The rounding's remainder to the largest weight.
            let big = (0..o.len()).max_by_key(|&i| o[i]).unwrap_or(0);
            o[big] = (o[big] as i32 + 256 - sum).clamp(0, 256) as u16;
        }
    }
    out
}

/// A precomputed camera → frame mapping (see the module docs).
#[derive(Clone, Debug)]
pub struct FrameMap {
    width: u32,
    height: u32,
    turn: bool,
    mm_per_px: f32,
    valid: Rect,
    path: Path,
}

impl FrameMap {
    /// Map `width` x `height` images (as the buffer holds them) whose
    /// pixels are `mm_per_px` millimetres; `turn`: the image is the
    /// camera's landscape view, turned to portrait.
    pub fn new(width: u32, height: u32, turn: bool, mm_per_px: f32) -> Result<FrameMap, String> {
        if width == 0 || height == 0 || width > 8192 || height > 8192 {
            return Err(format!("cannot map a {width}x{height} image"));
        }
        if !(mm_per_px.is_finite() && mm_per_px > 0.0) {
            return Err(format!(
                "{mm_per_px} mm per pixel is not a scale (a positive number of millimetres)"
            ));
        }
        let (pw, ph) = if turn {
            (height, width)
        } else {
            (width, height)
        };
        let f = FRAME_MM_PER_PX as f64 / mm_per_px as f64;
        let same = (f - 1.0).abs() < 1e-4;
        let half = (f - 2.0).abs() < 1e-4;
        let (path, valid) = if same && (pw, ph) == (WIDTH, HEIGHT) {
            (Path::Copy, Rect::FULL)
        } else if half && (pw, ph) == (2 * WIDTH, 2 * HEIGHT) {
            let n = if turn { WIDTH * width } else { HEIGHT * width };
            (
                Path::Half {
                    a: vec![0; n as usize * 3],
                },
                Rect::FULL,
            )
        } else {
            let (cols, vx) = Axis::new(pw, WIDTH, f)?;
            let (mut rows, vy) = Axis::new(ph, HEIGHT, f)?;
            let valid = Rect {
                x: vx.start,
                y: vy.start,
                w: vx.end - vx.start,
                h: vy.end - vy.start,
            };
            let (r_axis, r_valid, c_axis, c_valid) = if turn {
                // Image column C is portrait row Y = W-1-C.
                for i in rows.idx.iter_mut() {
                    *i = width - 1 - *i;
                }
                (cols, vx, rows, vy)
            } else {
                (rows, vy, cols, vx)
            };
            let (nr, nc) = (r_valid.len(), c_valid.len());
            let w = width as usize;
            let g = General {
                a: vec![0; nr * w * 3],
                t: vec![0; w * nr * 3],
                acc: vec![0; (w * 3).max(nr * 3)],
                o: if turn {
                    Vec::new()
                } else {
                    vec![0; nc * nr * 3]
                },
                r_w: fixed(&r_axis),
                c_w: fixed(&c_axis),
                r_axis,
                r_valid,
                c_axis,
                c_valid,
            };
            (Path::General(Box::new(g)), valid)
        };
        Ok(FrameMap {
            width,
            height,
            turn,
            mm_per_px,
            valid,
            path,
        })
    }

    /// The map for `profile`'s images of `width` x `height`: turned when
    /// the profile's camera streams landscape and the image is landscape
    /// (a portrait image is taken as already turned), at `mm_per_px` when
    /// given, else at the scale the profile's field of view gives this
    /// size. Refused: a size whose shape is not the field's (it would be
    /// another crop or another sensor), a profile without a field of view
    /// and no scale given.
    pub fn for_profile(
        profile: &SensorProfile,
        width: u32,
        height: u32,
        mm_per_px: Option<f32>,
    ) -> Result<FrameMap, String> {
        let turn = profile.landscape && width > height;
        // The camera's own width (its long side for a landscape camera).
        let cam_w = if profile.landscape {
            width.max(height)
        } else {
            width
        };
        let scale = match (mm_per_px, profile.field_mm) {
            (Some(s), _) => s,
            (None, Some((fw, fh))) => {
                let (long, short) = (width.max(height) as f32, width.min(height).max(1) as f32);
                let want = fw.max(fh) / fw.min(fh);
                if ((long / short) / want - 1.0).abs() > 0.02 {
                    return Err(format!(
                        "a {width}x{height} image is not the shape of the {}'s field of view ({fw} x {fh} mm); its modes are {}",
                        profile.label,
                        modes_text(profile)
                    ));
                }
                profile.mm_per_px(cam_w).unwrap_or(FRAME_MM_PER_PX)
            }
            (None, None) => {
                return Err(format!(
                    "the {} profile does not know its field of view: give its scale (sensor.mm_per_px, --mm-per-px)",
                    profile.label
                ))
            }
        };
        FrameMap::new(width, height, turn, scale)
    }

    /// The DIGIT's mapping of its own sizes (QVGA, VGA, landscape or
    /// portrait).
    pub fn digit(width: u32, height: u32) -> Result<FrameMap, String> {
        let long = width.max(height);
        if !matches!((long, width.min(height)), (320, 240) | (640, 480)) {
            return Err(format!(
                "cannot map a {width}x{height} image to the {WIDTH}x{HEIGHT} frame (it takes 240x320 or 480x640 portrait, or the camera's 320x240 or 640x480 landscape)"
            ));
        }
        FrameMap::for_profile(&crate::profile::DIGIT, width, height, None)
    }

    /// The image size it maps.
    pub fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    /// Millimetres per pixel of the images it maps.
    pub fn mm_per_px(&self) -> f32 {
        self.mm_per_px
    }

    /// Whether the images are turned.
    pub fn turns(&self) -> bool {
        self.turn
    }

    /// The part of the frame the camera's field covers (the rest mirrors
    /// it).
    pub fn valid(&self) -> Rect {
        self.valid
    }

    /// Map `rgb` (`width` x `height` x 3, row-major) into `out`, made
    /// 240x320 if it is not.
    pub fn map(&mut self, rgb: &[u8], out: &mut image::RgbImage) -> Result<(), String> {
        let (w, h) = (self.width as usize, self.height as usize);
        if rgb.len() != w * h * 3 {
            return Err(format!(
                "RGB buffer holds {} bytes, {}x{} needs {}",
                rgb.len(),
                self.width,
                self.height,
                w * h * 3
            ));
        }
        if (out.width(), out.height()) != (WIDTH, HEIGHT) {
            *out = image::RgbImage::new(WIDTH, HEIGHT);
        }
        let dst: &mut [u8] = out;
        match &mut self.path {
            Path::Copy if self.turn => transpose_rev(rgb, w, h, dst),
            Path::Copy => dst.copy_from_slice(rgb),
            Path::Half { a } => half(rgb, w, h, self.turn, a, dst),
            Path::General(g) => {
                g.run(rgb, w, self.turn, dst);
                mirror_fill(dst, self.valid);
            }
        }
        Ok(())
    }
}

/// Turn a landscape `w` x `h` RGB image into the `h` x `w` portrait one:
/// out (x, y) = in (w-1-y, x). In blocks, so both sides stay in cache;
/// each output row's block written in order.
fn transpose_rev<T: Copy>(src: &[T], w: usize, h: usize, dst: &mut [T]) {
    const B: usize = 32;
    for y0 in (0..w).step_by(B) {
        for x0 in (0..h).step_by(B) {
            let x1 = (x0 + B).min(h);
            for y in y0..(y0 + B).min(w) {
                let c = (w - 1 - y) * 3;
                let out = &mut dst[(y * h + x0) * 3..(y * h + x1) * 3];
                for (i, d) in out.chunks_exact_mut(3).enumerate() {
                    let p = &src[(x0 + i) * w * 3 + c..][..3];
                    d.copy_from_slice(p);
                }
            }
        }
    }
}

/// Sum the `k` weighted rows of `src` (each `acc.len()` long) at the
/// taps `idx` with their weights `wt` in 1/256 into `acc`, with half a
/// level to round.
#[inline]
fn weighted_rows(src: &[u8], idx: &[u32], wt: &[u16], acc: &mut [u16]) {
    let len = acc.len();
    acc.fill(128);
    for (&i, &w) in idx.iter().zip(wt) {
        if w == 0 {
            continue;
        }
        let row = &src[i as usize * len..][..len];
        for (a, &s) in acc.iter_mut().zip(row) {
            *a = a.wrapping_add(w.wrapping_mul(s as u16));
        }
    }
}

/// Transpose a `rows` x `cols` RGB image: out (r, c) at [c][r]. In
/// blocks, so both sides stay in cache.
fn transpose(src: &[u8], rows: usize, cols: usize, dst: &mut [u8]) {
    const B: usize = 32;
    for c0 in (0..cols).step_by(B) {
        for r0 in (0..rows).step_by(B) {
            let r1 = (r0 + B).min(rows);
            for c in c0..(c0 + B).min(cols) {
                let out = &mut dst[(c * rows + r0) * 3..(c * rows + r1) * 3];
                for (i, d) in out.chunks_exact_mut(3).enumerate() {
                    d.copy_from_slice(&src[((r0 + i) * cols + c) * 3..][..3]);
                }
            }
        }
    }
}

/// Round a sum in 1/256 of a level to the level.
#[inline]
fn store(acc: &[u16], out: &mut [u8]) {
    for (d, &a) in out.iter_mut().zip(acc) {
        *d = (a >> 8) as u8;
    }
}

impl General {
    fn run(&mut self, rgb: &[u8], w: usize, turn: bool, dst: &mut [u8]) {
        let (nr, nc) = (self.r_valid.len(), self.c_valid.len());
        let row_len = w * 3;
        // Pass A: each R output is a weighted sum of whole image rows.
        let k = self.r_axis.k;
        for (i, o) in self.r_valid.clone().enumerate() {
            let o = o as usize;
            let acc = &mut self.acc[..row_len];
            weighted_rows(
                rgb,
                &self.r_axis.idx[o * k..][..k],
                &self.r_w[o * k..][..k],
                acc,
            );
            store(acc, &mut self.a[i * row_len..][..row_len]);
        }
        // Image columns become rows.
        transpose(&self.a, nr, w, &mut self.t);
        // Pass B: each C output is a weighted sum of those rows.
        let k = self.c_axis.k;
        let out_len = nr * 3;
        for (i, o) in self.c_valid.clone().enumerate() {
            let o = o as usize;
            let acc = &mut self.acc[..out_len];
            weighted_rows(
                &self.t,
                &self.c_axis.idx[o * k..][..k],
                &self.c_w[o * k..][..k],
                acc,
            );
            let out = if turn {
                &mut dst[(o * WIDTH as usize + self.r_valid.start as usize) * 3..][..out_len]
            } else {
                &mut self.o[i * out_len..][..out_len]
            };
            store(acc, out);
        }
        if !turn {
            // o is x-major (nc rows of nr pixels): into the frame's rows.
            let (vx, vy) = (self.c_valid.start as usize, self.r_valid.start as usize);
            for x in 0..nc {
                for y in 0..nr {
                    let s = (x * nr + y) * 3;
                    let d = ((vy + y) * WIDTH as usize + vx + x) * 3;
                    dst[d..d + 3].copy_from_slice(&self.o[s..s + 3]);
                }
            }
        }
    }
}

/// The exact 2x2 mean of a `w` x `h` image twice the frame's size,
/// turned or not: row pairs summed (16 bits), then column pairs, rounded
/// half up.
fn half(rgb: &[u8], w: usize, h: usize, turn: bool, a: &mut [u16], dst: &mut [u8]) {
    let len = w * 3;
    // Turned, the frame's x is the image's rows; else its y.
    let n = if turn {
        WIDTH as usize
    } else {
        HEIGHT as usize
    };
    for i in 0..n.min(h / 2) {
        let (r0, r1) = (&rgb[2 * i * len..][..len], &rgb[(2 * i + 1) * len..][..len]);
        for ((d, &x), &y) in a[i * len..][..len].iter_mut().zip(r0).zip(r1) {
            *d = x as u16 + y as u16;
        }
    }
    let ow = WIDTH as usize;
    if turn {
        // Frame (x, y) from image columns w-1-2y and w-2-2y of row pair x.
        const B: usize = 16;
        for x0 in (0..ow).step_by(B) {
            for y0 in (0..HEIGHT as usize).step_by(B) {
                for x in x0..(x0 + B).min(ow) {
                    let row = &a[x * len..][..len];
                    for y in y0..(y0 + B).min(HEIGHT as usize) {
                        let (c0, c1) = ((w - 1 - 2 * y) * 3, (w - 2 - 2 * y) * 3);
                        let d = (y * ow + x) * 3;
                        for c in 0..3 {
                            dst[d + c] = ((row[c0 + c] + row[c1 + c] + 2) >> 2) as u8;
                        }
                    }
                }
            }
        }
    } else {
        for y in 0..HEIGHT as usize {
            let row = &a[y * len..][..len];
            let out = &mut dst[y * ow * 3..][..ow * 3];
            for (x, d) in out.chunks_exact_mut(3).enumerate() {
                for c in 0..3 {
                    d[c] = ((row[2 * x * 3 + c] + row[(2 * x + 1) * 3 + c] + 2) >> 2) as u8;
                }
            }
        }
    }
}

/// Fill the frame outside `valid` with its mirror image.
fn mirror_fill(dst: &mut [u8], valid: Rect) {
    if valid == Rect::FULL {
        return;
    }
    let (ow, oh) = (WIDTH as usize, HEIGHT as usize);
    let (a, b) = (valid.x as usize, (valid.x + valid.w) as usize);
    // One reflection covers each margin when the field is at least as
    // wide as it: a reversed run of pixels; else pixel by pixel.
    let single = a <= valid.w as usize && ow - b <= valid.w as usize;
    for y in valid.y as usize..(valid.y + valid.h) as usize {
        let row = &mut dst[y * ow * 3..][..ow * 3];
        if single {
            let (left, rest) = row.split_at_mut(a * 3);
            for (d, s) in left.chunks_exact_mut(3).rev().zip(rest.chunks_exact(3)) {
                d.copy_from_slice(s);
            }
            let (rest, right) = row.split_at_mut(b * 3);
            for (d, s) in right.chunks_exact_mut(3).zip(rest.chunks_exact(3).rev()) {
                d.copy_from_slice(s);
            }
        } else {
            for x in (0..a).chain(b..ow) {
                let m = mirror(x as i64, a as i64, b as i64);
                row.copy_within(m * 3..m * 3 + 3, x * 3);
            }
        }
    }
    let (a, b) = (valid.y as i64, (valid.y + valid.h) as i64);
    for y in (0..a as usize).chain(b as usize..oh) {
        let m = mirror(y as i64, a, b);
        dst.copy_within(m * ow * 3..(m + 1) * ow * 3, y * ow * 3);
    }
}

/// A profile's modes, for messages.
pub fn modes_text(profile: &SensorProfile) -> String {
    if profile.modes.is_empty() {
        return "whatever the camera offers".into();
    }
    profile
        .modes
        .iter()
        .map(Mode::text)
        .collect::<Vec<_>>()
        .join(", ")
}

/// What a camera of `profile` streaming `width` x `height` at
/// `mm_per_px` would see of `frame` (240x320 at [`FRAME_MM_PER_PX`]): the
/// inverse view, sampled bilinearly (camera pixels the frame does not
/// cover take its nearest edge), in the camera's own orientation. The
/// simulator renders at the frame's scale; this gives its presses the
/// geometry of another sensor or mode.
pub fn camera_view(
    frame: &image::RgbImage,
    width: u32,
    height: u32,
    turn: bool,
    mm_per_px: f32,
) -> image::RgbImage {
    let f = mm_per_px as f64 / FRAME_MM_PER_PX as f64; // frame px per camera px
    let (pw, ph) = if turn {
        (height, width)
    } else {
        (width, height)
    };
    let (fw, fh) = (frame.width() as f64, frame.height() as f64);
    let src = frame.as_raw();
    let stride = frame.width() as usize * 3;
    let sample = |x: f64, y: f64| -> [u8; 3] {
        let x = x.clamp(0.0, fw - 1.0);
        let y = y.clamp(0.0, fh - 1.0);
        let (x0, y0) = (x.floor() as usize, y.floor() as usize);
        let (x1, y1) = (
            (x0 + 1).min(frame.width() as usize - 1),
            (y0 + 1).min(frame.height() as usize - 1),
        );
        let (ax, ay) = (x - x0 as f64, y - y0 as f64);
        std::array::from_fn(|c| {
            let p = |xx: usize, yy: usize| src[yy * stride + xx * 3 + c] as f64;
            let top = p(x0, y0) * (1.0 - ax) + p(x1, y0) * ax;
            let bot = p(x0, y1) * (1.0 - ax) + p(x1, y1) * ax;
            (top * (1.0 - ay) + bot * ay).round().clamp(0.0, 255.0) as u8
        })
    };
    let mut out = image::RgbImage::new(width, height);
    for cy in 0..height {
        for cx in 0..width {
            // The camera pixel's portrait coordinates (X, Y).
            let (px, py) = if turn { (cy, width - 1 - cx) } else { (cx, cy) };
            let x = fw / 2.0 + (px as f64 + 0.5 - pw as f64 / 2.0) * f - 0.5;
            let y = fh / 2.0 + (py as f64 + 0.5 - ph as f64 / 2.0) * f - 0.5;
            out.put_pixel(cx, cy, image::Rgb(sample(x, y)));
        }
    }
    out
}

#[cfg(test)]
mod tests;
