//! Every setting of the renderer (paper 000's parameters and what fogcast adds), with
//! its default, its valid range and its names.
//!
//! The `settings!` list below defines each setting once: its field, documentation,
//! default and the keys it had before. Every place a user names a setting derives from
//! it: the field's name is the key of a server config file and of a `fogcast bench
//! --variant`, the name in JSON reports, and (kebab-case, after `--`) the flag of
//! `fogcast render` and `serve`; `fogcast eval` names its variants by the same
//! `key=value`s. Older keys stay readable everywhere.

use crate::scene::Scene;
use anyhow::{anyhow, bail};
use serde::{Deserialize, Serialize};

/// How shadows in the fog are computed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum Mode {
    /// Paper 000's baseline: a shadow ray per light per froxel, per viewer.
    Reference,
    /// Paper 000's method: shared world grid + per-viewer shadow frustum.
    Shared,
    /// What game engines (Unreal, Frostbite, Godot) do: per-viewer froxels lit from the
    /// shared shadow maps of every light (orthographic for the sun, perspective for
    /// spots, cubes for point lights) and the shared media transmittance volumes; no
    /// grid, no shadow frustum, no rays. Needs `shadow_map_px` > 0.
    Maps,
}

impl Mode {
    /// Every mode.
    pub fn all() -> impl Iterator<Item = Mode> {
        <Mode as clap::ValueEnum>::value_variants().iter().copied()
    }

    /// The mode's name in flags, config files, variants and reports.
    pub fn name(self) -> &'static str {
        match self {
            Mode::Reference => "reference",
            Mode::Shared => "shared",
            Mode::Maps => "maps",
        }
    }
}

/// `Some` of the literal, if one is given.
macro_rules! some {
    () => {
        None
    };
    ($value:literal) => {
        Some($value)
    };
}

