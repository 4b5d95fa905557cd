//! Sender core ↔ receiver core in simulated time, as quinn-proto's `Pair`
//! drives two endpoints: presses on one or more senders, their messages
//! through a network model (controls reliable and in order, latents as
//! datagrams that may be lost, delayed, reordered or duplicated), decisions
//! on the receiver. No tokio, no sockets, no sleeps.

use std::collections::BinaryHeap;
use std::sync::Arc;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use telextiles_press::decide::{FlatIndex, TextileIndex};
use telextiles_press::{ContactEvent, EndReason};
use telextiles_session::{
    Latent, ReceiverConfig, ReceiverCore, RxAction, RxInput, SenderCore, TxAction,
};

const DIM: usize = 16;
const PERIOD: u64 = 16_667;

/// Eight textiles at orthogonal-ish directions.
fn index() -> Arc<FlatIndex> {
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let rows: Vec<(String, Vec<Vec<f32>>)> = (0..8)
        .map(|k| {
            let v: Vec<f32> = (0..DIM).map(|_| rng.gen_range(-1.0f32..1.0)).collect();
            (format!("T{k:03}"), vec![v])
        })
        .collect();
    Arc::new(FlatIndex::from_embeddings(&rows).unwrap())
}

/// A frame of textile `k` under noise.
fn embedding(idx: &FlatIndex, k: usize, noise: f32, rng: &mut ChaCha8Rng) -> Vec<f32> {
    let c = centroid(idx, k);
    c.iter()
        .map(|x| x + noise * rng.gen_range(-1.0f32..1.0))
        .collect()
}

fn centroid(idx: &FlatIndex, k: usize) -> Vec<f32> {
    // The unit vector nearest to entry k: search the basis directions'
    // combination by asking the index for distances is overkill; the
    // FlatIndex keeps its centroids.
    idx.centroid(k).to_vec()
}

/// A message in flight.
#[derive(Debug)]
struct InFlight {
    at: u64,
    order: u64,
    peer: usize,
    msg: Msg,
}
#[derive(Debug, Clone)]
enum Msg {
    Tx(TxAction),
}
impl PartialEq for InFlight {
    fn eq(&self, o: &Self) -> bool {
        (self.at, self.order) == (o.at, o.order)
    }
}
impl Eq for InFlight {}
impl PartialOrd for InFlight {
    fn partial_cmp(&self, o: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(o))
    }
}
impl Ord for InFlight {
    fn cmp(&self, o: &Self) -> std::cmp::Ordering {
        (o.at, o.order).cmp(&(self.at, self.order))
    }
}

/// The network between senders and the receiver.
struct Net {
    loss: f64,
    dup: f64,
    delay_us: u64,
    jitter_us: u64,
    queue: BinaryHeap<InFlight>,
    /// Controls stay in order per peer: the earliest time the next may land.
    control_floor: Vec<u64>,
    order: u64,
    rng: ChaCha8Rng,
}

