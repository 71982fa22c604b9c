//! The checks of every value a scene file gives (ranges, finiteness, the fields each kind
//! needs); errors name the field and the offending value.

use super::{
    invalid, EmitterDesc, EmitterShape, Light, LightDesc, LightKind, MediumDesc, MediumKind, Noise,
    RenderDefaults, SceneError, Swing, VolumeDesc,
};
use glam::Vec3;

pub(crate) fn check_finite(field: &str, v: &[f32]) -> Result<(), SceneError> {
    if v.iter().all(|x| x.is_finite()) {
        Ok(())
    } else {
        Err(invalid(field, v, "must be a finite number"))
    }
}

pub(crate) fn check_range(
    field: &str,
    v: f32,
    lo: f32,
    hi: f32,
    what: &str,
) -> Result<(), SceneError> {
    if v.is_finite() && v >= lo && v <= hi {
        Ok(())
    } else {
        Err(invalid(field, v, what))
    }
}

pub(super) fn validate_render(r: &RenderDefaults) -> Result<(), SceneError> {
    check_range(
        "render.near_m",
        r.near_m,
        1e-4,
        1e3,
        "must be between 0.0001 and 1000 m",
    )?;
    check_range(
        "render.far_m",
        r.far_m,
        r.near_m * 1.01,
        1e5,
        "must be greater than near_m and at most 100000 m",
    )?;
    check_range(
        "render.voxel_size_m",
        r.voxel_size_m,
        0.01,
        100.0,
        "must be between 0.01 and 100 m",
    )?;
    check_finite("render.sky", &r.sky)?;
    check_finite("render.ambient", &r.ambient)?;
    for (f, v) in [("render.sky", r.sky), ("render.ambient", r.ambient)] {
        if v.iter().any(|x| *x < 0.0) {
            return Err(invalid(f, v, "must not be negative"));
        }
    }
    check_range("render.exposure", r.exposure, 1e-6, 1e6, "must be positive")
}

pub(super) fn validate_lights(
    lights: &[LightDesc],
) -> Result<Vec<(Light, glam::DVec3)>, SceneError> {
    let mut out = Vec::with_capacity(lights.len());
    for (i, l) in lights.iter().enumerate() {
        let f = |name: &str| format!("light[{i}].{name}");
        let unit = |name: &str, d: [f32; 3]| -> Result<Vec3, SceneError> {
            check_finite(&f(name), &d)?;
            Vec3::from(d)
                .try_normalize()
                .ok_or_else(|| invalid(f(name), d, "must be a non-zero vector"))
        };
        let radiance = |color: [f32; 3], intensity: f32| -> Result<Vec3, SceneError> {
            check_finite(&f("color"), &color)?;
            if color.iter().any(|c| *c < 0.0) {
                return Err(invalid(f("color"), color, "must not be negative"));
            }
            check_range(
                &f("intensity"),
                intensity,
                0.0,
                1e9,
                "must be between 0 and 1e9",
            )?;
            Ok(Vec3::from(color) * intensity)
        };
        let light = match *l {
            LightDesc::Directional {
                direction,
                color,
                intensity,
                ..
            } => (
                Light {
                    kind: LightKind::Directional,
                    position: Vec3::ZERO,
                    direction: unit("direction", direction)?,
                    radiance: radiance(color, intensity)?,
                    cos_outer: -1.0,
                    cos_inner: -1.0,
                    swing: None,
                },
                glam::DVec3::ZERO,
            ),
            LightDesc::Point {
                position,
                color,
                intensity,
                ..
            } => {
                check_finite(&f("position"), &position)?;
                (
                    Light {
                        kind: LightKind::Point,
                        position: Vec3::ZERO,
                        direction: Vec3::Y,
                        radiance: radiance(color, intensity)?,
                        cos_outer: -1.0,
                        cos_inner: -1.0,
                        swing: None,
                    },
                    Vec3::from(position).as_dvec3(),
                )
            }
            LightDesc::Spot {
                position,
                direction,
                color,
                intensity,
                inner_deg,
                outer_deg,
                ..
            } => {
                check_finite(&f("position"), &position)?;
                check_range(
                    &f("outer_deg"),
                    outer_deg,
                    0.1,
                    179.0,
                    "must be between 0.1 and 179 degrees",
                )?;
                check_range(
                    &f("inner_deg"),
                    inner_deg,
                    0.0,
                    outer_deg - 0.01,
                    "must be at least 0 and smaller than outer_deg",
                )?;
                (
                    Light {
                        kind: LightKind::Spot,
                        position: Vec3::ZERO,
                        direction: unit("direction", direction)?,
                        radiance: radiance(color, intensity)?,
                        cos_outer: outer_deg.to_radians().cos(),
                        cos_inner: inner_deg.to_radians().cos(),
                        swing: None,
                    },
                    Vec3::from(position).as_dvec3(),
                )
            }
        };
        let (mut light, world_pos) = light;
        let swing = match l {
            LightDesc::Directional { swing, .. }
            | LightDesc::Point { swing, .. }
            | LightDesc::Spot { swing, .. } => swing,
        };
        if let Some(sw) = swing {
            check_finite(&f("swing.pivot"), &sw.pivot)?;
            check_range(
                &f("swing.degrees"),
                sw.degrees,
                0.0,
                180.0,
                "must be between 0 and 180 degrees",
            )?;
            check_range(
                &f("swing.period_s"),
                sw.period_s,
                1e-3,
                1e6,
                "must be between 0.001 and 1e6 seconds",
            )?;
            light.swing = Some(Swing {
                pivot: Vec3::from(sw.pivot),
                axis: unit("swing.axis", sw.axis)?,
                amplitude_rad: sw.degrees.to_radians(),
                period_s: sw.period_s,
            });
        }
        out.push((light, world_pos));
    }
    Ok(out)
}

