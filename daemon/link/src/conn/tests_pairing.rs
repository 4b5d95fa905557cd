//! [`PairingExchange`] in simulated time: the entering and the showing side
//! over an ordered, delaying stream; right and wrong codes, no code,
//! silence, aborts, foreign and out-of-place messages.

use std::time::Duration;

use rand::rngs::OsRng;
use telextiles_certs::pairing::PairingAbort;
use telextiles_certs::{Identity, PairingCode, PairingRole};
use telextiles_proto::pairing::PairingMessage;
use telextiles_proto::peer::{Control, ErrorCode};

use super::pairing::{PairAction, PairingExchange, ABORT_LINGER};
use super::sim::Channel;
use crate::ErrorKind;

const MS: u64 = 1_000;
const TIMEOUT: Duration = Duration::from_secs(10);

fn addr() -> String {
    "203.0.113.5:4797".to_string()
}

#[derive(Debug, Default)]
struct Side {
    paired: Option<(telextiles_certs::Paired, u64)>,
    failed: Option<(ErrorKind, String, bool, u64)>,
    sent: Vec<Control>,
}

fn drain(x: &mut PairingExchange, side: &mut Side, out: &mut Channel<Control>, t: u64) {
    while let Some(a) = x.poll() {
        assert!(
            side.paired.is_none() && side.failed.is_none(),
            "after the end: {a:?}"
        );
        match a {
            PairAction::Send(m) => {
                side.sent.push(m.clone());
                out.send(t, m);
            }
            PairAction::Paired(p) => side.paired = Some((p, t)),
            PairAction::Fail {
                error,
                session_failed,
            } => side.failed = Some((error.kind, error.message, session_failed, t)),
        }
    }
}

/// The entering side dials and starts; the showing side starts when the
/// entering side's `Start` arrives (it is its first message). Runs until
/// both ended or 30 s.
fn exchange(enter_code: PairingCode, show_code: PairingCode, delay: u64) -> (Side, Side) {
    let (ide, ids) = (Identity::generate().unwrap(), Identity::generate().unwrap());
    let mut e = PairingExchange::start(
        PairingRole::EntersCode,
        Ok(enter_code),
        &ide.peer_key(),
        &ids.peer_key(),
        &mut OsRng,
        addr(),
        0,
        TIMEOUT,
    );
    let mut s: Option<PairingExchange> = None;
    let (mut es, mut ss) = (Side::default(), Side::default());
    let mut to_s: Channel<Control> = Channel::new(delay, 0, 0.0, 1);
    let mut to_e: Channel<Control> = Channel::new(delay, 0, 0.0, 2);
    drain(&mut e, &mut es, &mut to_s, 0);
    let mut t = 0;
    while t < 30_000 * MS
        && (es.paired.is_none() && es.failed.is_none()
            || s.is_none()
            || ss.paired.is_none() && ss.failed.is_none())
    {
        let next = [
            e.poll_timeout().unwrap_or(u64::MAX),
            s.as_ref()
                .and_then(|x| x.poll_timeout())
                .unwrap_or(u64::MAX),
            to_s.next_at().unwrap_or(u64::MAX),
            to_e.next_at().unwrap_or(u64::MAX),
        ]
        .into_iter()
        .min()
        .unwrap();
        if next == u64::MAX {
            break;
        }
        t = next;
        while let Some(m) = to_s.recv(t) {
            let x = s.get_or_insert_with(|| {
                PairingExchange::start(
                    PairingRole::ShowsCode,
                    Ok(show_code.clone()),
                    &ids.peer_key(),
                    &ide.peer_key(),
                    &mut OsRng,
                    addr(),
                    t,
                    TIMEOUT,
                )
            });
            x.handle_message(t, m);
            drain(x, &mut ss, &mut to_e, t);
        }
        while let Some(m) = to_e.recv(t) {
            e.handle_message(t, m);
            drain(&mut e, &mut es, &mut to_s, t);
        }
        e.handle_timeout(t);
        drain(&mut e, &mut es, &mut to_s, t);
        if let Some(x) = s.as_mut() {
            x.handle_timeout(t);
            drain(x, &mut ss, &mut to_e, t);
        }
    }
    (es, ss)
}