impl Net {
    fn new(peers: usize, loss: f64, dup: f64, delay_us: u64, jitter_us: u64, seed: u64) -> Net {
        Net {
            loss,
            dup,
            delay_us,
            jitter_us,
            queue: BinaryHeap::new(),
            control_floor: vec![0; peers],
            order: 0,
            rng: ChaCha8Rng::seed_from_u64(seed),
        }
    }
    fn send(&mut self, now: u64, peer: usize, a: TxAction) {
        let jitter = if self.jitter_us > 0 {
            self.rng.gen_range(0..=self.jitter_us)
        } else {
            0
        };
        let at = now + self.delay_us + jitter;
        match a {
            TxAction::Latent { .. } => {
                if self.rng.gen_bool(self.loss) {
                    return;
                }
                let copies = if self.rng.gen_bool(self.dup) { 2 } else { 1 };
                for c in 0..copies {
                    self.order += 1;
                    self.queue.push(InFlight {
                        at: at + c * 3_000,
                        order: self.order,
                        peer,
                        msg: Msg::Tx(a.clone()),
                    });
                }
            }
            _ => {
                // Reliable and ordered (a QUIC stream): never before the
                // previous control of this peer.
                let at = at.max(self.control_floor[peer]);
                self.control_floor[peer] = at;
                self.order += 1;
                self.queue.push(InFlight {
                    at,
                    order: self.order,
                    peer,
                    msg: Msg::Tx(a),
                });
            }
        }
    }
    /// Deliver everything due by `now`.
    fn deliver(
        &mut self,
        now: u64,
        rx: &mut ReceiverCore<FlatIndex>,
        out: &mut Vec<(usize, RxAction)>,
    ) {
        while self.queue.peek().is_some_and(|m| m.at <= now) {
            let m = self.queue.pop().unwrap();
            let peer = format!("peer{}", m.peer);
            let mut acts = Vec::new();
            let Msg::Tx(a) = &m.msg;
            let latency = Some((m.at - sent_at(a)) as i64);
            match a {
                TxAction::PressStart {
                    press_id,
                    capture_us,
                } => rx.handle(
                    &peer,
                    RxInput::PressStart {
                        press_id: *press_id,
                        capture_us: *capture_us,
                    },
                    &mut acts,
                ),
                TxAction::Latent {
                    press_id,
                    capture_us,
                    latent,
                } => rx.handle(
                    &peer,
                    RxInput::Latent {
                        press_id: *press_id,
                        seq: *capture_us / PERIOD,
                        capture_us: *capture_us,
                        // What the wire carries: direction times weight.
                        vector: &latent.wire(),
                        one_way_latency_us: latency,
                    },
                    &mut acts,
                ),
                TxAction::PressStop {
                    press_id,
                    capture_us,
                    final_latent,
                } => rx.handle(
                    &peer,
                    RxInput::PressStop {
                        press_id: *press_id,
                        capture_us: *capture_us,
                        final_latent: final_latent.as_ref().map(|l| (l.as_slice(), *capture_us)),
                    },
                    &mut acts,
                ),
            }
            out.extend(acts.into_iter().map(|a| (m.peer, a)));
        }
    }
}

fn sent_at(a: &TxAction) -> u64 {
    match a {
        TxAction::PressStart { capture_us, .. }
        | TxAction::Latent { capture_us, .. }
        | TxAction::PressStop { capture_us, .. } => *capture_us,
    }
}

/// One sender pressing textiles one after another.
struct Presser {
    core: SenderCore,
    /// (start frame, textile, frames held)
    plan: Vec<(u64, usize, u64)>,
}

impl Presser {
    /// Frame `f`: the contact event and embedding it would produce.
    fn frame(&mut self, f: u64, idx: &FlatIndex, rng: &mut ChaCha8Rng, out: &mut Vec<TxAction>) {
        let t = f * PERIOD;
        let mut event = None;
        let mut emb = None;
        for &(start, k, len) in &self.plan {
            if f == start {
                event = Some(ContactEvent::PressStart { t_us: t });
            }
            if f == start + len {
                event = Some(ContactEvent::PressEnd {
                    start_us: start * PERIOD,
                    t_us: t,
                    reason: EndReason::Released,
                });
            }
            if f >= start && f < start + len {
                emb = Some(embedding(idx, k, 0.35, rng));
            }
        }
        self.core.on_frame(t, event, emb.as_deref(), out);
    }
}

/// (sender, press, decided entry).
type Final = (usize, u32, usize);

/// Run `senders` pressing their plans through `net`; the final decisions
/// per (peer, press) and every action.
fn run(
    plans: Vec<Vec<(u64, usize, u64)>>,
    mut net: Net,
    frames: u64,
) -> (Vec<Final>, Vec<(usize, RxAction)>) {
    let idx = index();
    let mut rx = ReceiverCore::new(idx.clone(), ReceiverConfig::default());
    let mut senders: Vec<Presser> = plans
        .into_iter()
        .map(|plan| Presser {
            core: SenderCore::new(DIM),
            plan,
        })
        .collect();
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    let mut acts = Vec::new();
    for f in 0..frames {
        let now = f * PERIOD;
        for (i, s) in senders.iter_mut().enumerate() {
            let mut out = Vec::new();
            s.frame(f, &idx, &mut rng, &mut out);
            for a in out {
                net.send(now, i, a);
            }
        }
        net.deliver(now, &mut rx, &mut acts);
    }
    net.deliver(u64::MAX, &mut rx, &mut acts);
    let finals = acts
        .iter()
        .filter_map(|(p, a)| match a {
            RxAction::Decision(d) if d.final_decision => Some((*p, d.press_id, d.entry)),
            _ => None,
        })
        .collect();
    (finals, acts)
}

