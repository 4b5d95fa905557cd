//! The benchmark must be neither trivial nor noise: a simple rotation-
//! invariant baseline (radially averaged power spectrum + nearest centroid)
//! separates weave families on clean jig presses, near-twins are measurably
//! harder than random pairs, and hand-held presses are harder than jig ones.
mod common;
use common::*;
use std::collections::BTreeMap;
use telextiles_sim::catalogue::Family;
use telextiles_sim::{PressSpec, Simulator};

#[test]
fn weave_families_separable_by_power_spectrum() {
    let sim = Simulator::new().unwrap();
    let cat = sim.catalogue();
    // three textiles per family: centroids from two presses each, tested on
    // a third press (different seed: new rotation, offset, jitter, noise)
    let mut train: BTreeMap<Family, Vec<Vec<f32>>> = BTreeMap::new();
    let mut test: Vec<(Family, Vec<f32>)> = Vec::new();
    for fam in Family::ALL {
        for t in cat
            .training()
            .filter(|t| t.structure.family() == fam)
            .take(3)
        {
            for seed in [1u64, 2] {
                train
                    .entry(fam)
                    .or_default()
                    .push(spec_feature(&sim, &PressSpec::new(&t.id, seed)));
            }
            test.push((fam, spec_feature(&sim, &PressSpec::new(&t.id, 3))));
        }
    }
    let centroids: Vec<(Family, Vec<f32>)> = train.iter().map(|(f, v)| (*f, mean(v))).collect();
    let correct = test
        .iter()
        .filter(|(fam, x)| {
            let best = centroids
                .iter()
                .min_by(|a, b| dist(&a.1, x).total_cmp(&dist(&b.1, x)))
                .unwrap();
            best.0 == *fam
        })
        .count();
    let acc = correct as f32 / test.len() as f32;
    eprintln!(
        "family nearest-centroid accuracy: {correct}/{} = {acc:.3} (chance {:.3})",
        test.len(),
        1.0 / 11.0
    );
    assert!(acc >= 0.6, "families not separable: {acc}");
    assert!(acc < 1.0 || test.len() < 20, "suspiciously trivial");
}

/// Separability of two textiles: distance of their mean features over the
/// mean within-textile spread (Fisher-like ratio).
fn separability(sim: &Simulator, a: &str, b: &str) -> f32 {
    let feats = |id: &str| -> Vec<Vec<f32>> {
        (10..14u64)
            .map(|s| spec_feature(sim, &PressSpec::new(id, s)))
            .collect()
    };
    let (fa, fb) = (feats(a), feats(b));
    let (ma, mb) = (mean(&fa), mean(&fb));
    let spread =
        |f: &[Vec<f32>], m: &[f32]| f.iter().map(|x| dist(x, m)).sum::<f32>() / f.len() as f32;
    dist(&ma, &mb) / (0.5 * (spread(&fa, &ma) + spread(&fb, &mb))).max(1e-6)
}

#[test]
fn near_twins_are_harder_than_random_pairs() {
    let sim = Simulator::new().unwrap();
    let cat = sim.catalogue();
    let twins: Vec<(String, String)> = cat
        .twin_pairs()
        .iter()
        .take(5)
        .map(|(a, b)| (a.id.clone(), b.id.clone()))
        .collect();
    assert!(twins.len() >= 5);
    // random pairs: the same first textiles against a textile of another family
    let ids: Vec<&str> = cat.training().map(|t| t.id.as_str()).collect();
    let random: Vec<(String, String)> = twins
        .iter()
        .enumerate()
        .map(|(k, (a, _))| {
            let fa = cat.get(a).unwrap().structure.family();
            let other = ids
                .iter()
                .cycle()
                .skip(17 + 23 * k)
                .find(|id| cat.get(id).unwrap().structure.family() != fa)
                .unwrap();
            (a.clone(), other.to_string())
        })
        .collect();
    let mut st: Vec<f32> = twins
        .iter()
        .map(|(a, b)| separability(&sim, a, b))
        .collect();
    let mut sr: Vec<f32> = random
        .iter()
        .map(|(a, b)| separability(&sim, a, b))
        .collect();
    st.sort_by(f32::total_cmp);
    sr.sort_by(f32::total_cmp);
    let med = |v: &[f32]| v[v.len() / 2];
    eprintln!(
        "separability twins {st:?} median {:.2}; random {sr:?} median {:.2}",
        med(&st),
        med(&sr)
    );
    assert!(
        med(&st) < 0.6 * med(&sr),
        "near-twins not harder: {} vs {}",
        med(&st),
        med(&sr)
    );
}

#[test]
fn hand_held_presses_are_less_consistent_than_jig() {
    let sim = Simulator::new().unwrap();
    let bg0 = sim.background(0);
    // contact coverage at mid-hold and spread of the features of one textile
    let mut cover = [Vec::new(), Vec::new()];
    let mut spread = [0f32; 2];
    for (k, jig) in [true, false].into_iter().enumerate() {
        for id in ["T003", "T040", "T075"] {
            let feats: Vec<Vec<f32>> = (0..4u32)
                .map(|person| {
                    let spec = PressSpec {
                        person,
                        jig,
                        ..PressSpec::new(id, 20 + person as u64)
                    };
                    let f = sim.render_frame(&spec, 100).unwrap();
                    let sig = contact_signal(&f, &bg0);
                    let covered =
                        sig.iter().filter(|v| **v > 12.0).count() as f32 / sig.len() as f32;
                    cover[k].push(covered);
                    feature(&f, &bg0)
                })
                .collect();
            let m = mean(&feats);
            spread[k] += feats.iter().map(|x| dist(x, &m)).sum::<f32>();
        }
    }
    let mc = |v: &[f32]| v.iter().sum::<f32>() / v.len() as f32;
    eprintln!(
        "coverage jig {:.3} hand {:.3}; feature spread jig {:.2} hand {:.2}",
        mc(&cover[0]),
        mc(&cover[1]),
        spread[0],
        spread[1]
    );
    assert!(
        mc(&cover[1]) < mc(&cover[0]),
        "hand-held should lose contact area"
    );
    assert!(spread[1] > 1.2 * spread[0], "hand-held should vary more");
}
