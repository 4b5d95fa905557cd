//! [`Handshake`] in simulated time: a dialer and an acceptor over ordered,
//! delaying channels; mismatches, refusals, timeouts, early, duplicate and
//! made-up messages.

use std::time::Duration;

use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use telextiles_certs::pairing::PairingAbort;
use telextiles_certs::{DeviceId, Identity};
use telextiles_proto::pairing::PairingMessage;
use telextiles_proto::peer::{Control, ErrorCode, Hello, MismatchReason, PROTOCOL_VERSION};

use super::handshake::{Handshake, HandshakeConfig, HsAction, HsError, HsState, Local, Role};
use super::sim::Channel;
use crate::ErrorKind;

const MS: u64 = 1_000;
const TIMEOUT: Duration = Duration::from_secs(10);

fn hello(name: &str) -> Hello {
    Hello {
        protocol_version: PROTOCOL_VERSION,
        device_name: name.into(),
        encoder_hash: "e".repeat(64),
        index_fingerprint: "f".repeat(16),
        embedding_dim: 128,
    }
}

fn id() -> DeviceId {
    Identity::generate().expect("identity").device_id()
}

fn addr() -> String {
    "192.0.2.7:4797".to_string()
}

fn pinned() -> Local {
    Local {
        peer_pinned: true,
        showing_code: false,
    }
}

/// What a side ended with.
#[derive(Debug, Clone, PartialEq)]
enum Outcome {
    Up(Hello, u64),
    Fail(HsError, u64),
    /// The stream ended under a machine that was not lingering: the driver
    /// reports the read error itself.
    ReadError(u64),
}

#[derive(Debug)]
enum Wire {
    Msg(Control),
    /// The other side closed the connection.
    Closed,
}

struct End {
    hs: Handshake,
    local: Local,
    out: Option<Outcome>,
    pairs: Vec<PairingMessage>,
    sent: Vec<Control>,
}

impl End {
    fn new(hs: Handshake, local: Local) -> End {
        End {
            hs,
            local,
            out: None,
            pairs: Vec::new(),
            sent: Vec::new(),
        }
    }
}

/// Runs both machines until both ended or `end`. Returns (dialer, acceptor)
/// outcomes.
fn run(d: &mut End, a: &mut End, delay: u64, jitter: u64, end: u64) {
    run_seeded(d, a, delay, jitter, end, 1)
}

fn run_seeded(d: &mut End, a: &mut End, delay: u64, jitter: u64, end: u64, seed: u64) {
    let mut da: Channel<Wire> = Channel::new(delay, jitter, 0.0, seed);
    let mut ad: Channel<Wire> = Channel::new(delay, jitter, 0.0, seed + 1_000);
    let mut t = 0;
    loop {
        drain(d, &mut da, t);
        drain(a, &mut ad, t);
        let next = [
            d.hs.poll_timeout().unwrap_or(u64::MAX),
            a.hs.poll_timeout().unwrap_or(u64::MAX),
            da.next_at().unwrap_or(u64::MAX),
            ad.next_at().unwrap_or(u64::MAX),
        ]
        .into_iter()
        .min()
        .unwrap();
        if next > end || (d.out.is_some() && a.out.is_some()) {
            return;
        }
        t = next.max(t);
        while let Some(w) = da.recv(t) {
            feed(a, w, t);
            drain(a, &mut ad, t);
        }
        while let Some(w) = ad.recv(t) {
            feed(d, w, t);
            drain(d, &mut da, t);
        }
        d.hs.handle_timeout(t);
        a.hs.handle_timeout(t);
    }
}

fn feed(e: &mut End, w: Wire, t: u64) {
    if e.out.is_some() {
        return;
    }
    match w {
        Wire::Msg(m) => e.hs.handle_message(t, m, e.local),
        Wire::Closed => {
            if !e.hs.handle_read_error() {
                e.out = Some(Outcome::ReadError(t));
            }
        }
    }
}

