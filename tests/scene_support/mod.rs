//! Helpers shared by the scene tests: a scratch folder and a minimal glTF writer.
#![allow(dead_code)] // each test binary uses a different subset

use std::path::{Path, PathBuf};

/// A scratch folder for glTF files, removed on drop.
pub struct TempDir(PathBuf);

impl TempDir {
    /// A fresh folder under the system temp dir, unique to this process and `name`.
    pub fn new(name: &str) -> TempDir {
        let dir =
            std::env::temp_dir().join(format!("fogcast-scene-tests-{}-{name}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("temp dir");
        TempDir(dir)
    }

    /// The folder.
    pub fn path(&self) -> &Path {
        &self.0
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// Standard base64 (RFC 4648, padded), for glTF data URIs.
pub fn base64(bytes: &[u8]) -> String {
    const ALPHABET: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::new();
    for chunk in bytes.chunks(3) {
        let b = [
            chunk[0],
            *chunk.get(1).unwrap_or(&0),
            *chunk.get(2).unwrap_or(&0),
        ];
        let n = ((b[0] as u32) << 16) | ((b[1] as u32) << 8) | b[2] as u32;
        for k in 0..4 {
            if k <= chunk.len() {
                out.push(ALPHABET[((n >> (18 - 6 * k)) & 63) as usize] as char);
            } else {
                out.push('=');
            }
        }
    }
    out
}

/// A glTF with one non-indexed triangle-list mesh of `vertices`, its buffer embedded
/// as base64, written to `dir/mesh.gltf`. The accessor's min/max (required for
/// POSITION) ignore non-finite values.
pub fn write_gltf(dir: &Path, vertices: &[[f32; 3]]) -> PathBuf {
    let bytes: Vec<u8> = vertices
        .iter()
        .flatten()
        .flat_map(|x| x.to_le_bytes())
        .collect();
    let finite = || vertices.iter().flatten().copied().filter(|x| x.is_finite());
    let (lo, hi) = (
        finite().fold(f32::MAX, f32::min),
        finite().fold(f32::MIN, f32::max),
    );
    let json = format!(
        r#"{{
  "asset": {{ "version": "2.0" }},
  "scene": 0,
  "scenes": [{{ "nodes": [0] }}],
  "nodes": [{{ "mesh": 0 }}],
  "meshes": [{{ "primitives": [{{ "attributes": {{ "POSITION": 0 }} }}] }}],
  "buffers": [{{ "byteLength": {len}, "uri": "data:application/octet-stream;base64,{data}" }}],
  "bufferViews": [{{ "buffer": 0, "byteOffset": 0, "byteLength": {len} }}],
  "accessors": [{{ "bufferView": 0, "componentType": 5126, "count": {count}, "type": "VEC3",
                   "min": [{lo}, {lo}, {lo}], "max": [{hi}, {hi}, {hi}] }}]
}}"#,
        len = bytes.len(),
        data = base64(&bytes),
        count = vertices.len(),
    );
    let path = dir.join("mesh.gltf");
    std::fs::write(&path, json).expect("write glTF");
    path
}