#[test]
fn presses_through_a_clean_link_are_decided_right() {
    let plan = vec![(10, 3, 60), (100, 5, 60), (200, 1, 60)];
    let (finals, acts) = run(vec![plan], Net::new(1, 0.0, 0.0, 5_000, 0, 1), 300);
    assert_eq!(finals, [(0, 1, 3), (0, 2, 5), (0, 3, 1)]);
    // A decision before the press ended, with a latency and time since contact.
    let early = acts.iter().find_map(|(_, a)| match a {
        RxAction::Decision(d) if !d.final_decision => Some(d.clone()),
        _ => None,
    });
    let d = early.expect("a live decision");
    assert_eq!(d.latency_ms, Some(5.0));
    let since = d.since_contact_ms.unwrap();
    assert!(since > 5.0 && since < 300.0, "{since}");
    let targets: Vec<usize> = acts
        .iter()
        .filter_map(|(_, a)| match a {
            RxAction::RollerTarget { slot } => Some(*slot),
            _ => None,
        })
        .collect();
    assert_eq!(targets, [3, 5, 1]);
}

#[test]
fn loss_reordering_duplicates_and_delay_do_not_change_the_final_decisions() {
    let plan = vec![(10, 2, 50), (90, 6, 40), (160, 0, 70), (260, 7, 30)];
    for seed in 0..8 {
        let net = Net::new(1, 0.3, 0.2, 20_000, 60_000, seed);
        let (finals, acts) = run(vec![plan.clone()], net, 360);
        assert_eq!(
            finals,
            [(0, 1, 2), (0, 2, 6), (0, 3, 0), (0, 4, 7)],
            "seed {seed}: {acts:?}"
        );
        assert!(!acts
            .iter()
            .any(|(_, a)| matches!(a, RxAction::Refused { .. })));
    }
}

#[test]
fn two_and_three_peers_pressing_at_once_each_get_their_own_right_decisions() {
    for peers in [2usize, 3] {
        // Overlapping presses of different textiles.
        let plans: Vec<Vec<(u64, usize, u64)>> = (0..peers)
            .map(|p| {
                vec![
                    (10 + 7 * p as u64, p + 1, 80),
                    (120 + 11 * p as u64, 7 - p, 60),
                ]
            })
            .collect();
        let net = Net::new(peers, 0.1, 0.05, 10_000, 20_000, 3);
        let (finals, _) = run(plans, net, 260);
        let mut got = finals.clone();
        got.sort();
        let mut want: Vec<(usize, u32, usize)> = (0..peers)
            .flat_map(|p| [(p, 1, p + 1), (p, 2, 7 - p)])
            .collect();
        want.sort();
        assert_eq!(got, want, "{peers} peers");
    }
}

