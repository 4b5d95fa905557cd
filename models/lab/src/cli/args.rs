//! Every subcommand's arguments (clap), and the shared data and split
//! arguments with their checks.

use anyhow::{bail, ensure, Result};
use clap::Args;
use std::path::{Path, PathBuf};

use telextiles_lab::protocol::{Protocol, SourceKind};
use telextiles_lab::recorded::{Source, Split, StudyConfig};

#[derive(Args)]
pub(crate) struct MstatsScaleArgs {
    /// Recorded presses (the press format, found recursively).
    #[arg(long)]
    pub(crate) presses: PathBuf,
    /// Every how many frames in contact to take one.
    #[arg(long, default_value_t = 4)]
    pub(crate) every: usize,
}

#[derive(Args)]
pub(crate) struct ContactIdleArgs {
    /// Sensor units to render, CATALOGUE:UNIT,UNIT,... (repeat per
    /// catalogue) [default: 1:0,4,5, unless --footage is given].
    #[arg(long, num_args = 1)]
    pub(crate) units: Vec<String>,
    /// A recording of the sensor resting untouched (`telextilesd record
    /// --idle` writes them), or a directory of them; repeat for more. Read
    /// whole, beside the units rendered, and reported as catalogue 0.
    #[arg(long, num_args = 1)]
    pub(crate) footage: Vec<PathBuf>,
    /// Seconds of footage per unit.
    #[arg(long, default_value_t = 300.0)]
    pub(crate) seconds: f64,
    /// Extra LED flicker levels, % gain per channel per frame (0 = as rendered).
    #[arg(long, value_delimiter = ',', default_value = "0,0.5,1")]
    pub(crate) stress: Vec<f32>,
    #[arg(long, default_value_t = 2)]
    pub(crate) threads: usize,
    #[arg(long, default_value_t = 7)]
    pub(crate) seed: u64,
    /// Where idle.json and idle.md go.
    #[arg(long)]
    pub(crate) out: PathBuf,
}

#[derive(Args)]
pub(crate) struct ContactChooseArgs {
    /// A `contact-idle` study's idle.json.
    #[arg(long)]
    pub(crate) idle: PathBuf,
    /// `decider-timing` studies' timing.json, one per detector and source
    /// (those without a detector are the shipped one's).
    #[arg(long, required = true, num_args = 1)]
    pub(crate) timing: Vec<PathBuf>,
    /// Where choice.md and right-at-100ms.svg go.
    #[arg(long)]
    pub(crate) out: PathBuf,
}

#[derive(Args)]
pub(crate) struct DeciderSwitchArgs {
    /// A study's timing.json (`decider-timing --out DIR` writes
    /// DIR/timing.json); give two or more.
    #[arg(long, required = true, num_args = 1)]
    pub(crate) timing: Vec<PathBuf>,
    /// Where the markdown goes (printed too).
    #[arg(long)]
    pub(crate) out: Option<PathBuf>,
}

#[derive(Args)]
pub(crate) struct DeciderTimingArgs {
    #[command(flatten)]
    pub(crate) data: DataArgs,
    /// The ONNX encoder.
    #[arg(long, default_value = "models/encoder.onnx")]
    pub(crate) model: PathBuf,
    /// Held-out people (and their units) that press the queries, from the
    /// protocol's list (--heldout-people sets the list and the index).
    #[arg(long, default_value_t = 3)]
    pub(crate) people: usize,
    /// The contact detector's entry threshold (score above the noise
    /// floor; default: the shipped detector's).
    #[arg(long)]
    pub(crate) contact_enter: Option<f32>,
    /// Its exit threshold (default: the shipped one, or 0.6 x the entry
    /// threshold when that is lower).
    #[arg(long)]
    pub(crate) contact_exit: Option<f32>,
    /// Frames in a row over the entry threshold that start a press (and
    /// the time they span at 60 fps: (n - 1) x 16.7 ms, less 3 ms).
    #[arg(long)]
    pub(crate) contact_frames: Option<u32>,
    /// Score contact after the best per-channel gain (`true`) or plainly
    /// (`false`): the detector's `gain_compensated` (default: the shipped
    /// detector's).
    #[arg(long)]
    pub(crate) contact_gain: Option<bool>,
    /// Score the most changed tile of this many 4-px blocks a side
    /// instead of the whole frame: the detector's `tile` (0 = the whole
    /// frame; default: the shipped detector's).
    #[arg(long)]
    pub(crate) contact_tile: Option<u32>,
    /// Where timing.json, report.md and the charts go.
    #[arg(long)]
    pub(crate) out: PathBuf,
}