fn drain(e: &mut End, to_peer: &mut Channel<Wire>, t: u64) {
    while let Some(act) = e.hs.poll() {
        assert!(e.out.is_none(), "action after the end: {act:?}");
        match act {
            HsAction::Send(m) => {
                e.sent.push(m.clone());
                to_peer.send(t, Wire::Msg(m));
            }
            HsAction::FinishSend => {}
            HsAction::Pair(m) => e.pairs.push(m),
            HsAction::Up(h) => e.out = Some(Outcome::Up(h, t)),
            HsAction::Fail(err) => {
                e.out = Some(Outcome::Fail(err, t));
                to_peer.send(t, Wire::Closed);
            }
        }
    }
}

fn pair_of(dh: Hello, ah: Hello) -> (End, End) {
    let d = Handshake::new(
        HandshakeConfig::new(dh, TIMEOUT),
        Role::Dialer,
        addr(),
        id(),
        0,
    );
    let a = Handshake::new(
        HandshakeConfig::new(ah, TIMEOUT),
        Role::Acceptor,
        addr(),
        id(),
        0,
    );
    (End::new(d, pinned()), End::new(a, pinned()))
}

fn fail_kind(o: &Option<Outcome>) -> ErrorKind {
    match o {
        Some(Outcome::Fail(e, _)) => e.kind.clone(),
        other => panic!("not a failure: {other:?}"),
    }
}

/// Compatible hellos: both up after two one-way delays plus one (hello,
/// hello, ack), whatever the jitter; the peer's name reaches the caller
/// without its terminal escapes; the order on the wire is hello then ack.
#[test]
fn compatible_hellos_bring_both_up() {
    for seed in 0..10u64 {
        let (mut d, mut a) = pair_of(hello("dialer\x1b[31m"), hello("acceptor\u{202e}"));
        run_seeded(&mut d, &mut a, 20 * MS, 5 * MS, 60_000 * MS, seed);
        match (&d.out, &a.out) {
            (Some(Outcome::Up(hd, td)), Some(Outcome::Up(ha, ta))) => {
                assert_eq!(hd.device_name.trim_end(), "acceptor");
                assert!(ha.device_name.starts_with("dialer"), "{:?}", ha.device_name);
                assert!(!ha.device_name.contains('\x1b'));
                assert!(!hd.device_name.contains('\u{202e}'));
                assert!(*ta >= 3 * 20 * MS && *ta <= 3 * 25 * MS, "{ta}");
                assert!(*td >= 2 * 20 * MS && *td <= 2 * 25 * MS, "{td}");
            }
            other => panic!("{other:?}"),
        }
        assert_eq!(
            d.sent,
            vec![Control::Hello(hello("dialer\x1b[31m")), Control::HelloAck]
        );
        assert!(matches!(a.sent[..], [Control::Hello(_), Control::HelloAck]));
        assert_eq!(d.hs.state(), HsState::Up);
        assert_eq!(d.hs.poll_timeout(), None);
    }
}

