use rand::{Rng, SeedableRng};
use sha2::Digest;
use telextiles_index::select::{self, coverage, order_wheel, wheel_length, SelectionMethod};
use telextiles_index::{l2_normalise, Index, IndexBuilder, IndexError, TextileRecord};

const DIM: usize = 16;

/// `clusters` groups of `per` textiles; each textile has 10 noisy embeddings.
fn clustered(clusters: usize, per: usize, seed: u64) -> Vec<TextileRecord> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let mut out = Vec::new();
    for c in 0..clusters {
        let centre: Vec<f32> = (0..DIM).map(|_| rng.gen_range(-1.0..1.0)).collect();
        for t in 0..per {
            let own: Vec<f32> = centre
                .iter()
                .map(|x| x + rng.gen_range(-0.3..0.3))
                .collect();
            let embeddings = (0..10)
                .map(|_| own.iter().map(|x| x + rng.gen_range(-0.05..0.05)).collect())
                .collect();
            let id = format!("T{:03}", c * per + t + 1);
            out.push(TextileRecord {
                name: format!("textile {id}"),
                id,
                seen: t != per - 1,
                structure: format!("family{c}"),
                attributes: vec![("roughness".into(), c as f32 / clusters as f32)],
                embeddings,
                exemplars: vec![],
                press_frames: vec![],
            });
        }
    }
    out
}

fn build(method: SelectionMethod, n: usize) -> Index {
    let mut b = IndexBuilder::new("abc123", "test", DIM, 1);
    for r in clustered(8, 6, 7) {
        b.add(r).unwrap();
    }
    b.roller_n = n;
    b.method = method;
    b.build().unwrap()
}

#[test]
fn round_trip_is_exact_and_fingerprint_stable() {
    let index = build(SelectionMethod::KMedoids, 16);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("i.tlxi");
    index.write(&path).unwrap();
    let back = Index::read(&path).unwrap();
    assert_eq!(back, index);
    assert_eq!(back.fingerprint(), index.fingerprint());
    // Any change of content changes the fingerprint.
    let mut other = index.clone();
    other.entries[3].centroid[0] += 1e-3;
    assert_ne!(other.fingerprint(), index.fingerprint());
    // No temporary files left behind.
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
}

#[test]
fn bad_files_are_refused_with_clear_errors() {
    let index = build(SelectionMethod::FarthestPoint, 8);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("i.tlxi");
    index.write(&path).unwrap();
    let good = std::fs::read(&path).unwrap();

    let write = |bytes: &[u8]| {
        std::fs::write(&path, bytes).unwrap();
        Index::read(&path).unwrap_err()
    };
    let e = write(&good[..good.len() - 10]);
    assert!(matches!(e, IndexError::Truncated { .. }), "{e}");
    assert!(e.to_string().contains("i.tlxi"), "{e}");

    let mut flipped = good.clone();
    flipped[40] ^= 0x55;
    let e = write(&flipped);
    assert!(e.to_string().contains("checksum"), "{e}");

    let e = write(b"PNG\x89 this is not an index");
    assert!(matches!(e, IndexError::BadMagic(_)), "{e}");

    let mut v2 = good.clone();
    v2[4] = 9;
    let e = write(&v2);
    assert!(matches!(e, IndexError::Version { found: 9, .. }), "{e}");

    let mut long = good.clone();
    long.push(0);
    assert!(matches!(write(&long), IndexError::Corrupt { .. }));

    let e = Index::read(&dir.path().join("missing.tlxi")).unwrap_err();
    assert!(e.to_string().contains("missing.tlxi"), "{e}");
}

#[test]
fn index_for_another_model_is_refused() {
    let index = build(SelectionMethod::KMedoids, 8);
    assert!(index.check_encoder("abc123").is_ok());
    let e = index.check_encoder("def456").unwrap_err();
    assert!(e.to_string().contains("rebuild"), "{e}");
}

