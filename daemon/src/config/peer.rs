//! The peers named by `--connect`: `KEY@HOST:PORT` (the host may be a name,
//! looked up here) or `KEY` alone (found on the LAN or through the relay).
use std::net::ToSocketAddrs;

use anyhow::{bail, Context};
use telextiles_link::PeerAddr;

/// The peers of `--connect` (`KEY@HOST:PORT` or `KEY`), host names looked
/// up.
pub fn resolve(list: &[String]) -> anyhow::Result<Vec<PeerAddr>> {
    list.iter().map(|s| resolve_peer(s)).collect()
}

/// One `--connect` peer: `KEY@HOST:PORT` (the host may be a name) or `KEY`
/// alone (found through the relay).
pub fn resolve_peer(s: &str) -> anyhow::Result<PeerAddr> {
    let (key, host) = match s.split_once('@') {
        Some((k, h)) => (k, Some(h)),
        None => (s, None),
    };
    let mut addrs = Vec::new();
    if let Some(h) = host {
        addrs = h
            .to_socket_addrs()
            .with_context(|| format!("--connect {s}: {h} is not a reachable host:port"))?
            .collect();
        if addrs.is_empty() {
            bail!("--connect {s}: the name has no address");
        }
    }
    let text = if addrs.is_empty() {
        key.to_string()
    } else {
        let list: Vec<String> = addrs.iter().map(|a| a.to_string()).collect();
        format!("{key}@{}", list.join(","))
    };
    text.parse::<PeerAddr>()
        .map_err(|e| anyhow::anyhow!("--connect {s}: {e}"))
}