/// Each incompatibility (protocol, encoder, index, dimension, and all at
/// once) fails both sides with every reason, after each has sent its
/// `Mismatch`, within the linger time; nothing comes up.
#[test]
fn every_mismatch_fails_both_sides_with_its_reasons() {
    let base = hello("x");
    let variants: Vec<(Hello, usize)> = vec![
        (
            Hello {
                protocol_version: PROTOCOL_VERSION + 1,
                ..base.clone()
            },
            1,
        ),
        (
            Hello {
                encoder_hash: "0".repeat(64),
                ..base.clone()
            },
            1,
        ),
        (
            Hello {
                index_fingerprint: "1".into(),
                ..base.clone()
            },
            1,
        ),
        (
            Hello {
                embedding_dim: 0,
                ..base.clone()
            },
            1,
        ),
        (
            Hello {
                protocol_version: u16::MAX,
                device_name: String::new(),
                encoder_hash: String::new(),
                index_fingerprint: String::new(),
                embedding_dim: u16::MAX,
            },
            4,
        ),
    ];
    for (theirs, n) in variants {
        let (mut d, mut a) = pair_of(base.clone(), theirs.clone());
        run(&mut d, &mut a, 10 * MS, 0, 60_000 * MS);
        for (e, name) in [(&d, "dialer"), (&a, "acceptor")] {
            match fail_kind(&e.out) {
                ErrorKind::Incompatible(r) => assert_eq!(r.len(), n, "{name}: {r:?}"),
                k => panic!("{name}: {k:?}"),
            }
            assert!(
                e.sent.iter().any(|m| matches!(m, Control::Mismatch { .. })),
                "{name} told the peer"
            );
            assert!(!e.sent.contains(&Control::HelloAck));
            let Some(Outcome::Fail(_, t)) = e.out else {
                unreachable!()
            };
            assert!(t <= 3 * 10 * MS + 300 * MS, "{name}: {t}");
        }
    }
}

/// An acceptor that has not pinned the dialer refuses its hello: no hello
/// of ours goes out, the error names the device; the dialer sees the close.
#[test]
fn unpinned_dialer_is_refused_before_our_hello() {
    let (mut d, mut a) = pair_of(hello("d"), hello("a"));
    a.local.peer_pinned = false;
    run(&mut d, &mut a, 5 * MS, 0, 60_000 * MS);
    assert_eq!(fail_kind(&a.out), ErrorKind::RefusedPeer);
    assert!(a.sent.is_empty());
    match &a.out {
        Some(Outcome::Fail(e, _)) => assert!(e.message.contains("not paired"), "{}", e.message),
        _ => unreachable!(),
    }
    assert_eq!(d.out, Some(Outcome::ReadError(10 * MS)));
}

/// Silence: each wait ends at the handshake timeout with a message saying
/// which message did not come.
#[test]
fn silent_peers_time_out_at_each_step() {
    // Dialer, nobody answers.
    let mut d = Handshake::new(
        HandshakeConfig::new(hello("d"), TIMEOUT),
        Role::Dialer,
        addr(),
        id(),
        1_000,
    );
    assert!(matches!(d.poll(), Some(HsAction::Send(Control::Hello(_)))));
    assert_eq!(d.poll_timeout(), Some(1_000 + 10_000 * MS));
    d.handle_timeout(1_000 + 10_000 * MS - 1);
    assert_eq!(d.poll(), None);
    d.handle_timeout(1_000 + 10_000 * MS);
    match d.poll() {
        Some(HsAction::Fail(e)) => {
            assert_eq!(e.kind, ErrorKind::Connection);
            assert!(
                e.message.contains("no hello from 192.0.2.7:4797"),
                "{}",
                e.message
            );
        }
        other => panic!("{other:?}"),
    }
    // Acceptor gets a hello, acks, and the ack never comes.
    let mut a = Handshake::new(
        HandshakeConfig::new(hello("a"), TIMEOUT),
        Role::Acceptor,
        addr(),
        id(),
        0,
    );
    a.handle_message(5 * MS, Control::Hello(hello("d")), pinned());
    assert!(matches!(a.poll(), Some(HsAction::Send(Control::Hello(_)))));
    assert_eq!(a.poll(), Some(HsAction::Send(Control::HelloAck)));
    assert_eq!(a.state(), HsState::AwaitAck);
    a.handle_timeout(5 * MS + 10_000 * MS);
    match a.poll() {
        Some(HsAction::Fail(e)) => assert_eq!(e.message, "no hello ack"),
        other => panic!("{other:?}"),
    }
    // After pairing.
    let mut a = Handshake::new(
        HandshakeConfig::new(hello("a"), TIMEOUT),
        Role::Acceptor,
        addr(),
        id(),
        0,
    );
    let show = Local {
        peer_pinned: false,
        showing_code: true,
    };
    a.handle_message(1, start_msg(), show);
    assert!(matches!(a.poll(), Some(HsAction::Pair(_))));
    assert_eq!(a.poll_timeout(), None, "the driver times the pairing");
    a.handle_paired(50 * MS);
    assert!(matches!(a.poll(), Some(HsAction::Send(Control::Hello(_)))));
    a.handle_timeout(50 * MS + 10_000 * MS);
    match a.poll() {
        Some(HsAction::Fail(e)) => assert_eq!(e.message, "no hello after pairing"),
        other => panic!("{other:?}"),
    }
}

