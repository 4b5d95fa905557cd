//! `telextilesd map`: serve the live 2D textile map on its own, optionally
//! driven by simulated presses (`--demo`) so it can be watched with no peer
//! and no sensor. The running daemon serves the same map with `--map [ADDR]`
//! (see `telextiles_map::MapServer`).

use anyhow::{bail, Context, Result};
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::Arc;
use telextiles_index::Index;
use telextiles_map::{MapEvent, MapServer, TextureSource};

#[derive(clap::Args, Debug)]
pub struct Args {
    /// Textile index file (from `telextilesd index build`). Without it,
    /// `--demo` uses a demo index of the built-in catalogue whose positions
    /// come from ground-truth attributes, not from an encoder.
    #[arg(long)]
    pub index: Option<PathBuf>,
    /// Address to serve on. Keep it on 127.0.0.1 unless other machines
    /// should see the map.
    #[arg(long, default_value = telextiles_map::DEFAULT_ADDR)]
    pub bind: SocketAddr,
    /// Drive the live point with simulated presses.
    #[arg(long)]
    pub demo: bool,
    /// Texture images: `sim` (simulated DIGIT frames), `none`, or a
    /// directory with `<id>.png` files or recorded presses `<id>/`.
    #[arg(long, default_value = "sim")]
    pub textures: String,
    /// Seed of the demo presses.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Stop after this many demo presses (default: run until Ctrl-C).
    #[arg(long)]
    pub presses: Option<u64>,
}

#[cfg(feature = "sim")]
fn demo_index(seed: u64) -> Result<Index> {
    telextiles_map::demo::catalogue_index(None, 16, seed).context("building the demo index")
}

#[cfg(not(feature = "sim"))]
fn demo_index(_seed: u64) -> Result<Index> {
    Err(crate::sim_off("`map --demo`"))
}

pub fn run(a: Args) -> Result<()> {
    let index = match (&a.index, a.demo) {
        (Some(p), _) => Index::read(p).with_context(|| format!("reading index {}", p.display()))?,
        (None, true) => demo_index(a.seed)?,
        (None, false) => bail!(
            "give --index <file> (an index from `telextilesd index build`), \
             or --demo to watch simulated presses on a demo index of the built-in catalogue"
        ),
    };
    let textures = match a.textures.as_str() {
        "sim" => TextureSource::Simulated,
        "none" => TextureSource::None,
        dir => {
            let p = PathBuf::from(dir);
            if !p.is_dir() {
                bail!("--textures {dir}: not `sim`, `none` or a directory");
            }
            TextureSource::Directory(p)
        }
    };
    let index = Arc::new(index);
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()?;
    rt.block_on(async move {
        let (events, _) = tokio::sync::broadcast::channel::<MapEvent>(1024);
        let server = MapServer::bind(a.bind, index.clone(), textures, &events).await?;
        let addr = server.local_addr();
        println!(
            "map: http://{addr}/  ({} textiles, index {})",
            index.entries.len(),
            &server.fingerprint()[..12]
        );
        #[cfg(feature = "sim")]
        let demo = a.demo.then(|| {
            tokio::spawn(telextiles_map::demo::run(
                index.clone(),
                events.clone(),
                a.seed,
                a.presses,
            ))
        });
        // Without the simulator `--demo` was refused above.
        #[cfg(not(feature = "sim"))]
        let demo: Option<tokio::task::JoinHandle<()>> = None;
        let stop = async move {
            match demo {
                Some(d) if a.presses.is_some() => {
                    let _ = d.await;
                }
                _ => {
                    let _ = tokio::signal::ctrl_c().await;
                }
            }
        };
        server.serve_until(stop).await?;
        anyhow::Ok(())
    })
}
