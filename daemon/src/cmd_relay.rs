//! `telextilesd relay`: the relay two daemons on two networks meet
//! through (`telextiles_relay`, iroh's relay server in-process). It runs
//! on a host both can reach (a small public server; see
//! docs/relay.md and packaging/telextiles-relay.service), serves only the
//! device keys it is told, and never sees what the peers say.
use std::collections::HashSet;
use std::net::SocketAddr;
use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use telextiles_certs::PeerKey;
use telextiles_relay::{AccessList, CertSource, RelayOptions, RunningRelay};

#[derive(clap::Args, Debug, Clone)]
pub struct Args {
    /// TCP (HTTPS) and UDP (address discovery) address and port to serve on
    #[arg(long, value_name = "ADDR:PORT", default_value = "[::]:443")]
    pub listen: SocketAddr,
    /// A name peers reach the relay by, host name or IP address (repeat);
    /// the first is the URL's host [default: the --listen address]
    #[arg(long = "name", value_name = "HOST")]
    pub names: Vec<String>,
    /// Certificate chain (PEM), e.g. from an ACME client [default: a
    /// self-signed one, made once in --state-dir, that peers pin]
    #[arg(long, value_name = "FILE", requires = "key")]
    pub cert: Option<PathBuf>,
    /// The certificate's private key (PEM)
    #[arg(long, value_name = "FILE", requires = "cert")]
    pub key: Option<PathBuf>,
    /// Where the self-signed certificate is kept [default:
    /// $STATE_DIRECTORY, else $XDG_STATE_HOME/telextiles/relay]
    #[arg(long, value_name = "DIR")]
    pub state_dir: Option<PathBuf>,
    /// A device key that may use the relay (`telextilesd id` prints it;
    /// repeat or comma-separate)
    #[arg(long, value_name = "KEY", value_delimiter = ',')]
    pub allow: Vec<String>,
    /// A file of device keys that may use the relay, one per line (`#`
    /// starts a comment)
    #[arg(long, value_name = "FILE")]
    pub allow_file: Option<PathBuf>,
    /// Let any device key use the relay
    #[arg(long, conflicts_with_all = ["allow", "allow_file"])]
    pub open: bool,
}

pub fn run(a: Args) -> anyhow::Result<()> {
    let access = access_list(&a)?;
    let cert = match (&a.cert, &a.key) {
        (Some(cert), Some(key)) => CertSource::Files {
            cert: cert.clone(),
            key: key.clone(),
        },
        _ => CertSource::SelfSigned {
            dir: state_dir(&a)?,
        },
    };
    let opts = RelayOptions {
        listen: a.listen,
        names: a.names.clone(),
        cert,
        access,
    };
    let rt = tokio::runtime::Runtime::new().context("tokio runtime")?;
    rt.block_on(async move {
        let relay = RunningRelay::start(&opts).await?;
        println!("Relay: {}", relay.url());
        if let (CertSource::SelfSigned { .. }, Some(c)) = (&opts.cert, relay.cert_file()) {
            println!(
                "Self-signed certificate: {} (copy it to each device and set relay_cert to it)",
                c.display()
            );
        }
        match &opts.access {
            AccessList::Open => println!("Open to any device key (--open)."),
            AccessList::Keys(k) => println!("Serving {} device key(s).", k.len()),
        }
        println!(
            "Devices set: relay = \"{}\". Ctrl-C or SIGTERM stops.",
            relay.url()
        );
        let mut term = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate())
            .context("SIGTERM handler")?;
        tokio::select! {
            _ = tokio::signal::ctrl_c() => {}
            _ = term.recv() => {}
        }
        println!("Stopping.");
        relay.shutdown().await;
        Ok(())
    })
}

fn access_list(a: &Args) -> anyhow::Result<AccessList> {
    if a.open {
        return Ok(AccessList::Open);
    }
    let mut keys = HashSet::new();
    let mut add = |text: &str, from: &str| -> anyhow::Result<()> {
        let k: PeerKey = text
            .parse()
            .map_err(|e| anyhow::anyhow!("{from}: `{text}` is not a device key ({e})"))?;
        keys.insert(k);
        Ok(())
    };
    for k in &a.allow {
        add(k.trim(), "--allow")?;
    }
    if let Some(f) = &a.allow_file {
        for (n, line) in read(f)?.lines().enumerate() {
            let line = line.split('#').next().unwrap_or("").trim();
            if !line.is_empty() {
                add(line, &format!("{}:{}", f.display(), n + 1))?;
            }
        }
    }
    if keys.is_empty() {
        bail!(
            "no device may use this relay: name the keys it serves (--allow KEY, --allow-file FILE; \
             `telextilesd id` prints a device's key) or let anyone use it (--open)"
        );
    }
    Ok(AccessList::Keys(keys))
}

fn read(f: &Path) -> anyhow::Result<String> {
    std::fs::read_to_string(f).with_context(|| format!("--allow-file {}", f.display()))
}

fn state_dir(a: &Args) -> anyhow::Result<PathBuf> {
    if let Some(d) = &a.state_dir {
        return Ok(d.clone());
    }
    let var = |k: &str| std::env::var_os(k).filter(|v| !v.is_empty());
    if let Some(d) = var("STATE_DIRECTORY") {
        // systemd's StateDirectory= (may list several, colon-separated).
        let first = d
            .to_string_lossy()
            .split(':')
            .next()
            .unwrap_or("")
            .to_string();
        return Ok(PathBuf::from(first));
    }
    if let Some(d) = var("XDG_STATE_HOME") {
        return Ok(PathBuf::from(d).join("telextiles/relay"));
    }
    match var("HOME") {
        Some(h) => Ok(PathBuf::from(h).join(".local/state/telextiles/relay")),
        None => bail!("neither HOME nor XDG_STATE_HOME is set: pass --state-dir"),
    }
}