fn start_msg() -> Control {
    // Any start message will do: the machine hands it on unread.
    let id = Identity::generate().unwrap();
    let other = Identity::generate().unwrap();
    let (_, start) = telextiles_certs::PairingSession::start(
        telextiles_certs::PairingRole::EntersCode,
        telextiles_certs::PairingCode::generate(&mut rand::rngs::OsRng),
        &id.peer_key(),
        &other.peer_key(),
        &mut rand::rngs::OsRng,
    )
    .unwrap();
    Control::Pair(start)
}

fn acceptor() -> Handshake {
    Handshake::new(
        HandshakeConfig::new(hello("a"), TIMEOUT),
        Role::Acceptor,
        addr(),
        id(),
        0,
    )
}

fn dialer() -> Handshake {
    let mut d = Handshake::new(
        HandshakeConfig::new(hello("d"), TIMEOUT),
        Role::Dialer,
        addr(),
        id(),
        0,
    );
    assert!(matches!(d.poll(), Some(HsAction::Send(Control::Hello(_)))));
    d
}

fn last_fail(hs: &mut Handshake) -> HsError {
    let mut fail = None;
    while let Some(a) = hs.poll() {
        if let HsAction::Fail(e) = a {
            assert!(fail.is_none(), "two failures");
            fail = Some(e);
        }
    }
    fail.expect("a failure")
}

/// Before the ack only the expected message is allowed: early pings,
/// pongs, presses, errors, a first ack, a duplicate hello, a pairing
/// message out of place: each is a protocol error whose text names the
/// message kind but not the peer's strings.
#[test]
fn early_and_duplicate_messages_are_protocol_errors() {
    let early = vec![
        Control::Ping { id: 1, t1_us: 0 },
        Control::Pong {
            id: 1,
            t1_us: 0,
            t2_us: 0,
            t3_us: 0,
        },
        Control::PressStart {
            press_id: 1,
            capture_us: 0,
        },
        Control::PressStop {
            press_id: 1,
            capture_us: 0,
            final_latent: None,
        },
        Control::HelloAck,
        Control::Mismatch { reasons: vec![] },
        Control::Error {
            code: ErrorCode::Other,
            message: "\x1b]0;owned\x07".into(),
        },
    ];
    for m in &early {
        // Acceptor's first message.
        let mut a = acceptor();
        a.handle_message(1, m.clone(), pinned());
        let e = last_fail(&mut a);
        assert_eq!(e.kind, ErrorKind::Protocol, "{m:?}");
        assert!(
            e.message.starts_with("expected hello from"),
            "{}",
            e.message
        );
        assert!(!e.message.contains('\x1b'));
        // Dialer waiting for the hello.
        let mut d = dialer();
        d.handle_message(1, m.clone(), pinned());
        if matches!(m, Control::HelloAck | Control::Mismatch { .. }) {
            assert_eq!(last_fail(&mut d).kind, ErrorKind::Protocol);
            continue;
        }
        assert_eq!(last_fail(&mut d).kind, ErrorKind::Protocol, "{m:?}");
    }
    // Between hello and ack: a second hello, or anything but ack/mismatch.
    for m in early
        .iter()
        .filter(|m| !matches!(m, Control::HelloAck | Control::Mismatch { .. }))
        .cloned()
        .chain([Control::Hello(hello("a")), start_msg()])
    {
        let mut d = dialer();
        d.handle_message(1, Control::Hello(hello("a")), pinned());
        assert_eq!(d.poll(), Some(HsAction::Send(Control::HelloAck)));
        d.handle_message(2, m.clone(), pinned());
        let e = last_fail(&mut d);
        assert_eq!(e.kind, ErrorKind::Protocol, "{m:?}");
        assert!(
            e.message.starts_with("expected hello ack from"),
            "{}",
            e.message
        );
    }
    // A dialer is never asked to pair by the acceptor.
    let mut d = dialer();
    d.handle_message(1, start_msg(), pinned());
    assert_eq!(last_fail(&mut d).kind, ErrorKind::Protocol);
    // Messages after the end change nothing.
    let mut d = dialer();
    d.handle_message(1, Control::Hello(hello("a")), pinned());
    d.handle_message(2, Control::HelloAck, pinned());
    assert_eq!(d.poll(), Some(HsAction::Send(Control::HelloAck)));
    assert!(matches!(d.poll(), Some(HsAction::Up(_))));
    for m in early.iter().cloned().chain([Control::Hello(hello("a"))]) {
        d.handle_message(3, m, pinned());
        d.handle_timeout(u64::MAX);
    }
    assert_eq!(d.poll(), None);
    assert_eq!(d.state(), HsState::Up);
}

