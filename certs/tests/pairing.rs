//! Pairing state machine: codes, SPAKE2 + key confirmation, wrong codes,
//! a machine in the middle, protocol misuse, and arbitrary input.
use std::time::{Duration, Instant};

use proptest::prelude::*;
use rand::SeedableRng;
use rand_chacha::ChaCha20Rng;
use telextiles_certs::pairing::{
    damm, PairingAbort, PairingConfirm, PairingStart, CODE_DIGITS, PAIRING_VERSION,
};
use telextiles_certs::{
    CodeError, CodeOffer, Identity, Paired, PairingCode, PairingError, PairingMessage, PairingRole,
    PairingSession, PairingStep, DEFAULT_CODE_TTL,
};

fn rng(seed: u64) -> ChaCha20Rng {
    ChaCha20Rng::seed_from_u64(seed)
}

struct Pair {
    shows: Identity,
    enters: Identity,
}

fn pair() -> Pair {
    Pair {
        shows: Identity::generate().unwrap(),
        enters: Identity::generate().unwrap(),
    }
}

/// Runs both machines to the end, delivering messages in order; returns
/// each side's result.
fn run(
    p: &Pair,
    code_shown: PairingCode,
    code_typed: PairingCode,
) -> (Result<Paired, PairingError>, Result<Paired, PairingError>) {
    let (mut s, s_start) = PairingSession::start(
        PairingRole::ShowsCode,
        code_shown,
        &p.shows.peer_key(),
        &p.enters.peer_key(),
        &mut rng(1),
    )
    .unwrap();
    let (mut e, e_start) = PairingSession::start(
        PairingRole::EntersCode,
        code_typed,
        &p.enters.peer_key(),
        &p.shows.peer_key(),
        &mut rng(2),
    )
    .unwrap();
    let s_confirm = match s.handle(&e_start).unwrap() {
        PairingStep::Send(m @ PairingMessage::Confirm(_)) => m,
        other => panic!("{other:?}"),
    };
    let e_confirm = match e.handle(&s_start).unwrap() {
        PairingStep::Send(m @ PairingMessage::Confirm(_)) => m,
        other => panic!("{other:?}"),
    };
    let done = |r: Result<PairingStep, PairingError>| {
        r.map(|step| match step {
            PairingStep::Paired(p) => p,
            other => panic!("{other:?}"),
        })
    };
    let rs = done(s.handle(&e_confirm));
    let re = done(e.handle(&s_confirm));
    assert!(s.is_over() && e.is_over());
    (rs, re)
}

#[test]
fn matching_codes_pair_both_sides_with_the_same_verification_string() {
    let p = pair();
    let mut offer = CodeOffer::new(&mut rng(5), Instant::now(), DEFAULT_CODE_TTL);
    let shown = offer.display();
    assert_eq!(shown.len(), CODE_DIGITS + 1);
    let typed: PairingCode = shown.replace('-', " ").parse().unwrap();
    let code = offer.take(Instant::now()).unwrap();
    let (rs, re) = run(&p, code, typed);
    let (rs, re) = (rs.unwrap(), re.unwrap());
    assert_eq!(rs.peer_id, p.enters.device_id());
    assert_eq!(rs.peer_key, p.enters.peer_key());
    assert_eq!(re.peer_id, p.shows.device_id());
    assert_eq!(re.peer_key, p.shows.peer_key());
    assert_eq!(rs.verification, re.verification);
    let v = rs.verification.to_string();
    assert_eq!(v.len(), 7, "{v}");
}

