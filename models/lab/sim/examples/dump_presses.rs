//! Renders presses listed in a text file into flat arrays for experiments
//! outside Rust (the GPU ceiling study, `models/lab/scripts/gpu-ceiling/`):
//! for each press, the mean of its untouched reference frames and six
//! frames (33, 67 and 100 ms after contact, and 20, 50 and 80 % into the
//! hold), the centre 240x240 square of each.
//!
//! `cargo run --release -p telextiles-sim --example dump_presses -- <out-prefix> <catalogue> <generator> <specs.txt>`
//!
//! `specs.txt`: one press per line, `textile person unit jig(0|1) seed`.
//! Writes `<out>.frames.u8` (u8 `[N, 6, 240, 240, 3]`), `<out>.ref.u16`
//! (the reference x 64 as u16 `[N, 240, 240, 3]`, little-endian) and
//! `<out>.meta.txt` (a line per press: textile person unit jig seed
//! rotation force fps contact hold end swatch features). `T` (environment)
//! sets the render threads (default 2).
use std::io::{BufRead, Write};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;
use telextiles_sim::{PressSpec, Simulator};

const SIDE: u32 = 240;
/// Rows above the centre square of a 320-row frame.
const TOP: u32 = 40;

type Rendered = (Vec<u8>, Vec<u16>, String);

fn square(f: &image::RgbImage, out: &mut Vec<u8>) {
    for y in 0..SIDE {
        for x in 0..SIDE {
            out.extend_from_slice(&f.get_pixel(x, y + TOP).0);
        }
    }
}

fn render(sim: &Simulator, line: &str, cat: u32, gen: u32) -> Result<Rendered, String> {
    let f: Vec<&str> = line.split_whitespace().collect();
    if f.len() < 5 {
        return Err(format!("{line:?}: expected textile person unit jig seed"));
    }
    let num = |i: usize| -> Result<u64, String> {
        f[i].parse()
            .map_err(|e| format!("{line:?}: field {i}: {e}"))
    };
    let mut spec = PressSpec::new(f[0], num(4)?);
    spec.person = num(1)? as u32;
    spec.sensor = num(2)? as u32;
    spec.jig = f[3] == "1";
    spec.catalogue = Some(cat);
    spec.generator = Some(gen);
    let press = sim
        .render_press(&spec)
        .map_err(|e| format!("{line:?}: {e}"))?;
    let m = &press.meta;
    let p = m
        .params
        .as_ref()
        .ok_or("a simulated press has parameters")?;
    let nref = m.reference_frames.unwrap_or(3).max(1) as usize;
    let mut sum = vec![0f32; (SIDE * SIDE * 3) as usize];
    for fr in &press.frames[..nref] {
        let mut v = Vec::with_capacity(sum.len());
        square(fr, &mut v);
        sum.iter_mut().zip(&v).for_each(|(s, x)| *s += *x as f32);
    }
    let reference = sum
        .iter()
        .map(|v| (v / nref as f32 * 64.0).round() as u16)
        .collect();
    let ts = &m.timestamps_us;
    let last = press.frames.len() - 1;
    let c = (p.contact_frame as usize).min(last);
    let hold = p.hold_frame as usize;
    let end = p.release_frame.map_or(press.frames.len(), |r| r as usize);
    let after = |ms: u64| {
        (c..=last)
            .find(|&k| ts[k] >= ts[c] + ms * 1000)
            .unwrap_or(last)
    };
    let span = end.saturating_sub(hold);
    let picks = [
        after(33),
        after(67),
        after(100),
        hold + span / 5,
        hold + span / 2,
        hold + span * 4 / 5,
    ];
    let mut frames = Vec::with_capacity(6 * (SIDE * SIDE * 3) as usize);
    for k in picks {
        square(&press.frames[k.min(last)], &mut frames);
    }
    let meta = format!(
        "{} {} {} {} {} {:.1} {:.2} {} {} {} {} {:?} {:?}",
        f[0],
        spec.person,
        spec.sensor,
        f[3],
        spec.seed,
        p.rotation_deg,
        p.force_n,
        m.fps,
        c,
        hold,
        end,
        p.swatch,
        p.features
    );
    Ok((frames, reference, meta))
}

fn main() -> Result<(), String> {
    let a: Vec<String> = std::env::args().collect();
    if a.len() != 5 {
        return Err("usage: dump_presses <out-prefix> <catalogue> <generator> <specs.txt>".into());
    }
    let (out, cat, gen) = (
        &a[1],
        a[2].parse().map_err(|_| "catalogue")?,
        a[3].parse().map_err(|_| "generator")?,
    );
    let file = std::fs::File::open(&a[4]).map_err(|e| format!("{}: {e}", a[4]))?;
    let lines: Vec<String> = std::io::BufReader::new(file)
        .lines()
        .map_while(Result::ok)
        .filter(|l| !l.trim().is_empty())
        .collect();
    let threads = std::env::var("T")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(2);
    let sim = Simulator::with_options(cat, gen).map_err(|e| e.to_string())?;
    let n = lines.len();
    let results: Vec<Mutex<Option<Result<Rendered, String>>>> =
        (0..n).map(|_| Mutex::new(None)).collect();
    let next = AtomicUsize::new(0);
    std::thread::scope(|s| {
        for _ in 0..threads {
            s.spawn(|| loop {
                let i = next.fetch_add(1, Ordering::Relaxed);
                if i >= n {
                    break;
                }
                *results[i].lock().unwrap() = Some(render(&sim, &lines[i], cat, gen));
                if i.is_multiple_of(200) {
                    eprintln!("{i}/{n}");
                }
            });
        }
    });
    let create = |ext: &str| {
        std::fs::File::create(format!("{out}.{ext}"))
            .map(std::io::BufWriter::new)
            .map_err(|e| format!("{out}.{ext}: {e}"))
    };
    let (mut frames, mut refs, mut meta) = (
        create("frames.u8")?,
        create("ref.u16")?,
        create("meta.txt")?,
    );
    for r in results {
        let (f, r, m) = r
            .into_inner()
            .unwrap()
            .ok_or("a press was not rendered")??;
        let io = |e: std::io::Error| e.to_string();
        frames.write_all(&f).map_err(io)?;
        for v in r {
            refs.write_all(&v.to_le_bytes()).map_err(io)?;
        }
        writeln!(meta, "{m}").map_err(io)?;
    }
    for w in [&mut frames, &mut refs, &mut meta] {
        w.flush().map_err(|e| e.to_string())?;
    }
    Ok(())
}
