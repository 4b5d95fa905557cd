//! Fuzzing the receive path to its end: bytes as a peer could send them
//! (control frames and latent datagrams from several peers) → the real
//! decoders (`telextiles-proto`) → the receiver core. Runs the shared
//! stable harness (`proto/fuzz/harness.rs`: seeds, then mutations for
//! `FUZZ_SECONDS`) in the ordinary test suite; a panic is the failure.
//!
//! Input: records `peer: u8 | kind: u8 | len: u16 LE | bytes`; an even
//! kind is a latent datagram, an odd one a control payload.
#[allow(clippy::type_complexity)]
#[path = "../../../proto/fuzz/harness.rs"]
mod harness;

use std::sync::Arc;

use telextiles_press::decide::{FlatIndex, TextileIndex};
use telextiles_proto::peer::{
    decode_control_payload, encode_control, Control, LatentFrame, QuantVec, FLAG_FINAL,
};
use telextiles_session::{ReceiverConfig, ReceiverCore, RxAction, RxInput};

const DIM: usize = 16;

fn index() -> Arc<FlatIndex> {
    let rows: Vec<(String, Vec<Vec<f32>>)> = (0..6)
        .map(|k| {
            let v: Vec<f32> = (0..DIM)
                .map(|i| if i % 6 == k { 1.0 } else { 0.1 })
                .collect();
            (format!("T{k}"), vec![v])
        })
        .collect();
    Arc::new(FlatIndex::from_embeddings(&rows).unwrap())
}

fn body(data: &[u8]) {
    decisions(data);
}

/// The target body; returns how many decisions were made.
fn decisions(data: &[u8]) -> usize {
    let mut n = 0;
    let idx = index();
    let mut rx = ReceiverCore::new(
        idx.clone(),
        ReceiverConfig {
            max_peers: 2,
            ..Default::default()
        },
    );
    let mut out = Vec::new();
    let mut rest = data;
    while rest.len() >= 4 {
        let peer = format!("p{}", rest[0] % 3);
        let kind = rest[1];
        let len = usize::from(u16::from_le_bytes([rest[2], rest[3]]));
        let take = len.min(rest.len() - 4);
        let bytes = &rest[4..4 + take];
        rest = &rest[4 + take..];
        if kind.is_multiple_of(2) {
            let Ok(f) = LatentFrame::decode(bytes) else {
                continue;
            };
            let v = f.vector.dequantize();
            rx.handle(
                &peer,
                RxInput::Latent {
                    press_id: f.press_id,
                    seq: f.seq,
                    capture_us: f.capture_us,
                    vector: &v,
                    one_way_latency_us: Some(i64::from(kind) * 1000 - 50_000),
                },
                &mut out,
            );
        } else {
            let Ok(c) = decode_control_payload(bytes) else {
                continue;
            };
            match c {
                Control::PressStart {
                    press_id,
                    capture_us,
                } => rx.handle(
                    &peer,
                    RxInput::PressStart {
                        press_id,
                        capture_us,
                    },
                    &mut out,
                ),
                Control::PressStop {
                    press_id,
                    capture_us,
                    final_latent,
                } => {
                    let fin = final_latent.map(|l| (l.vector.dequantize(), l.capture_us));
                    rx.handle(
                        &peer,
                        RxInput::PressStop {
                            press_id,
                            capture_us,
                            final_latent: fin.as_ref().map(|(v, t)| (v.as_slice(), *t)),
                        },
                        &mut out,
                    )
                }
                _ => rx.handle(&peer, RxInput::PeerDown, &mut out),
            }
        }
        assert!(rx.peers() <= 2);
        for a in out.drain(..) {
            match a {
                RxAction::Decision(d) => {
                    n += 1;
                    assert!(d.entry < idx.len() && d.slot < idx.len());
                    assert!(d.distance.is_finite() && d.distance >= 0.0);
                    assert!(d.latency_ms.is_none_or(|l| l.is_finite() && l >= 0.0));
                    assert!(d.since_contact_ms.is_none_or(|l| l.is_finite() && l >= 0.0));
                }
                RxAction::RollerTarget { slot } => assert!(slot < idx.len()),
                RxAction::Touch { latent, .. } => {
                    let n: f32 = latent.as_slice().iter().map(|x| x * x).sum();
                    assert!((n - 1.0).abs() < 1e-3, "touch latent of norm² {n}");
                }
                _ => {}
            }
        }
    }
    n
}

fn record(out: &mut Vec<u8>, peer: u8, kind: u8, bytes: &[u8]) {
    out.extend_from_slice(&[peer, kind]);
    out.extend_from_slice(&(bytes.len() as u16).to_le_bytes());
    out.extend_from_slice(bytes);
}

/// Real sessions as seeds: presses of several textiles by one and two
/// peers, f16 and int8 latents, with and without final latents.
fn seeds(dir: &std::path::Path) {
    let d = dir.join("receiver_core");
    std::fs::create_dir_all(&d).unwrap();
    for (k, peers) in [(0u8, 1u8), (1, 2), (2, 3)] {
        let mut s = Vec::new();
        for p in 0..peers {
            let press_id = 1 + u32::from(p);
            let start = encode_control(&Control::PressStart {
                press_id,
                capture_us: 1000,
            })
            .unwrap();
            record(&mut s, p, 1, &start[4..]);
            let v: Vec<f32> = (0..DIM)
                .map(|i| {
                    if i % 6 == usize::from(k + p) % 6 {
                        1.0
                    } else {
                        0.1
                    }
                })
                .collect();
            for seq in 0..12u64 {
                let vector = if (seq + u64::from(p)) % 2 == 0 {
                    QuantVec::quantize_f16(&v)
                } else {
                    QuantVec::quantize_i8(&v)
                };
                let f = LatentFrame {
                    seq,
                    capture_us: 1000 + seq * 16_667,
                    press_id,
                    flags: if seq == 11 { FLAG_FINAL } else { 0 },
                    vector,
                };
                record(&mut s, p, 2 * (seq as u8 % 4), &f.encode().unwrap());
            }
            let stop = encode_control(&Control::PressStop {
                press_id,
                capture_us: 300_000,
                final_latent: (k != 1).then(|| LatentFrame {
                    seq: 12,
                    capture_us: 290_000,
                    press_id,
                    flags: FLAG_FINAL,
                    vector: QuantVec::quantize_f16(&v),
                }),
            })
            .unwrap();
            record(&mut s, p, 3, &stop[4..]);
        }
        std::fs::write(d.join(format!("session-{k}")), s).unwrap();
    }
}

#[test]
fn the_receive_path_holds_on_seeds_and_mutations() {
    let dir = tempfile::tempdir().unwrap();
    seeds(dir.path());
    // The seeds themselves decide (the path is really exercised).
    for k in 0..3 {
        let s = std::fs::read(dir.path().join(format!("receiver_core/session-{k}"))).unwrap();
        assert!(decisions(&s) >= 1, "seed {k} decides nothing");
    }
    harness::run_all(&[("receiver_core", body)], dir.path());
}
