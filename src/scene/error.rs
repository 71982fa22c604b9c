//! [`SceneError`]: what is wrong with a scene, naming the field and value at fault.

use super::builtin_names;
use std::path::PathBuf;

/// An error in a scene description, naming the field and value at fault.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    /// The file could not be read.
    #[error("cannot read scene file {path}: {source}")]
    Io {
        /// The path that failed.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
    /// TOML syntax or a type mismatch; the parser names line, column and field.
    #[error("scene file {path}: {message}")]
    Parse {
        /// The scene file.
        path: PathBuf,
        /// The parser's message.
        message: String,
    },
    /// A value that parsed but makes no sense.
    #[error("scene field `{field}` = {value}: {reason}")]
    Invalid {
        /// Dotted path of the field, e.g. `media[1].absorption`.
        field: String,
        /// The offending value as written.
        value: String,
        /// What is expected instead.
        reason: String,
    },
    /// A glTF file could not be loaded.
    #[error("glTF {path}: {message}")]
    Gltf {
        /// The glTF path.
        path: PathBuf,
        /// What went wrong.
        message: String,
    },
    /// No built-in scene and no file of that name.
    #[error("unknown scene `{0}`: not a built-in scene ({names}) and no such file", names = builtin_names().join(", "))]
    Unknown(String),
}

pub(crate) fn invalid(
    field: impl Into<String>,
    value: impl std::fmt::Debug,
    reason: &str,
) -> SceneError {
    SceneError::Invalid {
        field: field.into(),
        value: format!("{value:?}"),
        reason: reason.to_string(),
    }
}
