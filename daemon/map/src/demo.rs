//! Demo feed for `telextilesd map --demo`: simulated presses so a person can
//! watch the live map with no peer and no sensor.
//!
//! Each press picks a textile of the index and produces what the receiving
//! daemon would report: contact start, a stream of touch latents (noisy at
//! first, settling onto the textile's centroid as a running mean would),
//! a decision with the nearest textile and its roller slot, the roller
//! turning the shortest way to that slot, and contact end.
//!
//! The latents are synthesised around the index's own centroids, not encoded
//! from rendered frames (that needs an ONNX encoder; the real pipeline feeds
//! the map the same [`MapEvent`]s). [`Demo`] is pure and deterministic per
//! seed; [`run`] plays it in real time.

use crate::{ContactPhase, MapEvent};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::sync::Arc;
use std::time::Duration;
use telextiles_index::{l2_normalise, Index};
use tokio::sync::broadcast;

/// Name of the simulated peer.
pub const DEMO_PEER: &str = "demo-peer";
/// Touch updates per second.
pub const TOUCH_HZ: u32 = 30;
/// Roller speed in degrees per second.
pub const ROLLER_DEG_PER_S: f64 = 240.0;

/// Deterministic generator of simulated presses.
pub struct Demo {
    index: Arc<Index>,
    rng: ChaCha8Rng,
    angle: f64,
    presses: u64,
}

/// One timed event of a press: `at` from the press's start.
#[derive(Debug, Clone, PartialEq)]
pub struct Timed {
    pub at: Duration,
    pub event: MapEvent,
}

impl Demo {
    pub fn new(index: Arc<Index>, seed: u64) -> Demo {
        Demo {
            index,
            rng: ChaCha8Rng::seed_from_u64(seed),
            angle: 0.0,
            presses: 0,
        }
    }

    /// Events of the next press (about 3.5 s, including the pause after it),
    /// and the entry index of the textile pressed.
    pub fn next_press(&mut self) -> (usize, Vec<Timed>) {
        let idx = self.index.clone();
        let target = self.rng.gen_range(0..idx.entries.len());
        let dim = idx.dim;
        // The centroid lives in the index's space; the demo's queries are
        // encoder embeddings, as a sender's are.
        let centre = &idx
            .query_for(&idx.entries[target].centroid)
            .unwrap_or_else(|| idx.entries[target].centroid.clone());
        // A random start direction: the first frames of a press are far from
        // any textile; the running mean then settles on the one pressed.
        let start: Vec<f32> = (0..dim).map(|_| self.rng.gen_range(-1.0f32..1.0)).collect();
        let peer = Some(DEMO_PEER.to_string());
        let mut out = vec![Timed {
            at: Duration::ZERO,
            event: MapEvent::Contact {
                phase: ContactPhase::Start,
                score: Some(0.8),
                peer: peer.clone(),
            },
        }];
        let n_touch = (TOUCH_HZ as f32 * 2.5) as u32; // 2.5 s press, as in the paper
        let step = Duration::from_secs(1) / TOUCH_HZ;
        let mut decided = false;
        let mut t_end = Duration::ZERO;
        let mut roller_events = Vec::new();
        for k in 1..=n_touch {
            let at = step * k;
            let a = (k as f32 / (TOUCH_HZ as f32 * 0.8)).min(1.0);
            let noise = 0.15 * (1.0 - a) + 0.03;
            let mut q: Vec<f32> = centre
                .iter()
                .zip(&start)
                .map(|(c, s)| {
                    a * c + (1.0 - a) * 0.35 * s + noise * self.rng.gen_range(-1.0f32..1.0)
                })
                .collect();
            l2_normalise(&mut q);
            if !decided && k >= TOUCH_HZ * 6 / 10 {
                decided = true;
                let Some(near) = idx.nearest(&q) else {
                    continue;
                };
                let slot = idx.slot_of_entry(near.best);
                let e = &idx.entries[near.best];
                out.push(Timed {
                    at,
                    event: MapEvent::Decision {
                        textile: e.id.clone(),
                        name: Some(e.name.clone()),
                        slot: slot as u32,
                        distance: near.best_dist,
                        unknown: idx.unknown_distance().is_some_and(|d| near.best_dist > d),
                        latency_ms: at.as_secs_f64() * 1000.0,
                        peer: peer.clone(),
                    },
                });
                roller_events = self.turn_to(slot, at);
            }
            out.push(Timed {
                at,
                event: MapEvent::Touch {
                    latent: q,
                    peer: peer.clone(),
                },
            });
            t_end = at;
        }
        out.extend(roller_events);
        out.push(Timed {
            at: t_end + step,
            event: MapEvent::Contact {
                phase: ContactPhase::End,
                score: Some(0.05),
                peer,
            },
        });
        out.sort_by_key(|t| t.at);
        self.presses += 1;
        (target, out)
    }

