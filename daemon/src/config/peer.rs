//! The peers named by `--connect`: `KEY@HOST:PORT` (the host may be a name,
//! looked up here) or `KEY` alone (found on the LAN or through the relay).
use std::net::ToSocketAddrs;

use anyhow::{bail, Context};
use telextiles_link::{PeerAddr, RelaySpec};

use super::Config;

/// The peers of `--connect` (`KEY@HOST:PORT` or `KEY`), host names looked
/// up.
pub fn resolve(list: &[String]) -> anyhow::Result<Vec<PeerAddr>> {
    list.iter().map(|s| resolve_peer(s)).collect()
}

/// The relay of the configuration (`relay`, its pinned `relay_cert`
/// read now), or none.
pub fn relays(cfg: &Config) -> anyhow::Result<Vec<RelaySpec>> {
    let Some(url) = &cfg.relay else {
        return Ok(Vec::new());
    };
    let cert = match &cfg.relay_cert {
        Some(p) => Some(
            telextiles_relay::read_pinned_cert(p)
                .with_context(|| format!("`relay_cert` for {url}"))?,
        ),
        None => None,
    };
    Ok(vec![
        RelaySpec::new(url, cert).map_err(|e| anyhow::anyhow!("`relay`: {e}"))?
    ])
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

/// A relay URL: `https://HOST[:PORT]`, nothing after the authority.
pub(super) fn parse_relay(s: &str) -> Result<String, String> {
    let bad = |why: &str| {
        format!("`{s}` is not a relay URL ({why}); write https://HOST:PORT as `telextilesd relay` prints it")
    };
    let rest = s
        .strip_prefix("https://")
        .ok_or_else(|| bad("it must start with https://"))?;
    let auth = rest.strip_suffix('/').unwrap_or(rest);
    if auth.contains(['/', '?', '#', '@', ' ']) {
        return Err(bad("only a host and a port"));
    }
    let (host, port) = match auth.strip_prefix('[') {
        Some(v6) => v6
            .split_once(']')
            .map(|(h, p)| (h, p.strip_prefix(':')))
            .unwrap_or(("", None)),
        None => match auth.rsplit_once(':') {
            Some((h, p)) => (h, Some(p)),
            None => (auth, None),
        },
    };
    if host.is_empty() {
        return Err(bad("no host"));
    }
    if port.is_some_and(|p| p.parse::<u16>().map_or(true, |p| p == 0)) {
        return Err(bad("the port is not 1..=65535"));
    }
    Ok(auth.to_string()).map(|a| format!("https://{a}"))
}

pub(super) fn validate_peer(s: &str) -> Result<(), String> {
    let (key, addr) = match s.split_once('@') {
        Some((k, a)) => (k, Some(a)),
        None => (s, None),
    };
    if addr.is_none() && validate_host_port(s).is_ok() {
        return Err(format!(
            "`{s}` has no device key: the link dials a device by its key, so write KEY@{s} (`telextilesd id` on that device prints its key)"
        ));
    }
    key.parse::<telextiles_certs::PeerKey>()
        .map_err(|e| format!("`{s}`: {e}"))?;
    match addr {
        Some(a) => validate_host_port(a),
        None => Ok(()),
    }
}

fn validate_host_port(s: &str) -> Result<(), String> {
    let (host, port) = s
        .rsplit_once(':')
        .ok_or_else(|| format!("`{s}` is not HOST:PORT"))?;
    if host.is_empty() || port.parse::<u16>().is_err() {
        return Err(format!("`{s}` is not HOST:PORT with a port 0..=65535"));
    }
    Ok(())
}
