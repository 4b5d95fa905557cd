//! mDNS discovery (mdns-sd): advertise and browse `_telextiles._udp.local.`.
//!
//! The TXT record carries the device ID (`id`), the device's key (`key`,
//! what the link dials; it must hash to `id`), the protocol version (`pv`)
//! and whether the device is showing a pairing code (`pair=1`). None of it
//! is trusted: identity is proved only by the link's TLS handshake, which
//! a dial by key pins.
//!
//! Interfaces: multicast is first disabled on every interface
//! (`IfKind::All`), then enabled only on the selected ones
//! ([`Interfaces`]): an explicit allow-list, or every interface except
//! loopback and virtual ones (docker*, br-*, veth*, tun*, wg*, virbr*, ...).
use std::collections::HashMap;
use std::net::SocketAddr;
use std::str::FromStr;
use std::time::{Duration, Instant};

use mdns_sd::{IfKind, IfPredicate, ServiceDaemon, ServiceEvent, ServiceInfo};
use telextiles_certs::{DeviceId, PeerKey};
use tokio::sync::mpsc;

use crate::LinkError;

/// The DNS-SD service type of the peer link.
pub const SERVICE_TYPE: &str = "_telextiles._udp.local.";

/// Interface name prefixes skipped by default.
pub const DEFAULT_SKIP_PREFIXES: &[&str] = &[
    "lo",
    "docker",
    "br-",
    "veth",
    "tun",
    "tap",
    "wg",
    "virbr",
    "vnet",
    "zt",
    "tailscale",
];

/// Which network interfaces mDNS may use.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Interfaces {
    /// Only these interface names (the daemon's `--mdns-interface`; tests
    /// pass the namespace's veth).
    Only(Vec<String>),
    /// Every interface whose name starts with none of these prefixes.
    AllExcept(Vec<String>),
}

impl Default for Interfaces {
    fn default() -> Self {
        Interfaces::AllExcept(
            DEFAULT_SKIP_PREFIXES
                .iter()
                .map(|s| s.to_string())
                .collect(),
        )
    }
}

impl Interfaces {
    /// Whether mDNS may use the interface called `name`.
    pub fn allows(&self, name: &str) -> bool {
        match self {
            Interfaces::Only(names) => names.iter().any(|n| n == name),
            Interfaces::AllExcept(prefixes) => {
                !prefixes.iter().any(|p| name.starts_with(p.as_str()))
            }
        }
    }
}

/// mDNS settings.
#[derive(Debug, Clone, Default)]
pub struct DiscoveryConfig {
    pub interfaces: Interfaces,
    /// Instance name; default `telextiles-<short device id>`.
    pub instance_name: Option<String>,
}

impl DiscoveryConfig {
    /// Discovery on exactly these interfaces.
    pub fn only(interfaces: &[&str]) -> DiscoveryConfig {
        DiscoveryConfig {
            interfaces: Interfaces::Only(interfaces.iter().map(|s| s.to_string()).collect()),
            instance_name: None,
        }
    }
}

/// A device seen on the network (claims only; TLS proves identity).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Discovered {
    pub device_id: DeviceId,
    /// The key to dial (absent in adverts of protocol 1, which ran on
    /// certificates).
    pub key: Option<PeerKey>,
    pub protocol_version: u16,
    pub addrs: Vec<SocketAddr>,
    /// It is showing a pairing code.
    pub pairing: bool,
    pub fullname: String,
}

/// Adverts remembered (to report each change once) at most.
pub const MAX_SEEN: usize = 64;
/// An advert not heard again for this long is forgotten.
pub const SEEN_TTL: Duration = Duration::from_secs(120);
/// Adverts waiting for the link; more are dropped (mDNS repeats them).
pub const FOUND_QUEUE: usize = 64;

/// Bounded, expiring memory of the adverts already reported: anyone on the
/// LAN can send adverts with new names, so it must not grow with them.
#[derive(Debug, Default)]
pub struct Seen {
    map: HashMap<String, (Discovered, Instant)>,
}

impl Seen {
    /// Whether `d` is new or changed (report it); remembers it either way.
    pub fn is_new(&mut self, d: &Discovered, now: Instant) -> bool {
        self.map
            .retain(|_, (_, t)| now.saturating_duration_since(*t) < SEEN_TTL);
        let new = self.map.get(&d.fullname).map(|(old, _)| old) != Some(d);
        if !self.map.contains_key(&d.fullname) && self.map.len() >= MAX_SEEN {
            // Full of live entries: forget the one heard least recently.
            if let Some(oldest) = self
                .map
                .iter()
                .min_by_key(|(_, (_, t))| *t)
                .map(|(k, _)| k.clone())
            {
                self.map.remove(&oldest);
            }
        }
        self.map.insert(d.fullname.clone(), (d.clone(), now));
        new
    }

    pub fn len(&self) -> usize {
        self.map.len()
    }

