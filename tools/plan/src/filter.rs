//! The zero-phase low-pass filter of 000 Section 3.1: a second-order Butterworth low-pass run
//! forward and backward, with the edge handling of `scipy.signal.filtfilt`'s defaults so that a
//! result can be checked against SciPy number for number.
//!
//! Why these details matter: at the cut-offs 000 uses (millihertz, on 60 ms samples) the filter's
//! time constant is minutes, as long as the whole print. How the filter starts and ends — padding
//! and initial state — then shapes the base trajectory near the first and last points, where the
//! arm's reach is often largest. We copy SciPy's choices instead of inventing our own:
//!
//! - `butter(2, fc / (fs / 2))`: the analogue prototype, pre-warped, through the bilinear
//!   transform. For order 2 that is the closed form used in [`Butterworth2::lowpass`].
//! - `filtfilt(b, a, x)` with `padtype = "odd"`, `padlen = 3 · max(len(a), len(b)) = 9`: the signal
//!   is extended at each end by 9 samples mirrored through the end value (`2·x[0] − x[9..1]`), the
//!   forward pass starts from the steady state of a unit step (`lfilter_zi`) scaled by the first
//!   extended sample, the backward pass from the same steady state scaled by the forward pass's
//!   last output, and the padding is cut off again. A signal must be longer than 9 samples.

use strand_cli::error::{Result, ToolError};

/// Samples SciPy's `filtfilt` pads each end with for a second-order filter (3 · 3 taps).
pub(crate) const PAD: usize = 9;

/// A second-order IIR filter `b / a` with `a[0] = 1` (transposed direct form II, as `lfilter`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Butterworth2 {
    /// Numerator coefficients b0, b1, b2.
    pub b: [f64; 3],
    /// Denominator coefficients 1, a1, a2.
    pub a: [f64; 3],
}

impl Butterworth2 {
    /// The digital Butterworth low-pass of order 2 with −3 dB at `fc_hz`, sampled at `fs_hz`: SciPy's
    /// `butter(2, fc_hz / (fs_hz / 2))`. With K = tan(π·fc/fs) (the pre-warped cut-off):
    /// b = K²·(1, 2, 1)/D, a = (1, 2(K² − 1)/D, (1 − √2·K + K²)/D), D = 1 + √2·K + K².
    pub(crate) fn lowpass(fc_hz: f64, fs_hz: f64) -> Result<Self> {
        if !(fs_hz.is_finite() && fs_hz > 0.0) {
            return Err(ToolError::Usage(format!("sample rate {fs_hz} Hz must be positive")));
        }
        if !(fc_hz.is_finite() && fc_hz > 0.0 && fc_hz < fs_hz / 2.0) {
            return Err(ToolError::Usage(format!("cut-off {fc_hz} Hz must lie between 0 and the Nyquist frequency {} Hz", fs_hz / 2.0)));
        }
        let k = (std::f64::consts::PI * fc_hz / fs_hz).tan();
        let k2 = k * k;
        let r2 = std::f64::consts::SQRT_2;
        let d = 1.0 + r2 * k + k2;
        let b0 = k2 / d;
        Ok(Butterworth2 { b: [b0, 2.0 * b0, b0], a: [1.0, 2.0 * (k2 - 1.0) / d, (1.0 - r2 * k + k2) / d] })
    }

    /// The state (z0, z1) in which a constant input 1 gives a constant output `Σb / Σa` (SciPy's
    /// `lfilter_zi`): the solution of (I − Aᵀ)·z = b[1..] − a[1..]·b0.
    pub(crate) fn steady_state(&self) -> [f64; 2] {
        let [b0, b1, b2] = self.b;
        let [_, a1, a2] = self.a;
        let (c0, c1) = (b1 - a1 * b0, b2 - a2 * b0);
        let z0 = (c0 + c1) / (1.0 + a1 + a2);
        [z0, c1 - a2 * z0]
    }

