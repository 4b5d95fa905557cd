//! Duplicate-connection resolution: two connections to the same peer (both
//! sides dialled at once, or a reconnect before the old connection's idle
//! timeout), and which one survives, decided on each side without talking.
//!
//! Rule: keep the connection dialled by the side with the smaller device ID;
//! if both (or neither) were, keep the newer. "Dialled by the smaller ID" is
//! a property of the connection that both sides compute alike
//! ([`dialed_by_lower`]), so with exactly one such connection both keep it
//! whatever order their handshakes finished in. When both connections have
//! the same dialer, each side keeps the one that came up last there; if the
//! two sides saw them in different orders each closes the one the other
//! kept, both end (close code `DUPLICATE`), and the dialer's loop dials
//! again: never two live connections, at worst one redial.

use telextiles_certs::DeviceId;

/// Which of two connections to one peer survives.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Keep {
    /// The one registered before; the new one is closed.
    Existing,
    /// The new one; the existing one is closed.
    New,
}

/// Whether a connection was dialled by the side with the smaller device ID,
/// seen from `me` (`dialed_here`: this side dialled it). Both ends of one
/// connection compute the same value.
pub fn dialed_by_lower(dialed_here: bool, me: &DeviceId, peer: &DeviceId) -> bool {
    dialed_here == (me < peer)
}

/// The connection that survives when a new one to the same peer comes up
/// while `existing` is registered (each flag: [`dialed_by_lower`]).
pub fn resolve(existing_by_lower: bool, new_by_lower: bool) -> Keep {
    if existing_by_lower && !new_by_lower {
        Keep::Existing
    } else {
        Keep::New
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::rngs::StdRng;
    use rand::seq::SliceRandom;
    use rand::{Rng, SeedableRng};
    use telextiles_certs::Identity;

    #[test]
    fn the_rule() {
        assert_eq!(resolve(true, false), Keep::Existing);
        assert_eq!(resolve(true, true), Keep::New);
        assert_eq!(resolve(false, true), Keep::New);
        assert_eq!(resolve(false, false), Keep::New);
    }

    /// Both ends of one connection agree on who dialled it.
    #[test]
    fn both_ends_compute_the_same_flag() {
        let (x, y) = (
            Identity::generate().unwrap().device_id(),
            Identity::generate().unwrap().device_id(),
        );
        for x_dialed in [false, true] {
            assert_eq!(
                dialed_by_lower(x_dialed, &x, &y),
                dialed_by_lower(!x_dialed, &y, &x)
            );
        }
        let lower = if x < y { x } else { y };
        let higher = if x < y { y } else { x };
        assert!(dialed_by_lower(true, &lower, &higher));
        assert!(!dialed_by_lower(true, &higher, &lower));
    }

    /// The survivor on one side, given the order its connections came up in
    /// (`true` = dialled by the lower ID).
    fn survivor(order: &[usize], by_lower: &[bool]) -> usize {
        let mut kept = order[0];
        for &c in &order[1..] {
            if resolve(by_lower[kept], by_lower[c]) == Keep::New {
                kept = c;
            }
        }
        kept
    }

    /// 2–4 connections to one peer coming up in independent random orders
    /// on the two sides: never two live connections (a connection lives if
    /// both keep it); with exactly one dialled by the lower ID both sides
    /// keep that one whatever the orders; otherwise they agree when their
    /// last-up candidate is the same one, and else both close (one redial).
    #[test]
    fn both_sides_agree_without_talking() {
        let mut rng = StdRng::seed_from_u64(9);
        let (mut agreed, mut redials) = (0, 0);
        for _ in 0..20_000 {
            let n = rng.gen_range(2..=4);
            let by_lower: Vec<bool> = (0..n).map(|_| rng.gen_bool(0.5)).collect();
            let mut ox: Vec<usize> = (0..n).collect();
            let mut oy = ox.clone();
            ox.shuffle(&mut rng);
            oy.shuffle(&mut rng);
            let (kx, ky) = (survivor(&ox, &by_lower), survivor(&oy, &by_lower));
            let lowers = by_lower.iter().filter(|b| **b).count();
            if lowers == 1 {
                assert_eq!(kx, ky, "{by_lower:?} {ox:?} {oy:?}");
                assert!(by_lower[kx]);
            }
            if kx == ky {
                agreed += 1;
            } else {
                redials += 1;
                // Each one's choice is a connection the other closed.
                let last = |o: &[usize]| {
                    *o.iter()
                        .rev()
                        .find(|&&c| by_lower[c] == (lowers > 0))
                        .unwrap()
                };
                assert_eq!(kx, last(&ox));
                assert_eq!(ky, last(&oy));
            }
        }
        assert!(agreed > redials, "{agreed} {redials}");
    }

    /// The usual race: both sides dial each other at once (the lower one
    /// from mDNS, the higher one from `--connect`): whichever handshake
    /// finishes first on either side, both keep the lower one's connection.
    #[test]
    fn crossing_dials_keep_the_lower_ones_connection() {
        let by_lower = [true, false];
        for ox in [[0, 1], [1, 0]] {
            for oy in [[0, 1], [1, 0]] {
                assert_eq!(survivor(&ox, &by_lower), 0);
                assert_eq!(survivor(&oy, &by_lower), 0);
            }
        }
        // A reconnect by the lower side before the old connection's idle
        // timeout: the new one replaces the old on both sides.
        assert_eq!(survivor(&[0, 1], &[true, true]), 1);
    }
}