    pub fn is_empty(&self) -> bool {
        self.map.is_empty()
    }
}

/// Parses a resolved service's TXT record into a [`Discovered`].
pub fn parse_txt(
    fullname: &str,
    id: Option<&str>,
    key: Option<&str>,
    pv: Option<&str>,
    pair: Option<&str>,
    addrs: Vec<SocketAddr>,
) -> Result<Discovered, String> {
    let id = id.ok_or_else(|| format!("{fullname}: TXT record has no device id"))?;
    let device_id =
        DeviceId::from_str(id).map_err(|e| format!("{fullname}: bad device id in TXT: {e}"))?;
    let key = match key {
        None => None,
        Some(k) => {
            let k = PeerKey::from_str(k)
                .map_err(|e| format!("{fullname}: bad device key in TXT: {e}"))?;
            if k.device_id() != device_id {
                return Err(format!(
                    "{fullname}: the TXT record's key is not device {device_id}'s"
                ));
            }
            Some(k)
        }
    };
    let protocol_version = pv
        .ok_or_else(|| format!("{fullname}: TXT record has no protocol version"))?
        .parse::<u16>()
        .map_err(|e| format!("{fullname}: bad protocol version in TXT: {e}"))?;
    Ok(Discovered {
        device_id,
        key,
        protocol_version,
        addrs,
        pairing: pair == Some("1"),
        fullname: fullname.to_string(),
    })
}

/// Running advertisement + browser. Dropping it unregisters and stops.
pub struct Discovery {
    daemon: ServiceDaemon,
    fullname: String,
    instance: String,
    host: String,
    port: u16,
    id_text: String,
    key_text: String,
}

impl Discovery {
    /// Advertises this device on `port` and browses for others. Found
    /// devices (other than this one) arrive on the receiver.
    pub fn start(
        cfg: &DiscoveryConfig,
        my_key: &PeerKey,
        port: u16,
        pairing: bool,
    ) -> Result<(Discovery, mpsc::Receiver<Discovered>), LinkError> {
        let err = |e: mdns_sd::Error| LinkError::Discovery(e.to_string());
        let daemon = ServiceDaemon::new().map_err(err)?;
        // Never multicast anywhere but the selected interfaces.
        daemon.disable_interface(IfKind::All).map_err(err)?;
        let sel = cfg.interfaces.clone();
        daemon
            .enable_interface(IfKind::Predicate(IfPredicate::new(move |i| {
                sel.allows(&i.name)
            })))
            .map_err(err)?;

        let my_id = &my_key.device_id();
        let short = my_id.short().to_lowercase();
        let mut disc = Discovery {
            instance: cfg
                .instance_name
                .clone()
                .unwrap_or_else(|| format!("telextiles-{short}")),
            host: format!("telextiles-{short}.local."),
            port,
            id_text: my_id.to_string(),
            key_text: my_key.to_string(),
            fullname: String::new(),
            daemon,
        };
        let info = disc.service_info(pairing)?;
        disc.fullname = info.get_fullname().to_string();
        let daemon = &disc.daemon;
        let fullname = disc.fullname.clone();
        daemon.register(info).map_err(err)?;
        let events = daemon.browse(SERVICE_TYPE).map_err(err)?;

        let (tx, rx) = mpsc::channel(FOUND_QUEUE);
        let me = *my_id;
        let own = fullname.clone();
        std::thread::Builder::new()
            .name("telextiles-mdns".into())
            .spawn(move || {
                let mut seen = Seen::default();
                while let Ok(ev) = events.recv() {
                    let ServiceEvent::ServiceResolved(svc) = ev else {
                        continue;
                    };
                    if svc.fullname == own {
                        continue;
                    }
                    let addrs: Vec<SocketAddr> = svc
                        .get_addresses()
                        .iter()
                        .map(|a| SocketAddr::new(a.to_ip_addr(), svc.get_port()))
                        .filter(|a| !a.ip().is_unspecified())
                        .take(crate::limits::MAX_PEER_ADDRS)
                        .collect();
                    let d = match parse_txt(
                        &svc.fullname,
                        svc.get_property_val_str("id"),
                        svc.get_property_val_str("key"),
                        svc.get_property_val_str("pv"),
                        svc.get_property_val_str("pair"),
                        addrs,
                    ) {
                        Ok(d) => d,
                        Err(e) => {
                            tracing::debug!("ignoring mDNS service: {e}");
                            continue;
                        }
                    };
                    if d.device_id == me {
                        continue;
                    }
                    if !seen.is_new(&d, Instant::now()) {
                        continue;
                    }
                    match tx.try_send(d) {
                        Ok(()) | Err(mpsc::error::TrySendError::Full(_)) => {}
                        Err(mpsc::error::TrySendError::Closed(_)) => return,
                    }
                }
            })
            .map_err(|e| LinkError::Discovery(format!("cannot start the mDNS thread: {e}")))?;
        Ok((disc, rx))
    }

