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

/// An L2-normalised, finite embedding of a known dimension. The only way to
/// make one is [`Latent::new`], which checks all three.
#[derive(Clone, Debug, PartialEq)]
pub struct Latent(Box<[f32]>);

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
        Ok(Latent(out))
    }

    /// The values (unit length).
    pub fn as_slice(&self) -> &[f32] {
        &self.0
    }

    /// Its dimension.
    pub fn dim(&self) -> usize {
        self.0.len()
    }

    /// The mean direction of several latents (None when there are none or
    /// they cancel out).
    pub fn mean<'a>(latents: impl IntoIterator<Item = &'a Latent>) -> Option<Latent> {
        let mut it = latents.into_iter();
        let first = it.next()?;
        let mut sum: Vec<f64> = first.0.iter().map(|&x| x as f64).collect();
        for l in it {
            if l.dim() != sum.len() {
                return None;
            }
            for (s, &x) in sum.iter_mut().zip(l.0.iter()) {
                *s += x as f64;
            }
        }
        let v: Vec<f32> = sum.iter().map(|&x| x as f32).collect();
        Latent::new(&v, v.len()).ok()
    }
}

impl AsRef<[f32]> for Latent {
    fn as_ref(&self) -> &[f32] {
        &self.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