/// Defines `Settings`, its `Default` and `SETTINGS`, the table every name of a setting
/// is read from. Per setting: its documentation (the first paragraph is the flag's
/// help), serde attributes, `#[cli_default = "…"]` where commands start from something
/// else than the default (shown in the flag's help), `field: type = default`, and
/// `was "old_key" { "old value" => "value", … }, …` for keys it had before.
macro_rules! settings {
    ($(
        $(#[doc = $doc:literal])+
        $(#[serde($($serde:tt)+)])?
        $(#[cli_default = $cli_default:literal])?
        $field:ident: $ty:ty = $default:expr
        $(, was $($old:literal $({ $($old_value:literal => $value:literal),+ })?),+)?;
    )+) => {
        /// Every parameter of paper 000 and of what fogcast adds, with its default.
        #[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
        pub struct Settings {
            $(
                $(#[doc = $doc])+
                $(#[serde($($serde)+)])?
                pub $field: $ty,
            )+
        }

        impl Default for Settings {
            fn default() -> Self {
                Settings {
                    $($field: $default,)+
                }
            }
        }

        /// Every setting, in the order of the fields.
        const SETTINGS: &[Setting] = &[$(
            Setting {
                key: stringify!($field),
                doc: concat!($($doc, "\n"),+),
                cli_default: some!($($cli_default)?),
                was: &[$($(OldKey {
                    key: $old,
                    values: &[$($(($old_value, $value)),+)?],
                }),+)?],
                takes: <$ty as Value>::takes,
                placeholder: <$ty as Value>::placeholder,
                bare: <$ty as Value>::BARE,
                get: |s| Value::text(&s.$field),
                set: |s, text| {
                    s.$field = Value::parse(text)?;
                    Some(())
                },
            },
        )+];
    };
}

settings! {
    /// Rendering mode: `reference` (the paper's baseline), `shared` (its method) or
    /// `maps` (the game engines' shadow-map froxels).
    ///
    /// `maps` lights every froxel from the shared shadow maps of `shadow_map_px` (which
    /// it needs > 0) and the media transmittance volumes: no grid, no shadow frustum, no
    /// shadow rays.
    mode: Mode = Mode::Shared;

    /// Shared grid voxel edge, metres.
    #[cli_default = "the scene's"]
    voxel_size_m: f32 = 0.25, was "voxel", "voxel_size";

    /// Pixels per froxel of the lighting volume (8 in the paper).
    froxel_px: u32 = 8;

    /// Depth slices of the lighting volume (128 in the paper).
    slices: u32 = 128;

    /// Pixels per froxel of the per-viewer shadow frustum (16 in the paper).
    frustum_px: u32 = 16;

    /// Fraction of the depth slices the shadow frustum covers (1/3 in the paper; 0: none).
    frustum_slice_fraction: f32 = 1.0 / 3.0, was "frustum", "frustum_fraction";

    /// Alternate z-parity grid updates (half the grid per frame).
    parity: bool = false;

    /// 8-voxel trilinear grid lookup (off: the nearest voxel).
    trilinear: bool = true, was "lookup" { "nearest" => "off", "trilinear" => "on" };

    /// Temporal jitter along view rays + reprojection of last frame's froxels.
    temporal: bool = false;

    /// Curvature k of the depth-slice distribution (larger: more slices near the eye).
    ///
    /// `z = near + (far − near)·(e^{k·s/N} − 1)/(e^k − 1)`: large k crowds slices at the
    /// eye (k = ln(far/near) ≈ the pure exponential near·(far/near)^{s/N}), small k
    /// tends to linear. With near 0.1 m and far 40 m the pure exponential puts the
    /// first third of the slices (the shadow frustum's) within 0.75 m of the eye; the
    /// default 4 reaches 2 m there and is measured in `docs/accuracy.md`.
    depth_curve: f32 = 4.0;

    /// Demand-driven grid update: trace only the voxels some visible froxel reads
    /// (beyond the paper; off: its frustum-gated update).
    ///
    /// Instead of every voxel inside some frustum; froxels hidden behind the depth
    /// buffer are neither lit nor read. On by default, as `fogcast bench` shows it wins
    /// (docs/performance.md).
    // Reports from before a setting existed read it as off (`serde(default)`).
    #[serde(default)]
    demand: bool = true;

    /// Temporal shadow caching: keep a voxel's light bits until the light or an
    /// occluder moves (beyond the paper; off: re-trace every frame).
    ///
    /// A voxel's bit stays valid until that light changes or a mover's swept bounds
    /// cross its shadow ray, so a static scene traces each voxel once. On by default, as
    /// `fogcast bench` shows it wins; no effect on a sparse grid (its bricks are
    /// allocated afresh every frame).
    #[serde(default)]
    cache: bool = true;

    /// Sparse grid: bricks of 8³ voxels allocated each frame where froxels read, from a
    /// pool of this many bricks (0: a dense grid over the whole media box).
    ///
    /// Paper 000 §5.1, beyond its implementation. Implies `demand`; not with `cache`.
    /// A froxel whose brick did not fit in the pool traces its own rays.
    #[serde(default)]
    brick_pool: u32 = 0, was "pool";

    /// Shadows on surfaces and in the near-field fog from shared shadow maps of this
    /// many texels a side (`shared` and `maps`; 0: a ray per pixel or frustum froxel
    /// and light, as `reference` always does).
    ///
    /// Beyond the paper: rendered once for all viewers and only when a light or mover
    /// changed. Directional lights get an orthographic map of this size; spot lights a
    /// perspective map and point lights a cube of six faces, an eighth of it a side (at
    /// least 64). On by default, as `fogcast bench` shows it wins. `maps` mode lights
    /// every froxel from them and needs it > 0.
    #[serde(default)]
    shadow_map_px: u32 = 4096, was "map", "shadow_map";

    /// Shadow edges in the grid from the shadow maps (`shared`): where the 8 voxels
    /// around a froxel disagree for a light with a map, the froxel reads the map (2×2
    /// PCF) instead of their blend, and the shadow frustum is left out for such lights
    /// (off: the paper's frustum and trilinear voxels).
    ///
    /// Beyond the paper: the grid's 0.25 m voxels blur shafts, and a lookup costs one
    /// map read only where an edge runs (docs/decisions.md, "Shadow edges from the maps").
    // Reports from before a setting existed read it as off (`serde(default)`).
    #[serde(default)]
    map_edges: bool = true;

    /// The media's density in the shared grid (`shared`, dense trilinear grid, no media
    /// layer): the grid pass stores, beside each needed voxel's light bits, the density
    /// of the costly media (height fog, noise, volumes) at its centre, once per frame for
    /// every viewer; a froxel reads it with the same 8 voxels as the light bits instead of
    /// evaluating the noise (off: every froxel evaluates the media).
    ///
    /// Beyond the paper: issue 14's "a froxel's work a few fetches" for density, in the
    /// words the froxel reads anyway (docs/decisions.md, "Density in the shared grid").
    #[serde(default)]
    grid_media: bool = true;

    /// With the density in the grid (`grid_media`): the density on cells of half a
    /// voxel, 8 per voxel (8 bytes a voxel more), read trilinearly, the voxel's code
    /// their mean; off: one sample at each voxel's centre.
    ///
    /// Beyond the paper: a voxel's centre sample blurs the media's finest noise octave,
    /// which froxels near the eye, narrower than a voxel, resolve. Closer to the
    /// evaluated media and to `truth`, but on lavapipe froxel lighting costs 1.3–1.5×
    /// (docs/decisions.md, "Density in the shared grid"), so off by default.
    #[serde(default)]
    grid_media_fine: bool = false;

    /// With the density in the grid (`grid_media`) and a dense, cached, demand-driven
    /// grid: a froxel that reads a voxel the grid has not filled makes it itself as the
    /// grid pass would (the same picture) and requests it for the next frame's grid
    /// pass, instead of a request pass walking every froxel before the grid (off: that
    /// pass, every frame).
    ///
    /// Beyond the paper: where the lights stand still the cached grid holds what the
    /// froxels read after a frame or two, and the request pass (10.5 ms of colonnade's
    /// 138 ms at 16 viewers) only finds what is already there; a filled voxel whose
    /// bits a mover made stale is traced again unasked. Used from the second frame until
    /// the first frame in which a light changes; from then on the request pass runs.
    /// It runs too in a frame after one whose froxels made (or whose grid pass traced)
    /// more than one ray per 64 froxels with media: a camera moving into space nobody
    /// has seen (docs/decisions.md, "Grid requests from the froxels").
    #[serde(default)]
    froxel_requests: bool = true;

    /// `shared`'s froxels read the shared shadow maps (2×2 PCF, as `maps` does) for every
    /// light that has one: no grid and no shadow frustum when every light has one, the
    /// hidden froxels still culled.
    #[serde(default)]
    froxel_maps: bool = false;

    /// Node spacing of the shared media transmittance volumes, metres (`shared` and `maps`; 0:
    /// every froxel and pixel marches its own shadow ray through the media, as
    /// `reference` does).
    ///
    /// T toward each light is computed once per frame for all viewers and cached while
    /// media and light are static (src/render/media_transmittance.rs).
    #[serde(default = "default_transmittance_voxel_m")]
    transmittance_voxel_m: f32 = default_transmittance_voxel_m(),
        was "tvoxel", "transmittance_voxel";

    /// Voxel edge of the world media layer, metres (`shared` only; 0: every froxel,
    /// pixel and transmittance column evaluates the media itself, as `reference` does).
    ///
    /// Height fog, noisy media and volumes are filled once per frame into sparse bricks
    /// where some viewer looks, and read with one trilinear lookup
    /// (src/render/media_layer.rs). Off by default: on lavapipe eight gathered nodes cost
    /// more than three octaves of value noise (docs/decisions.md, "The world media layer").
    #[serde(default)]
    media_voxel_m: f32 = 0.0, was "media_voxel";

    /// Quadrature step of a shadow ray through height and noisy media, metres.
    ///
    /// At most 32 steps per medium; homogeneous media are integrated exactly.
    #[serde(default = "default_media_step_m")]
    media_step_m: f32 = default_media_step_m(), was "media_step";

    /// Nodes per texel of the smoke's adaptive volumetric shadow maps (seed 002): 4, 8 or
    /// 16. More nodes follow the smoke's transmittance curve more closely (issue 15).
    #[serde(default = "default_avsm_nodes")]
    avsm_nodes: u32 = default_avsm_nodes();

    /// Texels a side of each light's smoke shadow map (16..=1024): the map is fitted to
    /// the particles' bounds every frame, so this is the shadow's resolution across them.
    #[serde(default = "default_avsm_px")]
    avsm_px: u32 = default_avsm_px();

    /// Simpson steps of a smoke particle's in-scattering along one pixel's interval
    /// (seed 001 §3.10; even, 2..=64). The optical depth is exact whatever this is.
    #[serde(default = "default_smoke_simpson_steps")]
    smoke_simpson_steps: u32 = default_smoke_simpson_steps();

    /// Probe spacing of the shared ambient grid, metres (0: the scene's constant
    /// `ambient`).
    ///
    /// Order-2 spherical harmonics of the sky, the media's scattering and the surfaces'
    /// reflection arriving at world-space probes, traced once per frame for every viewer
    /// and accumulated over frames (seed 003; src/render/ambient_grid.rs). They replace
    /// the constant ambient of the fog, the smoke and the surfaces.
    #[serde(default)]
    sh_ambient_m: f32 = 0.0;

    /// Coupled stereo: two views of one frame (a stereo session's eyes, or split views
    /// that nearly coincide) with the same orientation and field of view, whose eyes lie
    /// at most this far apart, light one froxel volume, metres (0: only coincident views).
    ///
    /// The first view lights it; the other lights only its near field
    /// (`stereo_near_px`) and integrates the first view's froxels beyond, where its own
    /// froxels' points project (src/render/viewer_set.rs, `stereo_pairs`;
    /// shaders/volume_integration.wgsl). Wider pairs light their own volumes
    /// (docs/decisions.md, "Coupled stereo").
    #[serde(default = "default_stereo_share_m")]
    stereo_share_m: f32 = default_stereo_share_m();

    /// Coupled stereo's near field: the second eye lights its own froxels nearer than
    /// the depth where the two eyes' disparity falls to this many pixels, and takes the
    /// first eye's froxels only beyond (0: it lights none).
    ///
    /// Near the eyes their rays are an eye distance apart, up to several froxels, and
    /// cross the light's edges at different places; beyond the split the first eye's
    /// froxels lie less than this from the second eye's and are interpolated between
    /// (docs/decisions.md, "Coupled stereo").
    #[serde(default = "default_stereo_near_px")]
    stereo_near_px: f32 = default_stereo_near_px();

    /// Coupled stereo's shared volume is lit from the midpoint between the eyes (the
    /// head), and both eyes integrate it along their own rays; no eye lights a near field
    /// (off: the first eye lights it from its own eye and the second eye reads it beyond
    /// its near field, `stereo_near_px`).
    ///
    /// Each eye then reads froxels lit half an eye distance away, instead of one eye
    /// exactly and the other a whole eye distance away (docs/decisions.md, "Coupled
    /// stereo: the volume from between the eyes").
    // Reports from before a setting existed read it as off (`serde(default)`).
    #[serde(default)]
    stereo_head: bool = false;

    /// The G-buffer draws, per view, only the triangles the raster would make fragments
    /// of: a compute pass drops those outside a clip plane, the back faces of one-sided
    /// meshes and those whose screen box holds no pixel centre, and writes the rest, in
    /// order, into the view's index list (off: each view draws every triangle of the
    /// clusters its frustum touches).
    ///
    /// The picture is the same; lavapipe pays for every triangle it sets up, and at
    /// 320×180 half of Sponza's triangles in a view fall between pixel centres
    /// (docs/decisions.md, "G-buffer: per-view triangle culling").
    // Reports from before a setting existed read it as off (`serde(default)`).
    #[serde(default)]
    triangle_cull: bool = true;

    /// With `triangle_cull`, in scenes of at least `OCCLUSION_MIN_TRIANGLES` (65,536)
    /// static triangles, the G-buffer raster runs in two phases per view: first the
    /// triangles the view saw last frame, then those of the other kept triangles that
    /// lie in front of the farthest depth the first phase drew over their screen box
    /// (a depth pyramid of 2×2 to 16×16 pixel tiles). Off: one phase, every kept
    /// triangle.
    ///
    /// A triangle dropped lies behind what is drawn at every pixel it covers, so the
    /// picture is the same. Off by default: on Sponza's path it draws a third fewer
    /// triangles, but on lavapipe its depth pyramid, test and second render passes cost
    /// what those triangles did (G-buffer ×1.006–1.013 over 16–24 paired frames, and 0.35
    /// MiB more a viewer; docs/decisions.md, "G-buffer: two-phase occlusion culling").
    // Reports from before a setting existed read it as off (`serde(default)`).
    #[serde(default)]
    occlusion_cull: bool = false;

    /// With `triangle_cull` (and without `occlusion_cull`), in scenes of at least
    /// `MICRO_MIN_TRIANGLES` (65,536) static triangles, the culling pass rasterises
    /// the triangles whose screen box holds at most 4 × 4 pixel centres itself, in
    /// compute: it tests each centre against the triangle's edges (snapped to 1/256
    /// pixel, top-left rule, as the raster does) and keeps the nearest triangle per
    /// pixel with a 64-bit atomicMax of (depth, triangle); a resolve pass then writes
    /// those pixels the raster's own triangles do not cover nearer into the G-buffer.
    /// Off: the raster draws every kept triangle. Needs 64-bit storage atomics (else
    /// off).
    ///
    /// The picture is the raster's up to pixels where two triangles' coverage rules or
    /// depths tie differently; on lavapipe the small triangles were most of the
    /// G-buffer's cost (docs/decisions.md, "G-buffer: small triangles rasterised in
    /// compute").
    // Reports from before a setting existed read it as off (`serde(default)`).
    #[serde(default)]
    micro_raster: bool = true;
}

// What reports from before these settings existed read as (and their defaults).
fn default_stereo_share_m() -> f32 {
    0.07
}

fn default_stereo_near_px() -> f32 {
    6.0
}

fn default_transmittance_voxel_m() -> f32 {
    0.5
}

fn default_media_step_m() -> f32 {
    0.5
}

fn default_avsm_nodes() -> u32 {
    8
}

fn default_avsm_px() -> u32 {
    128
}

fn default_smoke_simpson_steps() -> u32 {
    8
}

/// One setting, as `settings!` defines it.
struct Setting {
    /// The field's name: the key of config files and variants.
    key: &'static str,
    /// The field's documentation.
    doc: &'static str,
    /// What flags show as the default, where commands do not start from `default()`.
    cli_default: Option<&'static str>,
    /// Keys it had before.
    was: &'static [OldKey],
    /// What its values are, for errors and help.
    takes: fn() -> String,
    /// What flags' help shows for the value.
    placeholder: fn() -> String,
    /// The value of a flag given without one (`--parity` is `--parity on`).
    bare: Option<&'static str>,
    /// The value's text, as `set` reads it.
    get: fn(&Settings) -> String,
    /// Reads a value; `None` when the text is not one.
    set: fn(&mut Settings, &str) -> Option<()>,
}

/// A key a setting had before, and values it spelled differently (old, new).
struct OldKey {
    key: &'static str,
    values: &'static [(&'static str, &'static str)],
}

impl Setting {
    /// The documentation's lines.
    fn doc_lines(&self) -> impl Iterator<Item = &'static str> {
        self.doc.lines().map(str::trim)
    }

    /// The first paragraph of the documentation, on one line.
    fn summary(&self) -> String {
        let lines: Vec<&str> = self.doc_lines().take_while(|l| !l.is_empty()).collect();
        lines.join(" ")
    }

    fn flag(key: &str) -> String {
        key.replace('_', "-")
    }
}

/// How a setting's type reads from and prints as text.
trait Value: Sized {
    /// The value a flag given without one means.
    const BARE: Option<&'static str> = None;
    /// What flags' help shows for the value.
    fn placeholder() -> String {
        Self::takes()
    }
    fn takes() -> String;
    fn parse(text: &str) -> Option<Self>;
    fn text(&self) -> String;
}

impl Value for f32 {
    fn placeholder() -> String {
        "X".into()
    }
    fn takes() -> String {
        "a number".into()
    }
    fn parse(text: &str) -> Option<Self> {
        text.parse::<f32>().ok().filter(|v| v.is_finite())
    }
    fn text(&self) -> String {
        // Rust prints the shortest text that reads back as the same f32.
        self.to_string()
    }
}

impl Value for u32 {
    fn placeholder() -> String {
        "N".into()
    }
    fn takes() -> String {
        "a whole number".into()
    }
    fn parse(text: &str) -> Option<Self> {
        text.parse().ok()
    }
    fn text(&self) -> String {
        self.to_string()
    }
}

impl Value for bool {
    const BARE: Option<&'static str> = Some("on");
    fn takes() -> String {
        "on|off".into()
    }
    fn parse(text: &str) -> Option<Self> {
        match text {
            "on" | "true" | "yes" => Some(true),
            "off" | "false" | "no" => Some(false),
            _ => None,
        }
    }
    fn text(&self) -> String {
        if *self { "on" } else { "off" }.into()
    }
}

impl Value for Mode {
    fn takes() -> String {
        let names: Vec<&str> = Self::all().map(Mode::name).collect();
        names.join("|")
    }
    fn parse(text: &str) -> Option<Self> {
        Self::all().find(|m| m.name() == text)
    }
    fn text(&self) -> String {
        self.name().into()
    }
}

/// The setting `key` names (its own key or one it had before), and the old key if so.
fn find(key: &str) -> Option<(&'static Setting, Option<&'static OldKey>)> {
    SETTINGS.iter().find_map(|s| {
        if s.key == key {
            Some((s, None))
        } else {
            s.was.iter().find(|o| o.key == key).map(|o| (s, Some(o)))
        }
    })
}

impl Settings {
    /// `shared`'s defaults with the scene's voxel size: what flags, config files and
    /// bench variants change.
    pub fn for_scene(scene: &Scene) -> Settings {
        Settings {
            voxel_size_m: scene.render.voxel_size_m,
            ..Settings::default()
        }
    }

    /// Every setting's key, in the order of the fields.
    pub fn keys() -> impl Iterator<Item = &'static str> {
        SETTINGS.iter().map(|s| s.key)
    }

    /// Whether `key` names a setting (its key or one it had before).
    pub fn knows(key: &str) -> bool {
        find(key).is_some()
    }

    /// Sets the setting `key` (or a key it had before) from `value` as flags, config
    /// files and variants spell it; returns its key. Errors name the key and value and
    /// say what the setting takes, or list the keys. Ranges are `validate`'s.
    pub fn set(&mut self, key: &str, value: &str) -> anyhow::Result<&'static str> {
        let Some((setting, old)) = find(key) else {
            let keys: Vec<&str> = Self::keys().collect();
            bail!("unknown key '{key}' (keys: {})", keys.join(", "));
        };
        let text = match old.filter(|o| !o.values.is_empty()) {
            Some(o) => o
                .values
                .iter()
                .find(|(old, _)| *old == value)
                .map(|(_, new)| *new)
                .ok_or_else(|| {
                    let olds: Vec<&str> = o.values.iter().map(|(old, _)| *old).collect();
                    anyhow!("{key}={value}: expected {}", olds.join("|"))
                })?,
            None => value,
        };
        (setting.set)(self, text).ok_or_else(|| {
            let takes = (setting.takes)();
            match old {
                Some(_) => anyhow!("{key}={value}: expected {takes} (for {})", setting.key),
                None => anyhow!("{key}={value}: expected {takes}"),
            }
        })?;
        Ok(setting.key)
    }

    /// Sets `key=value,key=value,…` in turn (see `set`).
    pub fn set_all(&mut self, pairs: &str) -> anyhow::Result<()> {
        for pair in pairs.split(',').map(str::trim).filter(|p| !p.is_empty()) {
            let (key, value) = pair
                .split_once('=')
                .ok_or_else(|| anyhow!("'{pair}' is not key=value"))?;
            self.set(key.trim(), value.trim())?;
        }
        Ok(())
    }

    /// `key=value` as today's key and value text spell it (`voxel=0.50` is
    /// `voxel_size_m=0.5`), or why it is not a setting.
    pub fn spell(key: &str, value: &str) -> anyhow::Result<(&'static str, String)> {
        let mut s = Settings::default();
        let key = s.set(key, value)?;
        let setting = find(key).expect("set returns a key of SETTINGS").0;
        Ok((key, (setting.get)(&s)))
    }

    /// The settings that differ from `base`, as `key=value,…` in the order of the fields
    /// (empty when none); `base.set_all` of it gives `self` back.
    pub fn changes_from(&self, base: &Settings) -> String {
        let changes: Vec<String> = SETTINGS
            .iter()
            .map(|s| (s, (s.get)(self)))
            .filter(|(s, value)| *value != (s.get)(base))
            .map(|(s, value)| format!("{}={value}", s.key))
            .collect();
        changes.join(",")
    }

    /// A flag for every setting but `mode` (commands declare it themselves: `render`
    /// adds `truth`): `--` and the key in kebab case, with what `set` reads; older keys
    /// are hidden aliases. Clap holds no defaults: only flags given change the settings
    /// a command starts from (`given_flags`); the help shows `default()`'s.
    pub fn flags() -> Vec<clap::Arg> {
        let default = Settings::default();
        let mut args = Vec::new();
        for s in SETTINGS.iter().filter(|s| s.key != "mode") {
            let shown = s
                .cli_default
                .map_or_else(|| (s.get)(&default), str::to_string);
            let mut arg = clap::Arg::new(s.key)
                .long(Setting::flag(s.key))
                .value_name((s.placeholder)())
                .help(format!(
                    "{} [default: {shown}]",
                    s.summary().trim_end_matches('.')
                ))
                .long_help(format!(
                    "{}\n\n[default: {shown}]",
                    s.doc_lines().collect::<Vec<_>>().join("\n").trim_end()
                ))
                .value_parser(move |v: &str| Settings::spell(s.key, v).map(|(_, text)| text));
            if let Some(bare) = s.bare {
                arg = arg.num_args(0..=1).default_missing_value(bare);
            }
            for old in s.was {
                if old.values.is_empty() {
                    arg = arg.alias(Setting::flag(old.key));
                } else {
                    let olds: Vec<&str> = old.values.iter().map(|(o, _)| *o).collect();
                    args.push(
                        clap::Arg::new(old.key)
                            .long(Setting::flag(old.key))
                            .value_name(olds.join("|"))
                            .hide(true)
                            .conflicts_with(s.key)
                            .value_parser(move |v: &str| {
                                Settings::spell(old.key, v).map(|(_, text)| text)
                            }),
                    );
                }
            }
            args.push(arg);
        }
        args
    }

    /// The settings given on the command line by `flags()`, as (key, value text).
    pub fn given_flags(matches: &clap::ArgMatches) -> Vec<(&'static str, String)> {
        let mut given = Vec::new();
        for s in SETTINGS.iter().filter(|s| s.key != "mode") {
            let ids = std::iter::once(s.key)
                .chain(s.was.iter().filter(|o| !o.values.is_empty()).map(|o| o.key));
            for id in ids {
                if let Some(text) = matches.get_one::<String>(id) {
                    given.push((s.key, text.clone()));
                }
            }
        }
        given
    }

    /// Checks ranges; the error names the setting's key and value.
    pub fn validate(&self) -> anyhow::Result<()> {
        anyhow::ensure!(
            self.voxel_size_m.is_finite() && self.voxel_size_m >= 0.01,
            "voxel_size_m={}: must be at least 0.01 m",
            self.voxel_size_m
        );
        anyhow::ensure!(
            (1..=64).contains(&self.froxel_px),
            "froxel_px={}: must be 1..=64",
            self.froxel_px
        );
        anyhow::ensure!(
            (2..=512).contains(&self.slices),
            "slices={}: must be 2..=512",
            self.slices
        );
        anyhow::ensure!(
            (1..=128).contains(&self.frustum_px),
            "frustum_px={}: must be 1..=128",
            self.frustum_px
        );
        anyhow::ensure!(
            (0.0..=1.0).contains(&self.frustum_slice_fraction),
            "frustum_slice_fraction={}: must be 0..=1",
            self.frustum_slice_fraction
        );
        anyhow::ensure!(
            self.brick_pool <= 1 << 20,
            "brick_pool={}: at most 1048576 bricks",
            self.brick_pool
        );
        anyhow::ensure!(
            self.shadow_map_px == 0 || (64..=8192).contains(&self.shadow_map_px),
            "shadow_map_px={}: must be 0 (rays) or 64..=8192 texels a side",
            self.shadow_map_px
        );
        anyhow::ensure!(
            self.media_voxel_m == 0.0
                || (self.media_voxel_m.is_finite() && self.media_voxel_m >= 0.01),
            "media_voxel_m={}: must be 0 (evaluate the media per sample) or at least 0.01 m",
            self.media_voxel_m
        );
        anyhow::ensure!(
            self.sh_ambient_m == 0.0
                || (self.sh_ambient_m.is_finite() && self.sh_ambient_m >= 0.01),
            "sh_ambient_m={}: must be 0 (the constant ambient) or at least 0.01 m",
            self.sh_ambient_m
        );
        anyhow::ensure!(
            self.stereo_share_m.is_finite() && (0.0..=10.0).contains(&self.stereo_share_m),
            "stereo_share_m={}: must be 0..=10 metres",
            self.stereo_share_m
        );
        anyhow::ensure!(
            self.stereo_near_px.is_finite() && (0.0..=4096.0).contains(&self.stereo_near_px),
            "stereo_near_px={}: must be 0 (no near field per eye) ..=4096 pixels",
            self.stereo_near_px
        );
        anyhow::ensure!(
            self.mode != Mode::Maps || self.shadow_map_px > 0,
            "shadow_map_px=0: mode maps lights froxels from the shadow maps and needs them \
             (64..=8192)"
        );
        anyhow::ensure!(
            self.transmittance_voxel_m == 0.0
                || (self.transmittance_voxel_m.is_finite() && self.transmittance_voxel_m >= 0.01),
            "transmittance_voxel_m={}: must be 0 (march per sample) or at least 0.01 m",
            self.transmittance_voxel_m
        );
        anyhow::ensure!(
            crate::smoke::avsm::NODE_COUNTS.contains(&(self.avsm_nodes as usize)),
            "avsm_nodes={}: must be 4, 8 or 16",
            self.avsm_nodes
        );
        anyhow::ensure!(
            (16..=1024).contains(&self.avsm_px),
            "avsm_px={}: must be 16..=1024",
            self.avsm_px
        );
        anyhow::ensure!(
            self.smoke_simpson_steps.is_multiple_of(2)
                && (2..=64).contains(&self.smoke_simpson_steps),
            "smoke_simpson_steps={}: must be even, 2..=64",
            self.smoke_simpson_steps
        );
        anyhow::ensure!(
            self.media_step_m.is_finite() && self.media_step_m >= 0.01,
            "media_step_m={}: must be at least 0.01 m",
            self.media_step_m
        );
        anyhow::ensure!(
            self.depth_curve.is_finite() && (0.01..=20.0).contains(&self.depth_curve),
            "depth_curve={}: must be 0.01..=20",
            self.depth_curve
        );
        Ok(())
    }

    /// Depth slices of the shadow frustum (none in `maps` mode, which has no frustum).
    pub(crate) fn frustum_slices(&self) -> u32 {
        if self.mode == Mode::Maps || self.froxels_read_maps() || self.edges_from_maps() {
            return 0;
        }
        (self.slices as f32 * self.frustum_slice_fraction).ceil() as u32
    }

    /// Whether `shared`'s froxels read the shadow maps of the lights that have one
    /// (`froxel_maps`; the shadow frustum then has no slices, and the grid serves only
    /// lights without a map).
    pub(crate) fn froxels_read_maps(&self) -> bool {
        self.mode == Mode::Shared && self.froxel_maps && self.shadow_map_px > 0
    }

    /// Whether `shared`'s grid takes its shadow edges from the maps (`map_edges`; the
    /// shadow frustum then has no slices: every light with geometry has a map).
    pub(crate) fn edges_from_maps(&self) -> bool {
        self.mode == Mode::Shared && self.map_edges && self.shadow_map_px > 0
    }

    /// Whether `shared`'s grid may carry the media's density (`grid_media`): a dense
    /// trilinear grid, and no media layer (which would hold the same media).
    pub(crate) fn density_in_grid(&self) -> bool {
        self.mode == Mode::Shared
            && self.grid_media
            && self.trilinear
            && self.brick_pool == 0
            && self.media_voxel_m <= 0.0
    }

    /// Whether froxels may request the grid voxels they find unfilled (`froxel_requests`):
    /// the density in the grid marks what was filled, the grid is dense, demand-driven
    /// and cached, and every needed voxel is traced in the frame it is requested (no
    /// parity).
    pub(crate) fn requests_from_froxels(&self) -> bool {
        self.froxel_requests && self.density_in_grid() && self.demand && self.cache && !self.parity
    }

    /// Whether the shared shadow maps and media transmittance volumes are built (`shared`
    /// and `maps`; `reference` traces and marches everything).
    pub(crate) fn shares_light_space(&self) -> bool {
        self.mode != Mode::Reference
    }

    /// Whether froxels hidden behind the depth buffer are culled: with the demand-driven
    /// grid (dense or sparse) of `shared`, when some slices read the grid and no temporal
    /// history needs the hidden froxels.
    pub fn culls_hidden_froxels(&self) -> bool {
        self.mode == Mode::Shared
            && super::GridUpdate::of(self).requests()
            && !self.temporal
            && self.frustum_slices() < self.slices
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Settings with `key` changed from the default to some other valid value, and the
    /// value's text.
    fn changed(key: &str) -> (Settings, String) {
        let default = Settings::default();
        [
            "off",
            "on",
            "reference",
            "shared",
            "maps",
            "0",
            "0.5",
            "2",
            "64",
            "3",
        ]
        .into_iter()
        .find_map(|text| {
            let mut s = default;
            s.set(key, text).ok()?;
            (s != default).then(|| (s, text.to_string()))
        })
        .unwrap_or_else(|| panic!("{key}: no other value found"))
    }

    #[test]
    fn every_setting_round_trips_through_its_spelling() {
        let default = Settings::default();
        let mut all = default;
        for key in Settings::keys() {
            let (s, text) = changed(key);
            let spelled = s.changes_from(&default);
            assert_eq!(
                spelled,
                format!("{key}={}", Settings::spell(key, &text).unwrap().1)
            );
            let mut back = default;
            back.set_all(&spelled).unwrap();
            assert_eq!(back, s, "{spelled}");
            all.set_all(&spelled).unwrap();
        }
        let mut back = default;
        back.set_all(&all.changes_from(&default)).unwrap();
        assert_eq!(back, all);
        assert_eq!(default.changes_from(&default), "");
    }

    #[test]
    fn the_table_has_every_field_under_its_serde_name() {
        let json = serde_json::to_value(Settings::default()).unwrap();
        let fields: Vec<&str> = json
            .as_object()
            .unwrap()
            .keys()
            .map(String::as_str)
            .collect();
        let mut keys: Vec<&str> = Settings::keys().collect();
        keys.sort_unstable();
        assert_eq!(fields, keys, "serde_json sorts its keys");
        for m in Mode::all() {
            assert_eq!(serde_json::to_value(m).unwrap(), m.name());
            let clap_name = clap::ValueEnum::to_possible_value(&m).unwrap();
            assert_eq!(clap_name.get_name(), m.name());
        }
    }

    #[test]
    fn the_docs_list_every_key() {
        for (doc, text) in [
            ("docs/protocol.md", include_str!("../../docs/protocol.md")),
            (
                "docs/performance.md",
                include_str!("../../docs/performance.md"),
            ),
        ] {
            for key in Settings::keys() {
                assert!(text.contains(&format!("`{key}`")), "{doc} lists `{key}`");
            }
        }
    }

    #[test]
    fn older_keys_still_read() {
        let mut s = Settings::default();
        s.set_all("voxel=0.5,frustum=0.25,lookup=nearest,pool=64,map=0,tvoxel=1,media_step=0.25")
            .unwrap();
        let mut today = Settings::default();
        today
            .set_all(
                "voxel_size_m=0.5,frustum_slice_fraction=0.25,trilinear=off,brick_pool=64,\
                 shadow_map_px=0,transmittance_voxel_m=1,media_step_m=0.25",
            )
            .unwrap();
        assert_eq!(s, today);
        assert_eq!(
            Settings::spell("lookup", "trilinear").unwrap(),
            ("trilinear", "on".into())
        );
    }

    #[test]
    fn errors_name_the_key_and_value() {
        for (pairs, needle) in [
            (
                "voxel=abc",
                "voxel=abc: expected a number (for voxel_size_m)",
            ),
            ("lookup=cubic", "lookup=cubic: expected nearest|trilinear"),
            ("trilinear=nearest", "trilinear=nearest: expected on|off"),
            ("mode=truth", "mode=truth: expected reference|shared|maps"),
            ("slices=-3", "slices=-3: expected a whole number"),
            ("voxel_size_m=inf", "voxel_size_m=inf"),
            (
                "speed=3",
                "unknown key 'speed' (keys: mode, voxel_size_m, froxel_px",
            ),
            ("parity", "'parity' is not key=value"),
        ] {
            let e = Settings::default().set_all(pairs).unwrap_err().to_string();
            assert!(e.contains(needle), "{pairs}: {e}");
        }
    }

    #[test]
    fn flags_show_the_defaults_and_change_only_what_is_given() {
        let command = || clap::Command::new("t").args(Settings::flags());
        let help = command().render_help().to_string();
        let default = Settings::default();
        let mut at_defaults = vec!["t".to_string()];
        for key in Settings::keys().filter(|k| *k != "mode") {
            let flag = format!("--{}", key.replace('_', "-"));
            let setting = find(key).unwrap().0;
            let shown = setting
                .cli_default
                .map_or_else(|| (setting.get)(&default), str::to_string);
            assert!(help.contains(&flag), "{flag} in\n{help}");
            assert!(
                help.contains(&format!("[default: {shown}]")),
                "{key}: {shown}"
            );
            if setting.cli_default.is_none() {
                at_defaults.extend([flag, shown]);
            }
        }
        let none = command().get_matches_from(["t"]);
        assert!(Settings::given_flags(&none).is_empty());
        let given = Settings::given_flags(&command().get_matches_from(&at_defaults));
        let mut s = default;
        for (key, value) in &given {
            s.set(key, value).unwrap();
        }
        assert_eq!(given.len(), Settings::keys().count() - 2);
        assert_eq!(s, default, "every flag at its shown default is the default");

        let m = command().get_matches_from([
            "t",
            "--parity",
            "--demand",
            "false",
            "--lookup",
            "nearest",
            "--voxel-size",
            "0.5",
            "--map",
            "0",
        ]);
        assert_eq!(
            Settings::given_flags(&m),
            [
                ("voxel_size_m", "0.5".to_string()),
                ("parity", "on".into()),
                ("trilinear", "off".into()),
                ("demand", "off".into()),
                ("shadow_map_px", "0".into()),
            ]
        );
        let bad = command().try_get_matches_from(["t", "--slices", "many"]);
        let e = bad.unwrap_err().to_string();
        assert!(e.contains("slices=many: expected a whole number"), "{e}");
    }
}
