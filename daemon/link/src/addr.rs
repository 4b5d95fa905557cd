//! Where peers are and how they are reached: [`PeerAddr`] (a key, with
//! addresses or not), [`Route`] (the path a connection takes now),
//! [`RelaySpec`] (a relay to meet peers through), and the endpoint they
//! all live on ([`bind_endpoint`]).
use std::fmt;
use std::net::SocketAddr;
use std::str::FromStr;
use std::time::Duration;

use iroh::endpoint::{Connection, EndpointHooks, QuicTransportConfig};
use iroh::{EndpointAddr, EndpointId, RelayMode, RelayUrl, TransportAddr};
use rustls::pki_types::CertificateDer;
use telextiles_certs::{PeerKey, PeerKeyError};

use crate::{LinkError, ALPN};

/// A peer to dial: its key (which the dial pins) and the addresses to try;
/// with none, the configured relay finds it.
///
/// Text form (`--connect`): `KEY@host:port`, or `KEY` alone through the
/// relay; `telextilesd id` prints a device's key.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PeerAddr {
    pub key: PeerKey,
    pub addrs: Vec<SocketAddr>,
}

impl PeerAddr {
    pub fn new(key: PeerKey, addrs: Vec<SocketAddr>) -> PeerAddr {
        PeerAddr { key, addrs }
    }

    /// `KEY@addr` for one address.
    pub fn at(key: PeerKey, addr: SocketAddr) -> PeerAddr {
        PeerAddr {
            key,
            addrs: vec![addr],
        }
    }
}

impl fmt::Display for PeerAddr {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.key)?;
        for (i, a) in self.addrs.iter().enumerate() {
            f.write_str(if i == 0 { "@" } else { "," })?;
            write!(f, "{a}")?;
        }
        Ok(())
    }
}

/// Why a `--connect` value is not a peer address.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum PeerAddrError {
    #[error("{0:?} has no device key: the link dials a device by its key, so write KEY@{0} (`telextilesd id` on that device prints its key)")]
    NoKey(String),
    #[error("{text:?}: {source}")]
    Key { text: String, source: PeerKeyError },
    #[error("{text:?} is not an address (host:port, e.g. 192.0.2.7:4797 or [2001:db8::7]:4797)")]
    Addr { text: String },
    #[error("{0} is not a valid Ed25519 public key")]
    Curve(String),
}

impl FromStr for PeerAddr {
    type Err = PeerAddrError;

    fn from_str(s: &str) -> Result<PeerAddr, PeerAddrError> {
        let s = s.trim();
        let (key_text, addrs_text) = match s.split_once('@') {
            Some((k, a)) => (k, Some(a)),
            None => (s, None),
        };
        if addrs_text.is_none() && key_text.parse::<SocketAddr>().is_ok() {
            return Err(PeerAddrError::NoKey(s.to_string()));
        }
        let key = PeerKey::from_str(key_text).map_err(|source| PeerAddrError::Key {
            text: key_text.to_string(),
            source,
        })?;
        endpoint_id_of(&key).map_err(|_| PeerAddrError::Curve(key.to_string()))?;
        let mut addrs = Vec::new();
        for a in addrs_text.into_iter().flat_map(|t| t.split(',')) {
            addrs.push(a.trim().parse().map_err(|_| PeerAddrError::Addr {
                text: a.to_string(),
            })?);
        }
        Ok(PeerAddr { key, addrs })
    }
}

/// The path a connection's packets take.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Route {
    /// Straight to the peer at this address (on the LAN, or through NATs
    /// after hole punching).
    Direct(SocketAddr),
    /// Through this relay.
    Relay(String),
    /// No path selected (yet).
    Unknown,
}

impl Route {
    /// `"direct"`, `"relay"` or `"unknown"`.
    pub fn kind(&self) -> &'static str {
        match self {
            Route::Direct(_) => "direct",
            Route::Relay(_) => "relay",
            Route::Unknown => "unknown",
        }
    }

    /// The peer's address on a direct path.
    pub fn direct(&self) -> Option<SocketAddr> {
        match self {
            Route::Direct(a) => Some(*a),
            _ => None,
        }
    }
}

impl fmt::Display for Route {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Route::Direct(a) => write!(f, "{a}"),
            Route::Relay(url) => write!(f, "relay {url}"),
            Route::Unknown => f.write_str("no path yet"),
        }
    }
}

fn route_of_addr(a: &TransportAddr) -> Route {
    match a {
        TransportAddr::Ip(ip) => Route::Direct(*ip),
        TransportAddr::Relay(url) => Route::Relay(url.to_string()),
        _ => Route::Unknown,
    }
}