#[derive(Args)]
pub(crate) struct SupconArgs {
    /// Architecture (fully convolutional ResNet; input size = -s<N>).
    #[arg(long, default_value = "resnet-d1111-w16-s96")]
    pub(crate) arch: String,
    /// Deployment centre crop (px of the frame).
    #[arg(long, default_value_t = 192)]
    pub(crate) crop: u32,
    /// Simulator catalogue and texture generator of the training presses.
    #[arg(long, default_value_t = 2)]
    pub(crate) catalogue: u32,
    #[arg(long, default_value_t = 1)]
    pub(crate) generator: u32,
    /// Presses rendered per training textile.
    #[arg(long, default_value_t = 14)]
    pub(crate) presses_per_textile: usize,
    /// Frames kept per training press: `--ramp-frames` of them from the
    /// contact ramp, the rest over the hold.
    #[arg(long, default_value_t = 4)]
    pub(crate) frames_per_press: usize,
    /// How many of the kept frames come from the contact ramp: 1 is one
    /// frame late in the ramp; more are spread over the whole ramp from the
    /// first frame in contact (the press's first tenth of a second).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=16))]
    pub(crate) ramp_frames: u32,
    /// Validation query presses per textile (person 7 on unit 15).
    #[arg(long, default_value_t = 1)]
    pub(crate) val_presses: usize,
    /// Only the first N training textiles (quick runs).
    #[arg(long)]
    pub(crate) textiles: Option<usize>,
    /// Training steps, and a validation every this many.
    #[arg(long, default_value_t = 3000)]
    pub(crate) steps: usize,
    #[arg(long, default_value_t = 250)]
    pub(crate) eval_every: usize,
    /// Textiles per batch and frames (each from another press) per textile.
    #[arg(long, default_value_t = 16)]
    pub(crate) classes_per_batch: usize,
    #[arg(long, default_value_t = 4)]
    pub(crate) views_per_class: usize,
    /// AdamW learning rate.
    #[arg(long, default_value_t = 2e-3)]
    pub(crate) lr: f64,
    /// Wall-time budget in minutes (rendering included); the best
    /// checkpoint so far is kept.
    #[arg(long)]
    pub(crate) max_minutes: Option<f64>,
    #[arg(long, default_value_t = 0)]
    pub(crate) seed: u64,
    /// Render threads.
    #[arg(long, default_value_t = 2)]
    pub(crate) threads: usize,
    /// Run directory (config.json, metrics.jsonl, best.bpk).
    #[arg(long)]
    pub(crate) run: PathBuf,
    /// Where the ONNX model goes.
    #[arg(long)]
    pub(crate) out: PathBuf,
}

#[derive(Args)]
pub(crate) struct RuleArgs {
    /// The bench's bench.json.
    #[arg(long)]
    pub(crate) bench: PathBuf,
    /// The method shipped when the study ran, by the name the bench gave
    /// it (the default: the descriptor shipped until 2026-11-26, the
    /// incumbent of every committed study; a study of the model shipped
    /// since names it, e.g. `--model wspec+lin128-p48=models/encoder.onnx`
    /// and `--incumbent wspec+lin128-p48`).
    #[arg(long, default_value = "fft-radial-c192-bg")]
    pub(crate) incumbent: String,
}