    /// Roller events turning the shortest way to `slot`, starting at `t0`.
    fn turn_to(&mut self, slot: usize, t0: Duration) -> Vec<Timed> {
        let n = self.index.roller.n().max(1);
        let target = slot as f64 * 360.0 / n as f64;
        let delta = (target - self.angle + 540.0).rem_euclid(360.0) - 180.0;
        let secs = delta.abs() / ROLLER_DEG_PER_S;
        let steps = (secs * 20.0).ceil().max(1.0) as u32;
        let mut out = Vec::new();
        for s in 1..steps {
            let f = s as f64 / steps as f64;
            out.push(Timed {
                at: t0 + Duration::from_secs_f64(secs * f),
                event: MapEvent::RollerPosition {
                    angle_deg: (self.angle + delta * f).rem_euclid(360.0),
                    target_slot: Some(slot as u32),
                },
            });
        }
        out.push(Timed {
            at: t0 + Duration::from_secs_f64(secs),
            event: MapEvent::RollerArrived {
                slot: slot as u32,
                angle_deg: target,
            },
        });
        self.angle = target;
        out
    }
}

/// Play simulated presses on `events` in real time until the task is dropped
/// (or `presses` presses, if given), with a pause between presses.
pub async fn run(
    index: Arc<Index>,
    events: broadcast::Sender<MapEvent>,
    seed: u64,
    presses: Option<u64>,
) {
    let mut demo = Demo::new(index, seed);
    let _ = events.send(MapEvent::PeerUp {
        peer: DEMO_PEER.into(),
        addr: Some("simulated".into()),
    });
    let mut done = 0;
    while presses.is_none_or(|p| done < p) {
        let start = tokio::time::Instant::now();
        let (_, evs) = demo.next_press();
        for t in evs {
            tokio::time::sleep_until(start + t.at).await;
            // No receiver (no page open yet) is fine.
            let _ = events.send(t.event);
        }
        done += 1;
        tokio::time::sleep(Duration::from_millis(1200)).await;
    }
}

/// Dimension of [`catalogue_index`]'s stand-in embeddings.
pub const DEMO_DIM: usize = 32;