/// The same code on both sides: both paired with the same verification
/// code, each knowing the other's ID, within three one-way trips.
#[test]
fn right_code_pairs_both_sides() {
    let code = PairingCode::generate(&mut OsRng);
    let (e, s) = exchange(code.clone(), code, 20 * MS);
    let (pe, te) = e.paired.expect("entering side paired");
    let (ps, ts) = s.paired.expect("showing side paired");
    assert_eq!(pe.verification, ps.verification);
    assert_ne!(pe.peer_id, ps.peer_id);
    assert!(te <= 60 * MS && ts <= 60 * MS, "{te} {ts}");
    assert!(e.sent.iter().all(|m| matches!(m, Control::Pair(_))));
}

/// Different codes: both fail, nobody is paired, an `Abort` was sent. The
/// showing side fails as a pairing failure of the exchange itself (it
/// leaves pairing mode: its code is used up); the entering side judged the
/// showing side's confirmation itself and fails one attempt only
/// (`PairingAttempt`, pairing mode kept: that device proved no code).
#[test]
fn wrong_code_fails_both_sides() {
    let (e, s) = exchange(
        PairingCode::generate(&mut OsRng),
        PairingCode::generate(&mut OsRng),
        20 * MS,
    );
    assert!(e.paired.is_none() && s.paired.is_none());
    let (kind, msg, session_failed, _) = s.failed.clone().expect("showing side failed");
    assert_eq!(kind, ErrorKind::Pairing);
    assert!(session_failed, "{msg}");
    assert!(msg.contains("203.0.113.5:4797"), "{msg}");
    let (kind, msg, session_failed, _) = e.failed.clone().expect("entering side failed");
    assert_eq!(kind, ErrorKind::PairingAttempt);
    assert!(!session_failed, "{msg}");
    assert!(msg.contains("203.0.113.5:4797"), "{msg}");
    assert!(msg.contains("did not prove the code you typed"), "{msg}");
    let aborts = e
        .sent
        .iter()
        .chain(&s.sent)
        .filter(|m| matches!(m, Control::Pair(PairingMessage::Abort(_))))
        .count();
    assert!(aborts >= 1);
}

fn one(code: Result<PairingCode, (Option<PairingAbort>, String)>) -> PairingExchange {
    one_as(PairingRole::ShowsCode, code)
}

fn one_as(
    role: PairingRole,
    code: Result<PairingCode, (Option<PairingAbort>, String)>,
) -> PairingExchange {
    let (a, b) = (Identity::generate().unwrap(), Identity::generate().unwrap());
    PairingExchange::start(
        role,
        code,
        &a.peer_key(),
        &b.peer_key(),
        &mut OsRng,
        addr(),
        1_000,
        TIMEOUT,
    )
}

fn fail_of(x: &mut PairingExchange) -> (ErrorKind, String, bool) {
    let mut out = None;
    while let Some(a) = x.poll() {
        if let PairAction::Fail {
            error,
            session_failed,
        } = a
        {
            assert!(out.is_none());
            out = Some((error.kind, error.message, session_failed));
        }
    }
    out.expect("a failure")
}

