//! Network namespaces for tests: two "hosts" joined by a veth pair, with
//! 10.x addresses that exist only inside the namespaces. Everything is torn
//! down on drop. Tests never touch the host's own interfaces.
use std::net::Ipv4Addr;
use std::process::{Command, Output};
use std::sync::atomic::{AtomicU32, Ordering};

static COUNTER: AtomicU32 = AtomicU32::new(0);

fn run(args: &[&str]) -> Result<Output, String> {
    let out = Command::new(args[0])
        .args(&args[1..])
        .output()
        .map_err(|e| format!("cannot run {}: {e}", args.join(" ")))?;
    if !out.status.success() {
        return Err(format!(
            "`{}` failed: {}",
            args.join(" "),
            String::from_utf8_lossy(&out.stderr).trim()
        ));
    }
    Ok(out)
}

/// Whether this process may create namespaces (root with `ip`). If not,
/// prints a loud SKIP line naming the test and returns `false` — except
/// under CI (`CI` set, as `.ci/run` runs), where a test that cannot run is
/// a failure, never a silent pass.
///
/// # Panics
/// Under CI, when namespaces are not available.
pub fn available_or_skip(test: &str) -> bool {
    let root = Command::new("id")
        .arg("-u")
        .output()
        .map(|o| String::from_utf8_lossy(&o.stdout).trim() == "0")
        .unwrap_or(false);
    let ip = Command::new("ip").arg("-V").output().is_ok();
    decide_skip(test, root && ip, std::env::var_os("CI").is_some())
}

/// The decision of [`available_or_skip`], given what it found.
pub fn decide_skip(test: &str, available: bool, ci: bool) -> bool {
    if available {
        // As root a failure to create namespaces is a real error: the test
        // goes on and reports it.
        return true;
    }
    assert!(
        !ci,
        "{test}: cannot create network namespaces (needs root and iproute2); under CI this test must run"
    );
    eprintln!();
    eprintln!("!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!");
    eprintln!("!!! SKIP {test}: cannot create network namespaces (needs root and iproute2).");
    eprintln!("!!! This test did NOT run. CI runs as root and must run it.");
    eprintln!("!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!");
    eprintln!();
    false
}

#[cfg(test)]
mod tests {
    #[test]
    fn a_test_that_cannot_run_fails_under_ci_and_skips_loudly_elsewhere() {
        assert!(super::decide_skip("t", true, true));
        assert!(!super::decide_skip("t", false, false));
        let r = std::panic::catch_unwind(|| super::decide_skip("t", false, true));
        assert!(r.is_err(), "skipped silently under CI");
    }
}

/// A network namespace, deleted on drop.
#[derive(Debug)]
pub struct Netns {
    pub name: String,
}

impl Netns {
    pub fn create(name: &str) -> Result<Netns, String> {
        let _ = run(&["ip", "netns", "del", name]);
        run(&["ip", "netns", "add", name])?;
        let ns = Netns { name: name.into() };
        ns.ip(&["link", "set", "lo", "up"])?;
        Ok(ns)
    }

    /// `ip -n <ns> <args>`.
    pub fn ip(&self, args: &[&str]) -> Result<(), String> {
        let mut v = vec!["ip", "-n", &self.name];
        v.extend_from_slice(args);
        run(&v).map(|_| ())
    }

    /// Runs a program inside the namespace and waits for it.
    pub fn exec(&self, args: &[&str]) -> Result<String, String> {
        let mut v = vec!["ip", "netns", "exec", &self.name];
        v.extend_from_slice(args);
        run(&v).map(|o| String::from_utf8_lossy(&o.stdout).into_owned())
    }

    /// A command that runs `program` inside the namespace (spawn it).
    pub fn command(&self, program: &str) -> Command {
        let mut c = Command::new("ip");
        c.args(["netns", "exec", &self.name, program]);
        c
    }

    /// Drops incoming and outgoing UDP to/from port 5353 (mDNS) with iptables.
    pub fn block_mdns(&self) -> Result<(), String> {
        for chain in [
            ("INPUT", "--dport"),
            ("OUTPUT", "--dport"),
            ("INPUT", "--sport"),
        ] {
            self.exec(&[
                "iptables", "-A", chain.0, "-p", "udp", chain.1, "5353", "-j", "DROP",
            ])?;
        }
        Ok(())
    }