/// The selected path of a connection and its round-trip time.
pub(crate) fn route_of(conn: &Connection) -> (Route, Option<Duration>) {
    let paths = conn.paths();
    let selected = paths.iter().find(|p| p.is_selected());
    match selected {
        Some(p) => (route_of_addr(p.remote_addr()), Some(p.rtt())),
        None => (Route::Unknown, None),
    }
}

/// A relay to meet peers through beyond the LAN.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RelaySpec {
    /// `https://host[:port]` of the relay (`telextilesd relay` prints it).
    pub url: RelayUrl,
    /// The relay's own certificate, pinned (a self-signed relay); `None`:
    /// the relay's certificate must chain to a public root.
    pub cert: Option<CertificateDer<'static>>,
    /// The relay's QUIC address-discovery port, if it serves one.
    pub quic_port: Option<u16>,
}

impl RelaySpec {
    /// A relay by its URL (`https://HOST[:PORT]`, as `telextilesd relay`
    /// prints it), its certificate pinned or not. Its QUIC address
    /// discovery is taken to be on the UDP port of the URL's number, as
    /// `telextilesd relay` serves it.
    pub fn new(url: &str, cert: Option<CertificateDer<'static>>) -> Result<RelaySpec, String> {
        let url: RelayUrl = url
            .parse()
            .map_err(|e| format!("`{url}` is not a relay URL ({e})"))?;
        if url.scheme() != "https" {
            return Err(format!("`{url}`: a relay is reached over https://"));
        }
        let quic_port = url.port_or_known_default();
        Ok(RelaySpec {
            url,
            cert,
            quic_port,
        })
    }
}

/// The iroh key of a device key (every key a device has is one; a key
/// typed by a user may not be a curve point).
pub(crate) fn endpoint_id_of(key: &PeerKey) -> Result<EndpointId, LinkError> {
    EndpointId::from_bytes(key.as_bytes())
        .map_err(|e| LinkError::Key(format!("{key} is not a valid Ed25519 public key ({e})")))
}

/// The device key of an iroh key.
pub(crate) fn key_of(id: &EndpointId) -> PeerKey {
    PeerKey::from_bytes(*id.as_bytes())
}

/// Where to dial a peer: its key, its addresses and, when configured, the
/// relays.
pub(crate) fn endpoint_addr(to: &PeerAddr, relays: &[RelayUrl]) -> Result<EndpointAddr, LinkError> {
    let id = endpoint_id_of(&to.key)?;
    let addrs = to
        .addrs
        .iter()
        .map(|a| TransportAddr::Ip(*a))
        .chain(relays.iter().map(|u| TransportAddr::Relay(u.clone())));
    Ok(EndpointAddr::from_parts(id, addrs))
}

/// Binds the link's endpoint: the device's key, only the given UDP
/// address (never every interface), the configured relays or none, no
/// port mapping (no UPnP/NAT-PMP probes on the LAN), no address lookup
/// service: nothing is sent anywhere the user did not name.
pub(crate) async fn bind_endpoint(
    secret: iroh::SecretKey,
    listen: SocketAddr,
    relays: &[RelaySpec],
    transport: QuicTransportConfig,
    hooks: impl EndpointHooks + 'static,
) -> Result<iroh::Endpoint, LinkError> {
    let bind_err = |e: String| LinkError::Bind {
        addr: listen,
        source: std::io::Error::other(e),
    };
    let mut builder = iroh::Endpoint::builder(iroh::endpoint::presets::Minimal)
        .secret_key(secret)
        .alpns(vec![ALPN.to_vec()])
        .clear_ip_transports()
        .bind_addr(listen)
        .map_err(|e| bind_err(e.to_string()))?
        .transport_config(transport)
        .portmapper_config(iroh::endpoint::PortmapperConfig::Disabled)
        .hooks(hooks);
    if relays.is_empty() {
        builder = builder.relay_mode(RelayMode::Disabled);
    } else {
        let map: iroh::RelayMap = relays
            .iter()
            .map(|r| {
                iroh::RelayConfig::new(
                    r.url.clone(),
                    r.quic_port.map(iroh_relay::RelayQuicConfig::new),
                )
            })
            .collect();
        builder = builder.relay_mode(RelayMode::Custom(map));
        let pinned: Vec<CertificateDer<'static>> =
            relays.iter().filter_map(|r| r.cert.clone()).collect();
        if !pinned.is_empty() {
            builder = builder.ca_tls_config(iroh_relay::tls::CaTlsConfig::custom_roots(pinned));
        }
        let mut report = iroh::NetReportConfig::default();
        // No captive-portal probe (an HTTP fetch of the relay host's port 80).
        report.captive_portal_check = false;
        builder = builder.net_report_config(report);
    }
    let ep = builder.bind().await.map_err(|e| bind_err(e.to_string()))?;
    Ok(ep)
}
