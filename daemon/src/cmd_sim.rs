//! `telextilesd sim`: simulated DIGIT presses, the paper's dataset protocol
//! and the contact sheet (crate `telextiles-sim`).

use anyhow::{bail, Context, Result};
use std::io::Write;
use std::path::{Path, PathBuf};
use telextiles_sim::catalogue::Book;
use telextiles_sim::dataset::{self, Protocol};
use telextiles_sim::{recording, sheet, PressSpec, Simulator};

/// Render a simulated press, a dataset or the contact sheet.
#[derive(clap::Args, Debug)]
#[command(args_conflicts_with_subcommands = true)]
pub struct Args {
    #[command(subcommand)]
    cmd: Option<SimCmd>,
    #[command(flatten)]
    press: PressArgs,
}

/// Options of one press (`telextilesd sim --textile T001 --seed 1 --out dir`).
#[derive(clap::Args, Debug)]
struct PressArgs {
    /// Textile id: T001..T119 (training) or U01..U20 (unseen).
    #[arg(long)]
    textile: Option<String>,
    /// Seed of the press (same seed, same frames).
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Output directory (must not exist; written atomically).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Simulated person 0..10.
    #[arg(long, default_value_t = 0)]
    person: u32,
    /// Simulated sensor unit (0 = nominal real calibration).
    #[arg(long, default_value_t = 0)]
    sensor: u32,
    /// Press with the spring jig (the default).
    #[arg(long, conflicts_with = "no_jig")]
    jig: bool,
    /// Press hand-held: tilt, partial contact, force wobble, slip.
    #[arg(long)]
    no_jig: bool,
    /// In-plane rotation in degrees (default: the person's habit).
    #[arg(long, allow_hyphen_values = true)]
    rotation: Option<f32>,
    /// Force in newtons (default: jig spring or the person's habit).
    #[arg(long)]
    force: Option<f32>,
    /// Tilt about the sensor's x and y axes in degrees, e.g. `--tilt 1.5,-0.5`
    /// (default: drawn from the jig's or the person's steadiness).
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true)]
    tilt: Option<Vec<f32>>,
    /// Number of frames.
    #[arg(long, default_value_t = telextiles_sim::PRESS_FRAMES)]
    frames: usize,
    /// Turn camera noise off.
    #[arg(long)]
    no_noise: bool,
    /// Catalogue version: 1 (the original) or 2 (bolts, 16+ sensor units,
    /// camera chain, 25-60 fps; docs/simulator.md).
    #[arg(long, default_value_t = 1)]
    catalogue: u32,
    /// Texture generator of catalogue 2: 1, or 2 (the independent Gabor
    /// generator of the cross-generator test set).
    #[arg(long, default_value_t = 1)]
    generator: u32,
    /// Frame rate (catalogue 2 only, 25..60; default: drawn per press).
    #[arg(long)]
    fps: Option<f32>,
    #[command(flatten)]
    camera: CameraArgs,
}

/// Another sensor's geometry for the simulated presses.
#[derive(clap::Args, Debug, Clone, Default)]
struct CameraArgs {
    /// Write the presses as this sensor profile's camera streams them
    /// (digit, gelsight-mini): its pixel size, landscape, at its mode's
    /// frame rate; the optics stay the simulated DIGIT's (docs/sensors.md)
    #[arg(long, value_name = "PROFILE", value_parser = telextiles_recording::profile::by_name)]
    sensor_profile: Option<&'static telextiles_recording::profile::SensorProfile>,
    /// The camera's mode, WIDTHxHEIGHT@FPS [default: the profile's first]
    #[arg(long, value_name = "MODE", requires = "sensor_profile")]
    sensor_mode: Option<telextiles_recording::profile::Mode>,
}

impl CameraArgs {
    fn camera(
        &self,
    ) -> Result<
        Option<(
            &'static telextiles_recording::profile::SensorProfile,
            telextiles_recording::profile::Mode,
        )>,
    > {
        let Some(p) = self.sensor_profile else {
            return Ok(None);
        };
        let mode = match self.sensor_mode.or(p.modes.first().copied()) {
            Some(m) => m,
            None => bail!("the {} profile lists no mode: give --sensor-mode", p.label),
        };
        // A profile without a field of view is refused by `as_camera`.
        Ok(Some((p, mode)))
    }
}

