//! Human-friendly rendering of replies and events for `telextilesd ctl`
//! (pure functions; `--json` prints the raw lines instead).

use crate::protocol::{ContactPhase, CtlError, Event, RecordPhase};
use serde_json::Value;
use std::fmt::Write;

/// Renders reply data as indented `key: value` lines. Scalars print bare,
/// `null` prints as `-`, arrays of scalars as a comma list, arrays of
/// objects as `- ` items.
pub fn human_value(v: &Value) -> String {
    let mut out = String::new();
    match v {
        Value::Object(_) | Value::Array(_) => write_block(&mut out, v, 0),
        other => {
            out.push_str(&scalar(other));
            out.push('\n');
        }
    }
    out
}

fn scalar(v: &Value) -> String {
    match v {
        Value::Null => "-".into(),
        Value::Bool(b) => if *b { "yes" } else { "no" }.into(),
        Value::Number(n) => n.to_string(),
        Value::String(s) => s.clone(),
        Value::Array(a) if a.is_empty() => "(none)".into(),
        Value::Object(o) if o.is_empty() => "(none)".into(),
        other => other.to_string(),
    }
}

fn is_flat(v: &Value) -> bool {
    match v {
        Value::Array(a) => a.iter().all(|x| !x.is_object() && !x.is_array()),
        Value::Object(o) => o.is_empty(),
        _ => true,
    }
}

fn flat(v: &Value) -> String {
    match v {
        Value::Array(a) if !a.is_empty() => a.iter().map(scalar).collect::<Vec<_>>().join(", "),
        other => scalar(other),
    }
}

fn write_block(out: &mut String, v: &Value, indent: usize) {
    let pad = "  ".repeat(indent);
    match v {
        Value::Object(o) => {
            if o.is_empty() {
                let _ = writeln!(out, "{pad}(none)");
            }
            for (k, x) in o {
                if is_flat(x) {
                    let _ = writeln!(out, "{pad}{k}: {}", flat(x));
                } else {
                    let _ = writeln!(out, "{pad}{k}:");
                    write_block(out, x, indent + 1);
                }
            }
        }
        Value::Array(a) => {
            if a.is_empty() {
                let _ = writeln!(out, "{pad}(none)");
            }
            for x in a {
                if is_flat(x) {
                    let _ = writeln!(out, "{pad}- {}", flat(x));
                } else {
                    let mut inner = String::new();
                    write_block(&mut inner, x, 0);
                    for (i, line) in inner.lines().enumerate() {
                        let lead = if i == 0 { "- " } else { "  " };
                        let _ = writeln!(out, "{pad}{lead}{line}");
                    }
                }
            }
        }
        other => {
            let _ = writeln!(out, "{pad}{}", scalar(other));
        }
    }
}

/// A press's coverage below which the line says it was partial: the
/// sensing pipeline's `PARTIAL_COVERAGE` (telextiles-sensing, which this
/// crate does not depend on; equal by a test in the daemon).
pub const PARTIAL_COVERAGE: f32 = 0.5;