#[test]
fn malformed_messages_are_refused_and_decisions_go_on() {
    let idx = index();
    let mut rx = ReceiverCore::new(idx.clone(), ReceiverConfig::default());
    let mut out = Vec::new();
    let good = centroid(&idx, 4);
    let bad: Vec<Vec<f32>> = vec![
        vec![f32::NAN; DIM],
        vec![1.0; DIM + 1],
        vec![1.0; 3],
        Vec::new(),
        vec![0.0; DIM],
        {
            let mut v = good.clone();
            v[0] = f32::INFINITY;
            v
        },
    ];
    rx.handle(
        "p",
        RxInput::PressStart {
            press_id: 7,
            capture_us: 0,
        },
        &mut out,
    );
    for (k, v) in bad.iter().enumerate() {
        rx.handle(
            "p",
            RxInput::Latent {
                press_id: 7,
                seq: k as u64,
                capture_us: k as u64 * PERIOD,
                vector: v,
                one_way_latency_us: Some(-5),
            },
            &mut out,
        );
    }
    assert_eq!(
        out.iter()
            .filter(|a| matches!(a, RxAction::Refused { .. }))
            .count(),
        bad.len()
    );
    // An empty or NaN final latent: refused, and the press still ends with
    // this side's own running decision.
    for k in 0..20u64 {
        rx.handle(
            "p",
            RxInput::Latent {
                press_id: 7,
                seq: 100 + k,
                capture_us: (10 + k) * PERIOD,
                vector: &good,
                one_way_latency_us: None,
            },
            &mut out,
        );
    }
    out.clear();
    rx.handle(
        "p",
        RxInput::PressStop {
            press_id: 7,
            capture_us: 40 * PERIOD,
            final_latent: Some((&[], 40 * PERIOD)),
        },
        &mut out,
    );
    assert!(matches!(out[0], RxAction::Refused { .. }), "{out:?}");
    let fin = out.iter().find_map(|a| match a {
        RxAction::Decision(d) if d.final_decision => Some(d.clone()),
        _ => None,
    });
    let fin = fin.expect("final decision from the running mean");
    assert_eq!(fin.entry, 4);
    // No clock offset known: no latency is made up from two clocks.
    assert_eq!((fin.latency_ms, fin.since_contact_ms), (None, None));
    // Extreme numbers: ids and timestamps at the limits.
    out.clear();
    rx.handle(
        "p",
        RxInput::PressStart {
            press_id: u32::MAX,
            capture_us: u64::MAX,
        },
        &mut out,
    );
    rx.handle(
        "p",
        RxInput::Latent {
            press_id: u32::MAX,
            seq: u64::MAX,
            capture_us: 0,
            vector: &good,
            one_way_latency_us: Some(i64::MIN),
        },
        &mut out,
    );
    rx.handle(
        "p",
        RxInput::PressStop {
            press_id: u32::MAX,
            capture_us: 0,
            final_latent: Some((&good, u64::MAX)),
        },
        &mut out,
    );
    assert!(
        out.iter()
            .any(|a| matches!(a, RxAction::Decision(d) if d.final_decision && d.entry == 4)),
        "{out:?}"
    );
    // A later press of the same peer is still decided, even when its
    // number starts again from 0 (the peer restarted).
    out.clear();
    rx.handle(
        "p",
        RxInput::PressStop {
            press_id: 0,
            capture_us: 50,
            final_latent: Some((&centroid(&idx, 2), 50)),
        },
        &mut out,
    );
    assert!(
        out.iter()
            .any(|a| matches!(a, RxAction::Decision(d) if d.final_decision && d.entry == 2)),
        "{out:?}"
    );
}

/// A press far from every textile of the index is decided as the nearest
/// one and flagged unknown (the decider's unknown-textile distance); a press
/// on a textile is not.
#[test]
fn a_press_of_a_textile_the_index_does_not_have_is_flagged_unknown() {
    let idx = index();
    let mut rng = ChaCha8Rng::seed_from_u64(99);
    let far: Vec<f32> = (0..DIM).map(|_| rng.gen_range(-1.0f32..1.0)).collect();
    let n = far.iter().map(|x| x * x).sum::<f32>().sqrt();
    let far: Vec<f32> = far.iter().map(|x| x / n).collect();
    let nearest = idx.nearest2(&far).unwrap();
    assert!(nearest.best_dist > 0.5, "{nearest:?}");
    for (press_id, v, unknown) in [(1, far, true), (2, centroid(&idx, 4), false)] {
        let mut rx = ReceiverCore::new(idx.clone(), ReceiverConfig::default());
        let mut out = Vec::new();
        rx.handle(
            "p",
            RxInput::PressStart {
                press_id,
                capture_us: 0,
            },
            &mut out,
        );
        rx.handle(
            "p",
            RxInput::PressStop {
                press_id,
                capture_us: 9,
                final_latent: Some((&v, 9)),
            },
            &mut out,
        );
        let d = out
            .iter()
            .find_map(|a| match a {
                RxAction::Decision(d) if d.final_decision => Some(d.clone()),
                _ => None,
            })
            .expect("a final decision");
        assert_eq!(d.entry, idx.nearest2(&v).unwrap().best);
        assert_eq!(d.unknown, unknown, "{d:?}");
    }
}