pub(super) fn validate_media(media: &[MediumDesc]) -> Result<(), SceneError> {
    for (i, m) in media.iter().enumerate() {
        let f = |name: &str| format!("medium[{i}].{name}");
        validate_optics(&f, m.scattering, m.absorption, m.g, m.emission)?;
        match m.kind {
            MediumKind::Constant => {}
            MediumKind::Height => {
                let base = m.base_y_m.ok_or_else(|| {
                    invalid(f("base_y_m"), "missing", "height fog needs base_y_m")
                })?;
                check_finite(&f("base_y_m"), &[base])?;
                let falloff = m.falloff_m.ok_or_else(|| {
                    invalid(f("falloff_m"), "missing", "height fog needs falloff_m")
                })?;
                check_range(
                    &f("falloff_m"),
                    falloff,
                    1e-3,
                    1e5,
                    "must be between 0.001 and 100000 m",
                )?;
            }
            MediumKind::Box => {
                let lo = m.min.ok_or_else(|| {
                    invalid(f("min"), "missing", "a box medium needs min and max")
                })?;
                let hi = m.max.ok_or_else(|| {
                    invalid(f("max"), "missing", "a box medium needs min and max")
                })?;
                check_finite(&f("min"), &lo)?;
                check_finite(&f("max"), &hi)?;
                if (0..3).any(|k| hi[k] <= lo[k]) {
                    return Err(invalid(
                        f("max"),
                        hi,
                        "must be greater than min on every axis",
                    ));
                }
            }
            MediumKind::Volume => {
                return Err(invalid(
                    f("kind"),
                    "volume",
                    "write a volume as a [[volume]] table",
                ));
            }
            MediumKind::Sphere => {
                let c = m.center.ok_or_else(|| {
                    invalid(
                        f("center"),
                        "missing",
                        "a sphere medium needs center and radius",
                    )
                })?;
                check_finite(&f("center"), &c)?;
                let r = m.radius.ok_or_else(|| {
                    invalid(
                        f("radius"),
                        "missing",
                        "a sphere medium needs center and radius",
                    )
                })?;
                check_range(
                    &f("radius"),
                    r,
                    1e-3,
                    1e5,
                    "must be between 0.001 and 100000 m",
                )?;
            }
        }
        if let Some(n) = m.noise {
            validate_noise(&f, &n)?;
        }
    }
    Ok(())
}

/// σs, σa, g and emission of a medium or volume (`f` names the field).
fn validate_optics(
    f: &impl Fn(&str) -> String,
    scattering: [f32; 3],
    absorption: f32,
    g: f32,
    emission: [f32; 3],
) -> Result<(), SceneError> {
    check_finite(&f("scattering"), &scattering)?;
    for c in scattering {
        check_range(
            &f("scattering"),
            c,
            0.0,
            1e6,
            "each channel must be between 0 and 1e6 m⁻¹",
        )?;
    }
    check_range(
        &f("absorption"),
        absorption,
        0.0,
        1e6,
        "must be between 0 and 1e6 m⁻¹",
    )?;
    check_range(
        &f("g"),
        g,
        -0.9999,
        0.9999,
        "Henyey-Greenstein g must be strictly between -1 and 1",
    )?;
    check_finite(&f("emission"), &emission)?;
    if emission.iter().any(|c| *c < 0.0) {
        return Err(invalid(f("emission"), emission, "must not be negative"));
    }
    Ok(())
}

/// A density `noise` table of a medium or volume.
fn validate_noise(f: &impl Fn(&str) -> String, n: &Noise) -> Result<(), SceneError> {
    check_range(
        &f("noise.frequency"),
        n.frequency,
        0.0,
        1e3,
        "must be between 0 and 1000 per metre",
    )?;
    if !(1..=6).contains(&n.octaves) {
        return Err(invalid(
            f("noise.octaves"),
            n.octaves,
            "must be between 1 and 6",
        ));
    }
    check_range(
        &f("noise.amplitude"),
        n.amplitude,
        0.0,
        1.0,
        "must be between 0 and 1",
    )?;
    check_finite(&f("noise.wind"), &n.wind)
}