    /// Filters `x` in place, starting from state `z` (SciPy's `lfilter(b, a, x, zi=z)`).
    pub(crate) fn run(&self, x: &mut [f64], mut z: [f64; 2]) {
        let [b0, b1, b2] = self.b;
        let [_, a1, a2] = self.a;
        for v in x.iter_mut() {
            let input = *v;
            let y = b0 * input + z[0];
            z[0] = b1 * input - a1 * y + z[1];
            z[1] = b2 * input - a2 * y;
            *v = y;
        }
    }

    /// Zero-phase filtering with SciPy's `filtfilt` defaults (see the module doc). `x` must have
    /// more than [`PAD`] samples.
    pub(crate) fn filtfilt(&self, x: &[f64]) -> Result<Vec<f64>> {
        let n = x.len();
        if n <= PAD {
            return Err(ToolError::Plan(format!("{n} samples: zero-phase filtering needs more than {PAD} (the edge padding)")));
        }
        let (first, last) = (x[0], x[n - 1]);
        let mut ext = Vec::with_capacity(n + 2 * PAD);
        ext.extend((1..=PAD).rev().map(|k| 2.0 * first - x[k]));
        ext.extend_from_slice(x);
        ext.extend((1..=PAD).map(|k| 2.0 * last - x[n - 1 - k]));
        let zi = self.steady_state();
        let x0 = ext[0];
        self.run(&mut ext, [zi[0] * x0, zi[1] * x0]);
        ext.reverse();
        let y0 = ext[0];
        self.run(&mut ext, [zi[0] * y0, zi[1] * y0]);
        ext.reverse();
        Ok(ext[PAD..PAD + n].to_vec())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    #[test]
    fn coefficients_match_scipy_butter() {
        // scipy.signal.butter(2, 0.2), SciPy 1.17.1.
        let f = Butterworth2::lowpass(1.0, 10.0).unwrap();
        let want_b = [0.067_455_273_889_071_9, 0.134_910_547_778_143_8, 0.067_455_273_889_071_9];
        let want_a = [1.0, -1.142_980_502_539_901_1, 0.412_801_598_096_188_77];
        for k in 0..3 {
            assert!((f.b[k] - want_b[k]).abs() < 1e-15, "b{k}: {} vs {}", f.b[k], want_b[k]);
            assert!((f.a[k] - want_a[k]).abs() < 1e-15, "a{k}: {} vs {}", f.a[k], want_a[k]);
        }
        // Unity gain at DC, zero at Nyquist.
        assert!((f.b.iter().sum::<f64>() / f.a.iter().sum::<f64>() - 1.0).abs() < 1e-14);
        assert!((f.b[0] - f.b[1] + f.b[2]).abs() < 1e-15);
        assert!(Butterworth2::lowpass(5.0, 10.0).is_err());
        assert!(Butterworth2::lowpass(0.0, 10.0).is_err());
    }

    #[test]
    fn a_step_settles_to_its_level_without_delay() {
        // Zero phase: the filtered step is antisymmetric about the edge (it crosses half-way at
        // the step itself), overshoots by the squared Butterworth response (a few %), and settles.
        let fs = 100.0;
        let n = 4001;
        let x: Vec<f64> = (0..n).map(|k| if k < n / 2 { 0.0 } else { 1.0 }).collect();
        let f = Butterworth2::lowpass(1.0, fs).unwrap();
        let y = f.filtfilt(&x).unwrap();
        let mid = n / 2;
        assert!((y[mid] + y[mid - 1] - 1.0).abs() < 0.05, "half-way at the step: {} {}", y[mid - 1], y[mid]);
        for k in 1..400 {
            assert!((y[mid + k] + y[mid - 1 - k] - 1.0).abs() < 1e-6, "antisymmetric at {k}");
        }
        let overshoot = y.iter().cloned().fold(f64::NEG_INFINITY, f64::max) - 1.0;
        assert!(overshoot > 0.005 && overshoot < 0.08, "overshoot {overshoot}");
        assert!(y[..200].iter().all(|v| v.abs() < 1e-6), "flat before the step");
        assert!(y[n - 200..].iter().all(|v| (v - 1.0).abs() < 1e-6), "settled after the step");
    }

    #[test]
    fn a_pass_band_sine_passes_and_a_stop_band_sine_is_removed() {
        let fs = 100.0;
        let fc = 2.0;
        let f = Butterworth2::lowpass(fc, fs).unwrap();
        let n = 20_000;
        let sine = |hz: f64| (0..n).map(|k| (2.0 * PI * hz * k as f64 / fs).sin()).collect::<Vec<f64>>();
        // Zero-phase gain is |H|² = 1 / (1 + (f/fc)^4) with the pre-warped frequencies; phase 0.
        let gain = |hz: f64| {
            let w = (PI * hz / fs).tan() / (PI * fc / fs).tan();
            1.0 / (1.0 + w.powi(4))
        };
        for hz in [0.2, 0.5, 2.0, 10.0, 20.0] {
            let x = sine(hz);
            let y = f.filtfilt(&x).unwrap();
            // Away from the ends: y = gain · x, in phase.
            let mid = 2000..n - 2000;
            let err = mid.clone().map(|k| (y[k] - gain(hz) * x[k]).abs()).fold(0.0, f64::max);
            assert!(err < 1e-6, "{hz} Hz: max |y − G·x| = {err}, G = {}", gain(hz));
        }
        assert!(gain(0.2) > 0.9999 && gain(2.0) > 0.49 && gain(2.0) < 0.51 && gain(20.0) < 1e-4);
    }

    #[test]
    fn edges_and_initial_state_match_scipy_filtfilt() {
        // Reference values from SciPy 1.17.1: `filtfilt(*butter(2, 0.1), x)` for
        // x[k] = sin(0.3k) + 0.01k², k = 0..39, and `lfilter_zi(*butter(2, 0.1))`.
        let f = Butterworth2::lowpass(0.05, 1.0).unwrap();
        let zi = f.steady_state();
        assert!((zi[0] - 0.979_916_634_435_788_7).abs() < 1e-13 && (zi[1] + 0.621_268_172_493_351_8).abs() < 1e-13, "{zi:?}");
        let x: Vec<f64> = (0..40).map(|k| (0.3 * k as f64).sin() + 0.01 * (k * k) as f64).collect();
        let y = f.filtfilt(&x).unwrap();
        let want = [
            (0, -0.008_682_634_508_600_254),
            (1, 0.207_214_613_742_454_3),
            (5, 0.864_846_929_607_892_6),
            (20, 3.834_711_920_266_821),
            (38, 13.915_770_545_019_857),
            (39, 14.575_010_974_740_863),
        ];
        for (k, v) in want {
            assert!((y[k] - v).abs() < 1e-12, "y[{k}] = {} vs SciPy {v}", y[k]);
        }
        // 000's regime: 2.5 mHz on 60 ms samples, a ramp of 500 samples. The start-up transient
        // of the step-shaped initial state lifts both ends by ~14 mm here: the same in SciPy.
        let f = Butterworth2::lowpass(0.0025, 1.0 / 0.06).unwrap();
        let x: Vec<f64> = (0..500).map(|k| 0.3 + 0.002 * k as f64).collect();
        let y = f.filtfilt(&x).unwrap();
        let want = [
            (0, 0.314_454_396_952_318_75),
            (1, 0.314_463_027_617_913_45),
            (100, 0.315_226_734_630_492_67),
            (250, 0.316_004_227_223_191_1),
            (498, 0.316_350_456_080_481_8),
            (499, 0.316_350_463_505_215_2),
        ];
        for (k, v) in want {
            assert!((y[k] - v).abs() < 1e-10, "y[{k}] = {} vs SciPy {v}", y[k]);
        }
        assert!(f.filtfilt(&x[..9]).is_err());
        assert_eq!(f.filtfilt(&x[..10]).unwrap().len(), 10);
    }
}