/// Pairing requests and aborts as the first message: a device not showing
/// a code answers `Abort(NotPairing)`, finishes its stream and fails after
/// the abort linger (messages meanwhile are ignored); one showing a code
/// hands the start to the driver. An abort is a pairing failure only from a
/// pinned device; from anyone else it is refused and ignored.
#[test]
fn pairing_requests_and_aborts_first() {
    let mut a = acceptor();
    a.handle_message(1_000, start_msg(), pinned());
    assert_eq!(
        a.poll(),
        Some(HsAction::Send(Control::Pair(PairingMessage::Abort(
            PairingAbort::NotPairing
        ))))
    );
    assert_eq!(a.poll(), Some(HsAction::FinishSend));
    assert_eq!(a.poll(), None);
    assert_eq!(a.poll_timeout(), Some(101_000));
    a.handle_message(2_000, Control::Hello(hello("d")), pinned());
    a.handle_timeout(100_999);
    assert_eq!(a.poll(), None);
    a.handle_timeout(101_000);
    let e = last_fail(&mut a);
    assert_eq!(e.kind, ErrorKind::RefusedPeer);
    assert!(e.message.contains("not showing a pairing code"));
    // The close during the linger ends it early.
    let mut a = acceptor();
    a.handle_message(0, start_msg(), pinned());
    assert!(a.handle_read_error());
    assert_eq!(last_fail(&mut a).kind, ErrorKind::RefusedPeer);
    // Showing a code.
    let mut a = acceptor();
    let show = Local {
        peer_pinned: false,
        showing_code: true,
    };
    a.handle_message(0, start_msg(), show);
    assert!(matches!(
        a.poll(),
        Some(HsAction::Pair(PairingMessage::Start(_)))
    ));
    assert_eq!(a.state(), HsState::Pairing);
    a.handle_message(1, Control::Ping { id: 1, t1_us: 0 }, show);
    assert_eq!(a.poll(), None, "the driver reads while pairing");
    a.handle_paired(10);
    a.handle_message(20, Control::Hello(hello("d")), pinned());
    assert!(matches!(a.poll(), Some(HsAction::Send(Control::Hello(_)))));
    assert_eq!(a.poll(), Some(HsAction::Send(Control::HelloAck)));
    // Aborts.
    for (pinned_, kind) in [(false, ErrorKind::RefusedPeer), (true, ErrorKind::Pairing)] {
        let mut a = acceptor();
        let local = Local {
            peer_pinned: pinned_,
            showing_code: true,
        };
        a.handle_message(
            0,
            Control::Pair(PairingMessage::Abort(PairingAbort::WrongCode)),
            local,
        );
        assert_eq!(last_fail(&mut a).kind, kind);
    }
    let mut d = dialer();
    d.handle_message(
        0,
        Control::Pair(PairingMessage::Abort(PairingAbort::NotPairing)),
        pinned(),
    );
    assert_eq!(last_fail(&mut d).kind, ErrorKind::Pairing);
}

