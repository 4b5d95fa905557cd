//! Two [`Connection`] machines, dialer and acceptor, in simulated time as
//! quinn-proto's `Pair`: skewed and drifting clocks, an ordered control
//! stream with delay and jitter, pings and pongs a full queue drops.

use std::net::SocketAddr;
use std::time::Duration;

use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use telextiles_certs::{DeviceId, Identity};
use telextiles_proto::peer::{Control, ErrorCode, Hello, PROTOCOL_VERSION};

use super::clock::ClockConfig;
use super::connection::{Action, Connection, Phase};
use super::handshake::{HandshakeConfig, HsError, Local, Role};
use super::sim::{Channel, SimClock};
use crate::ErrorKind;

const MS: u64 = 1_000;
const S: u64 = 1_000_000;

fn hello(name: &str) -> Hello {
    Hello {
        protocol_version: PROTOCOL_VERSION,
        device_name: name.into(),
        encoder_hash: "a".repeat(64),
        index_fingerprint: "b".repeat(16),
        embedding_dim: 64,
    }
}

fn id() -> DeviceId {
    Identity::generate().expect("identity").device_id()
}

#[derive(Debug)]
enum Wire {
    Msg(Control),
    Closed,
}

struct Node {
    m: Connection,
    clock: SimClock,
    local: Local,
    up: Option<(Hello, u64)>,
    fail: Option<(HsError, u64)>,
    read_error: Option<u64>,
    delivered: Vec<Control>,
    clock_msgs_sent: u64,
}

impl Node {
    fn new(role: Role, h: Hello, clock: SimClock) -> Node {
        let addr: SocketAddr = "198.51.100.1:4797".parse().unwrap();
        Node {
            m: Connection::new(
                HandshakeConfig::new(h, Duration::from_secs(10)),
                ClockConfig::new(Duration::from_millis(500)),
                role,
                addr.to_string(),
                id(),
                clock.at(0),
            ),
            clock,
            local: Local {
                peer_pinned: true,
                showing_code: false,
            },
            up: None,
            fail: None,
            read_error: None,
            delivered: Vec::new(),
            clock_msgs_sent: 0,
        }
    }

    fn ended(&self) -> bool {
        self.fail.is_some() || self.read_error.is_some()
    }
}

struct Pair {
    d: Node,
    a: Node,
    da: Channel<Wire>,
    ad: Channel<Wire>,
    /// Probability that a ping or pong is dropped by the full send queue.
    drop_clock: f64,
    rng: StdRng,
    t: u64,
}

impl Pair {
    fn new(d: Node, a: Node, delay: u64, jitter: u64, seed: u64) -> Pair {
        let mut p = Pair {
            d,
            a,
            da: Channel::new(delay, jitter, 0.0, seed),
            ad: Channel::new(delay, jitter, 0.0, seed + 500),
            drop_clock: 0.0,
            rng: StdRng::seed_from_u64(seed + 900),
            t: 0,
        };
        p.drain_all();
        p
    }

    fn drain(node: &mut Node, out: &mut Channel<Wire>, t: u64, drop: f64, rng: &mut StdRng) {
        while let Some(act) = node.m.poll() {
            assert!(!node.ended(), "action after the end: {act:?}");
            match act {
                Action::Send(m) => {
                    if matches!(m, Control::Ping { .. } | Control::Pong { .. }) {
                        assert!(node.up.is_some(), "clock message before up: {m:?}");
                        node.clock_msgs_sent += 1;
                        if drop > 0.0 && rng.gen_bool(drop) {
                            continue;
                        }
                    }
                    out.send(t, Wire::Msg(m));
                }
                Action::FinishSend | Action::Pair(_) => {}
                Action::Up(h) => {
                    assert!(node.up.is_none(), "up twice");
                    node.up = Some((h, t));
                }
                Action::Deliver(m) => {
                    assert!(node.up.is_some(), "delivered before up: {m:?}");
                    node.delivered.push(m);
                }
                Action::Fail(e) => {
                    node.fail = Some((e, t));
                    out.send(t, Wire::Closed);
                }
            }
        }
    }

    fn drain_all(&mut self) {
        let t = self.t;
        Self::drain(&mut self.d, &mut self.da, t, self.drop_clock, &mut self.rng);
        Self::drain(&mut self.a, &mut self.ad, t, self.drop_clock, &mut self.rng);
    }

