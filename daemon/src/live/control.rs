//! The control socket's handler: status, peers, unpair, sensor, roller
//! and index commands (`docs/control-protocol.md`).

use std::sync::Arc;

use serde_json::{json, Value};
use telextiles_certs::TrustStore;
use telextiles_control::{Command, CtlError, GotoTarget, Handler, HandlerFuture};
use telextiles_roller::{RollerDriver, Target};
#[cfg(feature = "sim")]
use telextiles_sensing::source::sim::SimCommand;

use super::sensing::SensorCmd;
use super::{lock, Counters, State};

pub(crate) struct Daemon(pub(crate) Arc<State>);

impl Daemon {
    fn status(&self) -> Value {
        let s = &self.0;
        let c = &s.counters;
        let n = Counters::get;
        let link = s.link.stats();
        let roller = s.roller.as_ref().map(|r| {
            let st = r.state();
            json!({
                "port": st.port, "connected": st.connected,
                "position": lock(&s.roller_pos).map(|(mdeg, slot, moving)| json!({"angle_deg": mdeg as f64 / 1000.0, "slot": slot, "moving": moving})),
                "moving": st.status.map(|x| x.moving()),
                "target": st.target.map(|t| format!("{t:?}")),
                "reconnects": st.reconnects,
            })
        });
        json!({
            "name": s.name,
            "device_id": s.device_id,
            "version": env!("CARGO_PKG_VERSION"),
            "uptime_s": s.started.elapsed().as_secs_f64(),
            "listen": s.link.local_addr().to_string(),
            "sensor": {"source": s.sensor_desc, "in_contact": s.in_contact.load(std::sync::atomic::Ordering::Relaxed)},
            "roller": {"source": s.roller_desc, "state": roller},
            "peers": lock(&s.peers).values().cloned().collect::<Vec<_>>(),
            "relays": lock(&s.relays).values().cloned().collect::<Vec<_>>(),
            "model": {"path": s.model.path, "sha256": s.model.sha256, "arch": s.model.arch, "dim": s.model.dim},
            "index": {"fingerprint": s.index.fingerprint(), "textiles": s.index.entries.len(), "slots": s.index.roller.n()},
            "counters": {
                "frames": n(&c.frames), "bad_frames": n(&c.bad_frames), "recordings_skipped": n(&c.recordings_skipped),
                "presses_sent": n(&c.presses_sent), "latents_sent": n(&c.latents_sent),
                "presses_received": n(&c.presses_received), "latents_received": n(&c.latents_received),
                "decisions": n(&c.decisions), "refused": n(&c.refused),
                "bad_datagrams": link.bad_datagrams, "latents_dropped": link.latents_dropped,
            },
        })
    }

    fn roller(&self) -> Result<&RollerDriver, CtlError> {
        self.0
            .roller
            .as_ref()
            .ok_or_else(|| CtlError::unavailable("this daemon drives no roller (roller = none)"))
    }

    /// `sensor.sim`: press the simulated DIGIT once, or lift it.
    #[cfg(feature = "sim")]
    fn press_simulated(
        &self,
        sim: &super::sensing::Simulated,
        a: telextiles_control::SimPressArgs,
    ) -> Result<Value, CtlError> {
        let s = &self.0;
        if a.textile == "none" {
            s.sensor_tx
                .send(SensorCmd::Sim(SimCommand::Lift))
                .map_err(|_| CtlError::unavailable("the sensor has stopped"))?;
            return Ok(json!({"lifted": true}));
        }
        if telextiles_sim::catalogue::Catalogue::builtin()
            .get(&a.textile)
            .is_none()
        {
            return Err(CtlError::invalid_args(format!(
                "unknown textile {:?}: the simulator knows T001..T119 and U01..U20",
                a.textile
            )));
        }
        let mut spec = telextiles_sim::PressSpec::new(a.textile.clone(), a.seed.unwrap_or(1));
        spec.jig = a.jig.unwrap_or(true);
        spec.person = a.person.unwrap_or(0);
        spec.sensor = a.sensor.unwrap_or(0);
        spec.rotation_deg = a.rotation_deg.map(|v| v as f32);
        spec.force = a.force.map(|v| v as f32);
        sim.simulator
            .press_meta(&spec)
            .map_err(|e| CtlError::invalid_args(e.to_string()))?;
        s.sensor_tx
            .send(SensorCmd::Sim(SimCommand::PressOnce(spec.clone())))
            .map_err(|_| CtlError::unavailable("the sensor has stopped"))?;
        Ok(json!({
            "pressing": spec.textile, "person": spec.person, "sensor": spec.sensor,
            "jig": spec.jig, "seed": spec.seed,
        }))
    }

    #[cfg(not(feature = "sim"))]
    fn press_simulated(
        &self,
        sim: &super::sensing::Simulated,
        _a: telextiles_control::SimPressArgs,
    ) -> Result<Value, CtlError> {
        match *sim {}
    }
}

