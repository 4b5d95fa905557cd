//! Catalogue version 1 must keep rendering bit-identical: these hashes were
//! taken from the v1 renderer before catalogue version 2 was added. If one
//! changes, v1 output changed (a regression, not a test to update).
use telextiles_sim::{PressSpec, Simulator};

/// FNV-1a over the raw RGB bytes.
fn fnv(bytes: &[u8]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for &b in bytes {
        h ^= b as u64;
        h = h.wrapping_mul(0x0100_0000_01b3);
    }
    h
}

fn cases() -> Vec<(PressSpec, usize)> {
    vec![
        (PressSpec::new("T001", 3), 100),
        (
            PressSpec {
                person: 3,
                jig: false,
                sensor: 2,
                release: Some(true),
                ..PressSpec::new("T021", 7)
            },
            140,
        ),
        (
            PressSpec {
                sensor: 4,
                noise: false,
                ..PressSpec::new("T107", 1)
            },
            80,
        ),
        (
            PressSpec {
                person: 7,
                jig: false,
                ..PressSpec::new("U05", 2)
            },
            60,
        ),
    ]
}

#[test]
fn v1_frames_are_pinned() {
    let sim = Simulator::new().unwrap();
    let got: Vec<u64> = cases()
        .iter()
        .map(|(spec, i)| fnv(sim.render_frame(spec, *i).unwrap().as_raw()))
        .collect();
    let meta = sim.press_meta(&cases()[1].0).unwrap();
    let meta_hash = fnv(serde_json::to_string(&meta).unwrap().as_bytes());
    let bg = fnv(sim.background(5).as_raw());
    println!("frames {got:x?} meta {meta_hash:x} bg {bg:x}");
    let want: [u64; 4] = [
        0xfda4a5a106047cb4,
        0x5349f14e50580f68,
        0x1542c3a16682f0ec,
        0x99c2eff38af62779,
    ];
    assert_eq!(got, want);
    // the metadata JSON of a v1 press is unchanged too (new fields are
    // left out of v1 JSON)
    assert_eq!(meta_hash, 0xfe0feba9ad78fd83);
    assert_eq!(bg, 0x249698bb40d40ef5);
}