/// No code to pair with (a used or expired code, or not in pairing mode):
/// the abort goes out, the failure comes after the linger (or at the
/// stream's end); without an abort reason at once.
#[test]
fn no_code_aborts_then_fails_after_the_linger() {
    let mut x = one(Err((Some(PairingAbort::CodeUsed), "used".into())));
    assert!(matches!(
        x.poll(),
        Some(PairAction::Send(Control::Pair(PairingMessage::Abort(
            PairingAbort::CodeUsed
        ))))
    ));
    let linger = ABORT_LINGER.as_micros() as u64;
    assert_eq!(x.poll_timeout(), Some(1_000 + linger));
    x.handle_message(1_500, Control::HelloAck);
    x.handle_timeout(1_000 + linger - 1);
    assert!(x.poll().is_none());
    x.handle_timeout(1_000 + linger);
    assert_eq!(fail_of(&mut x), (ErrorKind::Pairing, "used".into(), false));
    assert!(x.is_done());

    let mut x = one(Err((Some(PairingAbort::NotPairing), "no".into())));
    let _ = x.poll();
    assert!(x.handle_read_error());
    assert_eq!(fail_of(&mut x).1, "no");

    let mut x = one(Err((None, "typo".into())));
    assert_eq!(fail_of(&mut x), (ErrorKind::Pairing, "typo".into(), false));
}

/// A silent peer: "pairing timed out" at exactly the timeout. A message
/// that is not a pairing message: a protocol error naming its kind, not
/// its text. The peer's abort: a failure of the exchange, no abort back.
#[test]
fn silence_foreign_messages_and_aborts() {
    let mut x = one(Ok(PairingCode::generate(&mut OsRng)));
    assert!(matches!(
        x.poll(),
        Some(PairAction::Send(Control::Pair(PairingMessage::Start(_))))
    ));
    x.handle_timeout(1_000 + 10_000 * MS - 1);
    assert!(x.poll().is_none());
    x.handle_timeout(1_000 + 10_000 * MS);
    assert_eq!(
        fail_of(&mut x),
        (ErrorKind::Pairing, "pairing timed out".into(), false)
    );

    let mut x = one(Ok(PairingCode::generate(&mut OsRng)));
    let _ = x.poll();
    x.handle_message(
        5,
        Control::Error {
            code: ErrorCode::Other,
            message: "\x1b[31mred".into(),
        },
    );
    let (kind, msg, _) = fail_of(&mut x);
    assert_eq!(kind, ErrorKind::Protocol);
    assert!(msg.contains("got Error") && !msg.contains('\x1b'), "{msg}");

    let mut x = one(Ok(PairingCode::generate(&mut OsRng)));
    let _ = x.poll();
    x.handle_message(
        5,
        Control::Pair(PairingMessage::Abort(PairingAbort::WrongCode)),
    );
    let mut sent_abort = false;
    let mut failed = None;
    while let Some(a) = x.poll() {
        match a {
            PairAction::Send(Control::Pair(PairingMessage::Abort(_))) => sent_abort = true,
            PairAction::Fail {
                error,
                session_failed,
            } => failed = Some((error.kind, session_failed)),
            other => panic!("{other:?}"),
        }
    }
    assert!(!sent_abort);
    assert_eq!(failed, Some((ErrorKind::Pairing, true)));
    // Nothing after the end.
    x.handle_message(6, Control::HelloAck);
    x.handle_timeout(u64::MAX);
    assert!(x.poll().is_none());
}