#[test]
fn nearest_finds_the_textile_a_noisy_query_came_from() {
    let index = build(SelectionMethod::KMedoids, 16);
    let records = clustered(8, 6, 7);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(99);
    let mut right = 0;
    for r in &records {
        let mut q: Vec<f32> = r.embeddings[0]
            .iter()
            .map(|x| x + rng.gen_range(-0.05..0.05))
            .collect();
        l2_normalise(&mut q);
        let n = index.nearest(&q).unwrap();
        assert!(n.margin() >= 0.0);
        assert!(n.second.is_some());
        if index.entries[n.best].id == r.id {
            right += 1;
        }
        // The map places the query next to its textile.
        let p = index.place_on_map(&q);
        let e = index.entries[n.best].map_xy;
        assert!(((p[0] - e[0]).powi(2) + (p[1] - e[1]).powi(2)).sqrt() < 0.5);
    }
    assert!(right as f32 / records.len() as f32 > 0.9, "{right}");
}

#[test]
fn roller_selection_invariants_and_coverage_beats_random() {
    let records = clustered(8, 6, 3);
    let points: Vec<Vec<f32>> = records
        .iter()
        .map(|r| {
            let mut v = r.embeddings[0].clone();
            l2_normalise(&mut v);
            v
        })
        .collect();
    let n = 16;
    let random: Vec<_> = (0..20)
        .map(|s| {
            let c = select::select(&points, n, SelectionMethod::Random, s);
            let sp: Vec<_> = c.iter().map(|&i| points[i].clone()).collect();
            coverage(&points, &sp)
        })
        .collect();
    let rand_mean = random.iter().map(|c| c.mean).sum::<f32>() / random.len() as f32;
    let rand_max = random.iter().map(|c| c.max).sum::<f32>() / random.len() as f32;
    for m in [
        SelectionMethod::Umap1d,
        SelectionMethod::FarthestPoint,
        SelectionMethod::KMedoids,
    ] {
        let c = select::select(&points, n, m, 1);
        let mut d = c.clone();
        d.sort_unstable();
        d.dedup();
        assert_eq!(d.len(), n, "{m}: slots must be distinct");
        let sp: Vec<_> = c.iter().map(|&i| points[i].clone()).collect();
        let cov = coverage(&points, &sp);
        match m {
            SelectionMethod::KMedoids => assert!(cov.mean <= rand_mean, "{cov:?} vs {rand_mean}"),
            SelectionMethod::FarthestPoint => assert!(cov.max <= rand_max, "{cov:?} vs {rand_max}"),
            _ => {}
        }
        // Ordering the wheel never makes adjacent slots less similar.
        let ordered = order_wheel(&points, &c);
        assert!(wheel_length(&points, &ordered) <= wheel_length(&points, &c) + 1e-4);
        let mut o = ordered.clone();
        o.sort_unstable();
        assert_eq!(o, d);
    }
}

#[test]
fn built_index_puts_only_seen_textiles_on_the_roller_and_is_deterministic() {
    let a = build(SelectionMethod::Umap1d, 16);
    let b = build(SelectionMethod::Umap1d, 16);
    assert_eq!(a.fingerprint(), b.fingerprint());
    assert_eq!(a.roller.n(), 16);
    for &s in &a.roller.slots {
        assert!(a.entries[s].seen);
    }
    for (i, &s) in a.roller.slots.iter().enumerate() {
        assert_eq!(
            a.slot_of_entry(s),
            i,
            "a roller textile maps to its own slot"
        );
    }
}

#[test]
fn builder_rejects_bad_input() {
    let mut b = IndexBuilder::new("h", "a", DIM, 1);
    let mut r = clustered(1, 2, 1).remove(0);
    r.embeddings[0].pop();
    assert!(b.add(r).unwrap_err().to_string().contains("dimension"));
    let r = clustered(1, 2, 1).remove(0);
    b.add(r.clone()).unwrap();
    assert!(b.add(r).unwrap_err().to_string().contains("twice"));
    b.roller_n = 5;
    assert!(b.build().unwrap_err().to_string().contains("slots"));
}