/// One line for an event, e.g. `decision  T012 -> slot 3  distance 0.213  latency 41.5 ms`.
pub fn human_event(e: &Event) -> String {
    match e {
        Event::Contact {
            phase,
            score,
            coverage,
        } => {
            let what = match phase {
                ContactPhase::Start => "start",
                ContactPhase::End => "end",
            };
            let mut line = match score {
                Some(s) => format!("contact   {what} (score {s:.3})"),
                None => format!("contact   {what}"),
            };
            if let Some(c) = coverage {
                line += &format!("  touched {:.0} % of the gel", 100.0 * c);
                if *c < PARTIAL_COVERAGE {
                    line += " (partial contact: hold the sensor flat)";
                }
            }
            line
        }
        Event::Decision {
            textile,
            name,
            slot,
            distance,
            unknown,
            latency_ms,
            peer,
            press,
            final_decision,
            since_contact_ms,
        } => {
            let mut s = format!(
                "{}  {textile}",
                if *final_decision {
                    "final   "
                } else {
                    "decision"
                }
            );
            if let Some(n) = name {
                let _ = write!(s, " ({n})");
            }
            let _ = write!(
                s,
                " -> slot {slot}  distance {distance:.3}  latency {latency_ms:.1} ms"
            );
            if let Some(p) = peer {
                let _ = write!(s, "  from {p}");
            }
            if let Some(n) = press {
                let _ = write!(s, "  press {n}");
            }
            if let Some(t) = since_contact_ms {
                let _ = write!(s, "  {t:.0} ms after contact");
            }
            if *unknown {
                s.push_str("  (unknown textile: nearest known)");
            }
            s
        }
        Event::PeerUp { peer, addr } => match addr {
            Some(a) => format!("peer up   {peer} at {a}"),
            None => format!("peer up   {peer}"),
        },
        Event::PeerDown { peer, reason } => format!("peer down {peer}: {reason}"),
        Event::PeerPath {
            peer,
            path,
            addr,
            rtt_ms,
        } => format!("peer path {peer}: {path} ({addr}, round trip {rtt_ms:.1} ms)"),
        Event::RollerPosition {
            angle_deg,
            target_slot,
        } => match target_slot {
            Some(t) => format!("roller    at {angle_deg:.1} deg -> slot {t}"),
            None => format!("roller    at {angle_deg:.1} deg"),
        },
        Event::RollerArrived { slot, angle_deg } => {
            format!("roller    arrived at slot {slot} ({angle_deg:.1} deg)")
        }
        Event::Felt {
            peer,
            press,
            slot,
            felt_ms,
        } => format!(
            "felt      press {press}{} at rest at slot {slot} {felt_ms:.0} ms after contact",
            peer.as_deref()
                .map(|p| format!(" of {p}"))
                .unwrap_or_default()
        ),
        Event::Record {
            state,
            textile,
            press,
            presses,
            held_ms,
            score,
            reason,
        } => {
            let at = format!("record    {textile} {press}/{presses}:");
            let held = held_ms.map(|t| t / 1000.0).unwrap_or(0.0);
            match state {
                RecordPhase::Waiting => {
                    format!("{at} waiting for a no-contact reference: do not touch the sensor")
                }
                RecordPhase::Ready => format!("{at} press now"),
                RecordPhase::Contact => format!("{at} contact"),
                RecordPhase::Holding => match score {
                    Some(s) => format!("{at} holding {held:.1} s, contact {s:.1}"),
                    None => format!("{at} holding {held:.1} s"),
                },
                RecordPhase::Release => format!("{at} release"),
                RecordPhase::Released => match score {
                    Some(s) => format!("{at} released after {held:.1} s (peak contact {s:.1})"),
                    None => format!("{at} released after {held:.1} s"),
                },
                RecordPhase::Done => format!("record    {textile}: done, {presses} presses"),
                RecordPhase::Stopped => match reason {
                    Some(r) => {
                        format!("record    {textile}: stopped before press {press}/{presses}: {r}")
                    }
                    None => format!("record    {textile}: stopped before press {press}/{presses}"),
                },
            }
        }
        Event::RecordSaved {
            textile,
            press,
            presses,
            path,
            frames,
            duration_ms,
            peak,
            reference_frames,
            fps,
            warnings,
        } => {
            let mut s = format!(
                "record    {textile} saved press {press}/{presses}: {frames} frames, {:.1} s, peak contact {peak:.1} ({path}; reference {reference_frames} frames, {fps:.1} fps)",
                duration_ms / 1000.0
            );
            if !warnings.is_empty() {
                let _ = write!(s, " warnings: {}", warnings.join(", "));
            }
            s
        }
        Event::RecordWarning {
            textile,
            press,
            code: _,
            message,
            rejected,
        } => {
            if *rejected {
                format!("record    {textile} {press}: press not kept: {message}")
            } else {
                format!("record    {textile} {press}: warning: {message}")
            }
        }
        Event::Error { source, message } => format!("error     [{source}] {message}"),
        Event::Dropped { reason } => format!("dropped   by the daemon: {reason}"),
    }
}

