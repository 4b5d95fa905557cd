//! Encoding the run of frames that starts a press (`FrontEnd::set_encode_run`):
//! the contact detector starts a press on the last of `min_enter_frames`
//! frames over its threshold; with the option on, the front end encodes
//! the run's earlier frames too, on the frame that starts the press, so a
//! press's embeddings begin at its first frame over the threshold.

mod common;

use telextiles_sensing::contact::{ContactConfig, ContactEvent};
use telextiles_sensing::decide::{FlatIndex, TextileIndex};
use telextiles_sensing::encoder::{Encoder, EncoderOptions};
use telextiles_sensing::frame::Frame;
use telextiles_sensing::front::{recording_reference, segment, FrontEnd};
use telextiles_sensing::pipeline::{Pipeline, PipelineConfig};
use telextiles_sim::{Press, PressSpec};

const PERIOD: u64 = 16_667;

fn encoder() -> Encoder {
    Encoder::open(
        &common::fixture("fixture_subtract.onnx"),
        &EncoderOptions::default(),
    )
    .unwrap()
}

/// What the front end gave on each frame of a press: (frame, timestamp of
/// the press start if it started there, the earlier frames' (timestamp,
/// embedding), this frame's embedding).
type Seen = Vec<(usize, Option<u64>, Vec<(u64, Vec<f32>)>, Option<Vec<f32>>)>;

fn run(front: &mut FrontEnd, press: &Press) -> Seen {
    front.reset(recording_reference(press).as_deref());
    let mut out = Vec::new();
    for (i, f) in press.frames.iter().enumerate() {
        let frame = Frame::new(f.clone(), press.meta.timestamps_us[i], i as u64).unwrap();
        let o = front.process(&frame).unwrap();
        let start = match o.contact.event {
            Some(ContactEvent::PressStart { t_us }) => Some(t_us),
            _ => None,
        };
        let earlier = o
            .earlier
            .iter()
            .map(|e| (e.t_us, e.embedding.clone()))
            .collect();
        out.push((i, start, earlier, o.embedding.map(<[f32]>::to_vec)));
    }
    out
}

/// The reference the front end holds after `frames` frames of `press`.
fn reference_after(front: &mut FrontEnd, press: &Press, frames: usize) -> Vec<f32> {
    front.reset(recording_reference(press).as_deref());
    for (i, f) in press.frames.iter().take(frames).enumerate() {
        let frame = Frame::new(f.clone(), press.meta.timestamps_us[i], i as u64).unwrap();
        front.process(&frame).unwrap();
    }
    front.contact().reference_pixels().unwrap().to_vec()
}

#[test]
fn the_run_that_starts_a_press_is_encoded_on_the_frame_that_starts_it() {
    let sim = common::sim();
    let press = sim.render_press(&PressSpec::new("T030", 3)).unwrap();
    let cfg = ContactConfig::default();
    let mut front = FrontEnd::new(encoder(), cfg.clone(), None);
    let off = run(&mut front, &press);
    front.set_encode_run(true);
    let on = run(&mut front, &press);
    // The press starts on one frame, the same either way.
    let started: Vec<usize> = on.iter().filter(|x| x.1.is_some()).map(|x| x.0).collect();
    assert_eq!(started.len(), 1, "one press");
    let k = started[0];
    assert_eq!(off[k].1, on[k].1);
    let start_us = on[k].1.unwrap();
    // Off: nothing earlier, ever. On: only on that frame, the run's
    // `min_enter_frames - 1` frames before it, oldest first, the first at
    // the press's start.
    assert!(off.iter().all(|x| x.2.is_empty()));
    assert!(on.iter().filter(|x| x.0 != k).all(|x| x.2.is_empty()));
    let n = cfg.min_enter_frames as usize - 1;
    let early = &on[k].2;
    assert_eq!(early.len(), n);
    let ts = &press.meta.timestamps_us;
    let want_t: Vec<u64> = (k - n..k).map(|i| ts[i]).collect();
    assert_eq!(early.iter().map(|e| e.0).collect::<Vec<_>>(), want_t);
    assert_eq!(early[0].0, start_us);
    // Each is what the encoder gives that frame against the reference in
    // force when the press started (it followed the quiet frames before).
    let mut alone = encoder();
    let reference = reference_after(&mut front, &press, k + 1);
    alone.set_reference_pixels(&reference).unwrap();
    for (j, (_, e)) in early.iter().enumerate() {
        let want = alone.encode(&press.frames[k - n + j]).unwrap();
        assert_eq!(e.as_slice(), want, "run frame {j}");
    }
    // Holding the run's frames changes nothing else: every frame's own
    // embedding is the same with the option on.
    for (a, b) in off.iter().zip(&on) {
        assert_eq!(a.3, b.3, "frame {}", a.0);
    }
    assert!(
        on[k].3.is_some(),
        "the frame that starts the press is encoded too"
    );
    // The lab's segment flags the same frames as the run.
    let seg = segment(&press, &cfg).unwrap();
    let flagged: Vec<usize> = seg
        .contact
        .iter()
        .filter(|c| c.early)
        .map(|c| c.index)
        .collect();
    assert_eq!(flagged, (k - n..k).collect::<Vec<_>>());
    assert!(seg.contact.iter().all(|c| c.press_start_us == start_us));
}

