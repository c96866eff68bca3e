//! What a preview reads from an SCT file's provenance (the GENR section's `parameters`):
//! the source's up axis and how textures were bound when it was sampled, so that the
//! default view and the mesh reference match how the file was built.
//!
//! A one-step build (`sct-build-tree MESH`) and a two-step build (`sct-voxelize` then
//! `sct-build-tree SAMPLES`) both keep the sampler's record under
//! `parameters.sampling.parameters`; a file written by a sampler directly has it at
//! `parameters`. Both places are read, the sampling record first.

use std::path::{Path, PathBuf};

use sct_format::view::UpAxis;
use sct_format::Generator;
use serde_json::Value;

/// The settings a preview takes from a file's provenance (all absent when not recorded).
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct Provenance {
    /// The source's up axis (`up` or `up_axis`: `"x"`, `"y"`, `"z"`, optionally `+`-signed).
    pub up: Option<UpAxis>,
    /// The image bound as every material's base-colour texture (`texture_override`, as
    /// `sct-voxelize --texture` records it, or `texture`), as written: relative paths are
    /// relative to the directory the build ran in.
    pub texture: Option<String>,
    /// Whether textures were decoded: false for `--no-textures` (recorded as
    /// `no_textures: true` or `load_textures: false`).
    pub textures: Option<bool>,
}

impl Provenance {
    /// Reads the settings from a generator record; unknown or malformed values are ignored.
    pub fn from_generator(g: &Generator) -> Provenance {
        let records: Vec<&Value> =
            [g.parameters.get("sampling").and_then(|s| s.get("parameters")), Some(&g.parameters)].into_iter().flatten().collect();
        let find = |keys: &[&str]| records.iter().find_map(|r| keys.iter().find_map(|k| r.get(*k).filter(|v| !v.is_null())));
        let up = find(&["up", "up_axis"]).and_then(Value::as_str).and_then(|s| s.parse().ok());
        let texture = find(&["texture_override", "texture"]).and_then(Value::as_str).filter(|s| !s.is_empty()).map(String::from);
        let textures = records.iter().find_map(|r| {
            r.get("no_textures").and_then(Value::as_bool).map(|b| !b).or_else(|| r.get("load_textures").and_then(Value::as_bool))
        });
        Provenance { up, texture, textures }
    }

    /// Where the recorded texture is: the path as written if it exists (the build ran in
    /// this directory or recorded an absolute path), else the same relative path beside the
    /// reference mesh, then beside the SCT file. `Err` lists the places tried.
    pub fn locate_texture(&self, mesh: &Path, sct: &Path) -> Option<Result<PathBuf, Vec<PathBuf>>> {
        let t = Path::new(self.texture.as_deref()?);
        let mut tried = vec![t.to_path_buf()];
        if t.is_relative() {
            for dir in [mesh.parent(), sct.parent()].into_iter().flatten() {
                tried.push(dir.join(t));
                if let Some(name) = t.file_name() {
                    tried.push(dir.join(name));
                }
            }
        }
        tried.dedup();
        Some(tried.iter().find(|p| p.is_file()).cloned().ok_or(tried))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn gen(parameters: Value) -> Generator {
        Generator { parameters, ..Generator::default() }
    }

    #[test]
    fn reads_the_sampling_record_then_the_top_level() {
        let p = Provenance::from_generator(&gen(serde_json::json!({
            "profile": "default",
            "sampling": { "tool": "sct-voxelize", "parameters": { "texture_override": "spot_texture.png", "up": "+Z", "no_textures": false } }
        })));
        assert_eq!(p, Provenance { up: Some(UpAxis::Z), texture: Some("spot_texture.png".into()), textures: Some(true) });
        let p = Provenance::from_generator(&gen(serde_json::json!({ "up_axis": "x", "load_textures": false, "texture_override": null })));
        assert_eq!(p, Provenance { up: Some(UpAxis::X), texture: None, textures: Some(false) });
        assert_eq!(Provenance::from_generator(&gen(Value::Null)), Provenance::default());
        // Garbage is ignored rather than fatal.
        let p = Provenance::from_generator(&gen(serde_json::json!({ "up": "sideways", "texture": 3 })));
        assert_eq!(p, Provenance::default());
    }

    #[test]
    fn the_texture_is_found_beside_the_mesh() {
        let dir = tempfile::tempdir().unwrap();
        let mesh_dir = dir.path().join("m");
        std::fs::create_dir(&mesh_dir).unwrap();
        std::fs::write(mesh_dir.join("tex.png"), b"x").unwrap();
        let p = Provenance { texture: Some("build/dir/tex.png".into()), ..Default::default() };
        let found = p.locate_texture(&mesh_dir.join("a.obj"), &dir.path().join("a.sct")).unwrap();
        assert_eq!(found, Ok(mesh_dir.join("tex.png")));
        let p = Provenance { texture: Some("nope.png".into()), ..Default::default() };
        let Some(Err(tried)) = p.locate_texture(&mesh_dir.join("a.obj"), &dir.path().join("a.sct")) else { panic!() };
        assert!(tried.len() >= 3, "{tried:?}");
        assert!(Provenance::default().locate_texture(Path::new("a.obj"), Path::new("a.sct")).is_none());
    }
}
