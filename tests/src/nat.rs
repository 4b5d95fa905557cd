//! Two home networks behind NAT routers and a "public" network between
//! them, all network namespaces (nothing touches the host's interfaces):
//!
//! ```text
//!  home_a (192.168.A.2) ── router_a ── 198.18.A.0/24 ──┐
//!                          (NAT)                       public (relay at 198.18.1.1)
//!  home_b (192.168.B.2) ── router_b ── 198.18.B.0/24 ──┘
//! ```
//!
//! The routers masquerade their home network behind their public address
//! (nftables) and let in only packets of flows their home started
//! (conntrack `established,related`): a home host cannot be reached
//! unless it has sent to that address first, so only hole punching
//! opens a direct path.
//! * [`Mapping::EndpointIndependent`]: conntrack keeps the source port,
//!   one public port for every destination (most home routers): punching
//!   works.
//! * [`Mapping::Symmetric`]: `masquerade random`: a new random port for
//!   each destination, so the port the relay saw is not the one a peer
//!   would have to hit: punching fails and traffic stays relayed.
use std::net::Ipv4Addr;
use std::sync::atomic::{AtomicU32, Ordering};

use crate::netns::Netns;

static COUNTER: AtomicU32 = AtomicU32::new(0);

/// How a router maps a home host's UDP flows to its public address.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mapping {
    EndpointIndependent,
    Symmetric,
}

/// One home network: a host behind a router.
#[derive(Debug)]
pub struct Home {
    /// The host's private address.
    pub ip: Ipv4Addr,
    /// The router's public address.
    pub public_ip: Ipv4Addr,
    pub host: Netns,
    pub router: Netns,
}

/// The whole lab; namespaces are deleted on drop.
#[derive(Debug)]
pub struct NatLab {
    /// The public network's own address, where the relay listens.
    pub relay_ip: Ipv4Addr,
    pub a: Home,
    pub b: Home,
    pub public: Netns,
}

fn sh(ns: &Netns, cmd: &str) -> Result<(), String> {
    ns.exec(&["sh", "-c", cmd]).map(|_| ())
}

fn veth(a: &Netns, a_if: &str, b: &Netns, b_if: &str) -> Result<(), String> {
    let out = std::process::Command::new("ip")
        .args([
            "link", "add", a_if, "netns", &a.name, "type", "veth", "peer", "name", b_if, "netns",
            &b.name,
        ])
        .output()
        .map_err(|e| e.to_string())?;
    if !out.status.success() {
        return Err(format!(
            "veth {a_if}/{b_if}: {}",
            String::from_utf8_lossy(&out.stderr).trim()
        ));
    }
    a.ip(&["link", "set", a_if, "up"])?;
    b.ip(&["link", "set", b_if, "up"])
}

impl NatLab {
    /// Builds the lab with both routers mapping as `mapping`.
    pub fn new(mapping: Mapping) -> Result<NatLab, String> {
        let n = COUNTER.fetch_add(1, Ordering::SeqCst);
        let tag = format!("{}{}", std::process::id() % 10_000, n);
        let public = Netns::create(&format!("txnp{tag}"))?;
        sh(&public, "sysctl -qw net.ipv4.ip_forward=1")?;
        let relay_ip = Ipv4Addr::new(198, 18, 1, 1);
        let mut homes = Vec::new();
        for (side, k) in [("a", 1u8), ("b", 2u8)] {
            let router = Netns::create(&format!("txr{side}{tag}"))?;
            let host = Netns::create(&format!("txh{side}{tag}"))?;
            // public <-> router ("wan"), router <-> host ("lan").
            let (p_if, w_if) = (format!("np{side}{tag}"), format!("nw{side}{tag}"));
            let (l_if, h_if) = (format!("nl{side}{tag}"), format!("nh{side}{tag}"));
            assert!(p_if.len() <= 15 && h_if.len() <= 15);
            veth(&public, &p_if, &router, &w_if)?;
            veth(&router, &l_if, &host, &h_if)?;
            let public_ip = Ipv4Addr::new(198, 18, k, 2);
            let ip = Ipv4Addr::new(192, 168, k, 2);
            public.ip(&["addr", "add", &format!("198.18.{k}.1/24"), "dev", &p_if])?;
            router.ip(&["addr", "add", &format!("{public_ip}/24"), "dev", &w_if])?;
            router.ip(&["addr", "add", &format!("192.168.{k}.1/24"), "dev", &l_if])?;
            host.ip(&["addr", "add", &format!("{ip}/24"), "dev", &h_if])?;
            router.ip(&["route", "add", "default", "via", &format!("198.18.{k}.1")])?;
            host.ip(&["route", "add", "default", "via", &format!("192.168.{k}.1")])?;
            sh(&router, "sysctl -qw net.ipv4.ip_forward=1")?;
            let masq = match mapping {
                Mapping::EndpointIndependent => "masquerade",
                Mapping::Symmetric => "masquerade random",
            };
            let rules = format!(
                "table ip nat {{\n  chain masq {{\n    type nat hook postrouting priority 100;\n    \
                 oifname \"{w_if}\" {masq}\n  }}\n}}\n\
                 table ip filter {{\n  chain routed {{\n    type filter hook forward priority 0; policy drop;\n    \
                 ct state established,related accept\n    iifname \"{l_if}\" oifname \"{w_if}\" accept\n  }}\n  \
                 chain inbound {{\n    type filter hook input priority 0; policy accept;\n    \
                 iifname \"{w_if}\" ct state new drop\n  }}\n}}\n"
            );
            let path = std::env::temp_dir().join(format!("txnat-{side}{tag}.nft"));
            std::fs::write(&path, rules).map_err(|e| e.to_string())?;
            let r = router.exec(&["nft", "-f", &path.display().to_string()]);
            let _ = std::fs::remove_file(&path);
            r?;
            homes.push(Home {
                ip,
                public_ip,
                host,
                router,
            });
        }
        let b = homes.pop().expect("two homes");
        let a = homes.pop().expect("two homes");
        Ok(NatLab {
            relay_ip,
            a,
            b,
            public,
        })
    }

    /// The routers' conntrack tables' UDP entries (for a failing test's
    /// report).
    pub fn conntrack(&self) -> String {
        let mut s = String::new();
        for (n, h) in [("a", &self.a), ("b", &self.b)] {
            let t = h
                .router
                .exec(&[
                    "sh",
                    "-c",
                    "cat /proc/net/nf_conntrack 2>/dev/null | grep udp || true",
                ])
                .unwrap_or_default();
            s.push_str(&format!("router {n}:\n{t}"));
        }
        s
    }
}
