//! The contact sheet: simulated presses of several textiles beside the real
//! DIGIT background, labelled with a tiny built-in 5x7 bitmap font.

use crate::catalogue::Family;
use crate::{PressSpec, SimError, Simulator, HEIGHT, WIDTH};
use image::{Rgb, RgbImage};

/// 5x7 glyphs, one byte per row (low 5 bits, MSB = left column).
fn glyph(c: char) -> [u8; 7] {
    match c.to_ascii_uppercase() {
        'A' => [0x0E, 0x11, 0x11, 0x1F, 0x11, 0x11, 0x11],
        'B' => [0x1E, 0x11, 0x11, 0x1E, 0x11, 0x11, 0x1E],
        'C' => [0x0E, 0x11, 0x10, 0x10, 0x10, 0x11, 0x0E],
        'D' => [0x1E, 0x11, 0x11, 0x11, 0x11, 0x11, 0x1E],
        'E' => [0x1F, 0x10, 0x10, 0x1E, 0x10, 0x10, 0x1F],
        'F' => [0x1F, 0x10, 0x10, 0x1E, 0x10, 0x10, 0x10],
        'G' => [0x0E, 0x11, 0x10, 0x17, 0x11, 0x11, 0x0F],
        'H' => [0x11, 0x11, 0x11, 0x1F, 0x11, 0x11, 0x11],
        'I' => [0x0E, 0x04, 0x04, 0x04, 0x04, 0x04, 0x0E],
        'J' => [0x07, 0x02, 0x02, 0x02, 0x02, 0x12, 0x0C],
        'K' => [0x11, 0x12, 0x14, 0x18, 0x14, 0x12, 0x11],
        'L' => [0x10, 0x10, 0x10, 0x10, 0x10, 0x10, 0x1F],
        'M' => [0x11, 0x1B, 0x15, 0x15, 0x11, 0x11, 0x11],
        'N' => [0x11, 0x11, 0x19, 0x15, 0x13, 0x11, 0x11],
        'O' => [0x0E, 0x11, 0x11, 0x11, 0x11, 0x11, 0x0E],
        'P' => [0x1E, 0x11, 0x11, 0x1E, 0x10, 0x10, 0x10],
        'Q' => [0x0E, 0x11, 0x11, 0x11, 0x15, 0x12, 0x0D],
        'R' => [0x1E, 0x11, 0x11, 0x1E, 0x14, 0x12, 0x11],
        'S' => [0x0F, 0x10, 0x10, 0x0E, 0x01, 0x01, 0x1E],
        'T' => [0x1F, 0x04, 0x04, 0x04, 0x04, 0x04, 0x04],
        'U' => [0x11, 0x11, 0x11, 0x11, 0x11, 0x11, 0x0E],
        'V' => [0x11, 0x11, 0x11, 0x11, 0x11, 0x0A, 0x04],
        'W' => [0x11, 0x11, 0x11, 0x15, 0x15, 0x15, 0x0A],
        'X' => [0x11, 0x11, 0x0A, 0x04, 0x0A, 0x11, 0x11],
        'Y' => [0x11, 0x11, 0x0A, 0x04, 0x04, 0x04, 0x04],
        'Z' => [0x1F, 0x01, 0x02, 0x04, 0x08, 0x10, 0x1F],
        '0' => [0x0E, 0x11, 0x13, 0x15, 0x19, 0x11, 0x0E],
        '1' => [0x04, 0x0C, 0x04, 0x04, 0x04, 0x04, 0x0E],
        '2' => [0x0E, 0x11, 0x01, 0x02, 0x04, 0x08, 0x1F],
        '3' => [0x1F, 0x02, 0x04, 0x02, 0x01, 0x11, 0x0E],
        '4' => [0x02, 0x06, 0x0A, 0x12, 0x1F, 0x02, 0x02],
        '5' => [0x1F, 0x10, 0x1E, 0x01, 0x01, 0x11, 0x0E],
        '6' => [0x06, 0x08, 0x10, 0x1E, 0x11, 0x11, 0x0E],
        '7' => [0x1F, 0x01, 0x02, 0x04, 0x08, 0x08, 0x08],
        '8' => [0x0E, 0x11, 0x11, 0x0E, 0x11, 0x11, 0x0E],
        '9' => [0x0E, 0x11, 0x11, 0x0F, 0x01, 0x02, 0x0C],
        '-' => [0x00, 0x00, 0x00, 0x1F, 0x00, 0x00, 0x00],
        '/' => [0x01, 0x01, 0x02, 0x04, 0x08, 0x10, 0x10],
        '.' => [0x00, 0x00, 0x00, 0x00, 0x00, 0x0C, 0x0C],
        ',' => [0x00, 0x00, 0x00, 0x00, 0x0C, 0x04, 0x08],
        ':' => [0x00, 0x0C, 0x0C, 0x00, 0x0C, 0x0C, 0x00],
        '(' => [0x02, 0x04, 0x08, 0x08, 0x08, 0x04, 0x02],
        ')' => [0x08, 0x04, 0x02, 0x02, 0x02, 0x04, 0x08],
        '+' => [0x00, 0x04, 0x04, 0x1F, 0x04, 0x04, 0x00],
        '=' => [0x00, 0x00, 0x1F, 0x00, 0x1F, 0x00, 0x00],
        _ => [0; 7],
    }
}

