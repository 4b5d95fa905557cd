//! Roller protocol: round trips, resynchronisation after garbage, and
//! random-byte property tests (the normal-suite counterpart of the cargo-fuzz
//! target `proto/fuzz/fuzz_targets/roller_decode.rs`).
use proptest::prelude::*;
use telextiles_proto::roller::*;

fn all_commands() -> Vec<Command> {
    vec![
        Command::Hello { protocol: 1 },
        Command::GotoSlot { slot: 15 },
        Command::GotoAngle { mdeg: 359_999 },
        Command::GotoSteps { steps: 3199 },
        Command::Zero,
        Command::SetMotion {
            max_speed: 3200,
            accel: 6400,
        },
        Command::SetSlots { slots: 16 },
        Command::QueryStatus,
        Command::Stop,
    ]
}

fn all_replies() -> Vec<Reply> {
    let s = Status {
        position: 1234,
        target: 3000,
        speed: -2500,
        slots: 16,
        flags: status_flags::MOVING | status_flags::ENABLED,
    };
    vec![
        Reply::Version(Version {
            protocol: 1,
            firmware: [0, 1, 2],
            steps_per_rev: 3200,
            slots: 16,
            watchdog_ms: 2000,
            max_speed: 3200,
            accel: 6400,
        }),
        Reply::Ack(s),
        Reply::Arrived(s),
        Reply::Status(s),
        Reply::Error {
            code: ErrorCode::Busy,
            command: kind::ZERO,
        },
        Reply::Error {
            code: ErrorCode::Other(77),
            command: 0,
        },
    ]
}

fn decode_all(dec: &mut FrameDecoder, bytes: &[u8]) -> Vec<Frame> {
    dec.feed(bytes).filter_map(Result::ok).collect()
}

#[test]
fn every_command_and_reply_round_trips() {
    let mut dec = FrameDecoder::new();
    for (i, c) in all_commands().into_iter().enumerate() {
        let buf = c.encode(i as u8);
        let frames = decode_all(&mut dec, buf.as_bytes());
        assert_eq!(frames.len(), 1);
        assert_eq!(frames[0].seq, i as u8);
        assert_eq!(Command::from_frame(&frames[0]), Ok(c));
        assert!(Reply::from_frame(&frames[0]).is_err());
    }
    for (i, r) in all_replies().into_iter().enumerate() {
        let buf = r.encode(200 + i as u8);
        let frames = decode_all(&mut dec, buf.as_bytes());
        assert_eq!(frames.len(), 1);
        assert_eq!(Reply::from_frame(&frames[0]), Ok(r));
        assert!(Command::from_frame(&frames[0]).is_err());
    }
    assert_eq!(dec.stats().crc_errors, 0);
    assert_eq!(dec.buffered(), 0);
}

#[test]
fn invalid_values_are_refused() {
    let f = Frame::new(1, kind::GOTO_ANGLE, &360_000u32.to_le_bytes()).unwrap();
    assert_eq!(
        Command::from_frame(&f),
        Err(MessageError::BadValue {
            kind: kind::GOTO_ANGLE
        })
    );
    let f = Frame::new(1, kind::SET_SLOTS, &0u16.to_le_bytes()).unwrap();
    assert!(Command::from_frame(&f).is_err());
    let f = Frame::new(1, kind::GOTO_SLOT, &[1]).unwrap();
    assert_eq!(
        Command::from_frame(&f),
        Err(MessageError::BadLength {
            kind: kind::GOTO_SLOT,
            len: 1
        })
    );
    let f = Frame::new(1, 0x42, &[]).unwrap();
    assert_eq!(
        Command::from_frame(&f),
        Err(MessageError::UnknownKind(0x42))
    );
    assert_eq!(
        Command::from_frame(&f).unwrap_err().code(),
        ErrorCode::UnknownCommand
    );
    assert!(Frame::new(0, 1, &[0u8; MAX_BODY + 1]).is_none());
}