pub(super) fn validate_volumes(volumes: &[VolumeDesc]) -> Result<(), SceneError> {
    for (i, v) in volumes.iter().enumerate() {
        let f = |name: &str| format!("volume[{i}].{name}");
        check_finite(&f("center"), &v.center)?;
        check_range(
            &f("radius"),
            v.radius,
            1e-3,
            1e5,
            "must be between 0.001 and 100000 m",
        )?;
        validate_optics(&f, v.scattering, v.absorption, v.g, v.emission)?;
        if let Some(d) = v.displacement {
            check_range(
                &f("displacement.amplitude"),
                d.amplitude,
                0.0,
                0.9,
                "must be between 0 and 0.9 (a fraction of the radius)",
            )?;
            check_range(
                &f("displacement.frequency"),
                d.frequency,
                0.1,
                64.0,
                "must be between 0.1 and 64 cycles per radius",
            )?;
            if !(1..=6).contains(&d.octaves) {
                return Err(invalid(
                    f("displacement.octaves"),
                    d.octaves,
                    "must be between 1 and 6",
                ));
            }
            if d.seed > 1000 {
                return Err(invalid(
                    f("displacement.seed"),
                    d.seed,
                    "must be between 0 and 1000",
                ));
            }
        }
        if let Some(m) = v.motion {
            check_finite(&f("motion.velocity"), &m.velocity)?;
            check_range(
                &f("motion.period_s"),
                m.period_s,
                1e-3,
                1e6,
                "must be between 0.001 and 1e6 seconds",
            )?;
            let path_m = Vec3::from(m.velocity).length() * m.period_s;
            if !path_m.is_finite() || path_m > 1e5 {
                return Err(invalid(
                    f("motion.velocity"),
                    m.velocity,
                    "times period_s must be a path of at most 100000 m",
                ));
            }
        }
        if let Some(n) = v.noise {
            validate_noise(&f, &n)?;
        }
    }
    Ok(())
}

/// The most particles one emitter may keep alive (the GPU's per-emitter buffers are sized
/// from it).
pub(crate) const MAX_EMITTER_PARTICLES: u32 = 1 << 20;

pub(super) fn validate_emitters(emitters: &[EmitterDesc]) -> Result<(), SceneError> {
    for (i, e) in emitters.iter().enumerate() {
        let f = |name: &str| format!("emitter[{i}].{name}");
        check_finite(&f("position"), &e.position)?;
        if e.shape == EmitterShape::Point {
            check_range(&f("radius"), e.radius, 0.0, 0.0, "must be 0 (or left out) for a point emitter; use shape = \"sphere\" or \"disc\" for a radius")?;
        } else {
            check_range(
                &f("radius"),
                e.radius,
                1e-3,
                1e4,
                "must be between 0.001 and 10000 m for a sphere or disc emitter",
            )?;
        }
        check_range(
            &f("rate_per_s"),
            e.rate_per_s,
            1e-3,
            1e5,
            "must be between 0.001 and 100000 particles per second",
        )?;
        check_range(
            &f("lifetime_s"),
            e.lifetime_s,
            1e-3,
            1e4,
            "must be between 0.001 and 10000 seconds",
        )?;
        check_finite(&f("velocity"), &e.velocity)?;
        if Vec3::from(e.velocity).length() > 1e3 {
            return Err(invalid(
                f("velocity"),
                e.velocity,
                "must be at most 1000 m/s",
            ));
        }
        check_range(
            &f("spread"),
            e.spread,
            0.0,
            1e3,
            "must be between 0 and 1000 m/s",
        )?;
        check_range(
            &f("buoyancy"),
            e.buoyancy,
            -1e3,
            1e3,
            "must be between -1000 and 1000 m/s²",
        )?;
        check_finite(&f("wind"), &e.wind)?;
        if Vec3::from(e.wind).length() > 1e3 {
            return Err(invalid(f("wind"), e.wind, "must be at most 1000 m/s"));
        }
        check_range(
            &f("growth"),
            e.growth,
            0.0,
            1e3,
            "must be between 0 and 1000 m/s (particles do not shrink)",
        )?;
        check_range(
            &f("falloff_u"),
            e.falloff_u,
            1e-3,
            1e3,
            "must be between 0.001 and 1000 m",
        )?;
        validate_optics(&f, e.scattering, e.absorption, e.g, [0.0; 3])?;
        if e.max_particles > MAX_EMITTER_PARTICLES {
            return Err(invalid(
                f("max_particles"),
                e.max_particles,
                "must be at most 1048576",
            ));
        }
        if e.seed > 1000 {
            return Err(invalid(f("seed"), e.seed, "must be between 0 and 1000"));
        }
    }
    Ok(())
}
