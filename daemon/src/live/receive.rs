//! The receiver task: link events → the receiver core (per-peer presses and
//! decisions, no I/O) → roller targets, control events, map touches.

use std::sync::Arc;

use telextiles_control::Event;
use telextiles_link::{now_us, LinkEvent};
use telextiles_roller::Target;
use telextiles_session::{RxAction, RxInput};

use super::{lock, say, ConnectedPeer, Counters, Receiver, RelayState, State};

/// One link event; the receiver core's actions are carried out here.
pub(crate) fn on_link_event(state: &Arc<State>, rx: &mut Receiver, ev: LinkEvent) {
    let mut actions = Vec::new();
    match ev {
        LinkEvent::Listening { addr } => say(&format!("Listening on {addr} (UDP/QUIC)")),
        LinkEvent::Discovered {
            peer,
            addrs,
            paired,
            pairing,
        } => {
            if pairing && !paired && *lock(&state.pairing_pending) {
                say(&format!(
                    "Found a device showing a pairing code: {} at {addrs:?}",
                    peer.short()
                ));
            } else if paired {
                say(&format!(
                    "Found paired device {} at {addrs:?}",
                    peer.short()
                ));
            }
        }
        LinkEvent::Paired { peer, verification } => {
            *lock(&state.pairing_pending) = false;
            say(&format!("Paired with {peer}."));
            say(&format!(
                "Verification code: {verification}  — the other device shows the same code; if not, run `telextilesd unpair {}`.",
                peer.short()
            ));
            state.pins.insert(peer);
        }
        LinkEvent::PeerUp { peer, name, addr } => {
            // A new connection is a new session with that peer (its capture
            // clock may have restarted with its process): forget its presses.
            rx.handle(&peer.to_string(), RxInput::PeerDown, &mut actions);
            say(&format!(
                "Peer up: {name} ({}) at {addr} — live session running (Ctrl-C to stop)",
                peer.short()
            ));
            lock(&state.peers).insert(
                peer.to_string(),
                ConnectedPeer {
                    id: peer.to_string(),
                    name: name.clone(),
                    addr: addr.to_string(),
                    path: addr.kind().to_string(),
                    rtt_ms: None,
                    path_since: unix_now(),
                },
            );
            let _ = state.events.send(Event::PeerUp {
                peer: name,
                addr: Some(addr.to_string()),
            });
        }
        LinkEvent::PathChanged { peer, route, rtt } => {
            let rtt_ms = rtt.as_secs_f64() * 1e3;
            say(&format!(
                "Path to {}: {} ({}, round trip {rtt_ms:.1} ms)",
                peer.short(),
                route.kind(),
                route
            ));
            let name = if let Some(p) = lock(&state.peers).get_mut(&peer.to_string()) {
                if p.path != route.kind() {
                    p.path_since = unix_now();
                }
                p.addr = route.to_string();
                p.path = route.kind().to_string();
                p.rtt_ms = Some(rtt_ms);
                p.name.clone()
            } else {
                peer.to_string()
            };
            let _ = state.events.send(Event::PeerPath {
                peer: name,
                path: route.kind().to_string(),
                addr: route.to_string(),
                rtt_ms,
            });
        }
        LinkEvent::Relay {
            url,
            connected,
            error,
        } => {
            say(&telextiles_link::relay_status_line(
                &url,
                connected,
                error.as_deref(),
            ));
            let mut relays = lock(&state.relays);
            let since = match relays.get(&url) {
                Some(r) if r.connected == connected => r.since,
                _ => unix_now(),
            };
            relays.insert(
                url.clone(),
                RelayState {
                    url,
                    connected,
                    error,
                    since,
                },
            );
        }
        LinkEvent::PeerDown { peer, reason } => {
            say(&format!(
                "Peer down: {} ({}); reconnecting when it is back",
                peer.short(),
                reason.clone()
            ));
            rx.handle(&peer.to_string(), RxInput::PeerDown, &mut actions);
            let name = lock(&state.peers)
                .remove(&peer.to_string())
                .map(|p| p.name)
                .unwrap_or_else(|| peer.to_string());
            let _ = state.events.send(Event::PeerDown {
                peer: name,
                reason: reason.clone(),
            });
        }
        LinkEvent::Error { kind, message, .. } => {
            eprintln!("error: {message}");
            // `PairingAttempt`: one device failed to prove the code;
            // pairing goes on with the others (until the deadline).
            if kind == telextiles_link::ErrorKind::Pairing && *lock(&state.pairing_pending) {
                *lock(&state.fatal) = Some("pairing failed".into());
                let _ = state.shutdown.send(true);
            }
            if let telextiles_link::ErrorKind::Incompatible(_) = kind {
                eprintln!("(no streaming with this peer until both devices have the same encoder and index)");
            }
            let _ = state.events.send(Event::Error {
                source: "link".into(),
                message,
            });
        }
        LinkEvent::Control { peer, msg } => {
            rx.on_control(&peer.to_string(), &msg, &mut actions);
            apply(state, rx, &mut actions);
        }
        LinkEvent::Latent(l) => {
            let handled_us = now_us();
            Counters::bump(&state.counters.latents_received);
            rx.handle(
                &l.peer.to_string(),
                RxInput::Latent {
                    press_id: l.press_id,
                    seq: l.seq,
                    capture_us: l.capture_us,
                    vector: &l.vector,
                    one_way_latency_us: l.one_way_latency_us,
                },
                &mut actions,
            );
            let commanded = apply(state, rx, &mut actions);
            if let Some(t) = &state.trace {
                t.rx(
                    l.seq,
                    l.press_id,
                    [l.received_us, handled_us, now_us()],
                    commanded,
                );
            }
        }
    }
    apply(state, rx, &mut actions);
}