    fn service_info(&self, pairing: bool) -> Result<ServiceInfo, LinkError> {
        let pv = telextiles_proto::peer::PROTOCOL_VERSION.to_string();
        let props = [
            ("id", self.id_text.as_str()),
            ("key", self.key_text.as_str()),
            ("pv", pv.as_str()),
            ("pair", if pairing { "1" } else { "0" }),
        ];
        Ok(ServiceInfo::new(
            SERVICE_TYPE,
            &self.instance,
            &self.host,
            (),
            self.port,
            &props[..],
        )
        .map_err(|e| LinkError::Discovery(e.to_string()))?
        .enable_addr_auto())
    }

    /// Re-announces the advert with `pair=1` or `pair=0`: the pairing flag
    /// is withdrawn as soon as pairing mode ends.
    pub fn set_pairing(&self, pairing: bool) -> Result<(), LinkError> {
        let info = self.service_info(pairing)?;
        self.daemon
            .register(info)
            .map_err(|e| LinkError::Discovery(e.to_string()))
    }
}

impl Drop for Discovery {
    fn drop(&mut self) {
        let _ = self.daemon.unregister(&self.fullname);
        let _ = self.daemon.shutdown();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_interfaces_skip_loopback_and_virtual() {
        let i = Interfaces::default();
        for bad in [
            "lo", "docker0", "br-1234", "veth12", "tun0", "wg0", "virbr0",
        ] {
            assert!(!i.allows(bad), "{bad}");
        }
        for good in ["eth0", "enp3s0", "wlan0", "wlp2s0"] {
            assert!(i.allows(good), "{good}");
        }
        let only = Interfaces::Only(vec!["veth-a".into()]);
        assert!(only.allows("veth-a"));
        assert!(!only.allows("eth0"));
    }

    fn advert(i: usize, port: u16) -> Discovered {
        Discovered {
            fullname: format!("telextiles-{i}._telextiles._udp.local."),
            device_id: DeviceId::from_bytes([(i % 251) as u8; 32]),
            key: None,
            protocol_version: 1,
            pairing: false,
            addrs: vec![SocketAddr::from(([192, 0, 2, 1], port))],
        }
    }

    /// A flood of spoofed adverts with fresh names keeps the memory at
    /// [`MAX_SEEN`] (issue 19: the map only grew); a repeated advert is
    /// reported once, a changed one again, an expired one again.
    #[test]
    fn seen_adverts_are_bounded_and_expire() {
        let t0 = Instant::now();
        let mut seen = Seen::default();
        for i in 0..10_000 {
            assert!(seen.is_new(&advert(i, 1), t0));
            assert!(seen.len() <= MAX_SEEN);
        }
        assert_eq!(seen.len(), MAX_SEEN);
        let a = advert(20_000, 1);
        assert!(seen.is_new(&a, t0));
        assert!(!seen.is_new(&a, t0 + Duration::from_secs(1)));
        assert!(seen.is_new(&advert(20_000, 2), t0 + Duration::from_secs(2)));
        let later = t0 + SEEN_TTL + Duration::from_secs(3);
        assert!(seen.is_new(&advert(20_000, 2), later));
        assert_eq!(seen.len(), 1, "everything else expired");
    }

    #[test]
    fn txt_parsing_reports_what_is_wrong() {
        let id = DeviceId::from_bytes([7; 32]);
        let text = id.to_string();
        let d = parse_txt("x", Some(&text), None, Some("1"), Some("1"), vec![]).unwrap();
        assert_eq!(d.device_id, id);
        assert_eq!(d.key, None, "a protocol-1 advert has no key");
        assert!(d.pairing);
        assert!(parse_txt("x", None, None, Some("1"), None, vec![])
            .unwrap_err()
            .contains("no device id"));
        assert!(
            parse_txt("x", Some("nonsense"), None, Some("1"), None, vec![])
                .unwrap_err()
                .contains("bad device id")
        );
        assert!(parse_txt("x", Some(&text), None, Some("x"), None, vec![])
            .unwrap_err()
            .contains("bad protocol version"));
        // The key must be the device's: a claim of another's key is dropped.
        let key = PeerKey::from_bytes([9; 32]);
        let kid = key.device_id().to_string();
        let d = parse_txt(
            "x",
            Some(&kid),
            Some(&key.to_string()),
            Some("2"),
            None,
            vec![],
        )
        .unwrap();
        assert_eq!(d.key, Some(key));
        assert!(parse_txt(
            "x",
            Some(&text),
            Some(&key.to_string()),
            Some("2"),
            None,
            vec![]
        )
        .unwrap_err()
        .contains("is not device"));
        assert!(
            parse_txt("x", Some(&kid), Some("xyz"), Some("2"), None, vec![])
                .unwrap_err()
                .contains("bad device key")
        );
    }
}