#[derive(Args)]
pub(crate) struct SpectralArgs {
    /// Presses rendered per training textile.
    #[arg(long, default_value_t = 24)]
    pub(crate) presses_per_textile: usize,
    /// Augmented copies of every kept frame.
    #[arg(long, default_value_t = 3)]
    pub(crate) augs: usize,
    /// Frames kept per training press: `--ramp-frames` of them from the
    /// contact ramp, the rest over the hold.
    #[arg(long, default_value_t = 4)]
    pub(crate) frames_per_press: usize,
    /// How many of the kept frames come from the contact ramp: 1 is one
    /// frame late in the ramp; more are spread over the whole ramp from the
    /// first frame in contact (the press's first tenth of a second).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=16))]
    pub(crate) ramp_frames: u32,
    /// Validation presses per textile (person 7 on unit 15; each a query).
    #[arg(long, default_value_t = 1)]
    pub(crate) val_presses: usize,
    /// Only the first N training textiles (quick runs).
    #[arg(long)]
    pub(crate) textiles: Option<usize>,
    #[arg(long, default_value_t = 4000)]
    pub(crate) steps: usize,
    /// The fixed descriptor under the head: `fft` (the luma spectrum of the
    /// 192-px crop), `wspec` (the colour-whitened spectrum with angular
    /// harmonics of the 240-px crop at 120 px) or `wspec-cw` (the same under
    /// a window centred on the contact).
    #[arg(long, default_value = "fft")]
    pub(crate) front: telextiles_lab::spectral::Front,
    /// The front end's window taper in %: 100 is the Hann window of the
    /// shipped model; below, a flatter Tukey window (the centred windows,
    /// `fft` and `wspec`; `wspec-cw` refuses it).
    #[arg(long, default_value_t = 100, value_parser = clap::value_parser!(u32).range(1..=100))]
    pub(crate) taper: u32,
    /// Hidden units of the head (0: a linear head).
    #[arg(long, default_value_t = 256)]
    pub(crate) hidden: usize,
    #[arg(long, default_value_t = 128)]
    pub(crate) dim: usize,
    #[arg(long, default_value_t = 3e-3)]
    pub(crate) lr: f64,
    /// SupCon temperature.
    #[arg(long, default_value_t = 0.1)]
    pub(crate) temperature: f32,
    /// Simulator catalogue of the training presses.
    #[arg(long, default_value_t = 2)]
    pub(crate) catalogue: u32,
    /// Weight of the attribute objective (0: off): the embedding also
    /// predicts the training textiles' measured tactile attributes.
    #[arg(long, default_value_t = 0.0)]
    pub(crate) attr_weight: f32,
    #[arg(long, default_value_t = 0)]
    pub(crate) seed: u64,
    #[arg(long, default_value_t = 2)]
    pub(crate) threads: usize,
    /// Cache of rendered spectra (shared by runs with the same data).
    #[arg(long, default_value = "target/telextiles-lab/cache")]
    pub(crate) cache_dir: PathBuf,
    /// Run directory (config.json, metrics.jsonl).
    #[arg(long)]
    pub(crate) run: PathBuf,
    /// Where the ONNX model goes.
    #[arg(long)]
    pub(crate) out: PathBuf,
}

