//! Stage 4: FFT circular cross-correlation of boundary signals (method step 4).
//!
//! The squared distance between a part's signal `a` shifted by `s` bins and a template's `b` is
//! `|a|^2 + |b|^2 - 2 (a * b)(s)`, so one forward and one inverse FFT give it for every shift at
//! once. Means are removed first: a different scale only adds a constant to log r.

use rustfft::num_complex::Complex;
use rustfft::{Fft, FftPlanner};
use std::sync::Arc;

/// A mean-removed signal in the frequency domain.
#[derive(Clone)]
pub struct Spectrum {
    /// Mean of the signal (log r), before removal: gives the scale.
    pub mean: f64,
    /// Sum of squares of the mean-removed signal.
    pub energy: f64,
    /// The FFT of the mean-removed signal.
    pub bins: Vec<Complex<f64>>,
}

impl std::fmt::Debug for Spectrum {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Spectrum({} bins)", self.bins.len())
    }
}

/// Harmonics a [`Key`] keeps: enough for a bound that tells most templates apart, cheap
/// enough to compare with every template of a catalogue (64 multiply-adds each).
pub const KEY_HARMONICS: usize = 64;

/// A signal's rotation- and face-free key: the magnitudes of its first harmonics. A rotation
/// shifts the signal (a phase per harmonic) and turning the part over mirrors it (conjugates the
/// harmonics of a real signal): neither changes a magnitude.
#[derive(Debug, Clone, PartialEq)]
pub struct Key(pub Vec<f64>);

impl Key {
    /// The key of `s`.
    pub fn of(s: &Spectrum) -> Self {
        Self(s.bins.iter().skip(1).take(KEY_HARMONICS).map(|c| c.norm()).collect())
    }

    /// A lower bound of [`Alignment::rms`] between the signals of `self` and `other`, whatever
    /// the shift: by Parseval, `n * sum |a_s - b|^2 = sum_k |A_k e^(i k s) - B_k|^2 >=
    /// sum_k (|A_k| - |B_k|)^2`, each harmonic `k < n/2` counted twice (`n - k` mirrors it), the
    /// harmonics the key leaves out counted as 0. So a template whose bound exceeds a distance
    /// cannot come nearer than it, and need not be correlated.
    pub fn bound(&self, other: &Key, n: usize) -> f64 {
        let sum: f64 = self.0.iter().zip(&other.0).map(|(a, b)| (a - b) * (a - b)).sum();
        (2.0 * sum).sqrt() / n as f64
    }
}

/// Result of correlating a part's signal with one template's.
#[derive(Debug, Clone, Copy)]
pub struct Alignment {
    /// Best circular shift in (fractional) bins: part(k + shift) ~ template(k).
    pub shift: f64,
    /// RMS difference of log r at the best shift (dimensionless: ~ relative radius error).
    pub rms: f64,
    /// Scale of the part relative to the template, from the log r means.
    pub scale: f64,
}

/// Plans once, correlates many times. Cheap to clone and safe to share between threads.
#[derive(Clone)]
pub struct Correlator {
    n: usize,
    fwd: Arc<dyn Fft<f64>>,
    inv: Arc<dyn Fft<f64>>,
}

impl std::fmt::Debug for Correlator {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Correlator({} bins)", self.n)
    }
}

impl Correlator {
    /// A correlator of signals of `n` bins.
    pub fn new(n: usize) -> Self {
        let mut planner = FftPlanner::new();
        Self { n, fwd: planner.plan_fft_forward(n), inv: planner.plan_fft_inverse(n) }
    }
    /// Bins of the signals it correlates.
    pub fn bins(&self) -> usize {
        self.n
    }

    /// The spectrum of a signal of [`Correlator::bins`] samples.
    pub fn spectrum(&self, signal: &[f64]) -> Spectrum {
        assert_eq!(signal.len(), self.n, "signal length must equal the correlator's bins");
        let mean = signal.iter().sum::<f64>() / self.n as f64;
        let mut bins: Vec<Complex<f64>> = signal.iter().map(|&v| Complex::new(v - mean, 0.0)).collect();
        let energy = bins.iter().map(|c| c.re * c.re).sum();
        self.fwd.process(&mut bins);
        Spectrum { mean, energy, bins }
    }