#[test]
fn late_and_duplicated_messages_of_finished_presses_are_ignored() {
    let idx = index();
    let mut rx = ReceiverCore::new(idx.clone(), ReceiverConfig::default());
    let mut out = Vec::new();
    let a = centroid(&idx, 1);
    rx.handle(
        "p",
        RxInput::PressStart {
            press_id: 1,
            capture_us: 0,
        },
        &mut out,
    );
    rx.handle(
        "p",
        RxInput::PressStop {
            press_id: 1,
            capture_us: 9,
            final_latent: Some((&a, 9)),
        },
        &mut out,
    );
    let n = out.len();
    // A late datagram and a duplicated stop of press 1 start nothing.
    rx.handle(
        "p",
        RxInput::Latent {
            press_id: 1,
            seq: 3,
            capture_us: 5,
            vector: &a,
            one_way_latency_us: None,
        },
        &mut out,
    );
    rx.handle(
        "p",
        RxInput::PressStop {
            press_id: 1,
            capture_us: 9,
            final_latent: Some((&a, 9)),
        },
        &mut out,
    );
    rx.handle(
        "p",
        RxInput::PressStart {
            press_id: 1,
            capture_us: 0,
        },
        &mut out,
    );
    assert_eq!(out.len(), n, "{out:?}");
    assert_eq!(rx.press_of("p"), None);
    // Press 3 is under way; a late datagram of press 2 does not reset it.
    rx.handle(
        "p",
        RxInput::PressStart {
            press_id: 3,
            capture_us: 100,
        },
        &mut out,
    );
    rx.handle(
        "p",
        RxInput::Latent {
            press_id: 2,
            seq: 1,
            capture_us: 50,
            vector: &a,
            one_way_latency_us: None,
        },
        &mut out,
    );
    assert_eq!(rx.press_of("p"), Some(3));
    // A peer that goes down leaves nothing behind.
    rx.handle("p", RxInput::PeerDown, &mut out);
    assert_eq!(rx.peers(), 0);
}

#[test]
fn peers_are_bounded() {
    let idx = index();
    let mut rx = ReceiverCore::new(
        idx.clone(),
        ReceiverConfig {
            max_peers: 4,
            ..Default::default()
        },
    );
    let mut out = Vec::new();
    for k in 0..100u32 {
        rx.handle(
            &format!("peer{k}"),
            RxInput::PressStart {
                press_id: 1,
                capture_us: 0,
            },
            &mut out,
        );
        assert!(rx.peers() <= 4);
    }
    assert_eq!(rx.press_of("peer99"), Some(1));
}

proptest::proptest! {
    /// Any sequence of messages from any peers: no panic, state bounded.
    #[test]
    fn any_message_sequence_is_handled(msgs in proptest::collection::vec((0u8..4, 0u8..3, proptest::num::u32::ANY, proptest::num::u64::ANY, proptest::collection::vec(proptest::num::f32::ANY, 0..20), proptest::option::of(proptest::num::i64::ANY)), 0..200)) {
        let idx = index();
        let mut rx = ReceiverCore::new(idx, ReceiverConfig { max_peers: 2, ..Default::default() });
        let mut out = Vec::new();
        for (kind, peer, id, t, v, lat) in &msgs {
            let peer = format!("p{peer}");
            let input = match kind {
                0 => RxInput::PressStart { press_id: *id, capture_us: *t },
                1 => RxInput::Latent { press_id: *id, seq: *t, capture_us: *t, vector: v, one_way_latency_us: *lat },
                2 => RxInput::PressStop { press_id: *id, capture_us: *t, final_latent: Some((v, *t)) },
                _ => RxInput::PeerDown,
            };
            rx.handle(&peer, input, &mut out);
            proptest::prop_assert!(rx.peers() <= 2);
            for a in out.drain(..) {
                if let RxAction::Decision(d) = a {
                    proptest::prop_assert!(d.entry < 8 && d.distance.is_finite());
                    proptest::prop_assert!(d.latency_ms.is_none_or(|l| l.is_finite() && l >= 0.0));
                }
            }
        }
        let _ = idx_dim_check();
    }
}

