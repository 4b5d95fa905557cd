//! What the live session and `pair` share about finding and pairing
//! peers: the mDNS interfaces from the configuration, and why `pair
//! --enter` gave up.

use telextiles_link::{discovery::DEFAULT_SKIP_PREFIXES, DiscoveryConfig, Interfaces};

use crate::config::Config;

/// mDNS discovery on the configured interfaces: only `mdns_allow` when
/// given, else every interface except virtual ones and `mdns_deny`.
pub(crate) fn discovery_config(cfg: &Config) -> DiscoveryConfig {
    let interfaces = if !cfg.mdns_allow.is_empty() {
        Interfaces::Only(cfg.mdns_allow.clone())
    } else {
        let mut deny: Vec<String> = DEFAULT_SKIP_PREFIXES
            .iter()
            .map(|s| s.to_string())
            .collect();
        deny.extend(cfg.mdns_deny.iter().cloned());
        Interfaces::AllExcept(deny)
    };
    DiscoveryConfig {
        interfaces,
        instance_name: None,
    }
}

/// Why `pair --enter` gave up at its deadline (`ttl`: how long it tried).
pub(crate) fn enter_expired_message(ttl: std::time::Duration) -> String {
    let took = if ttl.as_secs() >= 120 {
        format!("{} minutes", ttl.as_secs() / 60)
    } else {
        format!("{:.1} s", ttl.as_secs_f64())
    };
    format!(
        "no device proved the code within {took}; check the code shown on the other device (it expires after that time too) and run `telextilesd pair --enter` again"
    )
}