impl Handler for Daemon {
    fn handle(&self, command: Command) -> HandlerFuture<'_> {
        Box::pin(async move {
            let s = &self.0;
            match command {
                Command::Status => Ok(self.status()),
                Command::Peers => {
                    let store = TrustStore::load(&s.state_dir)
                        .map_err(|e| CtlError::failed(e.to_string()))?;
                    let connected: std::collections::BTreeSet<String> =
                        lock(&s.peers).keys().cloned().collect();
                    Ok(Value::Array(
                        store
                            .peers()
                            .iter()
                            .map(|p| {
                                let id = p.device_id.to_string();
                                json!({"id": id, "name": p.name, "connected": connected.contains(&id)})
                            })
                            .collect(),
                    ))
                }
                Command::Pair(_) => Err(CtlError::unavailable(
                    "pairing runs from the command line: `telextilesd pair` on both devices",
                )),
                Command::Unpair(a) => {
                    let removed = TrustStore::update(&s.state_dir, |st| match st.find(&a.peer) {
                        Ok(p) => {
                            let id = p.device_id;
                            (true, Ok(st.remove(&id)))
                        }
                        Err(e) => (false, Err(e)),
                    })
                    .map_err(|e| CtlError::failed(e.to_string()))?
                    .map_err(|e| CtlError::invalid_args(e.to_string()))?
                    .ok_or_else(|| {
                        CtlError::invalid_args(format!("no paired peer {:?}", a.peer))
                    })?;
                    // Drops the pin and closes the live connection at once.
                    s.link.unpair(&removed.device_id);
                    Ok(json!({"unpaired": removed.device_id.to_string(), "name": removed.name}))
                }
                Command::SensorRecalibrate => {
                    s.sensor_tx
                        .send(SensorCmd::Recapture)
                        .map_err(|_| CtlError::unavailable("the sensor has stopped"))?;
                    Ok(json!({"recalibrating": true}))
                }
                Command::SensorLed(l) => {
                    let (tx, rx) = tokio::sync::oneshot::channel();
                    s.sensor_tx
                        .send(SensorCmd::Led {
                            r: l.r,
                            g: l.g,
                            b: l.b,
                            reply: tx,
                        })
                        .map_err(|_| CtlError::unavailable("the sensor has stopped"))?;
                    match tokio::time::timeout(std::time::Duration::from_secs(2), rx).await {
                        Ok(Ok(Ok(()))) => Ok(json!({"led": {"r": l.r, "g": l.g, "b": l.b}})),
                        Ok(Ok(Err(why))) => Err(CtlError::unavailable(why)),
                        _ => Err(CtlError::unavailable(
                            "the sensor did not answer (is it stuck reading a frame?)",
                        )),
                    }
                }
                Command::SensorSim(a) => {
                    let Some(sim) = &s.sim else {
                        return Err(CtlError::unavailable(format!(
                            "the sensor is not simulated ({})",
                            s.sensor_desc
                        )));
                    };
                    self.press_simulated(sim, a)
                }
                Command::RollerGoto(t) => {
                    let r = self.roller()?;
                    let slot = match t {
                        GotoTarget::Slot(n) if (n as usize) < s.index.roller.n() => n as usize,
                        GotoTarget::Slot(n) => {
                            return Err(CtlError::invalid_args(format!(
                                "slot {n} is out of range (the roller has {} slots)",
                                s.index.roller.n()
                            )))
                        }
                        GotoTarget::Textile(id) => {
                            let e = s.index.entry_by_id(&id).ok_or_else(|| {
                                CtlError::invalid_args(format!(
                                    "textile {id:?} is not in the index"
                                ))
                            })?;
                            s.index.slot_of_entry(e)
                        }
                    };
                    r.set_target(Target::Slot(slot as u16));
                    Ok(json!({"slot": slot}))
                }
                Command::RollerHome => {
                    self.roller()?.set_target(Target::Slot(0));
                    Ok(json!({"slot": 0}))
                }
                Command::RollerJog(j) => {
                    let r = self.roller()?;
                    let now = lock(&s.roller_pos).map(|p| p.0 as i64).unwrap_or(0);
                    let to = (now + (j.degrees * 1000.0).round() as i64).rem_euclid(360_000);
                    r.set_target(Target::AngleMdeg(to as u32));
                    Ok(json!({"angle_deg": to as f64 / 1000.0}))
                }
                Command::IndexInfo => Ok(json!({
                    "fingerprint": s.index.fingerprint(),
                    "encoder": s.index.encoder_hash,
                    "arch": s.index.encoder_arch,
                    "dim": s.index.dim,
                    "textiles": s.index.entries.len(),
                    "roller": s.index.roller.slots.iter().map(|&i| &s.index.entries[i].id).collect::<Vec<_>>(),
                    "selection": s.index.roller.method.to_string(),
                })),
                Command::Shutdown => {
                    let _ = s.shutdown.send(true);
                    Ok(json!({"shutting_down": true}))
                }
                Command::Subscribe(_) => {
                    Err(CtlError::internal("subscribe is handled by the server"))
                }
                Command::RecordStart(a) => {
                    use super::recording::{label_from_description, LiveRecording, RecordCtl};
                    let (source, serial) = label_from_description(&s.sensor_desc);
                    let (rec, reply) = LiveRecording::start(&a, source, serial, s.sensor_profile)
                        .map_err(|e| CtlError::failed(format!("{e:#}")))?;
                    s.sensor_tx
                        .send(SensorCmd::Record(RecordCtl::Start(Box::new(rec))))
                        .map_err(|_| CtlError::unavailable("the sensor has stopped"))?;
                    Ok(reply)
                }
                Command::RecordStop => {
                    let (tx, rx) = tokio::sync::oneshot::channel();
                    s.sensor_tx
                        .send(SensorCmd::Record(super::recording::RecordCtl::Stop(tx)))
                        .map_err(|_| CtlError::unavailable("the sensor has stopped"))?;
                    // Stopping waits for the presses already complete to be written.
                    match tokio::time::timeout(std::time::Duration::from_secs(30), rx).await {
                        Ok(Ok(Some(saved))) => Ok(json!({"stopped": true, "saved": saved})),
                        Ok(Ok(None)) => Ok(json!({"stopped": false})),
                        _ => Err(CtlError::unavailable(
                            "the sensor did not answer (is it stuck reading a frame?)",
                        )),
                    }
                }
            }
        })
    }
}
