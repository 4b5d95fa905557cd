//! [`Latent`]: an embedding valid by construction.

/// Why a vector is not a latent.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum LatentError {
    /// Not the dimension the peers agreed on.
    #[error("latent of dimension {got}, expected {want}")]
    Dimension {
        /// Received.
        got: usize,
        /// Agreed.
        want: usize,
    },
    /// NaN or infinity in it.
    #[error("latent with non-finite values")]
    NonFinite,
    /// All zeros (no direction).
    #[error("latent of zero length")]
    Zero,
}

/// An L2-normalised, finite embedding of a known dimension, with its weight
/// in a press's running mean. The only way to make one is [`Latent::new`],
/// which checks all three.
///
/// On the wire a latent is its direction times its weight
/// ([`Latent::wire`]): the sender weights each frame by its contact depth
/// ([`crate::decide::contact_weight`], in (0, 1]) and the
/// receiver reads the length back as the weight, clamped to
/// [[`MIN_WEIGHT`], 1]. A sender that sends unit vectors gives every frame
/// weight 1, as before.
#[derive(Clone, Debug, PartialEq)]
pub struct Latent {
    v: Box<[f32]>,
    weight: f32,
}

/// The smallest weight a latent carries.
pub const MIN_WEIGHT: f32 = 1e-3;

fn clamp_weight(w: f64) -> f32 {
    if w.is_finite() {
        (w as f32).clamp(MIN_WEIGHT, 1.0)
    } else {
        1.0
    }
}

impl Latent {
    /// Check `v` (dimension `dim`, finite, not zero) and normalise it to
    /// unit length.
    pub fn new(v: &[f32], dim: usize) -> Result<Latent, LatentError> {
        if v.len() != dim {
            return Err(LatentError::Dimension {
                got: v.len(),
                want: dim,
            });
        }
        if v.iter().any(|x| !x.is_finite()) {
            return Err(LatentError::NonFinite);
        }
        // In f64: a finite f32 vector's squared norm cannot overflow.
        let n = v
            .iter()
            .map(|&x| (x as f64) * (x as f64))
            .sum::<f64>()
            .sqrt();
        if n.is_nan() || n <= 0.0 {
            return Err(LatentError::Zero);
        }
        let out: Box<[f32]> = v.iter().map(|&x| (x as f64 / n) as f32).collect();
        if out.iter().any(|x| !x.is_finite()) || out.iter().all(|x| *x == 0.0) {
            return Err(LatentError::Zero);
        }
        Ok(Latent {
            v: out,
            weight: clamp_weight(n),
        })
    }

    /// The same direction with weight `w` (clamped to [[`MIN_WEIGHT`], 1];
    /// not finite: 1).
    pub fn with_weight(mut self, w: f32) -> Latent {
        self.weight = clamp_weight(w as f64);
        self
    }

    /// The values (unit length).
    pub fn as_slice(&self) -> &[f32] {
        &self.v
    }

    /// Its weight in a press's running mean, in [[`MIN_WEIGHT`], 1].
    pub fn weight(&self) -> f32 {
        self.weight
    }

    /// What goes on the wire: the direction times the weight.
    pub fn wire(&self) -> Vec<f32> {
        self.v.iter().map(|x| x * self.weight).collect()
    }

    /// Its dimension.
    pub fn dim(&self) -> usize {
        self.v.len()
    }

    /// The mean direction of several latents (None when there are none or
    /// they cancel out).
    pub fn mean<'a>(latents: impl IntoIterator<Item = &'a Latent>) -> Option<Latent> {
        let mut it = latents.into_iter();
        let first = it.next()?;
        let mut sum: Vec<f64> = first.v.iter().map(|&x| x as f64).collect();
        for l in it {
            if l.dim() != sum.len() {
                return None;
            }
            for (s, &x) in sum.iter_mut().zip(l.v.iter()) {
                *s += x as f64;
            }
        }
        let v: Vec<f32> = sum.iter().map(|&x| x as f32).collect();
        Latent::new(&v, v.len()).ok().map(|l| l.with_weight(1.0))
    }
}

impl AsRef<[f32]> for Latent {
    fn as_ref(&self) -> &[f32] {
        &self.v
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_length_sent_is_the_weight_within_bounds() {
        let l = Latent::new(&[0.0, 0.25], 2).unwrap();
        assert_eq!((l.as_slice(), l.weight()), (&[0.0, 1.0][..], 0.25));
        assert_eq!(l.wire(), vec![0.0, 0.25]);
        // A unit vector (what senders without weights send) weighs 1; long
        // and tiny vectors are clamped; a weight round-trips through the
        // wire.
        assert_eq!(Latent::new(&[0.6, 0.8], 2).unwrap().weight(), 1.0);
        assert_eq!(Latent::new(&[3.0, 4.0], 2).unwrap().weight(), 1.0);
        assert_eq!(Latent::new(&[f32::MAX, f32::MAX], 2).unwrap().weight(), 1.0);
        assert_eq!(
            Latent::new(&[f32::MIN_POSITIVE, 0.0], 2).unwrap().weight(),
            MIN_WEIGHT
        );
        let w = Latent::new(&[1.0, 1.0], 2).unwrap().with_weight(0.3);
        let back = Latent::new(&w.wire(), 2).unwrap();
        assert!((back.weight() - 0.3).abs() < 1e-6);
        assert_eq!(w.with_weight(f32::NAN).weight(), 1.0);
    }

    #[test]
    fn only_valid_vectors_become_latents_and_they_have_unit_length() {
        let l = Latent::new(&[3.0, 4.0], 2).unwrap();
        assert_eq!(l.as_slice(), &[0.6, 0.8]);
        assert_eq!(
            Latent::new(&[1.0; 3], 2),
            Err(LatentError::Dimension { got: 3, want: 2 })
        );
        assert_eq!(
            Latent::new(&[], 2),
            Err(LatentError::Dimension { got: 0, want: 2 })
        );
        assert_eq!(
            Latent::new(&[f32::NAN, 1.0], 2),
            Err(LatentError::NonFinite)
        );
        assert_eq!(
            Latent::new(&[f32::INFINITY, 1.0], 2),
            Err(LatentError::NonFinite)
        );
        assert_eq!(Latent::new(&[0.0, 0.0], 2), Err(LatentError::Zero));
        // Extremes of f32 neither overflow nor underflow to garbage.
        let big = Latent::new(&[f32::MAX, f32::MAX], 2).unwrap();
        assert!((big.as_slice()[0] - std::f32::consts::FRAC_1_SQRT_2).abs() < 1e-6);
        let tiny = Latent::new(&[f32::MIN_POSITIVE, 0.0], 2).unwrap();
        assert_eq!(tiny.as_slice(), &[1.0, 0.0]);
        let sub = Latent::new(&[1e-45, 0.0], 2).unwrap();
        assert_eq!(sub.as_slice(), &[1.0, 0.0]);
    }

    #[test]
    fn the_mean_of_latents_is_a_latent() {
        let a = Latent::new(&[1.0, 0.0], 2).unwrap();
        let b = Latent::new(&[0.0, 1.0], 2).unwrap();
        let m = Latent::mean([&a, &b]).unwrap();
        assert!((m.as_slice()[0] - m.as_slice()[1]).abs() < 1e-6);
        let c = Latent::new(&[-1.0, 0.0], 2).unwrap();
        assert_eq!(Latent::mean([&a, &c]), None);
        assert_eq!(Latent::mean(std::iter::empty()), None);
    }
}
