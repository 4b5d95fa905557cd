use super::*;
use serde_json::json;

fn err_of(line: &str) -> RequestError {
    parse_request(line.as_bytes()).unwrap_err()
}

#[test]
fn parses_each_command() {
    let cases: Vec<(&str, Command)> = vec![
        (r#"{"id":1,"cmd":"status"}"#, Command::Status),
        (r#"{"id":1,"cmd":"peers","args":{}}"#, Command::Peers),
        (
            r#"{"cmd":"pair","args":{"code":"12-34","timeout_s":60}}"#,
            Command::Pair(PairArgs {
                code: Some("12-34".into()),
                timeout_s: Some(60),
            }),
        ),
        (
            r#"{"cmd":"unpair","args":{"peer":"alice"}}"#,
            Command::Unpair(UnpairArgs {
                peer: "alice".into(),
            }),
        ),
        (
            r#"{"cmd":"sensor.recalibrate"}"#,
            Command::SensorRecalibrate,
        ),
        (
            r#"{"cmd":"sensor.led","args":{"intensity":7}}"#,
            Command::SensorLed(LedArgs { r: 7, g: 7, b: 7 }),
        ),
        (
            r#"{"cmd":"sensor.led","args":{"r":1,"g":2,"b":15}}"#,
            Command::SensorLed(LedArgs { r: 1, g: 2, b: 15 }),
        ),
        (
            r#"{"cmd":"roller.goto","args":{"slot":3}}"#,
            Command::RollerGoto(GotoTarget::Slot(3)),
        ),
        (
            r#"{"cmd":"roller.goto","args":{"textile":"T012"}}"#,
            Command::RollerGoto(GotoTarget::Textile("T012".into())),
        ),
        (
            r#"{"cmd":"sensor.sim","args":{"textile":"T012"}}"#,
            Command::SensorSim(SimPressArgs {
                textile: "T012".into(),
                ..Default::default()
            }),
        ),
        (
            r#"{"cmd":"sensor.sim","args":{"textile":"U03","person":9,"sensor":4,"jig":false,"seed":7,"rotation_deg":-45.5,"force":1.5}}"#,
            Command::SensorSim(SimPressArgs {
                textile: "U03".into(),
                person: Some(9),
                sensor: Some(4),
                jig: Some(false),
                seed: Some(7),
                rotation_deg: Some(-45.5),
                force: Some(1.5),
            }),
        ),
        (r#"{"cmd":"roller.home"}"#, Command::RollerHome),
        (
            r#"{"cmd":"roller.jog","args":{"degrees":-22.5}}"#,
            Command::RollerJog(JogArgs { degrees: -22.5 }),
        ),
        (r#"{"cmd":"index.info"}"#, Command::IndexInfo),
        (
            r#"{"cmd":"subscribe"}"#,
            Command::Subscribe(SubscribeArgs { events: None }),
        ),
        (
            r#"{"cmd":"subscribe","args":{"events":["decision","peer_up","decision"]}}"#,
            Command::Subscribe(SubscribeArgs {
                events: Some(vec![EventKind::Decision, EventKind::PeerUp]),
            }),
        ),
        (r#"{"cmd":"shutdown","args":null}"#, Command::Shutdown),
        (
            r#"{"cmd":"record.start","args":{"textile":"T030","presses":5,"out":"/data/rec"}}"#,
            Command::RecordStart(RecordStartArgs {
                textile: "T030".into(),
                name: None,
                presses: 5,
                out: "/data/rec".into(),
            }),
        ),
        (
            r#"{"cmd":"record.start","args":{"textile":"denim-1","name":"blue denim","presses":1,"out":"rec"}}"#,
            Command::RecordStart(RecordStartArgs {
                textile: "denim-1".into(),
                name: Some("blue denim".into()),
                presses: 1,
                out: "rec".into(),
            }),
        ),
        (r#"{"cmd":"record.stop"}"#, Command::RecordStop),
    ];
    for (line, want) in cases {
        let got = parse_request(line.as_bytes()).unwrap_or_else(|e| panic!("{line}: {e:?}"));
        assert_eq!(got.command, want, "{line}");
        // And the command encodes back to a request that parses to itself.
        let again =
            parse_request(got.command.to_request_line(&got.id).trim_end().as_bytes()).unwrap();
        assert_eq!(again, got);
    }
    assert_eq!(COMMANDS.len(), 15);
}

#[test]
fn ids_are_echoed_and_validated() {
    let r = parse_request(br#"{"id":"abc","cmd":"status"}"#).unwrap();
    assert_eq!(r.id, RequestId::Str("abc".into()));
    let r = parse_request(br#"{"id":18446744073709551615,"cmd":"status"}"#).unwrap();
    assert_eq!(
        Reply::ok(r.id, json!(1)).to_line(),
        "{\"id\":18446744073709551615,\"ok\":true,\"data\":1}\n"
    );
    for bad in [
        r#"{"cmd":"sensor.sim"}"#,
        r#"{"cmd":"sensor.sim","args":{"textile":"T001","jig":"yes"}}"#,
        r#"{"cmd":"sensor.sim","args":{"textile":"T001","rotation_deg":1000}}"#,
        r#"{"cmd":"sensor.sim","args":{"textile":"T001","force":-1}}"#,
    ] {
        assert_eq!(err_of(bad).error.code, ErrorCode::InvalidArgs, "{bad}");
    }
    let e = err_of(r#"{"id":[1],"cmd":"status"}"#);
    assert_eq!(e.error.code, ErrorCode::InvalidRequest);
    assert!(e.error.message.contains("`id`"), "{}", e.error.message);
    // The id survives errors in later fields.
    let e = err_of(r#"{"id":7,"cmd":"nope"}"#);
    assert_eq!(e.id, RequestId::from(7));
    assert_eq!(e.error.code, ErrorCode::UnknownCommand);
    assert!(e.error.message.contains("`nope`") && e.error.message.contains("roller.goto"));
}

#[test]
fn malformed_requests_get_clear_errors() {
    let e = err_of(r#"{"id":1,"cmd":"status""#);
    assert_eq!(e.error.code, ErrorCode::ParseError);
    assert!(e.error.message.starts_with("malformed JSON"));
    assert_eq!(err_of("[1,2]").error.code, ErrorCode::InvalidRequest);
    assert_eq!(err_of(r#"{"id":1}"#).error.code, ErrorCode::InvalidRequest);
    assert!(err_of(r#"{"id":1}"#)
        .error
        .message
        .contains("missing `cmd`"));
    let e = err_of(r#"{"cmd":5}"#);
    assert!(e
        .error
        .message
        .contains("`cmd` must be a string, got number 5"));
    let e = err_of(r#"{"cmd":"status","args":[1]}"#);
    assert_eq!(e.error.code, ErrorCode::InvalidArgs);
    let e = err_of(r#"{"cmd":"status","extra":1}"#);
    assert!(e.error.message.contains("unknown request field `extra`"));
    assert_eq!(
        parse_request(&[0xff, 0xfe]).unwrap_err().error.code,
        ErrorCode::ParseError
    );
}

#[test]
fn wrong_argument_types_name_the_argument() {
    let cases = [
        (
            r#"{"cmd":"roller.goto","args":{"slot":"3"}}"#,
            "argument `slot` must be an integer",
        ),
        (
            r#"{"cmd":"roller.goto","args":{"slot":-1}}"#,
            "argument `slot`",
        ),
        (
            r#"{"cmd":"roller.goto","args":{"slot":1.5}}"#,
            "argument `slot`",
        ),
        (r#"{"cmd":"roller.goto","args":{}}"#, "needs `slot`"),
        (
            r#"{"cmd":"roller.goto","args":{"slot":1,"textile":"T001"}}"#,
            "not both",
        ),
        (
            r#"{"cmd":"roller.jog","args":{"degrees":"x"}}"#,
            "argument `degrees` must be a number",
        ),
        (
            r#"{"cmd":"roller.jog","args":{"degrees":400}}"#,
            "argument `degrees`",
        ),
        (r#"{"cmd":"roller.jog"}"#, "missing argument `degrees`"),
        (
            r#"{"cmd":"unpair","args":{"peer":3}}"#,
            "argument `peer` must be a string",
        ),
        (r#"{"cmd":"unpair"}"#, "missing argument `peer`"),
        (
            r#"{"cmd":"pair","args":{"timeout_s":0}}"#,
            "argument `timeout_s`",
        ),
        (
            r#"{"cmd":"sensor.led","args":{"intensity":16}}"#,
            "argument `intensity`",
        ),
        (
            r#"{"cmd":"sensor.led","args":{"r":1}}"#,
            "needs `intensity`",
        ),
        (
            r#"{"cmd":"subscribe","args":{"events":"decision"}}"#,
            "argument `events` must be an array",
        ),
        (
            r#"{"cmd":"subscribe","args":{"events":[1]}}"#,
            "argument `events[0]` must be a string",
        ),
        (
            r#"{"cmd":"subscribe","args":{"events":["nope"]}}"#,
            "unknown event kind `nope`",
        ),
        (
            r#"{"cmd":"subscribe","args":{"events":[]}}"#,
            "must not be empty",
        ),
        (
            r#"{"cmd":"status","args":{"verbose":true}}"#,
            "`status`: unknown argument `verbose`",
        ),
        (
            r#"{"cmd":"record.start","args":{"presses":1,"out":"r"}}"#,
            "missing argument `textile`",
        ),
        (
            r#"{"cmd":"record.start","args":{"textile":"../x","presses":1,"out":"r"}}"#,
            "plain directory name",
        ),
        (
            r#"{"cmd":"record.start","args":{"textile":"..","presses":1,"out":"r"}}"#,
            "plain directory name",
        ),
        (
            r#"{"cmd":"record.start","args":{"textile":"T1","presses":0,"out":"r"}}"#,
            "argument `presses`",
        ),
        (
            r#"{"cmd":"record.start","args":{"textile":"T1","out":"r"}}"#,
            "missing argument `presses`",
        ),
        (
            r#"{"cmd":"record.start","args":{"textile":"T1","presses":2}}"#,
            "missing argument `out`",
        ),
        (
            r#"{"cmd":"record.start","args":{"textile":"T1","presses":2,"out":"a\u0000b"}}"#,
            "NUL",
        ),
        (
            r#"{"cmd":"record.stop","args":{"now":true}}"#,
            "unknown argument `now`",
        ),
    ];
    for (line, want) in cases {
        let e = err_of(line);
        assert_eq!(e.error.code, ErrorCode::InvalidArgs, "{line}");
        assert!(
            e.error.message.contains(want),
            "{line}: {}",
            e.error.message
        );
    }
}

#[test]
fn replies_and_events_round_trip() {
    let ok = Reply::ok(RequestId::from(3), json!({"a": 1}));
    assert_eq!(ok.to_line(), "{\"id\":3,\"ok\":true,\"data\":{\"a\":1}}\n");
    let err = Reply::err(
        RequestId::Str("x".into()),
        CtlError::invalid_args("bad `slot`"),
    );
    assert_eq!(
        err.to_line(),
        "{\"id\":\"x\",\"ok\":false,\"error\":{\"code\":\"invalid_args\",\"message\":\"bad `slot`\"}}\n"
    );
    for r in [ok, err] {
        let line = r.to_line();
        assert_eq!(
            parse_server_line(line.trim_end().as_bytes()).unwrap(),
            ServerLine::Reply(r)
        );
    }
    let ev = Event::Decision {
        textile: "T012".into(),
        name: None,
        slot: 3,
        distance: 0.25,
        unknown: false,
        latency_ms: 41.5,
        peer: Some("alice".into()),
        press: None,
        final_decision: false,
        since_contact_ms: None,
    };
    assert_eq!(
        ev.to_line(),
        "{\"event\":\"decision\",\"textile\":\"T012\",\"slot\":3,\"distance\":0.25,\"latency_ms\":41.5,\"peer\":\"alice\"}\n"
    );
    assert_eq!(
        parse_server_line(ev.to_line().trim_end().as_bytes()).unwrap(),
        ServerLine::Event(ev.clone())
    );
    // A textile the index does not know: the flag is on the line and
    // reads back; a line without it is a known textile.
    let mut far = ev;
    if let Event::Decision { unknown, .. } = &mut far {
        *unknown = true;
    }
    assert!(
        far.to_line().contains(",\"unknown\":true,"),
        "{}",
        far.to_line()
    );
    assert_eq!(
        parse_server_line(far.to_line().trim_end().as_bytes()).unwrap(),
        ServerLine::Event(far)
    );
    let saved = Event::RecordSaved {
        textile: "T030".into(),
        press: 3,
        presses: 5,
        path: "/rec/T030/0003".into(),
        frames: 142,
        duration_ms: 2350.0,
        peak: 5.25,
        reference_frames: 30,
        fps: 60.0,
        warnings: vec![],
    };
    assert_eq!(
        saved.to_line(),
        "{\"event\":\"record_saved\",\"textile\":\"T030\",\"press\":3,\"presses\":5,\"path\":\"/rec/T030/0003\",\"frames\":142,\"duration_ms\":2350.0,\"peak\":5.25,\"reference_frames\":30,\"fps\":60.0}\n"
    );
    let state = Event::Record {
        state: RecordPhase::Holding,
        textile: "T030".into(),
        press: 3,
        presses: 5,
        held_ms: Some(500.0),
        score: Some(4.5),
        reason: None,
    };
    let warning = Event::RecordWarning {
        textile: "T030".into(),
        press: 3,
        code: "too_short".into(),
        message: "press too short".into(),
        rejected: true,
    };
    for ev in [saved, state, warning] {
        assert_eq!(ev.kind(), Some(EventKind::Record));
        assert_eq!(
            parse_server_line(ev.to_line().trim_end().as_bytes()).unwrap(),
            ServerLine::Event(ev)
        );
    }
    assert!(matches!(
        parse_server_line(br#"{"event":"future_kind","x":1}"#).unwrap(),
        ServerLine::UnknownEvent(_)
    ));
    // Unknown error codes from a newer server still decode.
    let r = parse_server_line(br#"{"id":1,"ok":false,"error":{"code":"new_code","message":"m"}}"#)
        .unwrap();
    let ServerLine::Reply(r) = r else { panic!() };
    assert_eq!(r.into_result().unwrap_err().code, ErrorCode::Unknown);
}

#[test]
fn filters() {
    let f = EventFilter::of(&[EventKind::Decision, EventKind::RollerArrived]);
    assert!(f.contains(EventKind::Decision));
    assert!(!f.contains(EventKind::Contact));
    assert!(f.matches(&Event::Dropped { reason: "x".into() }));
    assert!(!f.matches(&Event::PeerDown {
        peer: "p".into(),
        reason: "r".into()
    }));
    assert_eq!(EventFilter::all().kinds().len(), 10);
    for k in EventKind::ALL {
        assert_eq!(EventKind::parse(k.as_str()), Some(k));
        assert_eq!(serde_json::to_value(k).unwrap(), json!(k.as_str()));
    }
}

#[test]
fn framer_splits_caps_and_resyncs() {
    let mut f = LineFramer::new(10);
    f.feed(b"abc\r\n\n  \nde");
    assert_eq!(f.next_frame(), Some(Frame::Line(b"abc".to_vec())));
    assert_eq!(f.next_frame(), None);
    f.feed(b"f\n0123456789\n");
    assert_eq!(f.next_frame(), Some(Frame::Line(b"def".to_vec())));
    assert_eq!(f.next_frame(), Some(Frame::Line(b"0123456789".to_vec())));
    // 11 bytes split over two reads: reported once, then resync.
    f.feed(b"0123456");
    assert_eq!(f.next_frame(), None);
    f.feed(b"7890");
    assert_eq!(f.next_frame(), Some(Frame::TooLong));
    f.feed(&[b'x'; 100]);
    assert_eq!(f.next_frame(), None);
    assert_eq!(f.pending(), 0);
    f.feed(b"yyy\nok\n");
    assert_eq!(f.next_frame(), Some(Frame::Line(b"ok".to_vec())));
    assert_eq!(f.next_frame(), None);
    // Oversize line whose newline arrives in the same read.
    f.feed(b"0123456789ab\nz\n");
    assert_eq!(f.next_frame(), Some(Frame::TooLong));
    assert_eq!(f.next_frame(), Some(Frame::Line(b"z".to_vec())));
}