#[test]
fn verification_strings_differ_between_sessions() {
    let p = pair();
    let code = PairingCode::generate(&mut rng(0));
    let mut seen = std::collections::HashSet::new();
    for seed in 0..4u64 {
        let (mut s, s0) = PairingSession::start(
            PairingRole::ShowsCode,
            code.clone(),
            &p.shows.peer_key(),
            &p.enters.peer_key(),
            &mut rng(seed * 2),
        )
        .unwrap();
        let (mut e, e0) = PairingSession::start(
            PairingRole::EntersCode,
            code.clone(),
            &p.enters.peer_key(),
            &p.shows.peer_key(),
            &mut rng(seed * 2 + 1),
        )
        .unwrap();
        let PairingStep::Send(sc) = s.handle(&e0).unwrap() else {
            panic!()
        };
        let PairingStep::Send(ec) = e.handle(&s0).unwrap() else {
            panic!()
        };
        let PairingStep::Paired(a) = s.handle(&ec).unwrap() else {
            panic!()
        };
        let PairingStep::Paired(b) = e.handle(&sc).unwrap() else {
            panic!()
        };
        assert_eq!(a.verification, b.verification);
        seen.insert(a.verification.value());
    }
    assert!(seen.len() >= 3, "{seen:?}");
}

#[test]
fn wrong_code_fails_on_both_sides_with_a_clear_error() {
    let p = pair();
    let mut r = rng(9);
    let a = PairingCode::generate(&mut r);
    let mut b = PairingCode::generate(&mut r);
    while b == a {
        b = PairingCode::generate(&mut r);
    }
    let (rs, re) = run(&p, a, b);
    assert_eq!(rs.unwrap_err(), PairingError::WrongCode);
    let e = re.unwrap_err();
    assert_eq!(e, PairingError::WrongCode);
    assert!(e.to_string().contains("did not match"), "{e}");
    assert_eq!(
        e.abort_message(),
        Some(PairingMessage::Abort(PairingAbort::WrongCode))
    );
}

#[test]
fn machine_in_the_middle_with_the_right_code_still_fails() {
    // Each real device sees the attacker's certificate in TLS; the attacker
    // relays the PAKE messages. The transcripts (and SPAKE2 identities)
    // differ, so confirmation fails on both sides even though the code is
    // right.
    let p = pair();
    let mallory = Identity::generate().unwrap();
    let code = PairingCode::generate(&mut rng(3));
    let (mut s, s0) = PairingSession::start(
        PairingRole::ShowsCode,
        code.clone(),
        &p.shows.peer_key(),
        &mallory.peer_key(),
        &mut rng(1),
    )
    .unwrap();
    let (mut e, e0) = PairingSession::start(
        PairingRole::EntersCode,
        code,
        &p.enters.peer_key(),
        &mallory.peer_key(),
        &mut rng(2),
    )
    .unwrap();
    let PairingStep::Send(sc) = s.handle(&e0).unwrap() else {
        panic!()
    };
    let PairingStep::Send(ec) = e.handle(&s0).unwrap() else {
        panic!()
    };
    assert_eq!(s.handle(&ec).unwrap_err(), PairingError::WrongCode);
    assert_eq!(e.handle(&sc).unwrap_err(), PairingError::WrongCode);
}

#[test]
fn reflected_messages_do_not_pair() {
    // An attacker sending a device's own messages back: same role is
    // refused, and a reflected Confirm does not verify.
    let p = pair();
    let code = PairingCode::generate(&mut rng(4));
    let (mut s, s0) = PairingSession::start(
        PairingRole::ShowsCode,
        code.clone(),
        &p.shows.peer_key(),
        &p.enters.peer_key(),
        &mut rng(1),
    )
    .unwrap();
    assert_eq!(
        s.handle(&s0).unwrap_err(),
        PairingError::SameRole(PairingRole::ShowsCode)
    );
    assert!(s.is_over());
    assert_eq!(s.handle(&s0).unwrap_err(), PairingError::Over);

    let (mut s, _s0) = PairingSession::start(
        PairingRole::ShowsCode,
        code.clone(),
        &p.shows.peer_key(),
        &p.enters.peer_key(),
        &mut rng(1),
    )
    .unwrap();
    let (_e, e0) = PairingSession::start(
        PairingRole::EntersCode,
        code,
        &p.enters.peer_key(),
        &p.shows.peer_key(),
        &mut rng(2),
    )
    .unwrap();
    let PairingStep::Send(sc) = s.handle(&e0).unwrap() else {
        panic!()
    };
    assert_eq!(s.handle(&sc).unwrap_err(), PairingError::WrongCode);
}