/// A relay that passes messages of another device pair (same code, other
/// certificates): the key confirmation binds the certificates, so it fails
/// as a wrong code and nobody is paired.
#[test]
fn messages_of_another_device_pair_do_not_pair() {
    let code = PairingCode::generate(&mut OsRng);
    let (other_a, other_b) = (Identity::generate().unwrap(), Identity::generate().unwrap());
    let (mut other, replayed) = telextiles_certs::PairingSession::start(
        PairingRole::EntersCode,
        code.clone(),
        &other_a.peer_key(),
        &other_b.peer_key(),
        &mut OsRng,
    )
    .unwrap();
    let mut x = one(Ok(code));
    let Some(PairAction::Send(Control::Pair(our_start))) = x.poll() else {
        panic!("no start")
    };
    x.handle_message(10, Control::Pair(replayed));
    let mut ours = Vec::new();
    while let Some(a) = x.poll() {
        match a {
            PairAction::Send(Control::Pair(m)) => ours.push(m),
            other => panic!("{other:?}"),
        }
    }
    // The other pair's entering side answers our start with its confirmation.
    let telextiles_certs::PairingStep::Send(confirm) = other.handle(&our_start).unwrap() else {
        panic!("no confirmation")
    };
    x.handle_message(20, Control::Pair(confirm));
    let mut failed = None;
    while let Some(a) = x.poll() {
        match a {
            PairAction::Paired(_) => panic!("paired through a relay"),
            PairAction::Fail {
                error,
                session_failed,
            } => failed = Some((error.kind, session_failed)),
            PairAction::Send(_) => {}
        }
    }
    x.handle_timeout(u64::MAX);
    while let Some(a) = x.poll() {
        match a {
            PairAction::Paired(_) => panic!("paired through a relay"),
            PairAction::Fail {
                error,
                session_failed,
            } => failed = Some((error.kind, session_failed)),
            PairAction::Send(_) => {}
        }
    }
    assert_eq!(failed, Some((ErrorKind::Pairing, true)));
    assert!(x.is_done());
}

/// The entering side dials devices that only claim to show a code (anyone
/// can advertise `pair=1`). Whatever such a device does instead of proving
/// the code ends that one attempt (`PairingAttempt`, `session_failed`
/// false: this side stays in pairing mode), never the pairing: an
/// `Abort` (of any reason), silence until the timeout, a foreign message,
/// a malformed or out-of-place pairing message. The old exchange failed
/// each as `Pairing` with `session_failed` (the abort) and the front ends
/// ended `pair --enter` on it. Each message names the device's address.
#[test]
fn entering_side_failures_without_a_proof_are_one_attempt_only() {
    let entering = || {
        let mut x = one_as(
            PairingRole::EntersCode,
            Ok(PairingCode::generate(&mut OsRng)),
        );
        assert!(matches!(
            x.poll(),
            Some(PairAction::Send(Control::Pair(PairingMessage::Start(_))))
        ));
        x
    };
    let attempt = |x: &mut PairingExchange, what: &str| {
        let (kind, msg, session_failed) = fail_of(x);
        assert_eq!(kind, ErrorKind::PairingAttempt, "{what}: {msg}");
        assert!(!session_failed, "{what}: {msg}");
        assert!(msg.contains("203.0.113.5:4797"), "{what}: {msg}");
        assert!(msg.contains("still looking"), "{what}: {msg}");
        assert!(x.is_done(), "{what}");
        msg
    };

    for reason in [
        PairingAbort::CodeExpired,
        PairingAbort::CodeUsed,
        PairingAbort::NotPairing,
        PairingAbort::WrongCode,
        PairingAbort::SameRole,
        PairingAbort::UnsupportedVersion(9),
        PairingAbort::ProtocolViolation,
        PairingAbort::Cancelled,
    ] {
        let mut x = entering();
        x.handle_message(5, Control::Pair(PairingMessage::Abort(reason)));
        let msg = attempt(&mut x, &format!("abort {reason:?}"));
        assert!(msg.contains("without proving the code"), "{msg}");
    }

    let mut x = entering();
    x.handle_timeout(1_000 + 10_000 * MS - 1);
    assert!(x.poll().is_none());
    x.handle_timeout(1_000 + 10_000 * MS);
    let msg = attempt(&mut x, "silence");
    assert!(msg.contains("within 10 s"), "{msg}");

    let mut x = entering();
    x.handle_message(5, Control::HelloAck);
    let msg = attempt(&mut x, "foreign message");
    assert!(msg.contains("HelloAck"), "{msg}");

    // A confirmation before any start: out of place. This side tells the
    // device (an `Abort`), then fails the attempt after the linger.
    let mut x = entering();
    x.handle_message(
        5,
        Control::Pair(PairingMessage::Confirm(
            telextiles_proto::pairing::PairingConfirm { mac: [7; 32] },
        )),
    );
    assert!(matches!(
        x.poll(),
        Some(PairAction::Send(Control::Pair(PairingMessage::Abort(
            PairingAbort::ProtocolViolation
        ))))
    ));
    assert!(x.handle_read_error());
    attempt(&mut x, "confirmation before a start");
}