proptest::proptest! {
    #[test]
    fn decoder_never_panics_on_random_bytes(bytes in proptest::collection::vec(proptest::num::u8::ANY, 0..600)) {
        let _ = telextiles_index_from_bytes(&bytes);
    }

    #[test]
    fn decoder_never_panics_on_mutated_files(pos in 0usize..4000, val in proptest::num::u8::ANY) {
        let index = small();
        let mut bytes = index_bytes(&index);
        let p = pos % bytes.len();
        bytes[p] = val;
        let _ = telextiles_index_from_bytes(&bytes);
    }

    /// Past the checksum: a payload changed and re-summed (format version 1,
    /// 2 with a metric, 3 with a calibrated unknown-textile distance)
    /// decodes to an error or to a valid index that answers queries, never
    /// a panic.
    #[test]
    fn decoder_never_panics_on_mutated_payloads(pos in 0usize..20000, val in proptest::num::u8::ANY, version in 1u8..=3) {
        let index = nuisance_index_with((version >= 2).then_some(0.5), (version == 3).then_some(0.95)).unwrap();
        let mut bytes = index_bytes(&index);
        let payload = 16..bytes.len() - 32;
        let p = payload.start + pos % payload.len();
        bytes[p] = val;
        let sum = sha2::Sha256::digest(&bytes[payload.clone()]);
        let n = bytes.len();
        bytes[n - 32..].copy_from_slice(&sum);
        if let Ok(back) = telextiles_index_from_bytes(&bytes) {
            back.validate().unwrap();
            let q = vec![0.25f32; back.dim];
            let _ = back.nearest(&q);
            let _ = back.place_on_map(&q);
        }
    }
}

fn small() -> Index {
    let mut b = IndexBuilder::new("h", "a", DIM, 1);
    for r in clustered(2, 3, 5) {
        b.add(r).unwrap();
    }
    b.roller_n = 4;
    b.build().unwrap()
}

fn index_bytes(index: &Index) -> Vec<u8> {
    telextiles_index::to_bytes(index)
}

fn telextiles_index_from_bytes(bytes: &[u8]) -> Result<Index, IndexError> {
    telextiles_index::from_bytes(bytes, std::path::Path::new("fuzz.tlxi"))
}

/// Four fabrics whose presses vary mostly along a nuisance direction (the
/// last coordinate) that is larger than what tells them apart; fabric 0's
/// presses happened to lean one way along it, fabric 1's the other.
fn nuisance_records() -> Vec<TextileRecord> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
    (0..4)
        .map(|t| {
            let presses: Vec<Vec<f32>> = (0..4)
                .map(|_| {
                    let mut v = vec![0.0f32; DIM];
                    v[t] = 1.0;
                    for x in v.iter_mut().take(DIM - 1) {
                        *x += rng.gen_range(-0.05..0.05);
                    }
                    let lean = [1.0, -1.0, 0.0, 0.0][t];
                    v[DIM - 1] = lean + rng.gen_range(-0.6..0.6);
                    v
                })
                .collect();
            TextileRecord {
                id: format!("F{t}"),
                name: format!("fabric {t}"),
                seen: true,
                structure: String::new(),
                attributes: vec![],
                embeddings: presses.clone(),
                exemplars: presses,
                press_frames: vec![],
            }
        })
        .collect()
}

fn nuisance_index(shrinkage: Option<f32>) -> Result<Index, IndexError> {
    nuisance_index_with(shrinkage, None)
}

fn nuisance_index_with(shrinkage: Option<f32>, quantile: Option<f32>) -> Result<Index, IndexError> {
    nuisance_builder(shrinkage, quantile).build()
}