#[test]
fn protocol_misuse_is_reported() {
    let p = pair();
    let code = PairingCode::generate(&mut rng(4));
    let start = |role| {
        let (me, peer) = match role {
            PairingRole::ShowsCode => (&p.shows, &p.enters),
            PairingRole::EntersCode => (&p.enters, &p.shows),
        };
        PairingSession::start(
            role,
            code.clone(),
            &me.peer_key(),
            &peer.peer_key(),
            &mut rng(7),
        )
        .unwrap()
    };
    // Confirm before Start.
    let (mut s, _) = start(PairingRole::ShowsCode);
    let e = s
        .handle(&PairingMessage::Confirm(PairingConfirm { mac: [0; 32] }))
        .unwrap_err();
    assert!(
        matches!(e, PairingError::Unexpected { got: "Confirm", .. }),
        "{e}"
    );
    assert_eq!(
        e.abort_message(),
        Some(PairingMessage::Abort(PairingAbort::ProtocolViolation))
    );
    // Version mismatch.
    let (mut s, _) = start(PairingRole::ShowsCode);
    let bad = PairingMessage::Start(PairingStart {
        version: PAIRING_VERSION + 1,
        role: PairingRole::EntersCode,
        pake: vec![0x42; 33],
    });
    let e = s.handle(&bad).unwrap_err();
    assert!(matches!(e, PairingError::UnsupportedVersion { .. }), "{e}");
    // Malformed PAKE: wrong length, wrong side byte, oversized.
    for pake in [vec![0x42; 10], vec![0x41; 33], vec![0x42; 1000]] {
        let (mut s, _) = start(PairingRole::ShowsCode);
        let m = PairingMessage::Start(PairingStart {
            version: PAIRING_VERSION,
            role: PairingRole::EntersCode,
            pake,
        });
        assert!(matches!(s.handle(&m), Err(PairingError::Malformed(_))));
    }
    // Start twice.
    let (mut s, _) = start(PairingRole::ShowsCode);
    let (_, e0) = start(PairingRole::EntersCode);
    assert!(s.handle(&e0).is_ok());
    assert!(matches!(
        s.handle(&e0),
        Err(PairingError::Unexpected { got: "Start", .. })
    ));
    // Peer abort is surfaced with its reason.
    let (mut s, _) = start(PairingRole::EntersCode);
    let e = s
        .handle(&PairingMessage::Abort(PairingAbort::CodeExpired))
        .unwrap_err();
    assert_eq!(e, PairingError::PeerAborted(PairingAbort::CodeExpired));
    assert!(e.to_string().contains("expired"), "{e}");
    // Pairing with oneself.
    let e = PairingSession::start(
        PairingRole::ShowsCode,
        code.clone(),
        &p.shows.peer_key(),
        &p.shows.peer_key(),
        &mut rng(1),
    )
    .unwrap_err();
    assert_eq!(e, PairingError::SelfPairing);
}

#[test]
fn code_offer_is_single_use_and_expires() {
    let t0 = Instant::now();
    let mut offer = CodeOffer::new(&mut rng(1), t0, Duration::from_secs(120));
    assert!(offer.is_usable(t0));
    assert_eq!(
        offer.remaining(t0 + Duration::from_secs(20)),
        Duration::from_secs(100)
    );
    offer.take(t0 + Duration::from_secs(119)).unwrap();
    let e = offer.take(t0 + Duration::from_secs(1)).unwrap_err();
    assert_eq!(e, CodeError::Used);
    assert_eq!(e.abort_reason(), Some(PairingAbort::CodeUsed));

    let mut offer = CodeOffer::new(&mut rng(2), t0, Duration::from_secs(120));
    let e = offer.take(t0 + Duration::from_secs(120)).unwrap_err();
    assert_eq!(e, CodeError::Expired);
    assert_eq!(e.abort_reason(), Some(PairingAbort::CodeExpired));
    assert!(!offer.is_usable(t0 + Duration::from_secs(121)));
    assert_eq!(
        offer.remaining(t0 + Duration::from_secs(500)),
        Duration::ZERO
    );
    // Still usable before expiry if never taken.
    assert!(offer.take(t0).is_ok());
}

