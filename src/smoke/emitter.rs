//! The CPU twin of the particle simulation (issue 15): an emitter's live particles as a
//! pure function of time, so that `truth`, `bench`, the server and the GPU pass agree.
//!
//! Particle `i` (0, 1, 2, …) is born at `t_i = i / rate` at a point of the emitter's shape
//! and with a spread direction both drawn from a hash of `(seed, i mod 2³²)` (Wellons'
//! `lowbias32`, 32-bit so that the GPU pass, shaders/smoke_particles.wgsl, draws the very
//! same numbers: each draw is 24 bits, exact in f32 and f64), and at
//! age `a = t − t_i` it is at
//!
//! `p(a) = p_0 + (v + v_spread,i + wind) a + ½ buoyancy ŷ a²`, with falloff `u(a) = u_0 +
//! growth · a`,
//!
//! alive while `0 ≤ a < lifetime`. When more than `max_particles` would be alive, the
//! oldest go first: the live set is the `max_particles` newest.

use crate::scene::{EmitterDesc, EmitterShape};
use glam::DVec3;

/// One live particle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Particle {
    /// Birth order within its emitter (0 is the first ever born).
    pub index: u64,
    /// Centre, metres (the emitter's space: render space for a loaded scene).
    pub centre: DVec3,
    /// Falloff distance `u` (001 §3.8), metres.
    pub falloff_u_m: f64,
    /// Seconds since birth.
    pub age_s: f64,
}

/// The live particles of `emitter` at `time_s` (seconds since the emitter started), oldest
/// first. None before time 0.
pub fn particles_at(emitter: &EmitterDesc, time_s: f64) -> Vec<Particle> {
    let Some(live) = live_range(emitter, time_s) else {
        return Vec::new();
    };
    let rate = f64::from(emitter.rate_per_s);
    live.map(|i| particle(emitter, i, time_s - i as f64 / rate))
        .collect()
}

/// The birth indices of the live particles of `emitter` at `time_s` (the newest
/// `max_particles` of those born and not yet dead), `None` when there are none.
pub fn live_range(emitter: &EmitterDesc, time_s: f64) -> Option<std::ops::RangeInclusive<u64>> {
    let rate = f64::from(emitter.rate_per_s);
    let lifetime_s = f64::from(emitter.lifetime_s);
    if !(time_s >= 0.0 && rate > 0.0 && lifetime_s > 0.0) || emitter.max_particles == 0 {
        return None;
    }
    let birth_s = |i: u64| i as f64 / rate;
    // The newest particle born by now, and the oldest still alive (age < lifetime); the
    // float estimates are corrected by the exact tests on `birth_s`.
    let mut newest = (time_s * rate).floor() as u64;
    while birth_s(newest) > time_s {
        newest -= 1;
    }
    while birth_s(newest + 1) <= time_s {
        newest += 1;
    }
    let mut oldest = ((time_s - lifetime_s) * rate).floor().max(0.0) as u64;
    while oldest > 0 && time_s - birth_s(oldest - 1) < lifetime_s {
        oldest -= 1;
    }
    while oldest <= newest && time_s - birth_s(oldest) >= lifetime_s {
        oldest += 1;
    }
    if oldest > newest {
        return None;
    }
    let cap = u64::from(emitter.max_particles);
    Some(oldest.max((newest + 1).saturating_sub(cap))..=newest)
}

/// Particle `i` at age `age_s`, closed form (module header).
pub fn particle(e: &EmitterDesc, index: u64, age_s: f64) -> Particle {
    let mut hash = Hash::new(e.seed, index);
    let position = DVec3::from(e.position.map(f64::from));
    let radius = f64::from(e.radius);
    let birth = position
        + match e.shape {
            EmitterShape::Point => DVec3::ZERO,
            EmitterShape::Sphere => hash.unit_vector() * radius * hash.unit().cbrt(),
            EmitterShape::Disc => {
                let angle = std::f64::consts::TAU * hash.unit();
                let r = radius * hash.unit().sqrt();
                DVec3::new(r * angle.cos(), 0.0, r * angle.sin())
            }
        };
    let velocity = DVec3::from(e.velocity.map(f64::from))
        + DVec3::from(e.wind.map(f64::from))
        + f64::from(e.spread) * hash.unit_vector();
    let rise = 0.5 * f64::from(e.buoyancy) * age_s * age_s;
    Particle {
        index,
        centre: birth + velocity * age_s + DVec3::Y * rise,
        falloff_u_m: f64::from(e.falloff_u) + f64::from(e.growth) * age_s,
        age_s,
    }
}

/// Chris Wellons' `lowbias32` integer hash (`hash_u32` in shaders/smoke_particles.wgsl).
pub fn lowbias32(mut x: u32) -> u32 {
    x ^= x >> 16;
    x = x.wrapping_mul(0x7feb_352d);
    x ^= x >> 15;
    x = x.wrapping_mul(0x846c_a68b);
    x ^ (x >> 16)
}

