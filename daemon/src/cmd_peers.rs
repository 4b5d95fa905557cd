//! `telextilesd id`, `telextilesd peers`, `telextilesd unpair <peer>`:
//! this device's ID and the trust store of paired peers, read and changed
//! directly in the state directory (no running daemon needed; a running
//! one watches the trust store and revokes an unpaired peer at once).

use crate::config::{Config, ConfigArgs};
use anyhow::Context;
use clap::builder::BoolishValueParser;
use std::io::Write;
use std::path::PathBuf;
use telextiles_certs::{report, Identity, TrustStore};

/// Where the identity and trust store live.
#[derive(clap::Args, Debug, Clone, Default)]
pub struct StoreArgs {
    /// Config file [env: TELEXTILESD_CONFIG]
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Directory of the identity and trust store [env: TELEXTILESD_STATE_DIR] [default: $XDG_STATE_HOME/telextiles]
    #[arg(long, value_name = "DIR")]
    pub state_dir: Option<PathBuf>,
    /// Use the system-wide daemon's state (/var/lib/telextilesd) [env: TELEXTILESD_SYSTEM]
    #[arg(long, num_args = 0..=1, require_equals = true, default_missing_value = "true", value_parser = BoolishValueParser::new(), value_name = "BOOL")]
    pub system: Option<bool>,
}

impl StoreArgs {
    fn state_dir(&self) -> anyhow::Result<PathBuf> {
        if let Some(dir) = &self.state_dir {
            return Ok(dir.clone());
        }
        let args = ConfigArgs {
            config: self.config.clone(),
            system: self.system,
            // These commands never touch the control socket; a placeholder
            // keeps resolution from failing where XDG_RUNTIME_DIR is unset
            // (e.g. over ssh or in cron).
            runtime_dir: Some(PathBuf::from("/nonexistent/telextilesd-unused")),
            ..ConfigArgs::default()
        };
        Ok(Config::load(&args)?.state_dir)
    }
}

#[derive(clap::Args, Debug, Clone)]
pub struct IdArgs {
    #[command(flatten)]
    pub store: StoreArgs,
    /// Print JSON
    #[arg(long)]
    pub json: bool,
}

#[derive(clap::Args, Debug, Clone)]
pub struct PeersArgs {
    #[command(flatten)]
    pub store: StoreArgs,
    /// Print JSON
    #[arg(long)]
    pub json: bool,
}

#[derive(clap::Args, Debug, Clone)]
pub struct UnpairArgs {
    #[command(flatten)]
    pub store: StoreArgs,
    /// The peer: its full device ID, a unique prefix of it (at least one
    /// group of 5), or its name, as listed by `telextilesd peers`
    pub peer: String,
}

/// `telextilesd id`: shows this device's ID (creating the identity on the
/// first run).
pub fn id(args: IdArgs) -> anyhow::Result<()> {
    let dir = args.store.state_dir()?;
    let (me, created) = Identity::load_or_create(&dir)?;
    let file = Identity::path_in(&dir);
    let mut out = crate::out::stdout();
    if args.json {
        writeln!(
            out,
            "{}",
            report::identity_json(&me.device_id(), &me.peer_key(), &file, created)
        )?;
    } else {
        write!(
            out,
            "{}",
            report::identity_text(&me.device_id(), &me.peer_key(), &file, created)
        )?;
    }
    Ok(())
}

/// `telextilesd peers`: lists paired peers.
pub fn peers(args: PeersArgs) -> anyhow::Result<()> {
    let dir = args.store.state_dir()?;
    let store = TrustStore::load(&dir)?;
    let mut out = crate::out::stdout();
    if args.json {
        writeln!(
            out,
            "{}",
            serde_json::to_string_pretty(&report::peers_json(&store))?
        )?;
    } else {
        write!(out, "{}", report::peers_text(&store))?;
    }
    Ok(())
}

/// `telextilesd unpair <peer>`: removes a peer from the trust store.
pub fn unpair(args: UnpairArgs) -> anyhow::Result<()> {
    let dir = args.store.state_dir()?;
    let removed = TrustStore::update(&dir, |s| match s.find(&args.peer) {
        Ok(p) => {
            let id = p.device_id;
            (true, Ok(s.remove(&id)))
        }
        Err(e) => (false, Err(e)),
    })?
    .with_context(|| format!("cannot unpair {:?}", args.peer))?;
    if let Some(p) = removed {
        writeln!(
            crate::out::stdout(),
            "Unpaired {} ({}): removed from {}.\nA running daemon drops the peer's connection within a second.\nTo pair again, run `telextilesd pair` on both devices.",
            p.name,
            p.device_id,
            TrustStore::path_in(&dir).display()
        )?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use telextiles_certs::PeerRecord;

    fn store_args(dir: &std::path::Path) -> StoreArgs {
        StoreArgs {
            state_dir: Some(dir.to_path_buf()),
            ..StoreArgs::default()
        }
    }

    #[test]
    fn unpair_removes_only_the_named_peer_and_reports_unknown_ones() {
        let tmp = tempfile::tempdir().unwrap();
        let mut s = TrustStore::empty_in(tmp.path());
        let a = Identity::generate().unwrap();
        let b = Identity::generate().unwrap();
        for (i, n) in [(&a, "a"), (&b, "b")] {
            s.insert(PeerRecord::new(
                i.peer_key(),
                n,
                std::time::SystemTime::now(),
            ));
        }
        s.save().unwrap();
        let e = unpair(UnpairArgs {
            store: store_args(tmp.path()),
            peer: "nobody".into(),
        })
        .unwrap_err();
        assert!(format!("{e:#}").contains("no paired peer matches"), "{e:#}");
        unpair(UnpairArgs {
            store: store_args(tmp.path()),
            peer: a.device_id().to_string(),
        })
        .unwrap();
        let left = TrustStore::load(tmp.path()).unwrap();
        assert_eq!(left.device_ids().collect::<Vec<_>>(), vec![b.device_id()]);
    }

    #[test]
    fn id_creates_the_identity_once() {
        let tmp = tempfile::tempdir().unwrap();
        let args = || IdArgs {
            store: store_args(tmp.path()),
            json: true,
        };
        id(args()).unwrap();
        let first = Identity::load(tmp.path()).unwrap().device_id();
        id(args()).unwrap();
        assert_eq!(Identity::load(tmp.path()).unwrap().device_id(), first);
        peers(PeersArgs {
            store: store_args(tmp.path()),
            json: false,
        })
        .unwrap();
    }
}
