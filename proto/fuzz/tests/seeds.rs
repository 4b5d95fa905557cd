//! Writes the committed seed corpora `seeds/<target>/` from real messages.
//! Run after a wire-format change:
//!   FUZZ_WRITE_SEEDS=1 cargo test --release --no-default-features \
//!     --manifest-path proto/fuzz/Cargo.toml --test seeds -- --ignored
use std::path::Path;
use telextiles_proto::pairing::{PairingAbort, PairingMessage};
use telextiles_proto::peer::*;
use telextiles_proto::roller::Command;

fn write(target: &str, name: &str, bytes: &[u8]) {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("seeds")
        .join(target);
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join(name), bytes).unwrap();
}

fn latent(seq: u64, f16: bool, dim: usize, fin: bool) -> LatentFrame {
    let v: Vec<f32> = (0..dim)
        .map(|i| ((i * 37 % 11) as f32 - 5.0) / 20.0)
        .collect();
    LatentFrame {
        seq,
        capture_us: 1_000_000 + seq * 16_666,
        press_id: 7,
        flags: if fin { FLAG_FINAL } else { 0 },
        vector: if f16 {
            QuantVec::quantize_f16(&v)
        } else {
            QuantVec::quantize_i8(&v)
        },
    }
}

#[test]
#[ignore = "writes the seed corpus; run with FUZZ_WRITE_SEEDS=1"]
fn write_seeds() {
    assert!(std::env::var_os("FUZZ_WRITE_SEEDS").is_some());
    let hello = Hello {
        protocol_version: PROTOCOL_VERSION,
        device_name: "alice".into(),
        encoder_hash: "e".repeat(64),
        index_fingerprint: "f".repeat(64),
        embedding_dim: 95,
    };
    let msgs = vec![
        Control::Hello(hello),
        Control::HelloAck,
        Control::Mismatch {
            reasons: vec![MismatchReason::EmbeddingDim {
                ours: 95,
                theirs: 512,
            }],
        },
        Control::PressStart {
            press_id: 3,
            capture_us: 123_456,
        },
        Control::PressStop {
            press_id: 3,
            capture_us: 223_456,
            final_latent: Some(latent(9, false, 95, true)),
        },
        Control::Ping { id: 1, t1_us: 42 },
        Control::Pong {
            id: 1,
            t1_us: 42,
            t2_us: 1_000_042,
            t3_us: 1_000_050,
        },
        Control::Error {
            code: ErrorCode::Protocol,
            message: "bad".into(),
        },
        Control::Pair(PairingMessage::Abort(PairingAbort::NotPairing)),
    ];
    for (i, m) in msgs.iter().enumerate() {
        let frame = encode_control(m).unwrap();
        write("peer_decode", &format!("control-{i}"), &frame[4..]);
        write("peer_decode", &format!("frame-{i}"), &frame);
    }
    for (i, (f16, dim)) in [(true, 95), (false, 95), (false, 512), (true, 0)]
        .iter()
        .enumerate()
    {
        let b = latent(i as u64 + 1, *f16, *dim, i == 1).encode().unwrap();
        write("peer_decode", &format!("latent-{i}"), &b);
    }
    // latent_receive: sequences of `u16 LE length | datagram`.
    for (i, (f16, dim, n)) in [(true, 95, 6), (false, 95, 6), (false, 2048, 2)]
        .iter()
        .enumerate()
    {
        let mut seq = Vec::new();
        for k in 0..*n {
            let b = latent((k as u64 * 7) % 5 + 1, *f16, *dim, k + 1 == *n)
                .encode()
                .unwrap();
            seq.extend((b.len() as u16).to_le_bytes());
            seq.extend(b);
        }
        write("latent_receive", &format!("press-{i}"), &seq);
    }
    // clock_offset: window byte, then 32-byte samples (t1..t4 LE).
    let mut c = vec![8u8];
    for k in 0..6u64 {
        let t1 = 1_000_000 * k;
        let off = 5_000_000;
        for t in [t1, t1 + 500 + off, t1 + 600 + off, t1 + 1100 + k * 300] {
            c.extend(t.to_le_bytes());
        }
    }
    write("clock_offset", "symmetric", &c);
    let mut c = vec![3u8];
    for t in [u64::MAX, 0, u64::MAX, u64::MAX, 0, u64::MAX, u64::MAX, 0] {
        c.extend(t.to_le_bytes());
    }
    write("clock_offset", "extremes", &c);
    // roller_decode: first byte = chunk size, then frames.
    let cmds = [
        Command::Hello { protocol: 1 },
        Command::GotoSlot { slot: 3 },
        Command::GotoAngle { mdeg: 90_000 },
        Command::GotoSteps { steps: 1600 },
        Command::Zero,
        Command::SetMotion {
            max_speed: 4000,
            accel: 20_000,
        },
        Command::SetSlots { slots: 12 },
        Command::QueryStatus,
        Command::Stop,
    ];
    let mut all = vec![5u8];
    for (i, cmd) in cmds.iter().enumerate() {
        let f = cmd.encode(i as u8);
        let mut one = vec![64u8];
        one.extend_from_slice(f.as_bytes());
        write("roller_decode", &format!("cmd-{i}"), &one);
        all.extend_from_slice(f.as_bytes());
    }
    write("roller_decode", "all", &all);
}
