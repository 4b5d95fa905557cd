//! The relay users run so that two daemons on two networks can meet
//! (`telextilesd relay`): iroh's relay server, in-process.
//!
//! * One port number serves both the relay (HTTPS over TCP, the path the
//!   peers' packets take until they go direct) and QUIC address discovery
//!   (UDP: each peer learns the address its NAT shows the world, which
//!   hole punching needs). Peers configure `relay = "https://HOST:PORT"`;
//!   the QUIC port is taken to be the same number.
//! * TLS from a certificate and key the operator gives (e.g. from their
//!   ACME client), or a self-signed one made on first start and kept in the
//!   relay's state directory: peers then pin it (`relay_cert`), so nobody
//!   else can stand in for the relay.
//! * Access: only the device keys on its list (`--allow KEY`), or anyone
//!   (`--open`, said so at start). The relay forwards end-to-end encrypted
//!   QUIC packets by key: it never sees a pairing code, a latent or a
//!   decision in the clear.
use std::collections::HashSet;
use std::fmt;
use std::net::{IpAddr, SocketAddr};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use iroh_relay::server::{
    Access, AccessControl, CertConfig, ClientRequest, QuicConfig, RelayConfig, Server,
    ServerConfig, TlsConfig,
};
use rustls::pki_types::pem::PemObject;
use rustls::pki_types::{CertificateDer, PrivateKeyDer};
use telextiles_certs::PeerKey;

/// File names of the self-signed certificate in the state directory.
pub const CERT_FILE: &str = "relay-cert.pem";
/// The self-signed certificate's private key (mode 0600).
pub const KEY_FILE: &str = "relay-key.pem";
/// The names the self-signed certificate was made for, one per line.
const NAMES_FILE: &str = "relay-cert.names";

/// Where the relay's TLS certificate comes from.
#[derive(Debug, Clone)]
pub enum CertSource {
    /// PEM files the operator manages (a chain and its key).
    Files { cert: PathBuf, key: PathBuf },
    /// A self-signed certificate for the relay's names, made once and kept
    /// in this directory (made again, with a note, if the names change).
    SelfSigned { dir: PathBuf },
}

/// Who may use the relay.
#[derive(Debug, Clone)]
pub enum AccessList {
    /// Only these device keys.
    Keys(HashSet<PeerKey>),
    /// Any key.
    Open,
}

/// How to run the relay.
#[derive(Debug, Clone)]
pub struct RelayOptions {
    /// TCP (HTTPS) and UDP (QUIC address discovery) address.
    pub listen: SocketAddr,
    /// The names peers reach it by (host names or IP addresses): the first
    /// is the URL's host; all go in a self-signed certificate.
    pub names: Vec<String>,
    pub cert: CertSource,
    pub access: AccessList,
}

#[derive(Debug, thiserror::Error)]
pub enum RelayError {
    #[error("the relay needs a name peers reach it by (--name HOST or an address to listen on that is not 0.0.0.0/[::])")]
    NoName,
    #[error("`{0}` is not a host name or an IP address")]
    BadName(String),
    #[error("{path}: {msg}")]
    Cert { path: PathBuf, msg: String },
    #[error("making the self-signed certificate: {0}")]
    SelfSigned(String),
    #[error("TLS: {0}")]
    Tls(String),
    #[error("starting the relay on {addr}: {msg}")]
    Spawn { addr: SocketAddr, msg: String },
}

/// The running relay; dropping it stops it.
pub struct RunningRelay {
    server: Server,
    url: String,
    cert_file: Option<PathBuf>,
    https: SocketAddr,
    quic: Option<SocketAddr>,
}

impl fmt::Debug for RunningRelay {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("RunningRelay")
            .field("url", &self.url)
            .field("https", &self.https)
            .finish()
    }
}