    fn feed(node: &mut Node, w: Wire, t: u64) {
        if node.ended() {
            return;
        }
        let now = node.clock.at(t);
        match w {
            Wire::Msg(m) => node.m.handle_message(now, m, node.local),
            Wire::Closed => {
                if !node.m.handle_read_error() {
                    node.read_error = Some(t);
                }
            }
        }
    }

    /// What the daemon on one side sends itself (`LinkHandle::send_control`),
    /// or a hostile peer: straight onto the stream.
    fn inject(&mut self, from_dialer: bool, m: Control) {
        let t = self.t;
        if from_dialer {
            self.da.send(t, Wire::Msg(m));
        } else {
            self.ad.send(t, Wire::Msg(m));
        }
    }

    fn run_until(&mut self, end: u64) {
        loop {
            let due = |n: &Node| {
                if n.ended() {
                    return u64::MAX;
                }
                n.m.poll_timeout()
                    .map_or(u64::MAX, |l| n.clock.true_time(l))
            };
            let next = [
                due(&self.d),
                due(&self.a),
                self.da.next_at().unwrap_or(u64::MAX),
                self.ad.next_at().unwrap_or(u64::MAX),
            ]
            .into_iter()
            .min()
            .unwrap();
            if next > end {
                self.t = end;
                return;
            }
            self.t = next.max(self.t);
            let t = self.t;
            while let Some(w) = self.da.recv(t) {
                Self::feed(&mut self.a, w, t);
                Self::drain(&mut self.a, &mut self.ad, t, self.drop_clock, &mut self.rng);
            }
            while let Some(w) = self.ad.recv(t) {
                Self::feed(&mut self.d, w, t);
                Self::drain(&mut self.d, &mut self.da, t, self.drop_clock, &mut self.rng);
            }
            for n in [&mut self.d, &mut self.a] {
                if !n.ended() {
                    let now = n.clock.at(t);
                    if n.m.poll_timeout().is_some_and(|d| now >= d) {
                        n.m.handle_timeout(now);
                    }
                }
            }
            self.drain_all();
        }
    }

    fn true_offset_a_minus_d(&self) -> i64 {
        self.a.clock.at(self.t) as i64 - self.d.clock.at(self.t) as i64
    }
}

fn clocks() -> (SimClock, SimClock) {
    (
        SimClock {
            offset: 3 * S as i128,
            ppm: 0,
        },
        SimClock {
            offset: 500_000 * S as i128,
            ppm: -80,
        },
    )
}

/// Dialer and acceptor with clocks 6 days apart, the acceptor's 80 ppm
/// slow, 15 ms ± 5 ms each way: both come up after three one-way trips,
/// ping every 500 ms from then on, know the offset to within half the
/// jitter plus the drift over the estimator's window, and give a latent its
/// one-way latency as well. The daemon's control messages arrive in order,
/// an error text without its escapes; hello repeats after up are ignored.
#[test]
fn pair_comes_up_streams_and_estimates_latency() {
    for seed in 0..10 {
        let (cd, ca) = clocks();
        let mut p = Pair::new(
            Node::new(Role::Dialer, hello("d"), cd),
            Node::new(Role::Acceptor, hello("a"), ca),
            15 * MS,
            5 * MS,
            seed,
        );
        p.run_until(S);
        let (_, td) = p.d.up.clone().expect("dialer up");
        let (_, ta) = p.a.up.clone().expect("acceptor up");
        assert!((30 * MS..=40 * MS).contains(&td), "{td}");
        assert!((45 * MS..=60 * MS).contains(&ta), "{ta}");
        for m in [
            Control::PressStart {
                press_id: 1,
                capture_us: 10,
            },
            Control::Hello(hello("again")),
            Control::HelloAck,
            Control::Error {
                code: ErrorCode::Other,
                message: "\x1b[2Jgone".into(),
            },
            Control::PressStop {
                press_id: 1,
                capture_us: 20,
                final_latent: None,
            },
        ] {
            p.inject(true, m);
        }
        p.run_until(30 * S);
        assert_eq!(p.a.m.phase(), Phase::Up);
        assert_eq!(p.a.delivered.len(), 3, "{:?}", p.a.delivered);
        assert!(matches!(
            p.a.delivered[0],
            Control::PressStart { press_id: 1, .. }
        ));
        match &p.a.delivered[1] {
            Control::Error { message, .. } => assert!(!message.contains('\x1b'), "{message:?}"),
            other => panic!("{other:?}"),
        }
        assert!(matches!(
            p.a.delivered[2],
            Control::PressStop { press_id: 1, .. }
        ));
        assert!(p.d.delivered.is_empty());
        for n in [&p.d, &p.a] {
            let st = n.m.clock().unwrap().stats();
            assert!((59..=61).contains(&st.pings_sent), "{st:?}");
            assert_eq!(st.pongs_unknown + st.pongs_implausible, 0);
        }
        let truth = p.true_offset_a_minus_d();
        let d_err = p.d.m.clock().unwrap().offset_us().unwrap() - truth;
        let a_err = p.a.m.clock().unwrap().offset_us().unwrap() + truth;
        assert!(d_err.abs() <= 3_200, "seed {seed}: {d_err}");
        assert!(a_err.abs() <= 3_200, "seed {seed}: {a_err}");
        // A latent captured on the dialer now arrives 15 ms later.
        let cap = p.d.clock.at(p.t);
        let recv = p.a.clock.at(p.t + 15 * MS);
        let one_way = p.a.m.one_way_us(cap, recv).unwrap();
        assert!((one_way - 15_000).abs() <= 3_200, "{one_way}");
    }
}