#[derive(Args)]
pub(crate) struct SimPressesArgs {
    /// Where the presses go (`<out>/<textile>/p<person>-s<sensor>-<n>/`;
    /// existing presses are kept).
    #[arg(long)]
    pub(crate) out: PathBuf,
    /// Textile ids, comma-separated (default: --first of the training
    /// book).
    #[arg(long, value_delimiter = ',')]
    pub(crate) textiles: Vec<String>,
    /// The first N training textiles when --textiles is not given.
    #[arg(long, default_value_t = 12)]
    pub(crate) first: usize,
    /// Presses per textile.
    #[arg(long, default_value_t = 6)]
    pub(crate) presses: usize,
    /// Sensor units, cycled over the presses of a textile (each unit has
    /// its own background).
    #[arg(long, value_delimiter = ',', default_value = "0,4,5")]
    pub(crate) sensors: Vec<u32>,
    /// Simulated people, cycled over the presses of a textile.
    #[arg(long, value_delimiter = ',', default_value = "0")]
    pub(crate) people: Vec<u32>,
    /// Hand-held presses (tilt, wobble, slip) instead of the jig.
    #[arg(long)]
    pub(crate) hand: bool,
    /// Frames per press (60 fps).
    #[arg(long, default_value_t = 150)]
    pub(crate) frames: usize,
    /// Base seed.
    #[arg(long, default_value_t = 0)]
    pub(crate) seed: u64,
    /// Simulator catalogue (1 or 2).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=2))]
    pub(crate) catalogue: u32,
    /// Texture generator of catalogue 2 (1 or 2).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=2))]
    pub(crate) generator: u32,
}

#[derive(Args)]
pub(crate) struct QuantizeArgs {
    /// Float ONNX model.
    #[arg(long)]
    pub(crate) model: PathBuf,
    /// Output int8 model.
    #[arg(long)]
    pub(crate) out: PathBuf,
    /// Calibration frames (spread over the training people's frames).
    #[arg(long, default_value_t = 256)]
    pub(crate) calibration_frames: usize,
    /// Write the int8 model even if it gives non-finite embeddings (for the
    /// study's chart; such a model must not ship).
    #[arg(long)]
    pub(crate) allow_nonfinite: bool,
    #[command(flatten)]
    pub(crate) data: DataArgs,
}

#[derive(Args)]
pub(crate) struct BenchArgs {
    #[command(flatten)]
    pub(crate) data: DataArgs,
    /// ONNX models to measure beside the classical descriptors, as
    /// `NAME=PATH` or `PATH` (named after the file).
    #[arg(long)]
    pub(crate) model: Vec<String>,
    /// Leave the classical descriptors out.
    #[arg(long)]
    pub(crate) no_descriptors: bool,
    /// Descriptors computed in Rust to measure as well, `KIND[-bg]@CROP`
    /// (e.g. `wspec-bg@240`, `wspec-m3-bg@240`; kinds: pixels, lbp, fft,
    /// wspec, wspec-cw, mstats, and wspec-mW: the spectrum and the
    /// marginal statistics, each weighted as W spectral values).
    #[arg(long)]
    pub(crate) rust_descriptor: Vec<String>,
    /// ONNX Runtime thread counts to time the models with.
    #[arg(long, value_delimiter = ',', default_value = "1,2")]
    pub(crate) time_threads: Vec<usize>,
    /// Timed frames per method and thread count.
    #[arg(long, default_value_t = 300)]
    pub(crate) runs: usize,
    /// Two levels per stability factor (a smoke test of the harness).
    #[arg(long)]
    pub(crate) quick: bool,
    /// Skip the stability suite.
    #[arg(long)]
    pub(crate) no_stability: bool,
    /// Stability factors to run (default: all): rotation, force, tilt,
    /// handheld, led, sensor, noise, stale, unseen.
    #[arg(long, value_delimiter = ',')]
    pub(crate) factors: Vec<String>,
    /// Consecutive hold frames per stability query press.
    #[arg(long, default_value_t = 8)]
    pub(crate) stability_frames: usize,
    /// The stability suite's index also holds its frames with the cloth
    /// stretched by 1 ± A along each axis, both and opposed (eight
    /// copies; 0: as rendered).
    #[arg(long, default_value_t = 0.0)]
    pub(crate) index_stretch: f32,
    /// Frames from first contact for the time-to-decision curve (0: skip).
    #[arg(long, default_value_t = 30)]
    pub(crate) decision_frames: usize,
    /// Roller textiles for the user test: comma-separated ids, or an index
    /// file whose roller layout to use.
    #[arg(long, default_value = "models/index.tlxi")]
    pub(crate) roller: String,
    #[command(flatten)]
    pub(crate) recorded: SplitArgs,
    /// Also score every method on the cross-generator test set (the same
    /// protocol rendered by texture generator 2; needs --catalogue 2).
    #[arg(long)]
    pub(crate) cross_generator: bool,
    /// Where the results go [default: docs/bench for the simulator;
    /// required for presses:<dir>].
    #[arg(long)]
    pub(crate) out: Option<PathBuf>,
}