#[test]
fn typed_codes_catch_typos_before_any_traffic() {
    let code = PairingCode::generate(&mut rng(11));
    let text = code.to_string();
    let digits: Vec<u8> = text
        .bytes()
        .filter(u8::is_ascii_digit)
        .map(|b| b - b'0')
        .collect();
    assert_eq!(damm(&digits), 0);
    // Every single-digit substitution is caught.
    for pos in 0..CODE_DIGITS {
        for d in 0..10u8 {
            if d == digits[pos] {
                continue;
            }
            let mut t = digits.clone();
            t[pos] = d;
            let s: String = t.iter().map(|d| char::from(b'0' + d)).collect();
            assert!(
                matches!(s.parse::<PairingCode>(), Err(CodeError::Typo(_))),
                "{s}"
            );
        }
    }
    // Every swap of neighbouring different digits is caught.
    for pos in 0..CODE_DIGITS - 1 {
        if digits[pos] == digits[pos + 1] {
            continue;
        }
        let mut t = digits.clone();
        t.swap(pos, pos + 1);
        let s: String = t.iter().map(|d| char::from(b'0' + d)).collect();
        assert!(s.parse::<PairingCode>().is_err(), "{s}");
    }
    let e = "1234".parse::<PairingCode>().unwrap_err();
    assert!(e.to_string().contains("8 digits"), "{e}");
    let e = "1234-567x".parse::<PairingCode>().unwrap_err();
    assert!(matches!(e, CodeError::BadChar(_, 'x')), "{e}");
    assert_eq!(
        format!("{code:?}"),
        "PairingCode(..)",
        "codes must not leak into logs"
    );
}

#[test]
fn generated_codes_are_spread_out() {
    let mut r = rng(12);
    let mut firsts = [0u32; 10];
    let mut all = std::collections::HashSet::new();
    for _ in 0..2000 {
        let c = PairingCode::generate(&mut r).to_string();
        firsts[usize::from(c.as_bytes()[0] - b'0')] += 1;
        all.insert(c);
    }
    assert!(all.len() > 1990);
    assert!(
        firsts.iter().all(|&n| (140..=260).contains(&n)),
        "{firsts:?}"
    );
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]
    #[test]
    fn arbitrary_messages_never_panic(
        version in any::<u16>(),
        role in prop_oneof![Just(PairingRole::ShowsCode), Just(PairingRole::EntersCode)],
        pake in proptest::collection::vec(any::<u8>(), 0..80),
        mac in proptest::array::uniform32(any::<u8>()),
        confirm_first in any::<bool>(),
    ) {
        let p = pair_cached();
        let code = PairingCode::generate(&mut rng(1));
        let (mut s, _) = PairingSession::start(
            PairingRole::ShowsCode, code, &p.shows.peer_key(), &p.enters.peer_key(), &mut rng(2),
        ).unwrap();
        let start = PairingMessage::Start(PairingStart { version, role, pake });
        let confirm = PairingMessage::Confirm(PairingConfirm { mac });
        let msgs = if confirm_first { [confirm, start] } else { [start, confirm] };
        let mut paired = false;
        for m in &msgs {
            if let Ok(PairingStep::Paired(_)) = s.handle(m) {
                paired = true;
            }
        }
        // Random bytes never complete a pairing.
        prop_assert!(!paired);
    }
}

fn pair_cached() -> &'static Pair {
    static P: std::sync::OnceLock<Pair> = std::sync::OnceLock::new();
    P.get_or_init(pair)
}
