//! The roller: the driver is started with the index's slot count (index N
//! = roller N: an index built for 12 fabrics turns a 16-slot firmware to
//! twelfths), and its events go to the control bus.

use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use telextiles_control::Event;
use telextiles_proto::roller::steps_to_mdeg;
use telextiles_roller::{DriverConfig, RollerDriver, RollerEvent, Target};

use super::{lock, SessionOptions, State};
use crate::config::{Config, RollerSource};

/// A driver for the roller on `path` that sets the firmware to `slots`
/// slots (the index's count) whenever it connects.
pub(crate) fn driver(path: impl AsRef<std::path::Path>, slots: u16) -> DriverConfig {
    DriverConfig {
        slots: Some(slots),
        ..DriverConfig::path(path.as_ref())
    }
}

pub(crate) type SimRollerGuard = Option<telextiles_roller::SimRoller>;

pub(crate) fn start_roller(
    cfg: &Config,
    opts: &SessionOptions,
    slots: u16,
) -> Result<(Option<RollerDriver>, String, SimRollerGuard)> {
    let sim = |why: &str| -> Result<(Option<RollerDriver>, String, SimRollerGuard)> {
        let sim = telextiles_roller::SimRoller::spawn(telextiles_roller::SimConfig {
            speed: opts.sim_roller_speed.unwrap_or(1.0),
            ..Default::default()
        })
        .context("cannot start the simulated roller")?;
        let path = sim.path();
        let driver = RollerDriver::start(driver(&path, slots));
        Ok((
            Some(driver),
            format!("simulated roller on {}{why}", path.display()),
            Some(sim),
        ))
    };
    match &cfg.roller {
        RollerSource::None => Ok((None, "none".into(), None)),
        RollerSource::Sim => sim(""),
        RollerSource::Path(p) => Ok((
            Some(RollerDriver::start(driver(p, slots))),
            p.display().to_string(),
            None,
        )),
        RollerSource::Auto => match telextiles_roller::detect_port() {
            Ok(p) => Ok((Some(RollerDriver::start(driver(&p, slots))), p, None)),
            Err(e) => {
                eprintln!("{e}; using the simulated roller");
                sim(" (no roller found)")
            }
        },
    }
}

pub(crate) fn on_roller_event(state: &Arc<State>, ev: RollerEvent, last_pos: &mut Instant) {
    let deg = |mdeg: u32| mdeg as f64 / 1000.0;
    match ev {
        RollerEvent::Position {
            mdeg, slot, moving, ..
        } => {
            *lock(&state.roller_pos) = Some((mdeg, slot, moving));
            if last_pos.elapsed() >= Duration::from_millis(100) {
                *last_pos = Instant::now();
                let _ = state.events.send(Event::RollerPosition {
                    angle_deg: deg(mdeg),
                    target_slot: slot.map(u32::from),
                });
            }
        }
        RollerEvent::Arrived { target, status } => {
            let steps_per_rev = state
                .roller
                .as_ref()
                .and_then(|r| r.state().version)
                .map_or(0, |v| v.steps_per_rev);
            let mdeg = steps_to_mdeg(status.position, steps_per_rev);
            let slot = match target {
                Target::Slot(s) => s as u32,
                _ => u32::MAX,
            };
            *lock(&state.roller_pos) =
                Some((mdeg, (slot != u32::MAX).then_some(slot as u16), false));
            if slot != u32::MAX {
                let felt = lock(&state.felt).arrived(slot as usize, telextiles_link::now_us());
                if let Some(f) = felt {
                    felt_event(state, f);
                }
            }
            let _ = state.events.send(Event::RollerArrived {
                slot,
                angle_deg: deg(mdeg),
            });
        }
        RollerEvent::Error { message } => {
            let _ = state.events.send(Event::Error {
                source: "roller".into(),
                message,
            });
        }
        RollerEvent::Disconnected { reason } => {
            let _ = state.events.send(Event::Error {
                source: "roller".into(),
                message: format!("disconnected: {reason}"),
            });
        }
        RollerEvent::Connected { .. } => {}
        RollerEvent::TargetWritten { target, at } => {
            if let Some(t) = &state.trace {
                let slot = match target {
                    Target::Slot(s) => Some(s),
                    _ => None,
                };
                t.serial(slot, at);
            }
        }
    }
}

/// A received press's wheel came to rest at its final sample.
pub(crate) fn felt_event(state: &Arc<State>, f: telextiles_session::felt::FeltEvent) {
    let _ = state.events.send(Event::Felt {
        peer: Some(super::peer_name(state, &f.peer)),
        press: f.press_id,
        slot: f.slot as u32,
        felt_ms: f.felt_ms,
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Index N = roller N: the driver sets the firmware (here the simulated
    /// roller on a real pty, 16 slots by default) to the index's slot count,
    /// so slot 3 of a 12-slot index is at 90 degrees, not 67.5.
    #[test]
    fn the_roller_is_set_to_the_index_slot_count() {
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap();
        rt.block_on(async {
            let sim = telextiles_roller::SimRoller::spawn(telextiles_roller::SimConfig {
                speed: 50.0,
                ..Default::default()
            })
            .unwrap();
            let r = RollerDriver::start(driver(sim.path(), 12));
            let mut events = r.subscribe();
            r.set_target(Target::Slot(3));
            let arrived = tokio::time::timeout(Duration::from_secs(20), async {
                loop {
                    if let Ok(RollerEvent::Arrived { status, .. }) = events.recv().await {
                        return status;
                    }
                }
            })
            .await
            .expect("the roller arrives");
            let v = r.state().version.expect("connected");
            assert_eq!(v.slots, 12);
            assert_eq!(steps_to_mdeg(arrived.position, v.steps_per_rev), 90_000);
            r.shutdown().await;
        });
    }
}
