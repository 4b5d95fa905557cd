//! Property tests for the sans-IO protocol (the normal-suite complement of
//! the cargo-fuzz target): random bytes never panic the parser or the
//! framer, framing is independent of how bytes are split into reads, and
//! every valid command survives an encode/parse round trip.

use proptest::prelude::*;
use serde_json::{json, Value};
use telextiles_control::protocol::{
    parse_request, parse_server_line, Command, EventKind, Frame, GotoTarget, JogArgs, LedArgs,
    LineFramer, PairArgs, RecordStartArgs, RequestId, SubscribeArgs, UnpairArgs,
};

fn frames(f: &mut LineFramer) -> Vec<Frame> {
    std::iter::from_fn(|| f.next_frame()).collect()
}

fn arb_command() -> impl Strategy<Value = Command> {
    let kinds = proptest::sample::subsequence(EventKind::ALL.to_vec(), 1..=EventKind::ALL.len());
    prop_oneof![
        Just(Command::Status),
        Just(Command::Peers),
        (
            proptest::option::of("[a-z0-9-]{1,20}"),
            proptest::option::of(1u32..=3600)
        )
            .prop_map(|(code, timeout_s)| Command::Pair(PairArgs { code, timeout_s })),
        "[a-zA-Z0-9 ._-]{1,40}".prop_map(|peer| Command::Unpair(UnpairArgs { peer })),
        Just(Command::SensorRecalibrate),
        (0u8..=15, 0u8..=15, 0u8..=15).prop_map(|(r, g, b)| Command::SensorLed(LedArgs {
            r,
            g,
            b
        })),
        (0u32..=4095).prop_map(|s| Command::RollerGoto(GotoTarget::Slot(s))),
        "[TU][0-9]{2,3}".prop_map(|t| Command::RollerGoto(GotoTarget::Textile(t))),
        Just(Command::RollerHome),
        (-360.0f64..=360.0).prop_map(|degrees| Command::RollerJog(JogArgs { degrees })),
        Just(Command::IndexInfo),
        (
            "[A-Za-z0-9_-]{1,20}",
            proptest::option::of("[a-zA-Z0-9 ,.'-]{1,40}"),
            1u32..=10_000,
            "[a-zA-Z0-9 /._-]{1,60}",
        )
            .prop_map(|(textile, name, presses, out)| Command::RecordStart(
                RecordStartArgs {
                    textile,
                    name,
                    presses,
                    out
                }
            )),
        Just(Command::RecordStop),
        proptest::option::of(kinds).prop_map(|events| Command::Subscribe(SubscribeArgs { events })),
        Just(Command::Shutdown),
    ]
}

fn arb_json() -> impl Strategy<Value = Value> {
    let leaf = prop_oneof![
        Just(Value::Null),
        any::<bool>().prop_map(Value::from),
        any::<i64>().prop_map(Value::from),
        any::<f64>()
            .prop_map(|f| serde_json::Number::from_f64(f).map_or(Value::Null, Value::Number)),
        ".{0,12}".prop_map(Value::from),
        prop_oneof![
            Just("status"),
            Just("roller.goto"),
            Just("subscribe"),
            Just("slot"),
            Just("events"),
            Just("decision"),
            Just("sensor.led"),
            Just("degrees")
        ]
        .prop_map(Value::from),
    ];
    leaf.prop_recursive(3, 24, 6, |inner| {
        prop_oneof![
            proptest::collection::vec(inner.clone(), 0..5).prop_map(Value::Array),
            proptest::collection::btree_map(
                prop_oneof![
                    Just("id".to_string()),
                    Just("cmd".to_string()),
                    Just("args".to_string()),
                    Just("slot".to_string()),
                    Just("textile".to_string()),
                    Just("events".to_string()),
                    Just("intensity".to_string()),
                    "[a-z]{1,6}"
                ],
                inner,
                0..5
            )
            .prop_map(|m| Value::Object(m.into_iter().collect())),
        ]
    })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]

    #[test]
    fn random_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..512)) {
        let _ = parse_request(&bytes);
        let _ = parse_server_line(&bytes);
        let mut f = LineFramer::new(64);
        f.feed(&bytes);
        for fr in frames(&mut f) {
            if let Frame::Line(l) = fr {
                prop_assert!(l.len() <= 64);
                prop_assert!(!l.contains(&b'\n'));
                let _ = parse_request(&l);
            }
        }
    }

    #[test]
    fn structured_json_never_panics_and_errors_are_well_formed(v in arb_json()) {
        let line = v.to_string();
        match parse_request(line.as_bytes()) {
            Ok(req) => {
                // Valid requests re-encode to themselves.
                let again = parse_request(req.command.to_request_line(&req.id).trim_end().as_bytes());
                prop_assert_eq!(again.as_ref().ok(), Some(&req));
            }
            Err(e) => {
                prop_assert!(!e.error.message.is_empty());
                let reply: Value = serde_json::from_str(&e.to_reply_line()).unwrap();
                prop_assert_eq!(&reply["ok"], &json!(false));
            }
        }
    }

    #[test]
    fn commands_round_trip(cmd in arb_command(), id in any::<u32>()) {
        let id = RequestId::from(u64::from(id));
        let line = cmd.to_request_line(&id);
        let req = parse_request(line.trim_end().as_bytes()).unwrap();
        prop_assert_eq!(req.id, id);
        prop_assert_eq!(req.command, cmd);
    }

    #[test]
    fn framing_is_independent_of_read_boundaries(
        bytes in proptest::collection::vec(prop_oneof![Just(b'\n'), Just(b'a'), Just(b'\r'), Just(b' ')], 0..400),
        cuts in proptest::collection::vec(0usize..400, 0..20),
    ) {
        let mut whole = LineFramer::new(16);
        whole.feed(&bytes);
        let want = frames(&mut whole);
        let mut cuts: Vec<usize> = cuts.into_iter().filter(|c| *c <= bytes.len()).collect();
        cuts.sort_unstable();
        let mut pieces = LineFramer::new(16);
        let mut got = Vec::new();
        let mut start = 0;
        for c in cuts.into_iter().chain([bytes.len()]) {
            pieces.feed(&bytes[start..c]);
            got.extend(frames(&mut pieces));
            start = c;
        }
        prop_assert_eq!(got, want);
        prop_assert!(pieces.pending() <= 16);
    }
}
