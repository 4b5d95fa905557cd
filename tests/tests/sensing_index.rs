//! Sensing pipeline with the real textile index file: presses of several
//! simulated textiles encoded by the fixture ONNX encoder (real ONNX
//! Runtime) build an index with `telextiles-index` (written to disk and read
//! back); other presses of the same textiles, replayed through the whole
//! pipeline, resolve to the right textile and to the roller slot the index
//! assigns it.

use std::path::PathBuf;

use telextiles_index::{IndexBuilder, TextileRecord};
use telextiles_sensing::decide::TextileIndex;
use telextiles_sensing::encoder::{file_sha256, Encoder, EncoderOptions};
use telextiles_sensing::pipeline::{run_source, Pipeline, PipelineConfig};
use telextiles_sensing::source::recorded::{Pace, RecordedSource};
use telextiles_sim::{PressSpec, Simulator};

const TEXTILES: [&str; 6] = ["T010", "T030", "T040", "T050", "T080", "T110"];

fn fixture_model() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../daemon/sensing/tests/fixtures/fixture_encoder.onnx")
}

#[test]
fn replayed_presses_resolve_through_an_index_file() {
    let sim = Simulator::new().unwrap();
    let model = fixture_model();
    let mut enc = Encoder::open(&model, &EncoderOptions::default()).unwrap();
    let mut b = IndexBuilder::new(
        &file_sha256(&model).unwrap(),
        &enc.info().arch,
        enc.dim(),
        0,
    );
    b.roller_n = 4;
    for id in TEXTILES {
        let p = sim.render_press(&PressSpec::new(id, 1)).unwrap();
        // Every frame from first contact on, as `index build` takes a
        // press.
        let contact = p.meta.params.as_ref().unwrap().contact_frame as usize;
        let embeddings = p.frames[contact..]
            .iter()
            .map(|f| enc.encode(f).unwrap().to_vec())
            .collect();
        b.add(TextileRecord {
            id: id.into(),
            name: format!("textile {id}"),
            seen: true,
            structure: String::new(),
            attributes: Vec::new(),
            embeddings,
            exemplars: Vec::new(),
            press_frames: Vec::new(),
        })
        .unwrap();
    }
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("index.tlxi");
    b.build().unwrap().write(&path).unwrap();
    let index = telextiles_index::Index::read(&path).unwrap();
    assert_eq!(index.encoder_hash, enc.info().sha256);

    let mut pipeline = Pipeline::new(
        enc,
        index.clone(),
        PipelineConfig::default(),
        Some(&telextiles_sensing::front::pixels_of(&sim.background(0))),
    )
    .unwrap();
    let mut slots = std::collections::BTreeSet::new();
    for id in TEXTILES {
        let mut src = RecordedSource::from_press(
            sim.render_press(&PressSpec::new(id, 2)).unwrap(),
            Pace::AsFastAsPossible,
            id,
        );
        let mut reports = Vec::new();
        run_source(&mut pipeline, &mut src, None, |r| reports.push(r)).unwrap();
        assert_eq!(reports.len(), 1, "{id}: {reports:#?}");
        let r = &reports[0];
        assert_eq!(r.textile.as_deref(), Some(id), "{id}: {r:#?}");
        let entry = index.entry_by_id(id).unwrap();
        assert_eq!(
            r.slot,
            Some(index.slot_of_entry(entry)),
            "{id}: slot from the index's roller layout"
        );
        assert!(r.slot.unwrap() < 4);
        slots.insert(r.slot.unwrap());
        // The TextileIndex view agrees with the index's own search.
        assert_eq!(TextileIndex::id(&index, entry), id);
    }
    assert!(slots.len() > 1, "several slots used: {slots:?}");
}

#[test]
fn an_index_for_another_dimension_is_refused() {
    let model = fixture_model();
    let enc = Encoder::open(&model, &EncoderOptions::default()).unwrap();
    let mut b = IndexBuilder::new("00", "other", 8, 0);
    b.roller_n = 2;
    for (k, id) in ["A", "B", "C"].iter().enumerate() {
        let mut v = vec![0f32; 8];
        v[k] = 1.0;
        b.add(TextileRecord {
            id: id.to_string(),
            name: id.to_string(),
            seen: true,
            structure: String::new(),
            attributes: Vec::new(),
            embeddings: vec![v],
            exemplars: Vec::new(),
            press_frames: Vec::new(),
        })
        .unwrap();
    }
    let index = b.build().unwrap();
    let err = Pipeline::new(enc, index, PipelineConfig::default(), None)
        .err()
        .expect("refused");
    assert!(err.contains("8-d") && err.contains("64-d"), "{err}");
}