    /// Drops a random `probability` of incoming UDP packets (iptables
    /// statistic module).
    pub fn random_loss(&self, probability: f64) -> Result<(), String> {
        let p = format!("{probability}");
        self.exec(&[
            "iptables",
            "-A",
            "INPUT",
            "-p",
            "udp",
            "-m",
            "statistic",
            "--mode",
            "random",
            "--probability",
            &p,
            "-j",
            "DROP",
        ])
        .map(|_| ())
    }

    /// Keep UDP `port` of this host off the wire: packets to it or from it
    /// pass only on loopback. With a userspace relay in the same namespace
    /// in front of the port, the relay is then the only way between the
    /// hosts: the link cannot open a direct path around it (iroh's NAT
    /// traversal would otherwise find one, and should).
    pub fn only_local(&self, port: u16) -> Result<(), String> {
        let p = port.to_string();
        self.exec(&[
            "iptables", "-A", "INPUT", "-p", "udp", "--dport", &p, "!", "-i", "lo", "-j", "DROP",
        ])?;
        self.exec(&[
            "iptables", "-A", "OUTPUT", "-p", "udp", "--sport", &p, "!", "-o", "lo", "-j", "DROP",
        ])
        .map(|_| ())
    }

    /// Packet counters of the INPUT chain (for reporting).
    pub fn iptables_counters(&self) -> String {
        self.exec(&["iptables", "-L", "INPUT", "-v", "-n", "-x"])
            .unwrap_or_default()
    }
}

impl Drop for Netns {
    fn drop(&mut self) {
        let _ = run(&["ip", "netns", "del", &self.name]);
    }
}

/// Waits until `dev` in `ns` is up with a carrier (at most 5 s).
fn wait_for_carrier(ns: &Netns, dev: &str) -> Result<(), String> {
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(5);
    loop {
        let out = run(&["ip", "-n", &ns.name, "-o", "link", "show", "dev", dev])?;
        let text = String::from_utf8_lossy(&out.stdout);
        if text.contains("state UP") && !text.contains("NO-CARRIER") {
            return Ok(());
        }
        if std::time::Instant::now() > deadline {
            return Err(format!(
                "{dev} in {} has no carrier after 5 s: {text}",
                ns.name
            ));
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
}

/// Two namespaces `a` and `b` joined by a veth pair: `a_if` (a_ip/24) in
/// `a`, `b_if` (b_ip/24) in `b`.
#[derive(Debug)]
pub struct TwoHosts {
    pub a_if: String,
    pub b_if: String,
    pub a_ip: Ipv4Addr,
    pub b_ip: Ipv4Addr,
    // Dropped last (fields drop in order): deleting a namespace removes
    // its end of the veth pair and with it the other end.
    pub a: Netns,
    pub b: Netns,
}

impl TwoHosts {
    /// Creates the pair with names unique to this process and call.
    pub fn new() -> Result<TwoHosts, String> {
        let n = COUNTER.fetch_add(1, Ordering::SeqCst);
        let pid = std::process::id();
        let tag = format!("{}{}", pid % 100_000, n);
        let a = Netns::create(&format!("txa{tag}"))?;
        let b = Netns::create(&format!("txb{tag}"))?;
        let a_if = format!("vxa{tag}");
        let b_if = format!("vxb{tag}");
        assert!(a_if.len() <= 15, "interface name too long: {a_if}");
        run(&[
            "ip", "link", "add", &a_if, "netns", &a.name, "type", "veth", "peer", "name", &b_if,
            "netns", &b.name,
        ])?;
        let net = 200 + (n % 50) as u8;
        let sub = (pid % 250) as u8;
        let a_ip = Ipv4Addr::new(10, net, sub, 1);
        let b_ip = Ipv4Addr::new(10, net, sub, 2);
        a.ip(&["addr", "add", &format!("{a_ip}/24"), "dev", &a_if])?;
        b.ip(&["addr", "add", &format!("{b_ip}/24"), "dev", &b_if])?;
        a.ip(&["link", "set", &a_if, "up"])?;
        b.ip(&["link", "set", &b_if, "up"])?;
        // The veth carrier comes up asynchronously: a node started before
        // it is up loses its first mDNS announcements and queries, and
        // discovery then waits for mdns-sd's next retry (seconds).
        wait_for_carrier(&a, &a_if)?;
        wait_for_carrier(&b, &b_if)?;
        Ok(TwoHosts {
            a_if,
            b_if,
            a_ip,
            b_ip,
            a,
            b,
        })
    }

    /// Sets `a`'s end of the link down or up (carrier goes with it).
    pub fn set_link(&self, up: bool) -> Result<(), String> {
        self.a
            .ip(&["link", "set", &self.a_if, if up { "up" } else { "down" }])
    }
}