#[derive(Args)]
pub(crate) struct ExportDescriptorArgs {
    /// `fft` (radially averaged log power spectrum of the grey crop),
    /// `wspec` (colour-whitened spectrum with angular harmonics; needs
    /// --subtract), `wspec-cw` (the same, its window centred on the
    /// contact) or `pixels`.
    #[arg(long, default_value = "fft")]
    pub(crate) kind: String,
    /// Centre crop of the frame in px (even, up to 240).
    #[arg(long, default_value_t = 64)]
    pub(crate) crop: u32,
    /// Side of the model's input (the crop resized to it; default: the
    /// crop, no resampling).
    #[arg(long)]
    pub(crate) input: Option<u32>,
    /// The model takes the frame minus the no-contact reference
    /// (`telextiles.background = subtract`).
    #[arg(long)]
    pub(crate) subtract: bool,
    /// `fft`: the lowest radius bin kept (1 keeps all but DC).
    #[arg(long, default_value_t = 1)]
    pub(crate) min_bin: u32,
    /// The window's taper in % (`fft`, `wspec`): 100 is the Hann window of
    /// every shipped descriptor; below, a flatter Tukey window that keeps
    /// more of the crop (`wspec::tukey`).
    #[arg(long, default_value_t = 100, value_parser = clap::value_parser!(u32).range(1..=100))]
    pub(crate) taper: u32,
    /// Output ONNX file.
    #[arg(long)]
    pub(crate) out: PathBuf,
}

#[derive(Args, Clone)]
pub(crate) struct DataArgs {
    /// Frame source: `sim` (telextiles-sim), `synth` (procedural, for
    /// tests), or `presses:<dir>`: your own recordings (`eval` and `bench`
    /// only; the press format of `telextilesd record`, found recursively,
    /// else the PyTouch layout <dir>/<class>/<serial>/*.png).
    #[arg(long, default_value = "sim")]
    pub(crate) source: Source,
    /// Network input size the caches are made for.
    #[arg(long, default_value_t = 64)]
    pub(crate) input: u32,
    /// Deployment centre crop (px of the 240x320 frame).
    #[arg(long, default_value_t = 168)]
    pub(crate) crop: u32,
    /// Training frames per press.
    #[arg(long, default_value_t = 8)]
    pub(crate) train_frames: usize,
    /// Only the first N textiles (quick runs).
    #[arg(long)]
    pub(crate) textiles: Option<usize>,
    /// Cache directory.
    #[arg(long, default_value = "target/telextiles-lab/cache")]
    pub(crate) cache_dir: PathBuf,
    /// Render threads (presses:<dir>: recordings embedded at once, with
    /// one ONNX Runtime thread each).
    #[arg(long, default_value_t = 2)]
    pub(crate) threads: usize,
    /// Simulator catalogue: 1 (the original lattices, bit-identical) or 2
    /// (bolts with swatches, irregular relief, 16+ sensor units; see
    /// docs/simulator.md).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=2))]
    pub(crate) catalogue: u32,
    /// Texture generator of catalogue 2: 1 (structural; what methods are
    /// chosen on) or 2 (Gabor noise; the cross-generator test set).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=2))]
    pub(crate) generator: u32,
    /// Held-out people (at least 3): persons 8, 9, 10, ... on units 0, 4,
    /// 5 in turn; more than the paper's 3 give every group of the study
    /// more presses, so that methods can be told apart outside noise.
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u32).range(3..=30))]
    pub(crate) heldout_people: u32,
}