fn random_control(rng: &mut StdRng, base: &Hello) -> Control {
    match rng.gen_range(0..10) {
        0 | 1 => Control::Hello(if rng.gen_bool(0.7) {
            base.clone()
        } else {
            Hello {
                embedding_dim: rng.gen(),
                ..base.clone()
            }
        }),
        2 | 3 => Control::HelloAck,
        4 => Control::Mismatch {
            reasons: vec![MismatchReason::EmbeddingDim { ours: 1, theirs: 2 }],
        },
        5 => Control::Ping {
            id: rng.gen(),
            t1_us: rng.gen(),
        },
        6 => Control::Pair(PairingMessage::Abort(PairingAbort::NotPairing)),
        7 => Control::PressStart {
            press_id: rng.gen(),
            capture_us: rng.gen(),
        },
        8 => Control::Error {
            code: ErrorCode::Protocol,
            message: "x".into(),
        },
        _ => Control::Pong {
            id: 0,
            t1_us: 0,
            t2_us: 0,
            t3_us: 0,
        },
    }
}

/// Random message sequences, timeouts and stream ends into both roles:
/// never a panic, at most one final action (`Up` or `Fail`) and nothing
/// after it, no timer once ended, and `Up` only after a compatible hello
/// and an ack.
#[test]
fn random_inputs_end_at_most_once() {
    let base = hello("p");
    let mut rng = StdRng::seed_from_u64(17);
    let mut ups = 0;
    for i in 0..5_000 {
        let role = if i % 2 == 0 {
            Role::Dialer
        } else {
            Role::Acceptor
        };
        let mut hs = Handshake::new(
            HandshakeConfig::new(base.clone(), TIMEOUT),
            role,
            addr(),
            id_cached(),
            0,
        );
        let mut now = 0u64;
        let mut ended = false;
        let mut saw_hello = false;
        let mut saw_ack = false;
        for _ in 0..rng.gen_range(1..8) {
            now += rng.gen_range(0..4_000 * MS);
            let local = Local {
                peer_pinned: rng.gen_bool(0.8),
                showing_code: rng.gen_bool(0.2),
            };
            match rng.gen_range(0..10) {
                0 => hs.handle_timeout(now),
                1 => {
                    let _ = hs.handle_read_error();
                }
                2 => hs.handle_paired(now),
                _ => {
                    let m = random_control(&mut rng, &base);
                    if !ended {
                        saw_hello |= m == Control::Hello(base.clone());
                        saw_ack |= saw_hello && m == Control::HelloAck;
                    }
                    hs.handle_message(now, m, local);
                }
            }
            while let Some(a) = hs.poll() {
                match a {
                    HsAction::Up(_) | HsAction::Fail(_) => {
                        assert!(!ended, "ended twice");
                        ended = true;
                        if matches!(a, HsAction::Up(_)) {
                            assert!(saw_hello && saw_ack);
                            ups += 1;
                        }
                    }
                    other => assert!(!ended, "{other:?} after the end"),
                }
            }
            if ended {
                assert_eq!(hs.poll_timeout(), None);
            }
        }
    }
    assert!(ups > 50, "the random walk reaches Up sometimes: {ups}");
}

fn id_cached() -> DeviceId {
    use std::sync::OnceLock;
    static ID: OnceLock<DeviceId> = OnceLock::new();
    *ID.get_or_init(id)
}