/// The builder of the nuisance records: centroids only, 4 slots.
fn nuisance_builder(shrinkage: Option<f32>, quantile: Option<f32>) -> IndexBuilder {
    let mut b = IndexBuilder::new("abc123", "test", DIM, 0);
    for r in nuisance_records() {
        b.add(r).unwrap();
    }
    b.roller_n = 4;
    b.keep_exemplars = false;
    b.metric = telextiles_index::build::MetricFit::press_means(shrinkage);
    b.unknown_quantile = quantile;
    b
}

/// A new press of fabric `t` drawn as the nuisance records' presses are
/// (fabric 4 and above: fabrics the index does not have).
fn nuisance_press(t: usize, rng: &mut rand_chacha::ChaCha8Rng) -> Vec<f32> {
    let mut v = vec![0.0f32; DIM];
    v[t] = 1.0;
    for x in v.iter_mut().take(DIM - 1) {
        *x += rng.gen_range(-0.05..0.05);
    }
    let lean = [1.0, -1.0].get(t).copied().unwrap_or(0.0);
    v[DIM - 1] = lean + rng.gen_range(-0.6..0.6);
    l2_normalise(&mut v);
    v
}

#[test]
fn an_unknown_textile_distance_calibrated_on_the_presses_tells_new_fabrics_from_known_ones() {
    for shrinkage in [None, Some(0.5)] {
        let index = nuisance_index_with(shrinkage, Some(0.95)).unwrap();
        let u = index.unknown.expect("16 presses of 4 fabrics");
        assert_eq!((u.quantile, u.presses), (0.95, 16));
        let t = u.distance;
        // The 0.95 quantile of the 16 left-out distances the builder reports.
        let (uncalibrated, d) = nuisance_builder(shrinkage, None)
            .build_calibrated()
            .unwrap();
        assert_eq!(uncalibrated.unknown, None);
        assert_eq!(d.len(), 16);
        assert!(d.windows(2).all(|w| w[0] <= w[1]));
        assert_eq!(
            Some(t),
            telextiles_index::build::calibrated_distance(&d, 0.95)
        );
        assert_eq!(t, d[15]);
        // New presses of known fabrics are mostly within it; presses of
        // fabrics the index does not have are all beyond it.
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
        let flagged = |t_fab: usize, rng: &mut rand_chacha::ChaCha8Rng| {
            (0..50)
                .filter(|_| {
                    index
                        .nearest(&nuisance_press(t_fab, rng))
                        .unwrap()
                        .best_dist
                        > t
                })
                .count()
        };
        let known: usize = (0..4).map(|f| flagged(f, &mut rng)).sum();
        let unseen: usize = (4..8).map(|f| flagged(f, &mut rng)).sum();
        assert!(
            known <= 20,
            "{shrinkage:?}: {known} of 200 known presses flagged (t {t})"
        );
        assert_eq!(unseen, 200, "{shrinkage:?}: t {t}");
    }
    // Fewer than four left-out presses: nothing to calibrate on.
    let mut b = IndexBuilder::new("abc123", "test", DIM, 0);
    for mut r in nuisance_records() {
        r.exemplars.truncate(1);
        b.add(r).unwrap();
    }
    b.roller_n = 4;
    b.unknown_quantile = Some(0.95);
    assert_eq!(b.build().unwrap().unknown, None);
    // A quantile outside (0, 1] is an error.
    for q in [0.0, 1.5, f32::NAN] {
        assert!(matches!(
            nuisance_index_with(None, Some(q)),
            Err(IndexError::Invalid(_))
        ));
    }
}