/// Half the pings and pongs dropped by a full send queue: the estimate is
/// as good; nothing else is lost (the control stream is reliable).
#[test]
fn pair_with_dropped_pings_and_pongs_keeps_the_estimate() {
    let (cd, ca) = clocks();
    let mut p = Pair::new(
        Node::new(Role::Dialer, hello("d"), cd),
        Node::new(Role::Acceptor, hello("a"), ca),
        10 * MS,
        4 * MS,
        3,
    );
    p.drop_clock = 0.5;
    p.run_until(30 * S);
    let truth = p.true_offset_a_minus_d();
    let err = p.d.m.clock().unwrap().offset_us().unwrap() - truth;
    assert!(err.abs() <= 3_000, "{err}");
    assert!(p.d.m.clock().unwrap().stats().pings_lost > 5);
}

/// Incompatible hellos: both fail with the reasons, and not one ping or
/// pong is ever sent; an acceptor that has not pinned the dialer refuses
/// it, the dialer sees the close; no timer is left running.
#[test]
fn no_clock_traffic_unless_up() {
    let (cd, ca) = clocks();
    let mut p = Pair::new(
        Node::new(Role::Dialer, hello("d"), cd),
        Node::new(
            Role::Acceptor,
            Hello {
                embedding_dim: 65,
                ..hello("a")
            },
            ca,
        ),
        10 * MS,
        0,
        1,
    );
    p.run_until(20 * S);
    for n in [&p.d, &p.a] {
        let (e, t) = n.fail.clone().expect("failed");
        assert!(matches!(e.kind, ErrorKind::Incompatible(_)), "{e:?}");
        assert!(t <= 400 * MS, "{t}");
        assert!(n.up.is_none());
        assert_eq!(n.clock_msgs_sent, 0);
        assert_eq!(n.m.poll_timeout(), None);
        assert!(n.m.clock().is_none());
    }

    let (cd, ca) = clocks();
    let mut a = Node::new(Role::Acceptor, hello("a"), ca);
    a.local.peer_pinned = false;
    let mut p = Pair::new(Node::new(Role::Dialer, hello("d"), cd), a, 10 * MS, 0, 2);
    p.run_until(20 * S);
    assert_eq!(p.a.fail.clone().unwrap().0.kind, ErrorKind::RefusedPeer);
    assert_eq!(p.d.read_error, Some(20 * MS));
    assert_eq!(p.d.clock_msgs_sent + p.a.clock_msgs_sent, 0);
}

/// A hostile acceptor that sends a press (or a pong) before its hello: the
/// dialer fails with a protocol error and never comes up.
#[test]
fn stream_messages_before_up_fail_the_handshake() {
    for early in [
        Control::PressStart {
            press_id: 9,
            capture_us: 0,
        },
        Control::Pong {
            id: 1,
            t1_us: 0,
            t2_us: 0,
            t3_us: 0,
        },
    ] {
        let (cd, ca) = clocks();
        let mut p = Pair::new(
            Node::new(Role::Dialer, hello("d"), cd),
            Node::new(Role::Acceptor, hello("a"), ca),
            10 * MS,
            0,
            4,
        );
        p.inject(false, early);
        p.run_until(5 * S);
        let (e, t) = p.d.fail.clone().expect("dialer failed");
        assert_eq!(e.kind, ErrorKind::Protocol);
        assert_eq!(t, 10 * MS);
        assert!(p.d.up.is_none());
        assert_eq!(p.a.read_error, Some(20 * MS));
    }
}
