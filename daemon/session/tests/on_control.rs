//! `ReceiverCore::on_control`: the link's control messages go into the
//! receiver core directly, deciding exactly as the same inputs given one
//! by one, and the link's own messages change nothing.

use std::sync::Arc;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use telextiles_press::decide::FlatIndex;
use telextiles_proto::peer::{Control, LatentFrame, QuantVec, FLAG_FINAL};
use telextiles_session::{ReceiverConfig, ReceiverCore, RxAction, RxInput};

const DIM: usize = 16;

fn index() -> Arc<FlatIndex> {
    let mut rng = ChaCha8Rng::seed_from_u64(2);
    let rows: Vec<(String, Vec<Vec<f32>>)> = (0..6)
        .map(|k| {
            let v: Vec<f32> = (0..DIM).map(|_| rng.gen_range(-1.0f32..1.0)).collect();
            (format!("T{k:03}"), vec![v])
        })
        .collect();
    Arc::new(FlatIndex::from_embeddings(&rows).unwrap())
}

#[test]
fn control_messages_decide_as_the_inputs_they_carry() {
    let idx = index();
    let target = idx.centroid(3).to_vec();
    let quant = QuantVec::quantize_f16(&target);
    let stop = Control::PressStop {
        press_id: 7,
        capture_us: 900_000,
        final_latent: Some(LatentFrame {
            seq: 40,
            capture_us: 880_000,
            press_id: 7,
            flags: FLAG_FINAL,
            vector: quant.clone(),
        }),
    };
    let start = Control::PressStart {
        press_id: 7,
        capture_us: 500_000,
    };

    let mut direct = ReceiverCore::new(idx.clone(), ReceiverConfig::default());
    let mut got = Vec::new();
    for m in [&start, &stop] {
        direct.on_control("peer", m, &mut got);
    }

    let mut by_hand = ReceiverCore::new(idx, ReceiverConfig::default());
    let mut want = Vec::new();
    by_hand.handle(
        "peer",
        RxInput::PressStart {
            press_id: 7,
            capture_us: 500_000,
        },
        &mut want,
    );
    let v = quant.dequantize();
    by_hand.handle(
        "peer",
        RxInput::PressStop {
            press_id: 7,
            capture_us: 900_000,
            final_latent: Some((&v, 880_000)),
        },
        &mut want,
    );
    assert_eq!(got, want);
    // The press ended on the textile its final latent is nearest.
    let last = got.iter().rev().find_map(|a| match a {
        RxAction::Decision(d) => Some(d.clone()),
        _ => None,
    });
    let d = last.expect("a decision");
    assert!(d.final_decision);
    assert_eq!(d.entry, 3);
}

#[test]
fn the_links_own_messages_change_nothing() {
    let mut rx = ReceiverCore::new(index(), ReceiverConfig::default());
    let mut out = Vec::new();
    for m in [
        Control::Ping { id: 1, t1_us: 5 },
        Control::Error {
            code: telextiles_proto::peer::ErrorCode::Protocol,
            message: "x".into(),
        },
    ] {
        rx.on_control("peer", &m, &mut out);
    }
    assert!(out.is_empty());
}

/// Presses back to back: the next press's first datagrams can overtake the
/// previous press's stop on the control stream. The late stop still gives
/// its press's final answer, and the roller stays with the press under the
/// hand.
#[test]
fn a_stop_overtaken_by_the_next_press_still_gives_its_final_answer() {
    let idx = index();
    let first = idx.centroid(1).to_vec();
    let second = idx.centroid(4).to_vec();
    let mut rx = ReceiverCore::new(idx.clone(), ReceiverConfig::default());
    let mut out = Vec::new();
    let latent = |press_id, seq, capture_us, vector| RxInput::Latent {
        press_id,
        seq,
        capture_us,
        vector,
        one_way_latency_us: Some(2_000),
    };
    rx.handle(
        "peer",
        RxInput::PressStart {
            press_id: 1,
            capture_us: 0,
        },
        &mut out,
    );
    for i in 0..20u64 {
        rx.handle("peer", latent(1, i, i * 16_667, &first), &mut out);
    }
    // Press 2's datagrams come before press 1's stop.
    let t2 = 20 * 16_667;
    for i in 0..5u64 {
        rx.handle(
            "peer",
            latent(2, 20 + i, t2 + i * 16_667, &second),
            &mut out,
        );
    }
    out.clear();
    rx.handle(
        "peer",
        RxInput::PressStop {
            press_id: 1,
            capture_us: t2 - 1,
            final_latent: Some((&first, t2 - 1)),
        },
        &mut out,
    );
    let finals: Vec<_> = out
        .iter()
        .filter_map(|a| match a {
            RxAction::Decision(d) if d.final_decision => Some((d.press_id, d.entry)),
            _ => None,
        })
        .collect();
    assert_eq!(finals, vec![(1, 1)], "{out:?}");
    assert!(
        !out.iter()
            .any(|a| matches!(a, RxAction::RollerTarget { .. })),
        "a late stop does not move the roller away from press 2: {out:?}"
    );
    // A second copy of the stop (or a stray one) decides nothing more.
    out.clear();
    rx.handle(
        "peer",
        RxInput::PressStop {
            press_id: 1,
            capture_us: t2 - 1,
            final_latent: Some((&first, t2 - 1)),
        },
        &mut out,
    );
    assert!(out.is_empty(), "{out:?}");
    // Press 2 goes on and ends as itself, moving the roller.
    rx.handle(
        "peer",
        RxInput::PressStop {
            press_id: 2,
            capture_us: t2 + 10 * 16_667,
            final_latent: Some((&second, t2 + 10 * 16_667)),
        },
        &mut out,
    );
    let d = out
        .iter()
        .find_map(|a| match a {
            RxAction::Decision(d) if d.final_decision => Some(d.clone()),
            _ => None,
        })
        .expect("press 2's final answer");
    assert_eq!((d.press_id, d.entry), (2, 4));
}