#[test]
fn an_index_with_an_unknown_textile_distance_is_format_version_3() {
    let dir = tempfile::tempdir().unwrap();
    for shrinkage in [None, Some(0.5)] {
        let index = nuisance_index_with(shrinkage, Some(0.95)).unwrap();
        let path = dir.path().join("v3.tlxi");
        index.write(&path).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        assert_eq!(u32::from_le_bytes(bytes[4..8].try_into().unwrap()), 3);
        let back = Index::read(&path).unwrap();
        assert_eq!(back, index);
        assert_eq!(back.metric.is_some(), shrinkage.is_some());
        assert_eq!(back.fingerprint(), index.fingerprint());
        // The distance is part of the content peers compare.
        let mut other = index.clone();
        other.unknown.as_mut().unwrap().distance += 1e-3;
        assert_ne!(other.fingerprint(), index.fingerprint());
        // One that is no distance between unit vectors is refused on write
        // and on read.
        for t in [0.0, -0.1, 2.5, f32::NAN, f32::INFINITY] {
            let mut bad = index.clone();
            bad.unknown.as_mut().unwrap().distance = t;
            refused_on_write_and_read(&bad, dir.path(), "unknown-textile distance");
        }
        let mut bad = index.clone();
        bad.unknown.as_mut().unwrap().quantile = 0.0;
        assert!(matches!(bad.validate(), Err(IndexError::Invalid(_))));
    }
}

#[test]
fn a_metric_learned_from_the_presses_discounts_how_presses_of_one_fabric_differ() {
    let plain = nuisance_index(None).unwrap();
    let learned = nuisance_index(Some(0.5)).unwrap();
    assert!(plain.metric.is_none());
    let m = learned
        .metric
        .as_ref()
        .expect("four fabrics of four presses");
    assert_eq!((m.presses, m.fabrics, m.shrinkage), (16, 4, 0.5));
    // Presses of fabric 1 leaning the other way along the nuisance: plain
    // cosine calls most of them fabric 0, the learned metric none.
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
    let (mut plain_right, mut learned_right) = (0, 0);
    for _ in 0..50 {
        let mut q = vec![0.0f32; DIM];
        q[1] = 1.0;
        q[0] = 0.3;
        q[DIM - 1] = rng.gen_range(0.8..1.4);
        l2_normalise(&mut q);
        plain_right += (plain.nearest(&q).unwrap().best == 1) as usize;
        learned_right += (learned.nearest(&q).unwrap().best == 1) as usize;
        // Every query method agrees on the space.
        let n = learned.nearest(&q).unwrap();
        assert_eq!(learned.k_nearest(&q, 1)[0], (n.best, n.best_dist));
        assert_eq!(learned.entry_distance(n.best, &q), n.best_dist);
    }
    assert!(plain_right < 25, "plain {plain_right}/50");
    assert_eq!(learned_right, 50, "plain {plain_right}/50");
    // A query of another dimension is no answer, not a panic.
    assert!(learned.nearest(&[1.0; 3]).is_none());
    assert!(learned.k_nearest(&[1.0; 3], 2).is_empty());
}

/// `bad` is invalid: `validate` says so, `write` refuses it, and the same
/// content written anyway is refused on read with an error naming `what`.
fn refused_on_write_and_read(bad: &Index, dir: &std::path::Path, what: &str) {
    assert!(matches!(bad.validate(), Err(IndexError::Invalid(_))));
    let path = dir.join("bad.tlxi");
    assert!(bad.write(&path).is_err());
    std::fs::write(&path, telextiles_index::to_bytes(bad)).unwrap();
    let e = Index::read(&path).unwrap_err();
    assert!(e.to_string().contains(what), "{e}");
}

#[test]
fn an_index_with_a_metric_is_format_version_2_and_one_without_stays_version_1() {
    let dir = tempfile::tempdir().unwrap();
    for (shrinkage, version) in [(None, 1u32), (Some(0.5), 2)] {
        let index = nuisance_index(shrinkage).unwrap();
        let path = dir.path().join(format!("v{version}.tlxi"));
        index.write(&path).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        assert_eq!(u32::from_le_bytes(bytes[4..8].try_into().unwrap()), version);
        let back = Index::read(&path).unwrap();
        assert_eq!(back, index);
        assert_eq!(back.fingerprint(), index.fingerprint());
    }
    // The metric is part of the content peers compare.
    let a = nuisance_index(Some(0.5)).unwrap();
    let mut b = a.clone();
    b.metric.as_mut().unwrap().matrix[0] += 1e-3;
    assert_ne!(a.fingerprint(), b.fingerprint());
    // A metric that is not a finite map of the index's dimension is refused
    // on write and on read.
    let mut bad = a.clone();
    bad.metric.as_mut().unwrap().matrix[3] = f32::NAN;
    refused_on_write_and_read(&bad, dir.path(), "metric");
    let mut short = a.clone();
    short.metric.as_mut().unwrap().matrix.pop();
    assert!(short.validate().is_err());
    // Shrinkage outside 0..=1 is an error, not a silent identity.
    assert!(matches!(
        nuisance_index(Some(1.5)),
        Err(IndexError::Invalid(_))
    ));
}