#[derive(clap::Subcommand, Debug)]
enum SimCmd {
    /// Write (or stream as JSON lines) the paper's protocol.
    Dataset(DatasetArgs),
    /// Write the contact sheet PNG.
    ContactSheet {
        /// Output PNG.
        #[arg(long, default_value = "docs/contact-sheet.png")]
        out: PathBuf,
        /// Catalogue version (1 or 2).
        #[arg(long, default_value_t = 1)]
        catalogue: u32,
    },
    /// List the textile catalogue.
    List {
        /// Catalogue version (1 or 2).
        #[arg(long, default_value_t = 1)]
        catalogue: u32,
    },
    /// Print the validation statistics of a catalogue (docs/simulator.md).
    Stats(StatsArgs),
}

#[derive(clap::Args, Debug)]
struct StatsArgs {
    /// Catalogue version (1 or 2).
    #[arg(long, default_value_t = 2)]
    catalogue: u32,
    /// Texture generator (catalogue 2: 1 or 2).
    #[arg(long, default_value_t = 1)]
    generator: u32,
    /// Training textiles per family in the sample (one jig press each).
    #[arg(long, default_value_t = 3)]
    per_family: usize,
    /// Sensor units the sample cycles through and the background difference
    /// averages over.
    #[arg(long, default_value_t = 16)]
    units: u32,
    /// Whole presses (150 frames) rendered for the speed figure (0: skip).
    #[arg(long, default_value_t = 6)]
    speed_presses: usize,
    /// Print one line per press too.
    #[arg(long)]
    verbose: bool,
}

#[derive(clap::Args, Debug)]
struct DatasetArgs {
    /// Output root (`<root>/<textile>/p<person>-s<sensor>-<jig|hand>-<seed>/`).
    #[arg(long, required_unless_present = "stream")]
    out: Option<PathBuf>,
    /// Print the press specs as JSON lines instead of rendering them.
    #[arg(long)]
    stream: bool,
    /// Number of people.
    #[arg(long, default_value_t = telextiles_sim::PEOPLE)]
    people: u32,
    /// Sensor units, comma-separated.
    #[arg(long, value_delimiter = ',', default_values_t = [0u32, 1, 2])]
    sensors: Vec<u32>,
    /// Only jig presses.
    #[arg(long, conflicts_with = "hand_only")]
    jig_only: bool,
    /// Only hand-held presses.
    #[arg(long)]
    hand_only: bool,
    /// Only the training book.
    #[arg(long, conflicts_with = "unseen_only")]
    training_only: bool,
    /// Only the unseen book.
    #[arg(long)]
    unseen_only: bool,
    /// Presses per (sensor, jig mode, person, textile).
    #[arg(long, default_value_t = 1)]
    presses: u32,
    /// Base seed.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Frames per press.
    #[arg(long, default_value_t = telextiles_sim::PRESS_FRAMES)]
    frames: usize,
    /// Catalogue version (1 or 2).
    #[arg(long, default_value_t = 1)]
    catalogue: u32,
    /// Texture generator of catalogue 2 (1 or 2).
    #[arg(long, default_value_t = 1)]
    generator: u32,
    /// Stop after this many presses.
    #[arg(long)]
    limit: Option<usize>,
    #[command(flatten)]
    camera: CameraArgs,
}

pub fn run(args: Args) -> Result<()> {
    match args.cmd {
        Some(SimCmd::Dataset(d)) => dataset_cmd(d),
        Some(SimCmd::ContactSheet { out, catalogue }) => contact_sheet(&out, catalogue),
        Some(SimCmd::List { catalogue }) => list(catalogue),
        Some(SimCmd::Stats(s)) => stats_cmd(s),
        None => press(args.press),
    }
}

fn press(a: PressArgs) -> Result<()> {
    let (Some(textile), Some(out)) = (a.textile, a.out) else {
        bail!("usage: telextilesd sim --textile <id> --seed <n> --out <dir> (or a subcommand: dataset, contact-sheet, list)");
    };
    let tilt_deg = match a.tilt.as_deref() {
        None => None,
        Some(&[x, y]) => Some([x, y]),
        Some(t) => bail!("--tilt takes two angles, x,y in degrees (got {t:?})"),
    };
    let sim = Simulator::with_options(a.catalogue, a.generator)?;
    let spec = PressSpec {
        fps: a.fps,
        person: a.person,
        sensor: a.sensor,
        jig: !a.no_jig,
        rotation_deg: a.rotation,
        force: a.force,
        tilt_deg,
        frames: a.frames,
        noise: !a.no_noise,
        ..PressSpec::new(textile, a.seed)
    };
    let mut press = sim.render_press(&spec)?;
    if let Some((profile, mode)) = a.camera.camera()? {
        press = telextiles_sim::camera::as_camera(&press, profile, mode)?;
    }
    recording::write_press(&out, &press)?;
    let p = press.meta.params.as_ref();
    writeln!(
        crate::out::stdout(),
        "wrote {} frames of {} to {} (rotation {:.1} deg, force {:.2} N)",
        press.frames.len(),
        spec.textile,
        out.display(),
        p.map_or(0.0, |p| p.rotation_deg),
        p.map_or(0.0, |p| p.force_n)
    )?;
    Ok(())
}