/// A demo index of built-in catalogue textiles (`count` of them, training
/// and unseen interleaved; all if `None`) when no encoder-built index is at
/// hand. Its "embeddings" are NOT from an encoder: they are the textiles'
/// ground-truth attributes and structure parameters, one-hot structure family
/// and fibre, plus per-press noise, so similar fabrics land near each other
/// on the map. Marked by `encoder_arch = "demo-catalogue-features"`.
pub fn catalogue_index(
    count: Option<usize>,
    roller_n: usize,
    seed: u64,
) -> Result<Index, telextiles_index::IndexError> {
    use telextiles_index::{IndexBuilder, TextileRecord};
    use telextiles_sim::{Book, Catalogue};
    let cat = Catalogue::builtin();
    let train: Vec<_> = cat.training().collect();
    let unseen: Vec<_> = cat.unseen().collect();
    // Interleave so a small count still has both books: 5 training, 1 unseen.
    let mut order = Vec::new();
    let (mut a, mut b) = (train.iter(), unseen.iter());
    loop {
        let mut any = false;
        for _ in 0..5 {
            if let Some(t) = a.next() {
                order.push(*t);
                any = true;
            }
        }
        if let Some(t) = b.next() {
            order.push(*t);
            any = true;
        }
        if !any {
            break;
        }
    }
    order.truncate(count.unwrap_or(usize::MAX));
    let mut builder = IndexBuilder::new(
        "demo-no-encoder",
        "demo-catalogue-features",
        DEMO_DIM,
        cat.version,
    );
    builder.roller_n = roller_n;
    builder.seed = seed;
    for t in order {
        let mut base = [0.0f32; DEMO_DIM];
        for (k, v) in t.attributes.to_vec().iter().enumerate() {
            base[k] = 2.0 * v;
        }
        let numeric = [
            t.warp_per_cm / 40.0,
            t.weft_per_cm / 40.0,
            t.yarn_diameter_mm * 2.0,
            t.relief_mm * 2.0,
            t.fuzz,
            t.compliance,
            t.stiffness,
            t.irregularity,
            t.thickness_mm / 3.0,
        ];
        for (k, v) in numeric.iter().enumerate() {
            base[7 + k] = v.clamp(0.0, 2.0);
        }
        let fam = telextiles_sim::catalogue::hash_str(&format!("{:?}", t.structure.family()));
        base[16 + (fam % 8) as usize] += 1.5;
        let fib = telextiles_sim::catalogue::hash_str(t.fibre.name());
        base[24 + (fib % 8) as usize] += 0.8;
        let mut rng = ChaCha8Rng::seed_from_u64(telextiles_sim::catalogue::hash_str(&t.id) ^ seed);
        let embeddings = (0..5)
            .map(|_| {
                base.iter()
                    .map(|v| v + rng.gen_range(-0.08f32..0.08))
                    .collect()
            })
            .collect();
        builder.add(TextileRecord {
            id: t.id.clone(),
            name: t.name.clone(),
            seen: t.book == Book::Training,
            structure: t.structure.label(),
            attributes: telextiles_sim::catalogue::Attributes::NAMES
                .iter()
                .zip(t.attributes.to_vec())
                .map(|(n, v)| (n.to_string(), v))
                .collect(),
            embeddings,
            exemplars: Vec::new(),
            press_frames: Vec::new(),
        })?;
    }
    builder.build()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// With a learned distance, the index's centroids are not encoder
    /// embeddings; the demo's presses still end on the textile pressed.
    #[test]
    fn demo_presses_land_on_their_textile_in_an_index_with_a_metric() {
        let mut index = catalogue_index(Some(30), 8, 1).unwrap();
        let dim = index.dim;
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let groups: Vec<Vec<Vec<f32>>> = (0..6)
            .map(|_| {
                (0..4)
                    .map(|_| (0..dim).map(|_| rng.gen_range(-1.0f32..1.0)).collect())
                    .collect()
            })
            .collect();
        index.metric = telextiles_index::Metric::within_fabric(&groups, dim, 0.3);
        assert!(index.metric.is_some());
        let index = Arc::new(index);
        let mut demo = Demo::new(index.clone(), 7);
        for _ in 0..6 {
            let (target, evs) = demo.next_press();
            let last = evs
                .iter()
                .rev()
                .find_map(|t| match &t.event {
                    MapEvent::Touch { latent, .. } => Some(latent),
                    _ => None,
                })
                .unwrap();
            assert_eq!(index.nearest(last).unwrap().best, target);
        }
    }

    #[test]
    fn demo_presses_decide_the_pressed_textile_and_turn_the_roller_there() {
        let index = Arc::new(catalogue_index(Some(30), 8, 1).unwrap());
        assert_eq!(index.entries.len(), 30);
        assert!(index.entries.iter().any(|e| !e.seen));
        let mut demo = Demo::new(index.clone(), 7);
        let mut angle = 0.0f64;
        for _ in 0..6 {
            let (target, evs) = demo.next_press();
            assert!(evs.windows(2).all(|w| w[0].at <= w[1].at));
            assert!(matches!(
                evs.first().unwrap().event,
                MapEvent::Contact {
                    phase: ContactPhase::Start,
                    ..
                }
            ));
            assert!(matches!(
                evs.last().unwrap().event,
                MapEvent::Contact {
                    phase: ContactPhase::End,
                    ..
                }
            ));
            let touches: Vec<&Vec<f32>> = evs
                .iter()
                .filter_map(|t| match &t.event {
                    MapEvent::Touch { latent, .. } => Some(latent),
                    _ => None,
                })
                .collect();
            assert_eq!(touches.len(), 75);
            // The last touches sit on the pressed textile.
            let last = touches.last().unwrap();
            assert_eq!(index.nearest(last).unwrap().best, target);
            let decided: Vec<(String, u32)> = evs
                .iter()
                .filter_map(|t| match &t.event {
                    MapEvent::Decision { textile, slot, .. } => Some((textile.clone(), *slot)),
                    _ => None,
                })
                .collect();
            assert_eq!(decided.len(), 1);
            let best = index.entry_by_id(&decided[0].0).unwrap();
            assert_eq!(decided[0].1 as usize, index.slot_of_entry(best));
            // The roller moves in steps of at most 360/N/2 degrees... and
            // arrives at the decided slot, the short way round.
            let mut moves = Vec::new();
            for t in &evs {
                match t.event {
                    MapEvent::RollerPosition { angle_deg, .. } => moves.push(angle_deg),
                    MapEvent::RollerArrived { slot, angle_deg } => {
                        assert_eq!(slot, decided[0].1);
                        assert!((angle_deg - slot as f64 * 45.0).abs() < 1e-9);
                        moves.push(angle_deg);
                    }
                    _ => {}
                }
            }
            let mut prev = angle;
            let mut travelled = 0.0;
            for a in moves {
                let d = (a - prev + 540.0).rem_euclid(360.0) - 180.0;
                assert!(d.abs() <= 180.0);
                travelled += d.abs();
                prev = a;
            }
            assert!(travelled <= 180.0 + 1e-6, "took the long way: {travelled}");
            angle = prev;
        }
    }

    #[test]
    fn demo_is_deterministic() {
        let index = Arc::new(catalogue_index(Some(20), 6, 3).unwrap());
        let a = Demo::new(index.clone(), 5).next_press();
        let b = Demo::new(index, 5).next_press();
        assert_eq!(a, b);
    }
}
