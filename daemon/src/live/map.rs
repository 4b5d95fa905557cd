//! The map server of a live session.

use std::sync::Arc;

use anyhow::Result;
use telextiles_control::Event;
use telextiles_index::Index;
use tokio::sync::broadcast;

use super::State;
use crate::config::Config;

/// Serve the map until shutdown; control events are forwarded to it.
pub(crate) async fn spawn_map(
    cfg: &Config,
    index: Arc<Index>,
    tx: broadcast::Sender<telextiles_map::MapEvent>,
    events: &broadcast::Sender<Event>,
    state: &Arc<State>,
) -> Result<tokio::task::JoinHandle<()>> {
    let server = telextiles_map::MapServer::bind(
        cfg.map_bind,
        index,
        telextiles_map::TextureSource::Simulated,
        &tx,
    )
    .await?;
    println!("map: http://{}/", server.local_addr());
    let mut sub = events.subscribe();
    let forward = tokio::spawn(async move {
        loop {
            match sub.recv().await {
                Ok(ev) => {
                    if let Ok(m) = telextiles_map::MapEvent::from_control_json(&ev.to_line()) {
                        let _ = tx.send(m);
                    }
                }
                Err(broadcast::error::RecvError::Lagged(_)) => continue,
                Err(broadcast::error::RecvError::Closed) => break,
            }
        }
    });
    let mut sd = state.shutdown.subscribe();
    Ok(tokio::spawn(async move {
        let stop = async move {
            let _ = sd.wait_for(|v| *v).await;
        };
        if let Err(e) = server.serve_until(stop).await {
            eprintln!("map server: {e}");
        }
        forward.abort();
    }))
}