fn dataset_cmd(d: DatasetArgs) -> Result<()> {
    let protocol = Protocol {
        people: d.people,
        sensors: d.sensors,
        jig: if d.jig_only {
            vec![true]
        } else if d.hand_only {
            vec![false]
        } else {
            vec![true, false]
        },
        books: if d.training_only {
            vec![Book::Training]
        } else if d.unseen_only {
            vec![Book::Unseen]
        } else {
            vec![Book::Training, Book::Unseen]
        },
        presses: d.presses,
        seed: d.seed,
        frames: d.frames,
    };
    let sim = Simulator::with_options(d.catalogue, d.generator)?;
    let cat = sim.catalogue();
    let total = protocol.len(cat).min(d.limit.unwrap_or(usize::MAX));
    let generator = (d.catalogue == 2 && d.generator != 1).then_some(d.generator);
    let specs = protocol
        .specs(cat)
        .take(total)
        .map(move |s| PressSpec { generator, ..s });
    if d.stream {
        let mut w = std::io::BufWriter::new(crate::out::stdout());
        for s in specs {
            writeln!(w, "{}", s.to_json())?;
        }
        w.flush()?;
        return Ok(());
    }
    let out = d.out.context("--out is required unless --stream")?;
    let n = dataset::write_as(&sim, specs, &out, d.camera.camera()?, |n, s| {
        if n % 50 == 0 || n == total {
            eprintln!("{n}/{total} presses ({})", s.textile);
        }
    })?;
    writeln!(
        crate::out::stdout(),
        "wrote {n} presses under {} ({total} in the protocol slice)",
        out.display()
    )?;
    Ok(())
}

fn contact_sheet(out: &Path, catalogue: u32) -> Result<()> {
    let sim = Simulator::with_catalogue(catalogue)?;
    let (img, tiles) = sheet::contact_sheet(&sim)?;
    if let Some(dir) = out.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    let tmp = out.with_extension(format!("tmp-{}.png", std::process::id()));
    img.save_with_format(&tmp, image_png())
        .with_context(|| format!("writing {}", tmp.display()))?;
    std::fs::rename(&tmp, out).with_context(|| format!("renaming to {}", out.display()))?;
    for (i, t) in tiles.iter().enumerate() {
        writeln!(crate::out::stdout(), "{i:2} {}: {}", t.label, t.description)?;
    }
    Ok(())
}

fn image_png() -> telextiles_sim::ImageFormat {
    telextiles_sim::ImageFormat::Png
}

fn list(catalogue: u32) -> Result<()> {
    let sim = Simulator::with_catalogue(catalogue)?;
    let mut out = crate::out::stdout();
    for t in &sim.catalogue().textiles {
        writeln!(
            out,
            "{}\t{:?}\t{:?}\t{}{}",
            t.id,
            t.book,
            t.structure.family(),
            t.name,
            t.twin_of
                .as_ref()
                .map(|x| format!(" (near-twin of {x})"))
                .unwrap_or_default()
        )?;
    }
    Ok(())
}