#[test]
fn the_shipped_version_1_index_still_reads_and_encodes_byte_for_byte() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/index.tlxi");
    let bytes = std::fs::read(&path).unwrap();
    let index = Index::read(&path).unwrap();
    assert!(index.metric.is_none());
    assert_eq!(telextiles_index::to_bytes(&index), bytes);
}

/// Fabrics `0..n` that differ a little along their own axis, pressed
/// `presses` times with `frames` frames each; every frame wanders far
/// along `NUISANCE_AXES` more axes (a nuisance: another place on the
/// cloth, the gel's tilt), each press around its own offset there.
fn nuisance_frames(
    n: usize,
    presses: usize,
    frames: usize,
    nuisance: f32,
    seed: u64,
) -> Vec<TextileRecord> {
    let dim = n + NUISANCE_AXES;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    (0..n)
        .map(|t| {
            let press_frames: Vec<Vec<Vec<f32>>> = (0..presses)
                .map(|_| {
                    let offset: Vec<f32> = (0..NUISANCE_AXES)
                        .map(|k| rng.gen_range(-1.0..1.0) / (1.0 + k as f32 / 4.0))
                        .collect();
                    (0..frames)
                        .map(|_| {
                            let mut v = vec![1.0f32; dim];
                            v[t] += 0.35;
                            for x in v.iter_mut().take(n) {
                                *x += rng.gen_range(-0.04..0.04);
                            }
                            for (k, o) in offset.iter().enumerate() {
                                v[n + k] = nuisance * (o + rng.gen_range(-1.0..1.0));
                            }
                            v
                        })
                        .collect()
                })
                .collect();
            let means: Vec<Vec<f32>> = press_frames
                .iter()
                .map(|f| {
                    let mut m = vec![0.0f32; dim];
                    for v in f {
                        m.iter_mut().zip(v).for_each(|(a, b)| *a += b);
                    }
                    m
                })
                .collect();
            TextileRecord {
                id: format!("F{t}"),
                name: format!("fabric {t}"),
                seen: true,
                structure: String::new(),
                attributes: vec![],
                embeddings: press_frames.iter().flatten().cloned().collect(),
                exemplars: means,
                press_frames,
            }
        })
        .collect()
}

/// Axes the frames of [`nuisance_frames`] wander along.
const NUISANCE_AXES: usize = 16;

fn auto_report(records: Vec<TextileRecord>) -> telextiles_index::build::BuildReport {
    let dim = records[0].embeddings[0].len();
    let mut b = IndexBuilder::new("abc123", "test", dim, 0);
    for r in records {
        b.add(r).unwrap();
    }
    b.roller_n = 4;
    b.metric = telextiles_index::build::MetricFit::Auto;
    b.unknown_quantile = Some(0.9);
    b.build_report().unwrap()
}