#[test]
fn a_blip_too_short_to_start_a_press_is_never_encoded() {
    let sim = common::sim();
    let bg = sim.background(0);
    let touched = {
        let p = sim.render_press(&PressSpec::new("T030", 1)).unwrap();
        let hold = p.meta.params.as_ref().unwrap().hold_frame as usize;
        p.frames[hold + 5].clone()
    };
    let cfg = ContactConfig::default();
    let blip = cfg.min_enter_frames as usize - 1;
    // Quiet (the reference), a blip one frame short of a press, quiet,
    // then a press.
    let mut frames = vec![bg.clone(); 12];
    frames.extend(vec![touched.clone(); blip]);
    frames.extend(vec![bg.clone(); 6]);
    let press_from = frames.len();
    frames.extend(vec![touched.clone(); 8]);
    let mut front = FrontEnd::new(encoder(), cfg, None);
    front.set_encode_run(true);
    let mut starts = Vec::new();
    for (i, f) in frames.iter().enumerate() {
        let t = (i as u64 + 1) * PERIOD;
        let o = front
            .process(&Frame::new(f.clone(), t, i as u64).unwrap())
            .unwrap();
        if i < press_from {
            assert!(o.embedding.is_none() && o.earlier.is_empty(), "frame {i}");
        }
        if let Some(ContactEvent::PressStart { t_us }) = o.contact.event {
            // Only the press's own run, not the blip's frames.
            let ts: Vec<u64> = o.earlier.iter().map(|e| e.t_us).collect();
            let want: Vec<u64> = (press_from..i).map(|j| (j as u64 + 1) * PERIOD).collect();
            assert_eq!(ts, want);
            assert_eq!(t_us, want[0]);
            starts.push(i);
        }
    }
    assert_eq!(starts, vec![press_from + blip]);
}

#[test]
fn the_pipelines_decider_counts_the_run_from_the_press_start() {
    let sim = common::sim();
    let presses: Vec<Press> = ["T030", "T040"]
        .iter()
        .map(|id| sim.render_press(&PressSpec::new(*id, 2)).unwrap())
        .collect();
    // An index of the two textiles from their own presses.
    let mut front = FrontEnd::new(encoder(), ContactConfig::default(), None);
    let rows: Vec<(String, Vec<Vec<f32>>)> = presses
        .iter()
        .map(|p| {
            let embs = run(&mut front, p).into_iter().filter_map(|x| x.3).collect();
            (p.meta.textile.clone(), embs)
        })
        .collect();
    let index = FlatIndex::from_embeddings(&rows).unwrap();
    for p in &presses {
        let outcome = |encode_run: bool| {
            let mut pl =
                Pipeline::new(encoder(), index.clone(), PipelineConfig::default(), None).unwrap();
            pl.front_mut().set_encode_run(encode_run);
            pl.reset(recording_reference(p).as_deref());
            let mut first = None;
            for (i, f) in p.frames.iter().enumerate() {
                let frame = Frame::new(f.clone(), p.meta.timestamps_us[i], i as u64).unwrap();
                let o = pl.process(&frame, &mut Default::default()).unwrap();
                if let Some(s) = o.step.filter(|s| s.changed) {
                    first.get_or_insert((frame.timestamp_us(), s.decision.unwrap().entry));
                }
            }
            let end = *p.meta.timestamps_us.last().unwrap();
            (pl.finish(end).unwrap(), first.unwrap())
        };
        let (off, (t_off, e_off)) = outcome(false);
        let (on, (t_on, e_on)) = outcome(true);
        let n = ContactConfig::default().min_enter_frames - 1;
        // The same press, two more frames in its mean, decided no later
        // and (on these clean presses) the same way.
        assert_eq!(on.start_us, off.start_us);
        assert_eq!(on.frames, off.frames + n, "{}", p.meta.textile);
        assert!(t_on <= t_off, "{t_on} > {t_off}");
        assert_eq!(e_on, e_off);
        assert_eq!(index.id(e_on), p.meta.textile);
    }
}