fn stats_cmd(a: StatsArgs) -> Result<()> {
    use telextiles_sim::stats;
    let mut out = crate::out::stdout();
    let sim = Simulator::with_options(a.catalogue, a.generator)?;
    let specs = stats::sample_specs(&sim, a.catalogue, a.generator, a.per_family, a.units);
    let mut rows = Vec::with_capacity(specs.len());
    for s in &specs {
        let r = stats::press_stats(&sim, s)?;
        if a.verbose {
            writeln!(out,
                "{} {:?} sensor {}: contact std {:.2} DN, peak/median {:.0}, noise lag-1 {:.2}, colour {:.2}",
                r.textile, r.family, s.sensor, r.contact_std, r.peak_to_median, r.noise_lag1, r.noise_colour
            )?;
        }
        rows.push(r);
    }
    let units = stats::unit_background_difference(&sim, a.catalogue, a.units);
    let sum = stats::summarise(&rows, units);
    let speed = if let Some(step) = specs.len().checked_div(a.speed_presses) {
        let sp: Vec<PressSpec> = specs
            .iter()
            .step_by(step.max(1))
            .take(a.speed_presses)
            .enumerate()
            .map(|(k, s)| PressSpec {
                jig: k % 2 == 0,
                seed: s.seed + 7,
                ..s.clone()
            })
            .collect();
        Some(stats::render_speed(&sim, &sp)?)
    } else {
        None
    };
    let opt = |v: Option<f32>| v.map_or("-".to_string(), |v| format!("{v:.2}"));
    let label = if a.catalogue == 2 {
        format!("catalogue 2, generator {}", a.generator)
    } else {
        "catalogue 1".to_string()
    };
    writeln!(out, "| source | presses | contact std (DN), median / soft / terry+loop+tuft | peak-to-median, wovens+knits: median (max) over n plain-cloth presses | noise lag-1 / colour corr. | single-frame residual std (DN) / lag-1 | unit-to-unit background (DN) | frames/s/core |")?;
    writeln!(out, "|---|---|---|---|---|---|---|---|")?;
    writeln!(out,
        "| {label} | {} | {:.2} / {} / {} | {:.0} ({:.0}), n = {} | {:.2} / {:.2} | {:.2} / {:.2} | {:.1} (units 0..{}) | {} |",
        sum.presses,
        sum.contact_std_median,
        opt(sum.contact_std_soft),
        opt(sum.contact_std_rough),
        sum.peak_wovens_knits_median,
        sum.peak_wovens_knits_max,
        sum.peak_presses,
        sum.noise_lag1,
        sum.noise_colour,
        sum.residual_std,
        sum.residual_lag1,
        sum.unit_bg_difference,
        a.units,
        speed.map_or("-".to_string(), |s| format!("{s:.0}")),
    )?;
    let real = stats::background_difference(sim.real_background(), sim.real_background_tvl());
    let (ta, tb) = (
        stats::residual_noise(sim.real_background()),
        stats::residual_noise(sim.real_background_tvl()),
    );
    writeln!(out,
        "| real no-contact frames: tacto, tvl | - | - | - | - | {:.2} / {:.2}, {:.2} / {:.2} | {real:.1} (tacto vs tvl) | - |",
        ta.0, ta.1, tb.0, tb.1
    )?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        args: Args,
    }

    fn parse(v: &[&str]) -> Args {
        let mut all = vec!["sim"];
        all.extend_from_slice(v);
        Cli::try_parse_from(all).expect("arguments parse").args
    }

    #[test]
    fn press_command_writes_a_readable_press() {
        let tmp = tempfile::tempdir().unwrap();
        let out = tmp.path().join("press");
        let o = out.to_str().unwrap();
        run(parse(&[
            "--textile",
            "T042",
            "--seed",
            "7",
            "--person",
            "3",
            "--no-jig",
            "--rotation",
            "-30",
            "--force",
            "5.5",
            "--tilt",
            "1.5,-0.5",
            "--frames",
            "4",
            "--out",
            o,
        ]))
        .unwrap();
        let p = recording::read_press(&out).unwrap();
        assert_eq!(p.frames.len(), 4);
        assert_eq!(
            (p.meta.textile.as_str(), p.meta.person, p.meta.jig),
            ("T042", 3, false)
        );
        let params = p.meta.params.unwrap();
        assert_eq!((params.rotation_deg, params.force_n), (-30.0, 5.5));
        assert_eq!(params.tilt_deg, [1.5, -0.5]);
        // same seed, same frames; refuses to overwrite
        let again = tmp.path().join("again");
        run(parse(&[
            "--textile",
            "T042",
            "--seed",
            "7",
            "--person",
            "3",
            "--no-jig",
            "--rotation",
            "-30",
            "--force",
            "5.5",
            "--tilt",
            "1.5,-0.5",
            "--frames",
            "4",
            "--out",
            again.to_str().unwrap(),
        ]))
        .unwrap();
        assert_eq!(recording::read_press(&again).unwrap().frames, p.frames);
        let e = run(parse(&["--textile", "T042", "--frames", "2", "--out", o])).unwrap_err();
        assert!(e.to_string().contains("already exists"), "{e}");
    }

    #[test]
    fn bad_press_arguments_are_clear_errors() {
        let tmp = tempfile::tempdir().unwrap();
        let o = tmp.path().join("x");
        let e = run(parse(&["--textile", "X9", "--out", o.to_str().unwrap()])).unwrap_err();
        assert!(e.to_string().contains("X9"), "{e}");
        let e = run(parse(&[
            "--textile",
            "T001",
            "--tilt",
            "1",
            "--out",
            o.to_str().unwrap(),
        ]))
        .unwrap_err();
        assert!(e.to_string().contains("two angles"), "{e}");
        let e = run(parse(&[
            "--textile",
            "T001",
            "--tilt",
            "30,0",
            "--out",
            o.to_str().unwrap(),
        ]))
        .unwrap_err();
        assert!(e.to_string().contains("tilt"), "{e}");
        let e = run(parse(&["--textile", "T001"])).unwrap_err();
        assert!(e.to_string().contains("--out"), "{e}");
        assert!(Cli::try_parse_from(["sim", "--jig", "--no-jig"]).is_err());
    }

    #[test]
    fn dataset_and_contact_sheet_commands() {
        let tmp = tempfile::tempdir().unwrap();
        let root = tmp.path().join("ds");
        run(parse(&[
            "dataset",
            "--out",
            root.to_str().unwrap(),
            "--limit",
            "2",
            "--frames",
            "2",
            "--sensors",
            "1",
            "--hand-only",
        ]))
        .unwrap();
        let presses: Vec<_> = std::fs::read_dir(root.join("T001")).unwrap().collect();
        assert_eq!(presses.len(), 1);
        assert!(root.join("T002").is_dir());
        run(parse(&["dataset", "--stream", "--limit", "3"])).unwrap();
        let sheet = tmp.path().join("docs/sheet.png");
        run(parse(&["contact-sheet", "--out", sheet.to_str().unwrap()])).unwrap();
        let img = image_dims(&sheet);
        assert_eq!(img, (6 * 240, 2 * (320 + 22)));
    }

    #[test]
    fn catalogue_2_presses_and_stats() {
        let tmp = tempfile::tempdir().unwrap();
        let out = tmp.path().join("v2");
        run(parse(&[
            "--textile",
            "T090",
            "--seed",
            "3",
            "--catalogue",
            "2",
            "--generator",
            "2",
            "--fps",
            "25",
            "--sensor",
            "7",
            "--frames",
            "5",
            "--out",
            out.to_str().unwrap(),
        ]))
        .unwrap();
        let p = recording::read_press(&out).unwrap();
        assert_eq!(p.meta.fps, 25.0);
        assert_eq!(p.meta.timestamps_us[1], 40_000);
        let params = p.meta.params.unwrap();
        assert_eq!((params.catalogue_version, params.generator), (2, 2));
        // the same press from the library
        let sim = Simulator::with_options(2, 2).unwrap();
        let spec = PressSpec {
            sensor: 7,
            frames: 5,
            fps: Some(25.0),
            ..PressSpec::new("T090", 3)
        };
        assert_eq!(sim.render_press(&spec).unwrap().frames, p.frames);
        // generator 2 needs catalogue 2
        let e = run(parse(&[
            "--textile",
            "T090",
            "--generator",
            "2",
            "--out",
            tmp.path().join("x").to_str().unwrap(),
        ]))
        .unwrap_err();
        assert!(e.to_string().contains("generator"), "{e}");
        run(parse(&[
            "dataset",
            "--stream",
            "--limit",
            "2",
            "--catalogue",
            "2",
        ]))
        .unwrap();
        run(parse(&["list", "--catalogue", "2"])).unwrap();
        let sheet = tmp.path().join("sheet2.png");
        run(parse(&[
            "contact-sheet",
            "--catalogue",
            "2",
            "--out",
            sheet.to_str().unwrap(),
        ]))
        .unwrap();
        assert_eq!(image_dims(&sheet), (6 * 240, 2 * (320 + 22)));
        run(parse(&[
            "stats",
            "--catalogue",
            "2",
            "--per-family",
            "1",
            "--units",
            "2",
            "--speed-presses",
            "1",
        ]))
        .unwrap();
    }

    fn image_dims(p: &Path) -> (u32, u32) {
        let bytes = std::fs::read(p).unwrap();
        // PNG IHDR: width and height at bytes 16..24
        (
            u32::from_be_bytes(bytes[16..20].try_into().unwrap()),
            u32::from_be_bytes(bytes[20..24].try_into().unwrap()),
        )
    }
}