/// `error [code]: message`, for stderr.
pub fn human_error(e: &CtlError) -> String {
    format!("error [{}]: {}", e.code, e.message)
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn values_render_as_key_value_lines() {
        let v = json!({
            "name": "studio",
            "running": true,
            "peer": null,
            "slots": [0, 5, 9],
            "roller": {"angle_deg": 22.5, "moving": false},
            "peers": [{"name": "alice", "up": true}, {"name": "bob", "up": false}],
            "empty": [],
        });
        let s = human_value(&v);
        let want = "\
name: studio
running: yes
peer: -
slots: 0, 5, 9
roller:
  angle_deg: 22.5
  moving: no
peers:
  - name: alice
    up: yes
  - name: bob
    up: no
empty: (none)
";
        // serde_json without preserve_order sorts keys; compare as sets of blocks.
        let mut got: Vec<&str> = s.lines().collect();
        let mut exp: Vec<&str> = want.lines().collect();
        got.sort_unstable();
        exp.sort_unstable();
        assert_eq!(got, exp, "\n{s}");
        assert_eq!(human_value(&json!("done")), "done\n");
        assert_eq!(human_value(&json!(null)), "-\n");
    }

    #[test]
    fn events_render_on_one_line() {
        let e = Event::Decision {
            textile: "T012".into(),
            name: Some("denim".into()),
            slot: 3,
            distance: 0.2134,
            unknown: false,
            latency_ms: 41.46,
            peer: Some("alice".into()),
            press: Some(7),
            final_decision: true,
            since_contact_ms: Some(350.0),
        };
        assert_eq!(
            human_event(&e),
            "final     T012 (denim) -> slot 3  distance 0.213  latency 41.5 ms  from alice  press 7  350 ms after contact"
        );
        let mut far = e.clone();
        if let Event::Decision { unknown, .. } = &mut far {
            *unknown = true;
        }
        assert!(human_event(&far).ends_with("after contact  (unknown textile: nearest known)"));
        let end = |coverage| Event::Contact {
            phase: ContactPhase::End,
            score: Some(0.21),
            coverage,
        };
        assert_eq!(human_event(&end(None)), "contact   end (score 0.210)");
        assert_eq!(
            human_event(&end(Some(0.82))),
            "contact   end (score 0.210)  touched 82 % of the gel"
        );
        assert_eq!(
            human_event(&end(Some(0.31))),
            "contact   end (score 0.210)  touched 31 % of the gel (partial contact: hold the sensor flat)"
        );
        assert_eq!(
            human_event(&Event::RollerArrived {
                slot: 5,
                angle_deg: 112.5
            }),
            "roller    arrived at slot 5 (112.5 deg)"
        );
        assert_eq!(
            human_event(&Event::Felt {
                peer: Some("a".into()),
                press: 3,
                slot: 5,
                felt_ms: 212.4
            }),
            "felt      press 3 of a at rest at slot 5 212 ms after contact"
        );
        assert_eq!(
            human_event(&Event::Dropped {
                reason: "slow".into()
            }),
            "dropped   by the daemon: slow"
        );
        assert_eq!(
            human_event(&Event::RecordSaved {
                textile: "T030".into(),
                press: 3,
                presses: 5,
                path: "rec/T030/0003".into(),
                frames: 142,
                duration_ms: 2366.7,
                peak: 5.06,
                reference_frames: 30,
                fps: 60.0,
                warnings: vec!["too_weak".into()],
            }),
            "record    T030 saved press 3/5: 142 frames, 2.4 s, peak contact 5.1 (rec/T030/0003; reference 30 frames, 60.0 fps) warnings: too_weak"
        );
        assert_eq!(
            human_event(&Event::Record {
                state: RecordPhase::Holding,
                textile: "T030".into(),
                press: 2,
                presses: 5,
                held_ms: Some(1234.0),
                score: Some(4.44),
                reason: None,
            }),
            "record    T030 2/5: holding 1.2 s, contact 4.4"
        );
        assert_eq!(
            human_event(&Event::RecordWarning {
                textile: "T030".into(),
                press: 2,
                code: "too_short".into(),
                message: "press too short".into(),
                rejected: true,
            }),
            "record    T030 2: press not kept: press too short"
        );
        assert_eq!(
            human_error(&CtlError::invalid_args("`roller.goto`: bad")),
            "error [invalid_args]: `roller.goto`: bad"
        );
    }
}
