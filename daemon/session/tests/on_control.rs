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
