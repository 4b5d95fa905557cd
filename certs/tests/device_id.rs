//! Device ID text form: round trips, typo detection naming the group,
//! leniency, and no panics on arbitrary input.
use proptest::prelude::*;
use telextiles_certs::device_id::{GROUPS, GROUP_LEN, TEXT_LEN};
use telextiles_certs::{DeviceId, DeviceIdError};

const ALPHABET: &str = "ABCDEFGHIJKLMNOPQRSTUVWXYZ234567";

fn sample_id(seed: u8) -> DeviceId {
    let mut b = [0u8; 32];
    for (i, x) in b.iter_mut().enumerate() {
        *x = (i as u8)
            .wrapping_mul(37)
            .wrapping_add(seed.wrapping_mul(101));
    }
    DeviceId::from_bytes(b)
}

#[test]
fn known_hash_has_stable_text() {
    // SHA-256 of the empty string, written by hand: guards the encoding
    // against silent changes (peers compare these strings by eye).
    let id = DeviceId::from_spki_der(b"");
    let text = id.to_string();
    assert_eq!(text.len(), TEXT_LEN);
    let data: String = text.split('-').map(|g| &g[..GROUP_LEN - 1]).collect();
    // base32 of e3b0c442...b855
    assert!(data.starts_with("4OYMIQUY7QOBJGX36TEJS35ZEQT24QPEMSNZGTFESWMRW6CSXBKQ"));
    assert_eq!(text.parse::<DeviceId>().unwrap(), id);
}

#[test]
fn every_single_character_typo_is_caught_and_names_its_group() {
    let id = sample_id(7);
    let text = id.to_string();
    let chars: Vec<char> = text.chars().collect();
    let mut checked = 0;
    for (pos, &orig) in chars.iter().enumerate() {
        if orig == '-' {
            continue;
        }
        let group = pos / (GROUP_LEN + 1) + 1;
        for repl in ALPHABET.chars().filter(|&c| c != orig) {
            let mut typo = chars.clone();
            typo[pos] = repl;
            let typo: String = typo.into_iter().collect();
            match typo.parse::<DeviceId>() {
                Err(DeviceIdError::Checksum { group: g, text }) => {
                    assert_eq!(g, group, "{typo}");
                    assert_eq!(text.len(), GROUP_LEN);
                }
                other => panic!("typo {typo} not caught: {other:?}"),
            }
            checked += 1;
        }
    }
    assert_eq!(checked, GROUPS * GROUP_LEN * 31);
}

#[test]
fn most_neighbour_swaps_are_caught() {
    let mut caught = 0;
    let mut total = 0;
    for seed in 0..20u8 {
        let text = sample_id(seed).to_string();
        let chars: Vec<char> = text.chars().collect();
        for pos in 0..chars.len() - 1 {
            let (a, b) = (chars[pos], chars[pos + 1]);
            if a == '-' || b == '-' || a == b {
                continue;
            }
            let mut sw = chars.clone();
            sw.swap(pos, pos + 1);
            let sw: String = sw.into_iter().collect();
            total += 1;
            if sw.parse::<DeviceId>().is_err() {
                caught += 1;
            }
        }
    }
    // Luhn mod N misses only swaps of two specific value pairs.
    assert!(caught * 100 >= total * 95, "{caught}/{total}");
}

#[test]
fn parsing_is_lenient_about_case_spaces_dashes_and_lookalike_digits() {
    let id = sample_id(3);
    let text = id.to_string();
    assert_eq!(text.to_lowercase().parse::<DeviceId>().unwrap(), id);
    assert_eq!(text.replace('-', "").parse::<DeviceId>().unwrap(), id);
    assert_eq!(text.replace('-', " ").parse::<DeviceId>().unwrap(), id);
    let lookalike = text.replace('O', "0").replace('I', "1").replace('B', "8");
    assert_eq!(lookalike.parse::<DeviceId>().unwrap(), id);
}

#[test]
fn wrong_length_and_foreign_characters_have_clear_errors() {
    let text = sample_id(1).to_string();
    let short = &text[..text.len() - 1];
    let e = short.parse::<DeviceId>().unwrap_err();
    assert_eq!(
        e,
        DeviceIdError::Length {
            expected: GROUPS * GROUP_LEN,
            got: GROUPS * GROUP_LEN - 1
        }
    );
    assert!(e.to_string().contains("13 groups of 5"), "{e}");
    let mut bad: Vec<char> = text.chars().collect();
    bad[7] = '9';
    let bad: String = bad.into_iter().collect();
    let e = bad.parse::<DeviceId>().unwrap_err();
    assert_eq!(e, DeviceIdError::BadChar { ch: '9', group: 2 });
    assert!(e.to_string().contains("group 2"), "{e}");
}

#[test]
fn impossible_trailing_bits_are_refused() {
    // Build a text whose last data character carries non-zero padding bits,
    // with correct check characters everywhere.
    let text = sample_id(0).to_string();
    let mut groups: Vec<String> = text.split('-').map(String::from).collect();
    let last = groups.last_mut().unwrap();
    let mut data: Vec<char> = last.chars().take(GROUP_LEN - 1).collect();
    let v = ALPHABET.find(data[3]).unwrap();
    data[3] = ALPHABET.chars().nth(v | 1).unwrap();
    // Find the check character that makes this group valid.
    let found = ALPHABET.chars().find_map(|c| {
        let mut g = groups.clone();
        *g.last_mut().unwrap() = data.iter().chain(std::iter::once(&c)).collect();
        let t = g.join("-");
        match t.parse::<DeviceId>() {
            Err(DeviceIdError::Checksum { .. }) => None,
            other => Some(other),
        }
    });
    match found {
        Some(Err(DeviceIdError::Trailing { group, .. })) => assert_eq!(group, GROUPS),
        other => panic!("expected a trailing-bits error, got {other:?}"),
    }
}

#[test]
fn serde_uses_the_text_form_and_validates() {
    let id = sample_id(9);
    let json = serde_json::to_string(&id).unwrap();
    assert_eq!(json, format!("\"{id}\""));
    assert_eq!(serde_json::from_str::<DeviceId>(&json).unwrap(), id);
    let bad = json.replacen(|c: char| c.is_ascii_uppercase(), "2", 1);
    assert!(serde_json::from_str::<DeviceId>(&bad).is_err());
}

proptest! {
    #[test]
    fn round_trip(bytes in proptest::array::uniform32(any::<u8>())) {
        let id = DeviceId::from_bytes(bytes);
        let text = id.to_string();
        prop_assert_eq!(text.len(), TEXT_LEN);
        prop_assert_eq!(text.parse::<DeviceId>().unwrap(), id);
    }

    #[test]
    fn arbitrary_text_never_panics(s in ".{0,100}") {
        let _ = s.parse::<DeviceId>();
    }

    #[test]
    fn near_valid_text_never_panics(s in "[A-Z2-7018a-z\\- ]{60,80}") {
        let _ = s.parse::<DeviceId>();
    }
}
