//! The paper protocol as a stream of press specs, and the dataset writer.
use std::collections::HashSet;
use telextiles_sim::catalogue::Book;
use telextiles_sim::dataset::{self, Protocol};
use telextiles_sim::{recording, PressSpec, Simulator};

#[test]
fn paper_protocol_streams_every_press_once() {
    let sim = Simulator::new().unwrap();
    let cat = sim.catalogue();
    let p = Protocol::paper();
    assert_eq!(p.len(cat), 3 * 2 * 11 * (119 + 20));
    let specs: Vec<PressSpec> = p.specs(cat).collect();
    assert_eq!(specs.len(), p.len(cat));
    let seeds: HashSet<u64> = specs.iter().map(|s| s.seed).collect();
    assert_eq!(seeds.len(), specs.len(), "seeds must be distinct");
    let per_textile = specs
        .iter()
        .filter(|s| s.textile == "T042" && s.jig && s.sensor == 1)
        .count();
    assert_eq!(per_textile, 11);
    assert!(specs
        .iter()
        .all(|s| cat.get(&s.textile).is_some() && s.person < 11));
    // deterministic
    assert_eq!(p.specs(cat).nth(777), Some(specs[777].clone()));
    let training_only = Protocol {
        books: vec![Book::Training],
        jig: vec![true],
        sensors: vec![0],
        ..p
    };
    assert_eq!(training_only.specs(cat).count(), 11 * 119);
}

#[test]
fn writer_writes_resumes_and_reads_back() {
    let sim = Simulator::new().unwrap();
    let cat = sim.catalogue();
    let p = Protocol {
        frames: 3,
        sensors: vec![0],
        ..Protocol::paper()
    };
    let tmp = tempfile::tempdir().unwrap();
    let specs: Vec<PressSpec> = p.specs(cat).take(3).collect();
    let n = dataset::write(&sim, specs.clone(), tmp.path(), |_, _| {}).unwrap();
    assert_eq!(n, 3);
    // resuming skips what is there
    let n = dataset::write(&sim, specs.clone(), tmp.path(), |_, _| {}).unwrap();
    assert_eq!(n, 0);
    let back = recording::read_press(&dataset::press_path(tmp.path(), &specs[1])).unwrap();
    assert_eq!(back.frames, sim.render_press(&specs[1]).unwrap().frames);
    assert_eq!(back.meta.person, specs[1].person);
}