/// Carry out the receiver core's actions; the roller slot commanded, if
/// any.
fn apply(state: &Arc<State>, rx: &Receiver, actions: &mut Vec<RxAction>) -> Option<usize> {
    let mut commanded = None;
    for a in actions.drain(..) {
        match a {
            RxAction::PressStarted { .. } => {
                Counters::bump(&state.counters.presses_received);
            }
            RxAction::RollerTarget { slot } => {
                if let Some(r) = &state.roller {
                    r.set_target(Target::Slot(slot as u16));
                    lock(&state.felt).target(slot, now_us());
                }
                commanded = Some(slot);
            }
            RxAction::Touch { peer, latent } => {
                if let Some(tx) = &state.map_tx {
                    let _ = tx.send(telextiles_map::MapEvent::Touch {
                        latent: latent.as_slice().to_vec(),
                        peer: Some(super::peer_name(state, &peer)),
                    });
                }
            }
            RxAction::Decision(d) => {
                Counters::bump(&state.counters.decisions);
                // The press's contact on the local clock (known once the
                // link has a clock-offset estimate): felt latency runs
                // from there to the wheel at rest at the final sample.
                if let (true, Some(since), Some(_)) =
                    (d.final_decision, d.since_contact_ms, &state.roller)
                {
                    let contact_us = now_us().saturating_sub((since * 1000.0) as u64);
                    let felt =
                        lock(&state.felt).final_decision(&d.peer, d.press_id, contact_us, d.slot);
                    if let Some(f) = felt {
                        super::roller::felt_event(state, f);
                    }
                }
                let e = &rx.index().entries[d.entry];
                let _ = state.events.send(Event::Decision {
                    textile: e.id.clone(),
                    name: Some(e.name.clone()),
                    slot: d.slot as u32,
                    distance: d.distance,
                    unknown: d.unknown,
                    latency_ms: d.latency_ms.unwrap_or(0.0),
                    peer: Some(d.peer),
                    press: Some(d.press_id),
                    final_decision: d.final_decision,
                    since_contact_ms: d.since_contact_ms,
                });
            }
            RxAction::Refused { peer, why } => {
                // Counted always, logged at the 1st, 2nd, 4th, 8th, ...
                // refusal: a peer cannot flood the log.
                let n = Counters::bump(&state.counters.refused);
                if n.is_power_of_two() {
                    eprintln!(
                        "refused a message from {} ({n} refused so far): {why}",
                        super::peer_name(state, &peer)
                    );
                }
            }
        }
    }
    commanded
}

/// Seconds since the Unix epoch now.
pub(super) fn unix_now() -> u64 {
    telextiles_certs::trust::unix_seconds(std::time::SystemTime::now())
}
