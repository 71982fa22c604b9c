//! Renderer settings given by key — flags of `fogcast render` and `serve`, keys of a
//! server config file — over the settings a command starts from
//! ([`Settings::for_scene`]). Keys, values and flags are `Settings`' own
//! (`src/render/settings.rs`); this only holds the ones given.

use crate::render::Settings;
use serde::de::{self, MapAccess, Visitor};
use serde::{Deserialize, Deserializer, Serialize, Serializer};
use std::fmt;

/// Settings given by key, spelled as today's keys and values; a later value of a
/// setting replaces an earlier one.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SettingsOverrides(Vec<(&'static str, String)>);

impl SettingsOverrides {
    /// Adds `key=value` in any spelling [`Settings::set`] reads.
    pub fn set(&mut self, key: &str, value: &str) -> anyhow::Result<()> {
        let (key, text) = Settings::spell(key, value)?;
        self.put(key, text);
        Ok(())
    }

    /// Adds every setting of `later`, replacing these ones' values.
    pub fn extend(&mut self, later: &SettingsOverrides) {
        for (key, text) in &later.0 {
            self.put(key, text.clone());
        }
    }

    fn put(&mut self, key: &'static str, text: String) {
        self.0.retain(|(k, _)| *k != key);
        self.0.push((key, text));
    }

    /// `base` with these settings, checked.
    pub fn apply(&self, base: Settings) -> anyhow::Result<Settings> {
        let mut settings = base;
        for (key, text) in &self.0 {
            settings.set(key, text)?;
        }
        settings.validate()?;
        Ok(settings)
    }
}

impl clap::FromArgMatches for SettingsOverrides {
    fn from_arg_matches(matches: &clap::ArgMatches) -> Result<Self, clap::Error> {
        let mut given = SettingsOverrides::default();
        given.update_from_arg_matches(matches)?;
        Ok(given)
    }

    fn update_from_arg_matches(&mut self, matches: &clap::ArgMatches) -> Result<(), clap::Error> {
        for (key, text) in Settings::given_flags(matches) {
            self.put(key, text);
        }
        Ok(())
    }
}

impl clap::Args for SettingsOverrides {
    fn augment_args(cmd: clap::Command) -> clap::Command {
        cmd.args(Settings::flags())
    }

    fn augment_args_for_update(cmd: clap::Command) -> clap::Command {
        Self::augment_args(cmd)
    }
}

/// Writes the settings as a map of key to value: numbers as numbers, the rest as text.
impl Serialize for SettingsOverrides {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        #[derive(Serialize)]
        #[serde(untagged)]
        enum Written<'a> {
            Whole(i64),
            Number(f64),
            Text(&'a str),
        }
        serializer.collect_map(self.0.iter().map(|(key, text)| {
            let value = match (text.parse(), text.parse()) {
                (Ok(whole), _) => Written::Whole(whole),
                (_, Ok(number)) => Written::Number(number),
                _ => Written::Text(text),
            };
            (key, value)
        }))
    }
}

/// Reads a map of settings (a config file's keys beside its own): every key must be a
/// setting, every value a number, boolean or string that it takes.
impl<'de> Deserialize<'de> for SettingsOverrides {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        struct Map;
        impl<'de> Visitor<'de> for Map {
            type Value = SettingsOverrides;
            fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                f.write_str("renderer settings by key")
            }
            fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<Self::Value, A::Error> {
                let mut given = SettingsOverrides::default();
                while let Some(key) = map.next_key::<String>()? {
                    if !Settings::knows(&key) {
                        let keys: Vec<&str> = Settings::keys().collect();
                        return Err(de::Error::custom(format!(
                            "unknown key '{key}': neither a key of this file nor a renderer \
                             setting (settings: {})",
                            keys.join(", ")
                        )));
                    }
                    let Scalar(text) = map.next_value()?;
                    given.set(&key, &text).map_err(de::Error::custom)?;
                }
                Ok(given)
            }
        }
        deserializer.deserialize_map(Map)
    }
}

/// A number, boolean or string, as text.
struct Scalar(String);

impl<'de> Deserialize<'de> for Scalar {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        struct Text;
        impl Visitor<'_> for Text {
            type Value = Scalar;
            fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                f.write_str("a number, boolean or string")
            }
            fn visit_bool<E: de::Error>(self, v: bool) -> Result<Scalar, E> {
                Ok(Scalar(v.to_string()))
            }
            fn visit_i64<E: de::Error>(self, v: i64) -> Result<Scalar, E> {
                Ok(Scalar(v.to_string()))
            }
            fn visit_u64<E: de::Error>(self, v: u64) -> Result<Scalar, E> {
                Ok(Scalar(v.to_string()))
            }
            fn visit_f64<E: de::Error>(self, v: f64) -> Result<Scalar, E> {
                Ok(Scalar(v.to_string()))
            }
            fn visit_str<E: de::Error>(self, v: &str) -> Result<Scalar, E> {
                Ok(Scalar(v.to_string()))
            }
        }
        deserializer.deserialize_any(Text)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser as _;

    #[derive(clap::Parser)]
    struct Flags {
        #[command(flatten)]
        given: SettingsOverrides,
    }

    fn flags(args: &[&str]) -> SettingsOverrides {
        Flags::try_parse_from(std::iter::once("t").chain(args.iter().copied()))
            .unwrap()
            .given
    }

    #[test]
    fn no_flags_change_nothing() {
        let given = flags(&[]);
        assert_eq!(given, SettingsOverrides::default());
        let base = Settings {
            voxel_size_m: 0.7,
            ..Settings::default()
        };
        assert_eq!(given.apply(base).unwrap(), base);
    }

    #[test]
    fn later_values_win_in_todays_spelling() {
        let mut file: SettingsOverrides =
            toml::from_str("voxel = 0.5\nlookup = \"nearest\"\ndemand = false\nslices = 64")
                .unwrap();
        file.extend(&flags(&["--demand", "--voxel-size-m", "1"]));
        let mut expected = Settings::default();
        expected
            .set_all("voxel_size_m=1,trilinear=off,demand=on,slices=64")
            .unwrap();
        assert_eq!(file.apply(Settings::default()).unwrap(), expected);
        assert_eq!(
            toml::to_string(&file).unwrap(),
            "trilinear = \"off\"\nslices = 64\nvoxel_size_m = 1\ndemand = \"on\"\n"
        );
        let e = file
            .apply(Settings {
                froxel_px: 0,
                ..Settings::default()
            })
            .unwrap_err();
        assert!(e.to_string().contains("froxel_px=0"), "{e}");
    }
}