impl RunningRelay {
    /// Starts the relay (TLS, relay and QUIC address discovery on
    /// `opts.listen`; a plain-HTTP side port iroh's server requires, on an
    /// ephemeral port of the same address).
    pub async fn start(opts: &RelayOptions) -> Result<RunningRelay, RelayError> {
        let names = relay_names(opts)?;
        let (chain, key, cert_file) = match &opts.cert {
            CertSource::Files { cert, key } => {
                let (c, k) = load_pem(cert, key)?;
                (c, k, Some(cert.clone()))
            }
            CertSource::SelfSigned { dir } => {
                let (c, k) = self_signed(dir, &names)?;
                (c, k, Some(dir.join(CERT_FILE)))
            }
        };
        let tls = rustls::ServerConfig::builder_with_provider(Arc::new(
            rustls::crypto::ring::default_provider(),
        ))
        .with_protocol_versions(&[&rustls::version::TLS13])
        .map_err(|e| RelayError::Tls(e.to_string()))?
        .with_no_client_auth()
        .with_single_cert(chain, key)
        .map_err(|e| RelayError::Tls(e.to_string()))?;
        let mut relay = RelayConfig::new(SocketAddr::new(opts.listen.ip(), 0));
        relay.tls = Some(TlsConfig::new(
            opts.listen,
            CertConfig::Manual { server_config: tls },
        ));
        relay.key_cache_capacity = Some(1024);
        relay.access = Arc::new(KeyList(opts.access.clone()));
        let mut config = ServerConfig::default();
        config.relay = Some(relay);
        // QUIC address discovery on the UDP port of the same number (an
        // ephemeral TCP port asked for means an ephemeral UDP one too).
        config.quic = Some(QuicConfig::new(opts.listen));
        let server = Server::spawn(config).await.map_err(|e| RelayError::Spawn {
            addr: opts.listen,
            msg: e.to_string(),
        })?;
        let https = server.https_addr().ok_or_else(|| RelayError::Spawn {
            addr: opts.listen,
            msg: "the HTTPS server did not start".into(),
        })?;
        let host = match names[0].parse::<IpAddr>() {
            Ok(IpAddr::V6(v6)) => format!("[{v6}]"),
            _ => names[0].clone(),
        };
        let url = format!("https://{host}:{}", https.port());
        Ok(RunningRelay {
            quic: server.quic_addr(),
            server,
            url,
            cert_file,
            https,
        })
    }

    /// `https://HOST:PORT`: what peers put in `relay`.
    pub fn url(&self) -> &str {
        &self.url
    }

    /// The certificate file peers pin (`relay_cert`).
    pub fn cert_file(&self) -> Option<&Path> {
        self.cert_file.as_deref()
    }

    /// The bound HTTPS (TCP) address.
    pub fn https_addr(&self) -> SocketAddr {
        self.https
    }

    /// The bound QUIC address-discovery (UDP) address.
    pub fn quic_addr(&self) -> Option<SocketAddr> {
        self.quic
    }

    /// Stops serving, closing every client's connection.
    pub async fn shutdown(self) {
        let _ = self.server.shutdown().await;
    }
}

/// The relay's access list as iroh's server asks it.
#[derive(Debug)]
struct KeyList(AccessList);

impl AccessControl for KeyList {
    async fn on_connect(&self, request: &ClientRequest) -> Access {
        match &self.0 {
            AccessList::Open => Access::Allow,
            AccessList::Keys(keys) => {
                let key = PeerKey::from_bytes(*request.endpoint_id().as_bytes());
                if keys.contains(&key) {
                    Access::Allow
                } else {
                    tracing::info!(%key, "relay: refused a key not on the list");
                    Access::Deny {
                        reason: Some("this key is not on the relay's list".into()),
                    }
                }
            }
        }
    }
}

/// The names to serve under: the given ones, or the listen address when it
/// is a specific one.
fn relay_names(opts: &RelayOptions) -> Result<Vec<String>, RelayError> {
    let mut names = opts.names.clone();
    if names.is_empty() {
        if opts.listen.ip().is_unspecified() {
            return Err(RelayError::NoName);
        }
        names.push(opts.listen.ip().to_string());
    }
    for n in &names {
        let ok = n.parse::<IpAddr>().is_ok()
            || (!n.is_empty()
                && n.len() <= 253
                && n.split('.').all(|l| {
                    !l.is_empty()
                        && l.len() <= 63
                        && l.bytes().all(|b| b.is_ascii_alphanumeric() || b == b'-')
                }));
        if !ok {
            return Err(RelayError::BadName(n.clone()));
        }
    }
    Ok(names)
}