    /// Best alignment of `part` onto `template`, with parabolic sub-bin refinement of the peak.
    pub fn align(&self, part: &Spectrum, template: &Spectrum) -> Alignment {
        let n = self.n;
        let mut prod: Vec<Complex<f64>> = part.bins.iter().zip(&template.bins).map(|(a, b)| a * b.conj()).collect();
        self.inv.process(&mut prod);
        let nf = n as f64;
        // c(s) = sum_k a(k+s) b(k); rustfft's inverse is unnormalised.
        let d = |s: usize| (part.energy + template.energy - 2.0 * prod[s % n].re / nf).max(0.0) / nf;
        let (best, _) = (0..n).map(|s| (s, d(s))).fold((0, f64::INFINITY), |acc, (s, v)| if v < acc.1 { (s, v) } else { acc });
        let (dm, d0, dp) = (d(best + n - 1), d(best), d(best + 1));
        let den = dm - 2.0 * d0 + dp;
        let (delta, dmin) = if den > 0.0 {
            let delta = (0.5 * (dm - dp) / den).clamp(-0.5, 0.5);
            (delta, (d0 - 0.25 * (dm - dp) * delta).max(0.0))
        } else {
            (0.0, d0)
        };
        Alignment { shift: (best as f64 + delta).rem_euclid(nf), rms: dmin.sqrt(), scale: (part.mean - template.mean).exp() }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::TAU;

    fn smooth_signal(n: usize, shift_bins: f64) -> Vec<f64> {
        (0..n)
            .map(|k| {
                let a = (k as f64 - shift_bins) / n as f64 * TAU;
                4.0 + 0.3 * (2.0 * a).sin() + 0.2 * (3.0 * a + 0.7).cos() + 0.1 * (7.0 * a).sin()
            })
            .collect()
    }

    #[test]
    fn recovers_a_known_rotation_within_five_hundredths_of_a_degree() {
        let n = 1024;
        let c = Correlator::new(n);
        let t = c.spectrum(&smooth_signal(n, 0.0));
        for deg in [0.0, 0.37, 17.123, 123.456, 271.9, 359.97] {
            let shift = deg / 360.0 * n as f64;
            let a = c.align(&c.spectrum(&smooth_signal(n, shift)), &t);
            let got = a.shift * 360.0 / n as f64;
            let err = crate::vision::geometry::angle_diff_deg(got, deg);
            assert!(err.abs() < 0.05, "rotation {deg}: got {got} (error {err})");
            assert!(a.rms < 1e-3);
        }
    }

    #[test]
    fn the_key_bounds_the_distance_from_below_whatever_the_rotation_or_mirror() {
        let n = 1024;
        let c = Correlator::new(n);
        let other = |k: usize| {
            let a = k as f64 / n as f64 * TAU;
            4.0 + 0.25 * (2.0 * a).sin() + 0.3 * (3.0 * a + 0.2).cos() + 0.05 * (11.0 * a).sin()
        };
        let t = c.spectrum(&smooth_signal(n, 0.0));
        let u = c.spectrum(&(0..n).map(other).collect::<Vec<_>>());
        let (kt, ku) = (Key::of(&t), Key::of(&u));
        for deg in [0.0, 33.3, 181.0] {
            let shift = deg / 360.0 * n as f64;
            let s = smooth_signal(n, shift);
            let mirrored: Vec<f64> = (0..n).map(|k| s[(n - k) % n]).collect();
            for part in [c.spectrum(&s), c.spectrum(&mirrored)] {
                let kp = Key::of(&part);
                assert!(kp.bound(&kt, n) < 1e-9, "the same outline turned or mirrored has the same key");
                let (bound, rms) = (kp.bound(&ku, n), c.align(&part, &u).rms);
                assert!(bound > 0.05 && bound <= rms + 1e-9, "bound {bound} against the distance {rms}");
            }
        }
    }

    #[test]
    fn reads_scale_from_the_log_offset() {
        let n = 256;
        let c = Correlator::new(n);
        let s: Vec<f64> = smooth_signal(n, 0.0);
        let bigger: Vec<f64> = s.iter().map(|v| v + 1.2f64.ln()).collect();
        let a = c.align(&c.spectrum(&bigger), &c.spectrum(&s));
        assert!((a.scale - 1.2).abs() < 1e-9);
    }
}
