//! Built-in scenes, shipped inside the binary (their sources are `scenes/*.toml`).

const BUILTIN: &[(&str, &str)] = &[
    ("colonnade", include_str!("../../scenes/colonnade.toml")),
    ("street", include_str!("../../scenes/street.toml")),
    ("islands", include_str!("../../scenes/islands.toml")),
    ("cloud", include_str!("../../scenes/cloud.toml")),
    ("chimney", include_str!("../../scenes/chimney.toml")),
    ("smokehall", include_str!("../../scenes/smokehall.toml")),
];

/// Names of the built-in scenes.
pub fn builtin_names() -> Vec<&'static str> {
    BUILTIN.iter().map(|(n, _)| *n).collect()
}

/// The TOML text of a built-in scene.
pub fn builtin_scene(name: &str) -> Option<&'static str> {
    BUILTIN.iter().find(|(n, _)| *n == name).map(|(_, t)| *t)
}