#[test]
fn corrupted_frame_is_reported_and_next_frame_survives() {
    let a = Command::GotoSlot { slot: 3 }.encode(1);
    let b = Command::GotoSlot { slot: 4 }.encode(2);
    let mut bad = a.as_bytes().to_vec();
    bad[5] ^= 0x40;
    let mut line = bad;
    line.extend_from_slice(b.as_bytes());
    let mut dec = FrameDecoder::new();
    let items: Vec<_> = dec.feed(&line).collect();
    assert!(matches!(items[0], Err(FrameError::Crc { .. })), "{items:?}");
    let good: Vec<_> = items.into_iter().filter_map(Result::ok).collect();
    assert_eq!(good.len(), 1);
    assert_eq!(
        Command::from_frame(&good[0]),
        Ok(Command::GotoSlot { slot: 4 })
    );
    assert_eq!(dec.stats().crc_errors, 1);
}

#[test]
fn a_frame_hidden_inside_a_false_start_is_found() {
    // A false sync with a long announced length swallows a real frame; the
    // decoder must find it when the false one fails its checksum.
    let real = Command::Stop.encode(9);
    let mut line = vec![SYNC0, SYNC1, 30, 0, 0];
    line.extend_from_slice(real.as_bytes());
    line.extend_from_slice(&[0u8; 40]);
    let mut dec = FrameDecoder::new();
    let frames = decode_all(&mut dec, &line);
    assert_eq!(frames.len(), 1);
    assert_eq!(Command::from_frame(&frames[0]), Ok(Command::Stop));
}

#[test]
fn oversized_length_is_rejected_immediately() {
    let mut dec = FrameDecoder::new();
    let items: Vec<_> = dec.feed(&[SYNC0, SYNC1, 200]).collect();
    assert_eq!(items, vec![Err(FrameError::Length(200))]);
    assert_eq!(dec.buffered(), 0);
}

#[test]
fn byte_at_a_time_push_and_poll() {
    let mut dec = FrameDecoder::new();
    let mut line = vec![0x00, SYNC0, 0x13];
    for c in all_commands() {
        line.extend_from_slice(c.encode(5).as_bytes());
    }
    let mut got = Vec::new();
    for &b in &line {
        if let Some(Ok(f)) = dec.push(b) {
            got.push(Command::from_frame(&f).unwrap());
        }
        while let Some(Ok(f)) = dec.poll() {
            got.push(Command::from_frame(&f).unwrap());
        }
    }
    assert_eq!(got, all_commands());
}