#[test]
fn a_metric_fitted_on_every_frame_learns_what_three_press_means_cannot() {
    use telextiles_index::build::MetricFit;
    // Eight fabrics, three presses each: 16 degrees of freedom of press
    // means for a 24-d covariance, but 240 frames.
    let r = auto_report(nuisance_frames(8, 3, 10, 0.6, 1));
    assert_eq!(r.fits.len(), MetricFit::CANDIDATES.len());
    let right: Vec<usize> = r.fits.iter().map(|f| f.right()).collect();
    let cosine = right[0];
    let frames_lw = right[2];
    assert!(frames_lw > cosine + 3, "{right:?}");
    assert!(frames_lw > right[1] + 4, "{right:?}");
    // The chosen fit is the best, and the index carries its metric.
    assert_eq!(right[r.chosen], *right.iter().max().unwrap(), "{right:?}");
    assert!(
        matches!(r.fits[r.chosen].fit, MetricFit::Frames(_)),
        "{right:?}"
    );
    let m = r.index.metric.as_ref().expect("a frames fit");
    assert_eq!((m.presses, m.fabrics), (24, 8));
    // Its left-out presses are the index's self-check and calibrate its
    // unknown distance.
    assert_eq!(r.left.len(), 24);
    assert_eq!(
        r.left.iter().filter(|l| l.decided == l.fabric).count(),
        right[r.chosen]
    );
    assert!(r.index.unknown.is_some());
    // The Ledoit-Wolf fit chose its own shrinkage from the frames.
    let lw = MetricFit::Frames(None)
        .fit(
            &telextiles_index::build::press_data(
                &nuisance_frames(8, 3, 10, 0.6, 1)
                    .into_iter()
                    .map(|r| (r.exemplars, r.press_frames))
                    .collect::<Vec<_>>(),
                24,
            )
            .iter()
            .map(|f| f.iter().collect())
            .collect::<Vec<_>>(),
            24,
        )
        .unwrap();
    assert!(lw.shrinkage > 0.0 && lw.shrinkage < 0.5, "{}", lw.shrinkage);
}

#[test]
fn the_fit_chosen_on_the_presses_is_never_behind_plain_cosine_on_them() {
    use telextiles_index::build::MetricFit;
    // With no nuisance at all there is nothing for a fit to learn; with
    // one, there is. Either way the choice is at least as right as cosine
    // on the presses left out, and cosine when nothing beats it.
    for (seed, nuisance) in [(2, 0.0), (3, 0.05), (4, 0.3), (5, 1.0)] {
        let r = auto_report(nuisance_frames(6, 3, 6, nuisance, seed));
        let right: Vec<usize> = r.fits.iter().map(|f| f.right()).collect();
        assert!(right[r.chosen] >= right[0], "{seed}: {right:?}");
        if right.iter().all(|&x| x <= right[0]) {
            assert_eq!(r.fits[r.chosen].fit, MetricFit::Cosine, "{right:?}");
            assert!(r.index.metric.is_none());
        }
    }
}

#[test]
fn frames_must_match_the_presses_they_belong_to() {
    let mut records = nuisance_frames(4, 3, 4, 0.5, 6);
    records[1].press_frames.pop();
    let mut b = IndexBuilder::new("abc123", "test", 4 + NUISANCE_AXES, 0);
    let mut refused = None;
    for r in records {
        if let Err(e) = b.add(r) {
            refused = Some(e.to_string());
        }
    }
    let e = refused.expect("two frame lists for three presses");
    assert!(e.contains("frames of 2 presses for 3 press means"), "{e}");
    // A shrinkage outside 0..=1 is refused by name.
    let mut b = IndexBuilder::new("abc123", "test", 4 + NUISANCE_AXES, 0);
    for r in nuisance_frames(4, 3, 4, 0.5, 6) {
        b.add(r).unwrap();
    }
    b.roller_n = 4;
    b.metric = telextiles_index::build::MetricFit::Frames(Some(1.5));
    let e = b.build().unwrap_err().to_string();
    assert!(e.contains("shrinkage 1.5 is outside 0..=1"), "{e}");
}