fn load_pem(
    cert: &Path,
    key: &Path,
) -> Result<(Vec<CertificateDer<'static>>, PrivateKeyDer<'static>), RelayError> {
    let chain: Vec<CertificateDer<'static>> = CertificateDer::pem_file_iter(cert)
        .map_err(|e| RelayError::Cert {
            path: cert.into(),
            msg: e.to_string(),
        })?
        .collect::<Result<_, _>>()
        .map_err(|e| RelayError::Cert {
            path: cert.into(),
            msg: e.to_string(),
        })?;
    if chain.is_empty() {
        return Err(RelayError::Cert {
            path: cert.into(),
            msg: "no CERTIFICATE in the file".into(),
        });
    }
    let key = PrivateKeyDer::from_pem_file(key).map_err(|e| RelayError::Cert {
        path: key.into(),
        msg: format!("no usable private key ({e})"),
    })?;
    Ok((chain, key))
}

/// The self-signed certificate in `dir` for `names`: kept from an earlier
/// start when made for the same names, else made now (and written whole,
/// key 0600, before use).
fn self_signed(
    dir: &Path,
    names: &[String],
) -> Result<(Vec<CertificateDer<'static>>, PrivateKeyDer<'static>), RelayError> {
    let (cert_p, key_p, names_p) = (
        dir.join(CERT_FILE),
        dir.join(KEY_FILE),
        dir.join(NAMES_FILE),
    );
    let wanted = names.join("\n");
    if cert_p.exists() && key_p.exists() {
        let same = std::fs::read_to_string(&names_p).is_ok_and(|s| s.trim() == wanted);
        if same {
            return load_pem(&cert_p, &key_p);
        }
        eprintln!(
            "note: the relay's names changed ({}); making a new self-signed certificate: \
             peers must pin the new {}",
            names.join(", "),
            cert_p.display()
        );
    }
    let made = rcgen::generate_simple_self_signed(names.to_vec())
        .map_err(|e| RelayError::SelfSigned(e.to_string()))?;
    let io = |p: &Path, e: std::io::Error| RelayError::Cert {
        path: p.into(),
        msg: e.to_string(),
    };
    std::fs::create_dir_all(dir).map_err(|e| io(dir, e))?;
    write_atomic(&key_p, made.key_pair.serialize_pem().as_bytes(), 0o600)
        .map_err(|e| io(&key_p, e))?;
    write_atomic(&cert_p, made.cert.pem().as_bytes(), 0o644).map_err(|e| io(&cert_p, e))?;
    write_atomic(&names_p, format!("{wanted}\n").as_bytes(), 0o644).map_err(|e| io(&names_p, e))?;
    load_pem(&cert_p, &key_p)
}

/// Writes `path` through a temporary file and a rename: a crash leaves the
/// old file or the new one, never half of one.
fn write_atomic(path: &Path, bytes: &[u8], mode: u32) -> std::io::Result<()> {
    use std::io::Write;
    use std::os::unix::fs::OpenOptionsExt;
    let tmp = path.with_extension("tmp");
    let mut f = std::fs::OpenOptions::new()
        .write(true)
        .create(true)
        .truncate(true)
        .mode(mode)
        .open(&tmp)?;
    f.write_all(bytes)?;
    f.sync_all()?;
    std::fs::rename(&tmp, path)
}

/// Reads a relay certificate a peer pins (`relay_cert`): the first
/// certificate of a PEM file.
pub fn read_pinned_cert(path: &Path) -> Result<CertificateDer<'static>, RelayError> {
    CertificateDer::from_pem_file(path).map_err(|e| RelayError::Cert {
        path: path.into(),
        msg: format!("no certificate to pin ({e})"),
    })
}

#[cfg(test)]
mod tests;