impl DataArgs {
    /// The built-in source (recordings are for `eval` and `bench` only).
    pub(crate) fn kind(&self) -> Result<SourceKind> {
        match &self.source {
            Source::Builtin(k) => Ok(*k),
            Source::Presses(d) => bail!(
                "--source presses:{} works with `eval` and `bench` (the study on recorded presses); this command needs sim or synth",
                d.display()
            ),
        }
    }

    pub(crate) fn protocol(&self) -> Protocol {
        let mut p = Protocol::paper(self.input, self.crop);
        p.train_frames = self.train_frames;
        p.max_textiles = self.textiles;
        p.catalogue = self.catalogue;
        p.generator = self.generator;
        p.with_heldout_people(self.heldout_people as usize)
    }
}

/// How recorded presses are split (`--source presses:<dir>` only).
#[derive(Args, Clone)]
pub(crate) struct SplitArgs {
    /// K recordings of each textile build the index (the first K in sorted
    /// path order), the others are queries [default: 3].
    #[arg(long)]
    pub(crate) index_presses: Option<usize>,
    /// `index-presses` (see --index-presses) or `lopo` (leave one press
    /// out: each recording against an index of all the others).
    #[arg(long, value_parser = ["index-presses", "lopo"])]
    pub(crate) split: Option<String>,
    /// Frames in contact per recording used as index frames and as
    /// per-frame queries, spread over the contact (0: all); the per-press
    /// decision always uses every frame in contact.
    #[arg(long, default_value_t = 30)]
    pub(crate) frames_per_press: usize,
    /// Encode the run of frames that starts each press too (the front
    /// end's `set_encode_run`, the daemon's `encode_run`, off by default):
    /// embeddings and decisions begin at the press's first frame over the
    /// contact threshold, a frame sooner with the shipped detector.
    #[arg(long)]
    pub(crate) encode_run: bool,
    /// The sensor's no-contact frame (a 240x320 RGB PNG taken with nothing
    /// touching the gel), for recordings that carry no reference and whose
    /// first frames are already in contact (PyTouch sequences cut to the
    /// press): `PNG` for every sensor, `SERIAL=PNG` for one (repeat it).
    /// A recording's own reference always wins.
    #[arg(long = "reference", value_name = "[SERIAL=]PNG")]
    pub(crate) references: Vec<String>,
    /// Frame rate of recordings saved without timestamps (PyTouch-style
    /// datasets) [default: the DIGIT's stream rate at the frames' size:
    /// 60 fps for 240x320 or 320x240, 30 for VGA].
    #[arg(long, value_parser = telextiles_sim::recording::parse_fps)]
    pub(crate) fps: Option<f32>,
    /// Sensor profile of recordings that do not name theirs (PyTouch-style
    /// datasets): digit, gelsight-mini or uvc, as the daemon's
    /// `--sensor-profile` [default: recordings say their own, else digit]
    #[arg(long, value_name = "PROFILE", value_parser = telextiles_recording::profile::by_name)]
    pub(crate) sensor_profile: Option<&'static telextiles_recording::profile::SensorProfile>,
    /// Millimetres per pixel of those recordings' images (a uvc camera
    /// needs it), as the daemon's `--sensor-mm-per-px`
    #[arg(long, value_name = "MM", requires = "sensor_profile")]
    pub(crate) sensor_mm_per_px: Option<f32>,
    /// The contact detector's `enter_ms` (a run of two or more frames over
    /// its threshold that spans this long starts a press; 0: only its 3
    /// frames) [default: the daemon's, 30].
    #[arg(long, value_parser = contact_ms)]
    pub(crate) contact_enter_ms: Option<f32>,
    /// The contact detector's `exit_ms` (a run of two or more frames under
    /// its threshold that spans this long ends a press; 0: only its 5
    /// frames) [default: the daemon's, 60].
    #[arg(long, value_parser = contact_ms)]
    pub(crate) contact_exit_ms: Option<f32>,
    /// The decider's indexes learn a distance from their presses, with
    /// this shrinkage (within-fabric whitening, as `telextilesd index
    /// build --presses` does by default; without a value 0.5). Without
    /// the flag: cosine distance.
    #[arg(long, num_args = 0..=1, default_missing_value = "0.5", value_parser = shrinkage)]
    pub(crate) index_metric: Option<f32>,
    /// Also measure the unknown-textile flag on an open set: every query
    /// press against the index of the other textiles, besides the known
    /// presses; with the decider's fixed distance and with a distance
    /// calibrated on each index's presses at each of these quantiles (as
    /// `telextilesd index build --presses --unknown-quantile Q` makes it),
    /// e.g. 0.9,0.95,1.
    #[arg(long, value_delimiter = ',', value_parser = telextiles_index::build::parse_quantile)]
    pub(crate) unknown_quantiles: Vec<f32>,
}

