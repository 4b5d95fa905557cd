//! Pairing messages from a peer, decoded with bincode and fed to the state
//! machine: never panic, and random input never completes a pairing.
use std::sync::OnceLock;

use rand::{rngs::StdRng, SeedableRng};
use telextiles_certs::{
    Identity, PairingCode, PairingMessage, PairingRole, PairingSession, PairingStep,
};

fn ids() -> &'static (Identity, Identity) {
    static IDS: OnceLock<(Identity, Identity)> = OnceLock::new();
    IDS.get_or_init(|| (Identity::generate().unwrap(), Identity::generate().unwrap()))
}

/// The target body: must not panic for any input.
pub fn run(data: &[u8]) {
    let Some((&first, mut rest)) = data.split_first() else {
        return;
    };
    let role = if first & 1 == 0 {
        PairingRole::ShowsCode
    } else {
        PairingRole::EntersCode
    };
    let (me, peer) = ids();
    let mut rng = StdRng::seed_from_u64(u64::from(first));
    let code = PairingCode::generate(&mut rng);
    let (mut session, _) =
        PairingSession::start(role, code, &me.peer_key(), &peer.peer_key(), &mut rng).unwrap();
    let cfg = bincode::config::standard().with_limit::<4096>();
    while !rest.is_empty() {
        let Ok((msg, used)) = bincode::serde::decode_from_slice::<PairingMessage, _>(rest, cfg)
        else {
            return;
        };
        rest = &rest[used.max(1).min(rest.len())..];
        if let Ok(PairingStep::Paired(_)) = session.handle(&msg) {
            panic!("random input completed a pairing");
        }
    }
}
