//! Smoke (issue 15): the CPU references the GPU passes mirror.
//!
//! - [`interval`]: one Gaussian particle along one ray segment (seed 001 §3.7–3.10): the
//!   optical depth in closed form, the constant-extinction shading in a form that does not
//!   overflow, and the single-scattering integral `C_scat` with Simpson's rule.
//! - [`avsm`]: one light-space texel of an adaptive volumetric shadow map (seed 002): node
//!   insertion per particle, area-based node removal, lookup.
//! - [`emitter`]: an emitter's live particles as a pure function of time.
//!
//! Everything here is `f64`: these are the twins the `f32` shaders are tested against.

pub mod avsm;
pub mod emitter;
pub mod interval;

/// A small seeded generator for the randomised tests (SplitMix64), so that the tests need
/// no dependency and draw the same cases on every machine.
#[cfg(test)]
pub(crate) struct TestRng(u64);

#[cfg(test)]
impl TestRng {
    pub(crate) fn new(seed: u64) -> Self {
        Self(seed)
    }

    pub(crate) fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    pub(crate) fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Uniform in [lo, hi).
    pub(crate) fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.unit()
    }

    /// Log-uniform in [lo, hi) (both > 0).
    pub(crate) fn log_uniform(&mut self, lo: f64, hi: f64) -> f64 {
        (lo.ln() + (hi.ln() - lo.ln()) * self.unit()).exp()
    }
}