/// A device that answers the entering side's `Start` with a `Start` for
/// another code and a confirmation (what a fake device showing a code
/// does to guess it): the entering side checks the confirmation itself,
/// tells the device the code did not match, and fails that attempt only,
/// after the linger. The showing side's wrong-code failure is unchanged:
/// `Pairing`, `session_failed`.
#[test]
fn entering_side_judges_a_wrong_confirmation_itself() {
    let (ide, ids) = (Identity::generate().unwrap(), Identity::generate().unwrap());
    let mut e = PairingExchange::start(
        PairingRole::EntersCode,
        Ok(PairingCode::generate(&mut OsRng)),
        &ide.peer_key(),
        &ids.peer_key(),
        &mut OsRng,
        addr(),
        0,
        TIMEOUT,
    );
    let Some(PairAction::Send(Control::Pair(e_start))) = e.poll() else {
        panic!("no start")
    };
    let (mut fake, fake_start) = telextiles_certs::PairingSession::start(
        PairingRole::ShowsCode,
        PairingCode::generate(&mut OsRng),
        &ids.peer_key(),
        &ide.peer_key(),
        &mut OsRng,
    )
    .unwrap();
    let telextiles_certs::PairingStep::Send(fake_confirm) = fake.handle(&e_start).unwrap() else {
        panic!("no confirmation")
    };
    e.handle_message(10, Control::Pair(fake_start));
    assert!(matches!(
        e.poll(),
        Some(PairAction::Send(Control::Pair(PairingMessage::Confirm(_))))
    ));
    e.handle_message(20, Control::Pair(fake_confirm));
    assert!(matches!(
        e.poll(),
        Some(PairAction::Send(Control::Pair(PairingMessage::Abort(
            PairingAbort::WrongCode
        ))))
    ));
    assert!(e.poll().is_none(), "the failure waits for the linger");
    e.handle_timeout(20 + ABORT_LINGER.as_micros() as u64);
    let (kind, msg, session_failed) = fail_of(&mut e);
    assert_eq!(kind, ErrorKind::PairingAttempt, "{msg}");
    assert!(!session_failed, "{msg}");
    assert!(msg.contains("did not prove the code you typed"), "{msg}");
    assert!(msg.contains("203.0.113.5:4797"), "{msg}");

    // The same on the showing side (a device entering a wrong code).
    let mut s = one(Ok(PairingCode::generate(&mut OsRng)));
    let Some(PairAction::Send(Control::Pair(s_start))) = s.poll() else {
        panic!("no start")
    };
    let (mut guess, guess_start) = telextiles_certs::PairingSession::start(
        PairingRole::EntersCode,
        PairingCode::generate(&mut OsRng),
        &ide.peer_key(),
        &ids.peer_key(),
        &mut OsRng,
    )
    .unwrap();
    let telextiles_certs::PairingStep::Send(guess_confirm) = guess.handle(&s_start).unwrap() else {
        panic!("no confirmation")
    };
    s.handle_message(10, Control::Pair(guess_start));
    assert!(matches!(
        s.poll(),
        Some(PairAction::Send(Control::Pair(PairingMessage::Confirm(_))))
    ));
    s.handle_message(20, Control::Pair(guess_confirm));
    assert!(matches!(
        s.poll(),
        Some(PairAction::Send(Control::Pair(PairingMessage::Abort(
            PairingAbort::WrongCode
        ))))
    ));
    s.handle_timeout(u64::MAX);
    let (kind, msg, session_failed) = fail_of(&mut s);
    assert_eq!(kind, ErrorKind::Pairing, "{msg}");
    assert!(session_failed, "{msg}");
}
