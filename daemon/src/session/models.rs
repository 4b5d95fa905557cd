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
    let index = Index::read(index_path)?;
    index.check_encoder(&enc.info().sha256)?;
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
