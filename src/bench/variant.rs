//! Named renderer configurations of a benchmark: the modes (`reference`, `shared`,
//! `maps`) and `--variant 'name:key=value,…'` strings that change settings of `shared`.

use crate::render::{Mode, Settings};
use serde::{Deserialize, Serialize};

/// One configuration a benchmark renders at every point.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BenchVariant {
    /// Unique name (`reference`, `shared`, `maps`, or the variant's own).
    pub name: String,
    /// Renderer settings.
    pub settings: Settings,
}

/// The configurations for `modes`, in that order: each starts from the paper's
/// defaults with the scene's voxel size.
pub fn mode_variants(modes: &[Mode], scene_voxel_size_m: f32) -> Vec<BenchVariant> {
    modes
        .iter()
        .map(|&mode| BenchVariant {
            name: mode.name().to_string(),
            settings: base_settings(mode, scene_voxel_size_m),
        })
        .collect()
}

fn base_settings(mode: Mode, scene_voxel_size_m: f32) -> Settings {
    let shared = mode == Mode::Shared;
    Settings {
        mode,
        voxel_size_m: scene_voxel_size_m,
        // `reference` is the paper's baseline: no option of `shared` applies to it;
        // `maps` (the engines' way) has no grid to drive or cache, but the same shadow
        // maps and transmittance volumes as `shared`.
        demand: shared && Settings::default().demand,
        cache: shared && Settings::default().cache,
        shadow_map_px: if mode == Mode::Reference {
            0
        } else {
            Settings::default().shadow_map_px
        },
        ..Settings::default()
    }
}

/// Parses `name:key=value,…` (the keys of `Settings`, as config files and flags name
/// them) over the `shared` defaults with the scene's voxel size. Errors quote the whole
/// `--variant` value and name the key.
pub fn parse_variant(spec: &str, scene_voxel_size_m: f32) -> anyhow::Result<BenchVariant> {
    let fail = |why: String| anyhow::anyhow!("--variant '{spec}': {why}");
    let (name, body) = spec.split_once(':').unwrap_or((spec, ""));
    let name = name.trim();
    if name.is_empty() {
        return Err(fail(
            "needs a name before ':' (e.g. 'coarse:voxel_size_m=0.5')".into(),
        ));
    }
    if Mode::all().any(|m| m.name() == name) {
        return Err(fail(format!(
            "the name '{name}' is taken by a mode; pick another"
        )));
    }
    let mut s = base_settings(Mode::Shared, scene_voxel_size_m);
    s.set_all(body)
        .and_then(|()| s.validate())
        .map_err(|e| fail(format!("{e:#}")))?;
    Ok(BenchVariant {
        name: name.to_string(),
        settings: s,
    })
}

/// The modes followed by the variants; names must be unique and something must be left.
pub fn configurations(
    modes: &[Mode],
    variant_specs: &[String],
    scene_voxel_size_m: f32,
) -> anyhow::Result<Vec<BenchVariant>> {
    let mut all = mode_variants(modes, scene_voxel_size_m);
    for spec in variant_specs {
        let v = parse_variant(spec, scene_voxel_size_m)?;
        anyhow::ensure!(
            all.iter().all(|o| o.name != v.name),
            "--variant '{spec}': the name '{}' is used twice",
            v.name
        );
        all.push(v);
    }
    let mut seen = Vec::new();
    for m in modes {
        anyhow::ensure!(!seen.contains(m), "--modes: '{}' is given twice", m.name());
        seen.push(*m);
    }
    anyhow::ensure!(
        !all.is_empty(),
        "nothing to run: give --modes or at least one --variant"
    );
    Ok(all)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn variant_keys_set_settings() {
        let v = parse_variant(
            "fast:voxel=0.5, lookup=nearest,parity=on,frustum=0.25",
            0.25,
        )
        .unwrap();
        assert_eq!(v.name, "fast");
        assert_eq!(v.settings.mode, Mode::Shared);
        assert_eq!(v.settings.voxel_size_m, 0.5);
        assert!(!v.settings.trilinear && v.settings.parity);
        assert_eq!(v.settings.frustum_slice_fraction, 0.25);
        let plain = parse_variant("same", 0.3).unwrap();
        assert_eq!(plain.settings, base_settings(Mode::Shared, 0.3));
    }

    #[test]
    fn bad_variants_name_the_key_and_value() {
        for (spec, needle) in [
            ("x:voxel=abc", "voxel=abc"),
            (
                "x:voxel=0.001",
                "voxel_size_m=0.001: must be at least 0.01 m",
            ),
            ("x:tvoxel=-1", "transmittance_voxel_m=-1: must be 0"),
            ("x:lookup=cubic", "lookup=cubic: expected nearest|trilinear"),
            ("x:speed=3", "unknown key 'speed'"),
            ("x:parity", "'parity' is not key=value"),
            (":voxel=1", "needs a name"),
            ("shared:voxel=1", "taken by a mode"),
            ("x:slices=-3", "slices=-3"),
            ("x:voxel=inf", "voxel=inf"),
        ] {
            let e = parse_variant(spec, 0.25).unwrap_err().to_string();
            assert!(e.contains(needle), "{spec}: {e}");
            assert!(e.contains(&format!("'{spec}'")), "{spec}: {e}");
        }
    }

    #[test]
    fn names_must_be_unique() {
        let e = configurations(
            &[Mode::Reference],
            &["a:voxel=1".into(), "a:voxel=2".into()],
            0.25,
        )
        .unwrap_err();
        assert!(e.to_string().contains("used twice"), "{e}");
        let e = configurations(&[Mode::Shared, Mode::Shared], &[], 0.25).unwrap_err();
        assert!(e.to_string().contains("--modes"), "{e}");
        assert!(configurations(&[], &[], 0.25).is_err());
    }
}