fn idx_dim_check() -> usize {
    index().dim()
}

/// The length of a streamed latent is the frame's weight (its contact
/// depth): the receiver's running mean lets a deep frame outweigh shallow
/// ramp frames, exactly as the sender's local pipeline does; unit vectors
/// (a sender without weights) count alike.
#[test]
fn the_receiver_weights_frames_by_the_length_the_sender_gave_them() {
    let idx = index();
    let a = centroid(&idx, 2);
    let b = centroid(&idx, 5);
    let final_decision = |weighted: bool| {
        let mut rx = ReceiverCore::new(idx.clone(), ReceiverConfig::default());
        let mut out = Vec::new();
        rx.handle(
            "p",
            RxInput::PressStart {
                press_id: 1,
                capture_us: 0,
            },
            &mut out,
        );
        // A long shallow ramp like B (decided first either way), then deep
        // frames like A: weighted, the mean turns to A and the decision
        // switches; unweighted, 30 frames of B keep it.
        let frames: Vec<(Vec<f32>, f32)> = (0..30)
            .map(|_| (b.clone(), 0.01))
            .chain((0..15).map(|_| (a.clone(), 0.5)))
            .collect();
        for (k, (v, w)) in frames.iter().enumerate() {
            // The sender's wire form of a latent of that weight.
            let wire: Vec<f32> = if weighted {
                Latent::new(v, v.len()).unwrap().with_weight(*w).wire()
            } else {
                v.clone()
            };
            rx.handle(
                "p",
                RxInput::Latent {
                    press_id: 1,
                    seq: k as u64,
                    capture_us: (k as u64 + 1) * PERIOD,
                    vector: &wire,
                    one_way_latency_us: None,
                },
                &mut out,
            );
        }
        rx.handle(
            "p",
            RxInput::PressStop {
                press_id: 1,
                capture_us: 60 * PERIOD,
                final_latent: None,
            },
            &mut out,
        );
        out.iter()
            .find_map(|a| match a {
                RxAction::Decision(d) if d.final_decision => Some(d.entry),
                _ => None,
            })
            .expect("a final decision")
    };
    assert_eq!(final_decision(false), 5);
    assert_eq!(final_decision(true), 2);
}

/// A press's start travels on the control stream, its latents as
/// datagrams, so a latent may come first and start the press at its own
/// capture time. The start, when it comes, still dates the press: the
/// time since contact of every decision counts from the first frame of
/// the detector's run (here a frame before the first latent), as it does
/// when the start comes first.
#[test]
fn a_start_that_comes_after_its_first_latent_still_dates_the_press() {
    let idx = index();
    let a = centroid(&idx, 2);
    let pressed = |start_first: bool| {
        let mut rx = ReceiverCore::new(idx.clone(), ReceiverConfig::default());
        let mut out = Vec::new();
        let start = RxInput::PressStart {
            press_id: 1,
            capture_us: 10 * PERIOD,
        };
        let latent = |k: u64| RxInput::Latent {
            press_id: 1,
            seq: k,
            capture_us: (10 + k) * PERIOD,
            vector: &a,
            one_way_latency_us: Some(2_000),
        };
        if start_first {
            rx.handle("p", start, &mut out);
            rx.handle("p", latent(1), &mut out);
        } else {
            rx.handle("p", latent(1), &mut out);
            rx.handle("p", start, &mut out);
        }
        for k in 2..10 {
            rx.handle("p", latent(k), &mut out);
        }
        out.iter()
            .find_map(|x| match x {
                RxAction::Decision(d) => Some(d.since_contact_ms.unwrap() - d.latency_ms.unwrap()),
                _ => None,
            })
            .expect("a decision")
    };
    let ms = |frames: u64| (frames * PERIOD) as f64 / 1000.0;
    // A clear leader: decided on its second latent, two frames after the
    // run's first frame.
    assert!((pressed(true) - ms(2)).abs() < 1e-6, "{}", pressed(true));
    assert!((pressed(false) - ms(2)).abs() < 1e-6, "{}", pressed(false));
}
