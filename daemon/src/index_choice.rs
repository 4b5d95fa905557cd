//! Which features and which distance an index uses: the command-line
//! choices of `index build` and `index check`, the feature kinds taken from
//! one encoding, and the choice among them made on an owner's presses,
//! each press left out in turn (`Choice`).

use std::collections::BTreeMap;

use telextiles_index::build::{FitCheck, MetricFit, SelfCheck};
use telextiles_index::Features;

/// The frame embeddings of each press of one textile, and each press's
/// mean.
pub(crate) type FrameAndPressEmbeddings = (Vec<Vec<Vec<f32>>>, Vec<Vec<f32>>);

/// `--fit`: how the index's distance is fitted to the presses.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum FitArg {
    /// Whichever of the fits below decides the most of your presses right,
    /// each press left out in turn with the fit made again without it;
    /// plain cosine on a tie.
    Auto,
    /// Within-fabric whitening of every frame of the presses (shrinkage
    /// LDA), shrunk by the Ledoit-Wolf estimate unless --metric-shrinkage.
    Frames,
    /// Within-fabric whitening of the presses' means at --metric-shrinkage.
    PressMeans,
    /// Plain cosine distance (as --no-metric).
    Cosine,
}

/// The fit `--fit`, `--metric`/`--no-metric` and `--metric-shrinkage` ask
/// for (`learn`: whether a distance is learned at all).
/// `fallback` when nothing says otherwise (`index build`: plain cosine,
/// docs/studies/2026-12-04-fitted-metric.md; `index check`: every fit).
pub(crate) fn metric_fit(
    no_metric: bool,
    metric: bool,
    fit: Option<FitArg>,
    shrinkage: Option<f32>,
    fallback: MetricFit,
) -> MetricFit {
    let press_means =
        || MetricFit::PressMeans(shrinkage.unwrap_or(telextiles_index::metric::DEFAULT_SHRINKAGE));
    match fit {
        _ if no_metric => MetricFit::Cosine,
        Some(FitArg::Cosine) => MetricFit::Cosine,
        Some(FitArg::Auto) => MetricFit::Auto,
        Some(FitArg::Frames) => MetricFit::Frames(shrinkage),
        Some(FitArg::PressMeans) => press_means(),
        // A shrinkage, or --metric: press means, as before fits on frames.
        None if metric || shrinkage.is_some() => press_means(),
        None => fallback,
    }
}

/// `--features`: what the index's queries are made of.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum FeaturesArg {
    /// The encoder's embedding alone, or beside it the LBP histograms,
    /// the Gabor energies or both, whichever decides more of your presses
    /// right (with the fit chosen for each); the simpler on a tie.
    Auto,
    /// The encoder's embedding alone.
    Encoder,
    /// The encoder's embedding and rotation-invariant LBP histograms of
    /// the same frame minus its reference.
    Lbp,
    /// The encoder's embedding and rotation-invariant Gabor energies.
    Gabor,
    /// The encoder's embedding, the LBP histograms and the Gabor energies.
    LbpGabor,
}

/// The features `--features` asks for (None: chosen on the presses),
/// `fallback` when it is not given (`index build`: the encoder alone;
/// `index check`: chosen).
pub(crate) fn features_asked(
    arg: Option<FeaturesArg>,
    fallback: Option<Features>,
) -> Option<Features> {
    match arg {
        Some(FeaturesArg::Encoder) => Some(Features::Encoder),
        Some(FeaturesArg::Lbp) => Some(Features::EncoderLbp),
        Some(FeaturesArg::Gabor) => Some(Features::EncoderGabor),
        Some(FeaturesArg::LbpGabor) => Some(Features::EncoderLbpGabor),
        Some(FeaturesArg::Auto) => None,
        None => fallback,
    }
}

/// What the encoder computes so that every asked kind of features can be
/// taken from it ([`part_of`]).
pub(crate) fn features_computed(asked: Option<Features>) -> Features {
    asked.unwrap_or(Features::EncoderLbpGabor)
}

/// The `want` parts of an embedding computed as `computed` (which holds
/// them): the encoder's part, then the LBP histograms and the Gabor
/// energies `want` has. Every part has the same length in both, so after
/// the normalisation every consumer makes it is what an encoder set to
/// `want` computes.
pub(crate) fn part_of(
    v: &[f32],
    want: Features,
    computed: Features,
    encoder_dim: usize,
) -> Vec<f32> {
    if want == computed {
        return v.to_vec();
    }
    let (has_lbp, has_gabor) = computed.parts();
    let (want_lbp, want_gabor) = want.parts();
    let lbp = encoder_dim..encoder_dim + usize::from(has_lbp) * telextiles_index::LBP_DIM;
    let gabor = lbp.end..lbp.end + usize::from(has_gabor) * telextiles_index::GABOR_DIM;
    let mut out = v[..encoder_dim.min(v.len())].to_vec();
    if want_lbp {
        out.extend_from_slice(&v[lbp]);
    }
    if want_gabor {
        out.extend_from_slice(&v[gabor]);
    }
    out
}