fn arb_command() -> impl Strategy<Value = Command> {
    prop_oneof![
        any::<u8>().prop_map(|protocol| Command::Hello { protocol }),
        any::<u16>().prop_map(|slot| Command::GotoSlot { slot }),
        (0u32..360_000).prop_map(|mdeg| Command::GotoAngle { mdeg }),
        any::<u32>().prop_map(|steps| Command::GotoSteps { steps }),
        Just(Command::Zero),
        (1u32.., 1u32..).prop_map(|(max_speed, accel)| Command::SetMotion { max_speed, accel }),
        (1u16..).prop_map(|slots| Command::SetSlots { slots }),
        Just(Command::QueryStatus),
        Just(Command::Stop),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 512, .. ProptestConfig::default() })]

    /// Random bytes never panic, never grow the buffer beyond one frame, and
    /// whatever frames come out have valid checksums by construction.
    #[test]
    fn random_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..2048)) {
        let mut dec = FrameDecoder::new();
        for f in dec.feed(&bytes).flatten() {
            let _ = Command::from_frame(&f);
            let _ = Reply::from_frame(&f);
            let re = f.encode();
            prop_assert!(re.as_bytes().len() <= MAX_FRAME);
        }
        prop_assert!(dec.buffered() < MAX_FRAME);
    }

    /// Random bytes biased towards sync bytes and small lengths (the hard case).
    #[test]
    fn sync_heavy_bytes_never_panic(bytes in proptest::collection::vec(
        prop_oneof![Just(SYNC0), Just(SYNC1), 0u8..40, any::<u8>()], 0..2048)) {
        let mut dec = FrameDecoder::new();
        let n = dec.feed(&bytes).count();
        prop_assert!(n <= bytes.len());
        prop_assert!(dec.buffered() < MAX_FRAME);
    }

    /// Valid frames separated by garbage that contains no SYNC0: every
    /// frame is recovered, in order.
    #[test]
    fn frames_between_garbage_are_all_recovered(
        cmds in proptest::collection::vec((arb_command(), any::<u8>()), 1..40),
        garbage in proptest::collection::vec(proptest::collection::vec(any::<u8>().prop_filter("no sync", |b| *b != SYNC0), 0..50), 40),
    ) {
        let mut line = Vec::new();
        for (i, (c, seq)) in cmds.iter().enumerate() {
            line.extend_from_slice(&garbage[i]);
            line.extend_from_slice(c.encode(*seq).as_bytes());
        }
        let mut dec = FrameDecoder::new();
        let got: Vec<(Command, u8)> = decode_all(&mut dec, &line)
            .iter().map(|f| (Command::from_frame(f).unwrap(), f.seq)).collect();
        prop_assert_eq!(got, cmds);
    }

    /// Frames with arbitrary garbage (sync bytes included) in between: the
    /// frame after a garbage burst may be lost only to a false start, but the
    /// decoder always recovers: a clean frame sent after 40 zero bytes (longer
    /// than any false frame) is always decoded.
    #[test]
    fn always_recovers_after_arbitrary_garbage(
        garbage in proptest::collection::vec(any::<u8>(), 0..300),
        c in arb_command(), seq in any::<u8>(),
    ) {
        let mut line = garbage.clone();
        line.extend_from_slice(&[0u8; MAX_FRAME + 1]);
        line.extend_from_slice(c.encode(seq).as_bytes());
        let mut dec = FrameDecoder::new();
        let frames = decode_all(&mut dec, &line);
        let last = frames.last().expect("the final clean frame");
        prop_assert_eq!(Command::from_frame(last), Ok(c));
        prop_assert_eq!(last.seq, seq);
    }

    /// Chunking does not matter: feeding in random pieces gives the same frames.
    #[test]
    fn chunking_is_irrelevant(
        bytes in proptest::collection::vec(prop_oneof![Just(SYNC0), Just(SYNC1), any::<u8>()], 0..600),
        cmds in proptest::collection::vec(arb_command(), 0..10),
        cuts in proptest::collection::vec(1usize..20, 1..100),
    ) {
        let mut line = bytes;
        for c in &cmds { line.extend_from_slice(c.encode(1).as_bytes()); }
        let mut whole = FrameDecoder::new();
        let a = decode_all(&mut whole, &line);
        let mut pieces = FrameDecoder::new();
        let mut b = Vec::new();
        let mut rest = &line[..];
        let mut i = 0;
        while !rest.is_empty() {
            let n = cuts[i % cuts.len()].min(rest.len());
            b.extend(decode_all(&mut pieces, &rest[..n]));
            rest = &rest[n..];
            i += 1;
        }
        prop_assert_eq!(a, b);
    }

    #[test]
    fn geometry_properties(from in 0u32..3200, to in 0u32..3200, slots in 1u16..400, slot in any::<u16>()) {
        let d = shortest_delta(from, to, 3200);
        prop_assert!((-1600..1600).contains(&d));
        prop_assert_eq!((from as i64 + d as i64).rem_euclid(3200), to as i64);
        let s = slot_to_steps(slot, slots, 3200);
        prop_assert!(s < 3200);
        if slots <= 3200 {
            prop_assert_eq!(steps_to_slot(s, slots, 3200), Some(slot % slots));
        }
    }
}