#[test]
fn an_index_of_texture_features_is_format_version_4_and_says_so() {
    use telextiles_index::Features;
    let dim = 40;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(8);
    let mut b = IndexBuilder::new("abc123", "test", dim, 0);
    for t in 0..3 {
        let v = |rng: &mut rand_chacha::ChaCha8Rng| -> Vec<f32> {
            (0..dim)
                .map(|k| f32::from(k == t) + rng.gen_range(-0.1..0.1))
                .collect()
        };
        let presses: Vec<Vec<f32>> = (0..3).map(|_| v(&mut rng)).collect();
        b.add(TextileRecord {
            id: format!("F{t}"),
            name: format!("fabric {t}"),
            seen: true,
            structure: String::new(),
            attributes: vec![],
            embeddings: presses.clone(),
            exemplars: presses,
            press_frames: vec![],
        })
        .unwrap();
    }
    b.roller_n = 3;
    b.features = Features::EncoderLbp;
    let index = b.build().unwrap();
    assert_eq!(index.features, Features::EncoderLbp);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("lbp.tlxi");
    index.write(&path).unwrap();
    let bytes = std::fs::read(&path).unwrap();
    assert_eq!(u32::from_le_bytes(bytes[4..8].try_into().unwrap()), 4);
    let back = Index::read(&path).unwrap();
    assert_eq!(back, index);
    // The features are part of what peers compare.
    let mut plain = index.clone();
    plain.features = Features::Encoder;
    assert_ne!(plain.fingerprint(), index.fingerprint());
    // An index too narrow to hold the texture features beside an
    // encoder's embedding is refused, on write and on read.
    let mut narrow = nuisance_index(None).unwrap();
    narrow.features = Features::EncoderLbp;
    refused_on_write_and_read(&narrow, dir.path(), "leaves nothing of the encoder's");
}

#[test]
fn an_index_of_another_sensor_is_format_version_5_and_refuses_the_others() {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
    let dim = 16;
    let mut b = IndexBuilder::new("abc123", "test", dim, 0);
    for t in 0..3 {
        let presses: Vec<Vec<f32>> = (0..2)
            .map(|_| {
                (0..dim)
                    .map(|k| f32::from(k == t) + rng.gen_range(-0.1..0.1))
                    .collect()
            })
            .collect();
        b.add(TextileRecord {
            id: format!("F{t}"),
            name: format!("fabric {t}"),
            seen: true,
            structure: String::new(),
            attributes: vec![],
            embeddings: presses.clone(),
            exemplars: presses,
            press_frames: vec![],
        })
        .unwrap();
    }
    b.roller_n = 3;
    let digit = b.clone().build().unwrap();
    b.sensor = Some("gelsight-mini".into());
    let index = b.build().unwrap();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("gs.tlxi");
    index.write(&path).unwrap();
    let bytes = std::fs::read(&path).unwrap();
    assert_eq!(u32::from_le_bytes(bytes[4..8].try_into().unwrap()), 5);
    let back = Index::read(&path).unwrap();
    assert_eq!(back, index);
    assert_eq!(back.sensor.as_deref(), Some("gelsight-mini"));
    // The sensor is part of what peers compare; a DIGIT's index is as before.
    assert_ne!(digit.fingerprint(), index.fingerprint());
    let dpath = dir.path().join("digit.tlxi");
    digit.write(&dpath).unwrap();
    let dbytes = std::fs::read(&dpath).unwrap();
    assert_eq!(u32::from_le_bytes(dbytes[4..8].try_into().unwrap()), 1);
    // Frames of another sensor are refused by name, unless it is mixed.
    assert!(index.check_sensor("gelsight-mini").is_ok());
    let e = index.check_sensor("digit").unwrap_err();
    assert!(
        e.contains("gelsight-mini sensor")
            && e.contains("from a digit")
            && e.contains("--mix-sensors"),
        "{e}"
    );
    assert!(digit.check_sensor("digit").is_ok());
    assert!(digit.check_sensor("uvc").is_err());
    let mut mixed = index.clone();
    mixed.sensor = Some("mixed:digit+gelsight-mini".into());
    assert!(mixed.check_sensor("digit").is_ok());
    // A sensor name that is not one is refused on write and on read.
    let mut bad = index.clone();
    bad.sensor = Some("digit".into());
    refused_on_write_and_read(&bad, dir.path(), "not a sensor profile name");
}