/// Each textile's presses with only the `want` part of their vectors.
pub(crate) fn textiles_as(
    by_textile: &BTreeMap<String, FrameAndPressEmbeddings>,
    want: Features,
    computed: Features,
    encoder_dim: usize,
) -> BTreeMap<String, FrameAndPressEmbeddings> {
    let part = |v: &Vec<f32>| part_of(v, want, computed, encoder_dim);
    by_textile
        .iter()
        .map(|(id, (frames, means))| {
            (
                id.clone(),
                (
                    frames
                        .iter()
                        .map(|f| f.iter().map(part).collect())
                        .collect(),
                    means.iter().map(part).collect(),
                ),
            )
        })
        .collect()
}

/// Every (features, fit) checked on an owner's presses, each press left
/// out in turn with the fit made again without it, and the chosen one:
/// the most presses right, the earlier (the encoder alone, the simpler
/// fit) on a tie.
pub(crate) struct Choice {
    pub(crate) checks: Vec<(Features, FitCheck)>,
    pub(crate) chosen: usize,
}

impl Choice {
    pub(crate) fn of(
        by_textile: &BTreeMap<String, FrameAndPressEmbeddings>,
        ids: &[String],
        computed: Features,
        asked: Option<Features>,
        fit: MetricFit,
        exemplars: bool,
        encoder_dim: usize,
    ) -> Choice {
        let kinds = match asked {
            Some(f) => vec![f],
            None => Features::ALL.to_vec(),
        };
        let fits = match fit {
            MetricFit::Auto => MetricFit::CANDIDATES.to_vec(),
            f => vec![f],
        };
        let mut checks = Vec::new();
        for kind in kinds {
            let dim = encoder_dim + kind.extra_dim();
            let parts;
            let source = if kind == computed {
                by_textile
            } else {
                parts = textiles_as(by_textile, kind, computed, encoder_dim);
                &parts
            };
            let fabrics: Vec<telextiles_index::build::FabricPresses> = ids
                .iter()
                .map(|id| {
                    source
                        .get(id)
                        .map(|(frames, means)| (means.clone(), frames.clone()))
                        .unwrap_or_default()
                })
                .collect();
            let data = telextiles_index::build::press_data(&fabrics, dim);
            let (_, c) = telextiles_index::build::choose_fit(&data, dim, exemplars, &fits);
            checks.extend(c.into_iter().map(|c| (kind, c)));
        }
        let mut chosen = 0;
        for (k, (_, c)) in checks.iter().enumerate() {
            if c.right() > checks[chosen].1.right() {
                chosen = k;
            }
        }
        Choice { checks, chosen }
    }

    pub(crate) fn features(&self) -> Features {
        self.checks[self.chosen].0
    }

    pub(crate) fn fit(&self) -> &FitCheck {
        &self.checks[self.chosen].1
    }

    /// In words: "encoder + LBP, frames, Ledoit-Wolf shrinkage".
    pub(crate) fn label(&self) -> String {
        label(self.features(), self.fit().fit)
    }
}

/// A kind of features and a fit, in words.
pub(crate) fn label(features: Features, fit: MetricFit) -> String {
    format!("{}, {}", features.label(), fit.label())
}

/// A shrinkage for `--metric-shrinkage`: a number in 0..=1.
pub(crate) fn parse_shrinkage(s: &str) -> Result<f32, String> {
    let a: f32 = s.parse().map_err(|e| format!("{s}: {e}"))?;
    if (0.0..=1.0).contains(&a) {
        Ok(a)
    } else {
        Err(format!("{a} is outside 0..=1"))
    }
}

/// The fits checked on the presses, one line each, the chosen one marked:
/// what `index check` and `index build --presses` show of the choice.
pub(crate) fn fits_text(fits: &[(Features, FitCheck)], chosen: usize) -> String {
    let lines: Vec<String> = fits
        .iter()
        .enumerate()
        .map(|(k, (features, f))| {
            format!(
                "    {} {}: {} of {} right",
                if k == chosen { "*" } else { " " },
                label(*features, f.fit),
                f.right(),
                f.left.len()
            )
        })
        .collect();
    lines.join("\n")
}
/// "; taken for another: A as B (3), ..." (at most five pairs), or nothing.
pub(crate) fn confusions_text<'a>(check: &SelfCheck, id: &dyn Fn(usize) -> &'a str) -> String {
    if check.confusions.is_empty() {
        return String::new();
    }
    let shown: Vec<String> = check
        .confusions
        .iter()
        .take(5)
        .map(|&(f, d, n)| format!("{} as {} ({n})", id(f), id(d)))
        .collect();
    let more = check.confusions.len() - shown.len();
    let mut text = format!("; taken for another: {}", shown.join(", "));
    if more > 0 {
        text += &format!(" and {more} more");
    }
    text
}