pub(crate) fn contact_ms(s: &str) -> Result<f32, String> {
    let ms: f32 = s.parse().map_err(|e| format!("{s}: {e}"))?;
    if ms.is_finite() && ms >= 0.0 {
        Ok(ms)
    } else {
        Err(format!("{s} ms: expected 0 or more"))
    }
}

pub(crate) fn shrinkage(s: &str) -> Result<f32, String> {
    let a: f32 = s.parse().map_err(|e| format!("{s}: {e}"))?;
    if (0.0..=1.0).contains(&a) {
        Ok(a)
    } else {
        Err(format!("{a} is outside 0..=1"))
    }
}

impl SplitArgs {
    pub(crate) fn split(&self) -> Result<Split> {
        match (self.split.as_deref(), self.index_presses) {
            (Some("lopo"), Some(_)) => bail!("--split lopo and --index-presses exclude each other"),
            (Some("lopo"), None) => Ok(Split::Lopo),
            (_, k) => {
                let k = k.unwrap_or(3);
                ensure!(k > 0, "--index-presses must be at least 1");
                Ok(Split::IndexPresses(k))
            }
        }
    }

    pub(crate) fn given(&self) -> bool {
        self.split.is_some()
            || self.index_presses.is_some()
            || self.encode_run
            || self.index_metric.is_some()
            || !self.unknown_quantiles.is_empty()
            || !self.references.is_empty()
            || self.fps.is_some()
            || self.sensor_profile.is_some()
            || self.contact_enter_ms.is_some()
            || self.contact_exit_ms.is_some()
    }

    /// Refuse these options for a source that is not recordings.
    pub(crate) fn refuse_unless_presses(&self) -> Result<()> {
        ensure!(
            !self.given(),
            "--index-presses/--split/--encode-run/--contact-enter-ms/--contact-exit-ms/--unknown-quantiles/--reference/--fps/--sensor-profile are for --source presses:<dir>"
        );
        Ok(())
    }

    /// The study on the recordings under `dir` as these options set it
    /// (one ONNX Runtime thread per session; the caller sets the workers,
    /// timing and runs).
    pub(crate) fn study(&self, dir: &Path) -> Result<StudyConfig> {
        let mut cfg = StudyConfig::new(dir, self.split()?);
        cfg.frames_per_press = self.frames_per_press;
        cfg.encode_run = self.encode_run;
        cfg.metric = self.index_metric;
        cfg.unknown_quantiles = self.unknown_quantiles.clone();
        cfg.sensor = self
            .sensor_profile
            .map(|profile| telextiles_sim::recording::Sensor {
                profile,
                mm_per_px: self.sensor_mm_per_px,
            });
        cfg.references =
            telextiles_sensing::front::References::from_args_as(&self.references, cfg.sensor)?;
        cfg.fps = self.fps;
        if let Some(ms) = self.contact_enter_ms {
            cfg.contact.enter_ms = ms;
        }
        if let Some(ms) = self.contact_exit_ms {
            cfg.contact.exit_ms = ms;
        }
        cfg.threads = 1;
        Ok(cfg)
    }
}

