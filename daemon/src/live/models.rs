//! The encoder and index a session runs with.

use anyhow::{bail, Context, Result};
use telextiles_index::Index;
use telextiles_sensing::encoder::{Encoder, EncoderOptions};

use crate::config::Config;

/// Load encoder and index (from the configured paths: `--model`/`--index`,
/// `TELEXTILESD_MODEL`/`_INDEX`, the configuration file, else the data
/// directory) and check they belong together.
pub(crate) fn load_model(cfg: &Config, threads: usize) -> Result<(Encoder, Index)> {
    let (model, index_path) = (&cfg.model, &cfg.index);
    for (p, what, flag) in [
        (model, "encoder model", "--model"),
        (index_path, "textile index", "--index"),
    ] {
        if !p.is_file() {
            bail!(
                "{what} {} not found: put the shipped models/encoder.onnx and models/index.tlxi in {}, or pass {flag}",
                p.display(),
                cfg.data_dir.display()
            );
        }
    }
    let enc = Encoder::open(
        model,
        &EncoderOptions {
            threads,
            ..Default::default()
        },
    )
    .with_context(|| format!("cannot load the encoder {}", model.display()))?;
    let mut enc = enc;
    let index = Index::read(index_path)?;
    index.check_encoder(&enc.info().sha256)?;
    // The index says what a query is made of; the sender streams exactly
    // that, so both daemons compute it alike.
    enc.set_features(index.features);
    if index.dim != enc.dim() {
        bail!(
            "{} holds {}-d embeddings but {} produces {}-d ones",
            index_path.display(),
            index.dim,
            model.display(),
            enc.dim()
        );
    }
    Ok((enc, index))
}

/// The simulator whose fabrics an index's textile ids name: the index's
/// catalogue (an index of the user's own recordings, catalogue 0, gets the
/// default catalogue 1). The simulated DIGIT of `run`/`pair` and
/// `classify --sim` press with it, so that a catalogue-2 index is queried
/// with catalogue-2 fabrics.
#[cfg(feature = "sim")]
pub(crate) fn simulator_for(index: &Index) -> Result<telextiles_sim::Simulator> {
    let version = index.catalogue_version.max(1);
    telextiles_sim::Simulator::with_options(version, 1).with_context(|| {
        format!("the index is of simulator catalogue {version}, which this build cannot render")
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use telextiles_index::{IndexBuilder, TextileRecord};

    fn index_of(catalogue: u32) -> Index {
        let mut b = IndexBuilder::new("0".repeat(64).as_str(), "test", 2, catalogue);
        b.roller_n = 1;
        b.add(TextileRecord {
            id: "T001".into(),
            name: "one".into(),
            seen: true,
            structure: String::new(),
            attributes: Vec::new(),
            embeddings: vec![vec![1.0, 0.0]],
            exemplars: Vec::new(),
            press_frames: Vec::new(),
        })
        .unwrap();
        b.build().unwrap()
    }

    #[test]
    #[cfg(feature = "sim")]
    fn the_simulated_sensor_presses_fabrics_of_the_index_catalogue() {
        for (index, sim) in [(0, 1), (1, 1), (2, 2)] {
            let s = simulator_for(&index_of(index)).unwrap();
            assert_eq!(s.catalogue().version, sim, "index of catalogue {index}");
        }
        let Err(e) = simulator_for(&index_of(9)) else {
            panic!("catalogue 9 was accepted");
        };
        assert!(format!("{e:#}").contains("catalogue 9"), "{e:#}");
    }
}