/// A stream of draws seeded by `(seed, index mod 2³²)`: a particle's random draws depend
/// on nothing else. Mirrored by `Draws` in shaders/smoke_particles.wgsl.
struct Hash(u32);

impl Hash {
    fn new(seed: u32, index: u64) -> Self {
        Self(lowbias32(index as u32 ^ lowbias32(seed)))
    }

    fn next(&mut self) -> u32 {
        self.0 = self.0.wrapping_add(0x9e37_79b9);
        lowbias32(self.0)
    }

    /// Uniform in [0, 1), 24 bits (exact in f32).
    fn unit(&mut self) -> f64 {
        f64::from(self.next() >> 8) / f64::from(1u32 << 24)
    }

    /// Uniform on the unit sphere.
    fn unit_vector(&mut self) -> DVec3 {
        let z = 2.0 * self.unit() - 1.0;
        let angle = std::f64::consts::TAU * self.unit();
        let r = (1.0 - z * z).max(0.0).sqrt();
        DVec3::new(r * angle.cos(), r * angle.sin(), z)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn chimney() -> EmitterDesc {
        EmitterDesc {
            shape: EmitterShape::Disc,
            position: [2.0, 6.0, -1.0],
            radius: 0.3,
            rate_per_s: 20.0,
            lifetime_s: 4.0,
            velocity: [0.0, 0.5, 0.0],
            spread: 0.2,
            buoyancy: 0.3,
            wind: [0.8, 0.0, 0.0],
            growth: 0.25,
            falloff_u: 0.4,
            scattering: [2.0; 3],
            absorption: 0.5,
            g: 0.3,
            max_particles: 1000,
            seed: 7,
        }
    }

    #[test]
    fn a_pure_function_of_time() {
        let e = chimney();
        assert_eq!(particles_at(&e, 2.5), particles_at(&e, 2.5));
        // A particle is the same particle whenever it is looked at: its state follows from
        // its index and age alone.
        let early = particles_at(&e, 1.0);
        let late = particles_at(&e, 1.5);
        let p = early.iter().find(|p| p.index == 10).unwrap();
        let q = late.iter().find(|p| p.index == 10).unwrap();
        assert_eq!(q.age_s - p.age_s, 0.5);
        let v = DVec3::new(0.8, 0.5, 0.0);
        let spread_bound = 0.2 * 0.5 + 1e-12;
        let drift = q.centre
            - p.centre
            - v * 0.5
            - DVec3::Y * 0.15 * (q.age_s * q.age_s - p.age_s * p.age_s);
        assert!(drift.length() <= spread_bound, "{drift}");
        assert!((q.falloff_u_m - p.falloff_u_m - 0.125).abs() < 1e-12);
        // Another seed, other birth points.
        let other = EmitterDesc {
            seed: 8,
            ..e.clone()
        };
        assert_ne!(particles_at(&other, 2.5), particles_at(&e, 2.5));
        // Born on the disc.
        for p in particles_at(&e, 0.2) {
            let birth = p.centre - v * p.age_s - DVec3::Y * 0.15 * p.age_s * p.age_s;
            let offset = birth - DVec3::new(2.0, 6.0, -1.0);
            assert!(offset.length() <= 0.3 + 0.2 * p.age_s + 1e-9, "{offset}");
        }
    }

    #[test]
    fn lifetime_bounds_the_live_set() {
        let e = chimney();
        // Steady state: rate × lifetime = 80 alive, ages in [0, 4).
        let live = particles_at(&e, 10.0);
        assert_eq!(live.len(), 80);
        assert!(live.iter().all(|p| (0.0..4.0).contains(&p.age_s)));
        assert_eq!(live.first().unwrap().index, 121);
        assert_eq!(live.last().unwrap().index, 200);
        // Before the first lifetime is over, everyone born is alive.
        assert_eq!(particles_at(&e, 1.0).len(), 21);
    }

    #[test]
    fn the_cap_keeps_the_newest() {
        let e = EmitterDesc {
            max_particles: 30,
            ..chimney()
        };
        let live = particles_at(&e, 10.0);
        assert_eq!(live.len(), 30);
        assert_eq!(live.first().unwrap().index, 171);
        assert_eq!(live.last().unwrap().index, 200);
    }

    #[test]
    fn zero_particles() {
        let e = chimney();
        assert!(particles_at(&e, -0.1).is_empty());
        assert!(particles_at(
            &EmitterDesc {
                max_particles: 0,
                ..e.clone()
            },
            5.0
        )
        .is_empty());
        // Only particle 0 at time 0.
        let first = particles_at(&e, 0.0);
        assert_eq!(first.len(), 1);
        assert_eq!(first[0].age_s, 0.0);
    }
}