#[derive(Args)]
pub(crate) struct CacheArgs {
    #[command(flatten)]
    pub(crate) data: DataArgs,
}

#[derive(Args)]
pub(crate) struct TrainArgs {
    #[command(flatten)]
    pub(crate) data: DataArgs,
    /// Architecture, e.g. resnet18-w64-s224 or resnet-d1111-w16-s64 (-e<dim> adds an embedding layer).
    #[arg(long, default_value = "resnet-d1111-w16-s64")]
    pub(crate) arch: String,
    /// Run directory (checkpoints, metrics.jsonl).
    #[arg(long)]
    pub(crate) run: PathBuf,
    #[arg(long, default_value_t = 30)]
    pub(crate) epochs: usize,
    #[arg(long)]
    pub(crate) steps_per_epoch: Option<usize>,
    #[arg(long, default_value_t = 64)]
    pub(crate) batch: usize,
    #[arg(long, default_value_t = 512)]
    pub(crate) queue: usize,
    #[arg(long, default_value_t = 0.03)]
    pub(crate) lr: f64,
    #[arg(long, default_value_t = 0.2)]
    pub(crate) temperature: f32,
    #[arg(long, default_value_t = 0.99)]
    pub(crate) key_momentum: f32,
    #[arg(long, default_value_t = 2)]
    pub(crate) bn_splits: usize,
    #[arg(long, default_value_t = 0)]
    pub(crate) seed: u64,
    /// Continue from the run's latest checkpoint.
    #[arg(long)]
    pub(crate) resume: bool,
    /// Stop after this many steps (timing runs).
    #[arg(long)]
    pub(crate) max_steps: Option<usize>,
    /// Held-out kNN/std every this many epochs.
    #[arg(long, default_value_t = 1)]
    pub(crate) eval_every: usize,
}

#[derive(Args)]
pub(crate) struct ExportArgs {
    /// Run directory (uses its latest checkpoint) or a checkpoint directory.
    #[arg(long)]
    pub(crate) run: PathBuf,
    /// Output ONNX file.
    #[arg(long, default_value = "models/encoder.onnx")]
    pub(crate) out: PathBuf,
    #[command(flatten)]
    pub(crate) data: DataArgs,
}

#[derive(Args)]
pub(crate) struct EvalArgs {
    /// ONNX encoder.
    #[arg(long, default_value = "models/encoder.onnx")]
    pub(crate) model: PathBuf,
    #[command(flatten)]
    pub(crate) data: DataArgs,
    /// ONNX Runtime threads (presses:<dir>: recordings embedded at once,
    /// one thread each).
    #[arg(long, default_value_t = 2)]
    pub(crate) ort_threads: usize,
    /// Write the results as JSON here.
    #[arg(long)]
    pub(crate) json: Option<PathBuf>,
    #[command(flatten)]
    pub(crate) recorded: SplitArgs,
}

#[derive(Args)]
pub(crate) struct LatencyArgs {
    /// ONNX encoders to time.
    #[arg(long)]
    pub(crate) model: Vec<PathBuf>,
    /// Also time randomly initialised encoders of these architectures
    /// (latency does not depend on the weights).
    #[arg(long, value_delimiter = ',')]
    pub(crate) arch: Vec<String>,
    #[arg(long, value_delimiter = ',', default_value = "1,2")]
    pub(crate) threads: Vec<usize>,
    #[arg(long, default_value_t = 300)]
    pub(crate) runs: usize,
}

#[derive(Args)]
pub(crate) struct BenchTrainArgs {
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "resnet-d1111-w16-s64,resnet18-w64-s224"
    )]
    pub(crate) arch: Vec<String>,
    #[arg(long, default_value_t = 64)]
    pub(crate) batch: usize,
    #[arg(long, default_value_t = 5)]
    pub(crate) steps: usize,
}