/// Draw `text` at (x, y) with the 5x7 font scaled by `scale`.
pub fn draw_text(img: &mut RgbImage, x: u32, y: u32, text: &str, scale: u32, color: Rgb<u8>) {
    let mut cx = x;
    for ch in text.chars() {
        let g = glyph(ch);
        for (row, bits) in g.iter().enumerate() {
            for col in 0..5u32 {
                if bits & (0x10 >> col) != 0 {
                    for dy in 0..scale {
                        for dx in 0..scale {
                            let px = cx + col * scale + dx;
                            let py = y + row as u32 * scale + dy;
                            if px < img.width() && py < img.height() {
                                img.put_pixel(px, py, color);
                            }
                        }
                    }
                }
            }
        }
        cx += 6 * scale;
    }
}

/// One tile of the sheet.
#[derive(Clone, Debug)]
pub struct Tile {
    /// Short label drawn on the sheet.
    pub label: String,
    /// Longer description for the docs.
    pub description: String,
}

const LABEL_H: u32 = 22;
const COLS: u32 = 6;
/// Frame of each press shown (mid-hold).
pub const SHEET_FRAME: usize = 100;

/// Render the contact sheet: 2 rows x 6 tiles of full-resolution frames.
pub fn contact_sheet(sim: &Simulator) -> Result<(RgbImage, Vec<Tile>), SimError> {
    let cat = sim.catalogue();
    let mut tiles: Vec<(RgbImage, Tile)> = Vec::new();
    tiles.push((
        sim.real_background().clone(),
        Tile {
            label: "REAL DIGIT BG".into(),
            description: "the real DIGIT no-contact frame (tacto), sensor 0's background".into(),
        },
    ));
    let mut press = |spec: PressSpec, label: String| -> Result<(), SimError> {
        let t = cat
            .get(&spec.textile)
            .ok_or_else(|| SimError::UnknownTextile(spec.textile.clone()))?;
        let img = sim.render_frame(&spec, SHEET_FRAME)?;
        let description = format!(
            "{} {} ({:?} family), person {}, sensor {}, {}, frame {SHEET_FRAME}",
            t.id,
            t.name,
            t.structure.family(),
            spec.person,
            spec.sensor,
            if spec.jig { "jig" } else { "hand-held" }
        );
        tiles.push((img, Tile { label, description }));
        Ok(())
    };
    // a near-twin pair (same weave and counts, different fibre)
    let (a, b) = cat
        .twin_pairs()
        .into_iter()
        .find(|(a, _)| a.structure.family() == Family::Twill)
        .or_else(|| cat.twin_pairs().into_iter().next())
        .ok_or_else(|| SimError::InvalidSpec("catalogue has no twins".into()))?;
    let (a_id, b_id) = (a.id.clone(), b.id.clone());
    let (a_f, b_f) = (a.fibre.name(), b.fibre.name());
    press(
        PressSpec {
            rotation_deg: Some(0.0),
            ..PressSpec::new(&a_id, 1)
        },
        format!("{a_id} {a_f} JIG"),
    )?;
    press(
        PressSpec {
            rotation_deg: Some(0.0),
            ..PressSpec::new(&b_id, 1)
        },
        format!("{b_id} {b_f} TWIN"),
    )?;
    // one of each of several other families, jig
    let families = [
        Family::Plain,
        Family::Satin,
        Family::Knit,
        Family::Rib,
        Family::Pile,
        Family::Terry,
        Family::Fleece,
        Family::Felt,
    ];
    let mut picked = Vec::new();
    for f in families {
        if let Some(t) = cat
            .training()
            .find(|t| t.structure.family() == f && t.twin_of.is_none() && t.id != a_id)
        {
            picked.push((t.id.clone(), format!("{} {:?}", t.id, f)));
        }
    }
    for (id, label) in picked.into_iter().take(6) {
        press(PressSpec::new(&id, 2), format!("{label} JIG"))?;
    }
    // the first twin hand-held by two people: tilt, partial contact, slip
    for (person, seed) in [(3u32, 5u64), (7, 9)] {
        press(
            PressSpec {
                person,
                jig: false,
                sensor: 1 + person % 2,
                ..PressSpec::new(&a_id, seed)
            },
            format!("{a_id} HAND P{person}"),
        )?;
    }
    press(
        PressSpec {
            sensor: 4,
            ..PressSpec::new(&b_id, 3)
        },
        format!("{b_id} SENSOR 4"),
    )?;
    let rows = (tiles.len() as u32).div_ceil(COLS);
    let mut sheet =
        RgbImage::from_pixel(COLS * WIDTH, rows * (HEIGHT + LABEL_H), Rgb([20, 20, 20]));
    for (k, (img, tile)) in tiles.iter().enumerate() {
        let (c, r) = (k as u32 % COLS, k as u32 / COLS);
        let (x0, y0) = (c * WIDTH, r * (HEIGHT + LABEL_H));
        image::imageops::replace(&mut sheet, img, x0 as i64, (y0 + LABEL_H) as i64);
        draw_text(
            &mut sheet,
            x0 + 4,
            y0 + 4,
            &tile.label,
            2,
            Rgb([240, 240, 240]),
        );
    }
    Ok((sheet, tiles.into_iter().map(|(_, t)| t).collect()))
}
