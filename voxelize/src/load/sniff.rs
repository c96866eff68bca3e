//! What a file is, from its first bytes: so that a tool handed the wrong kind of file can
//! say what it got ("this is an STL file", "this is an SCT scene file") instead of "bad
//! magic bytes", and a mesh without its extension still loads.

use std::io::Read;
use std::path::Path;

/// Bytes [`sniff_path`] reads: enough for every signature below.
pub const SNIFF_BYTES: usize = 512;

/// A file kind recognised by its content.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum FileKind {
    /// Binary glTF (`glTF` magic).
    GltfBinary,
    /// glTF JSON (an object with an `"asset"` member near the start).
    GltfJson,
    /// PLY (`ply` magic line).
    Ply,
    /// Wavefront OBJ (text whose first statements are OBJ keywords).
    Obj,
    /// STL, ASCII (`solid …`) or binary (80-byte header and a triangle count that matches
    /// the file size).
    Stl,
    /// Autodesk FBX, binary or ASCII.
    Fbx,
    /// An SCT scene file (what `sct-build-tree` writes).
    SctScene,
    /// An SCT samples file (what `sct-voxelize` writes).
    SctSamples,
    /// A PNG, JPEG, BMP, TGA or other image.
    Image,
    /// None of the above.
    Unknown,
}

impl FileKind {
    /// A short name for messages: "STL", "an SCT scene file", …
    pub fn describe(self) -> &'static str {
        match self {
            FileKind::GltfBinary => "a binary glTF (GLB) file",
            FileKind::GltfJson => "a glTF JSON file",
            FileKind::Ply => "a PLY file",
            FileKind::Obj => "an OBJ file",
            FileKind::Stl => "an STL file",
            FileKind::Fbx => "an FBX file",
            FileKind::SctScene => "an SCT scene file",
            FileKind::SctSamples => "an SCT samples file",
            FileKind::Image => "an image",
            FileKind::Unknown => "not a file this tool recognises by its extension or content",
        }
    }

    /// Whether the voxelizer loads this kind as a mesh.
    pub fn is_mesh(self) -> bool {
        matches!(self, FileKind::GltfBinary | FileKind::GltfJson | FileKind::Ply | FileKind::Obj)
    }

    /// For a kind no SCT tool reads as a mesh: what to do instead, as one sentence.
    pub fn unsupported_mesh_hint(self) -> Option<&'static str> {
        match self {
            FileKind::Stl => Some("STL is not supported: convert it to glTF or PLY (e.g. in Blender or MeshLab)"),
            FileKind::Fbx => Some("FBX is not supported: convert it to glTF (e.g. with FBX2glTF or Blender)"),
            _ => None,
        }
    }
}

/// The kind of a file from its first bytes (`head`; [`SNIFF_BYTES`] are plenty) and, for
/// binary STL, its total length.
pub fn sniff(head: &[u8], file_len: u64) -> FileKind {
    if head.starts_with(&sct_format::raw::SCT_MAGIC) {
        return FileKind::SctScene;
    }
    if head.starts_with(&sct_format::raw::SAMPLES_MAGIC) {
        return FileKind::SctSamples;
    }
    if head.starts_with(b"glTF") {
        return FileKind::GltfBinary;
    }
    if head.starts_with(b"Kaydara FBX Binary") {
        return FileKind::Fbx;
    }
    if head.starts_with(b"\x89PNG") || head.starts_with(b"\xff\xd8\xff") || head.starts_with(b"BM") && head.len() > 14 && file_len > 26 {
        return FileKind::Image;
    }
    // Binary STL: an 80-byte header, a u32 triangle count, 50 bytes per triangle. Checked
    // before the text kinds: its header may well start with "solid".
    if head.len() >= 84 {
        let n = u32::from_le_bytes([head[80], head[81], head[82], head[83]]) as u64;
        if n > 0 && 84 + 50 * n == file_len {
            return FileKind::Stl;
        }
    }
    let text = String::from_utf8_lossy(head);
    let t = text.trim_start_matches('\u{feff}').trim_start();
    if t.starts_with("ply") && t[3..].starts_with(['\r', '\n']) {
        return FileKind::Ply;
    }
    if t.starts_with("solid") && (text.contains("facet") || text.contains("endsolid")) {
        return FileKind::Stl;
    }
    if t.starts_with("; FBX") || t.contains("FBXHeaderExtension") {
        return FileKind::Fbx;
    }
    if t.starts_with('{') && text.contains("\"asset\"") {
        return FileKind::GltfJson;
    }
    if looks_like_obj(t) {
        return FileKind::Obj;
    }
    FileKind::Unknown
}

/// Text whose first statements (comments and blank lines aside) are OBJ keywords.
fn looks_like_obj(t: &str) -> bool {
    const KEYWORDS: [&str; 14] = ["v", "vt", "vn", "vp", "f", "l", "p", "o", "g", "s", "mtllib", "usemtl", "cstype", "deg"];
    let mut statements = 0;
    for line in t.lines() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let word = line.split_whitespace().next().unwrap_or("");
        if !KEYWORDS.contains(&word) {
            // A partial last line cut by the sniff window is not evidence against.
            return statements >= 2 && !t.ends_with('\n') && t.ends_with(line);
        }
        statements += 1;
    }
    statements >= 1
}

/// The kind of the file at `path` from its first [`SNIFF_BYTES`] bytes; `None` when it
/// cannot be read as a regular file (the caller's own open reports why).
pub fn sniff_path(path: &Path) -> Option<FileKind> {
    let file = sct_format::fsio::open_regular(path).ok()?;
    let len = file.metadata().ok()?.len();
    let mut head = Vec::with_capacity(SNIFF_BYTES);
    file.take(SNIFF_BYTES as u64).read_to_end(&mut head).ok()?;
    Some(sniff(&head, len))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn kind(bytes: &[u8]) -> FileKind {
        sniff(bytes, bytes.len() as u64)
    }

    #[test]
    fn kinds_are_recognised_by_content() {
        assert_eq!(kind(b"solid cube\n facet normal 0 0 1\n"), FileKind::Stl);
        let mut stl = vec![b's'; 80];
        stl.extend_from_slice(&1u32.to_le_bytes());
        stl.extend_from_slice(&[0u8; 50]);
        assert_eq!(kind(&stl), FileKind::Stl, "binary STL whose header starts with 'solid'");
        assert_eq!(kind(b"Kaydara FBX Binary  \0\x1a\0"), FileKind::Fbx);
        assert_eq!(kind(b"; FBX 7.4.0 project file\n"), FileKind::Fbx);
        assert_eq!(kind(b"glTF\x02\0\0\0"), FileKind::GltfBinary);
        assert_eq!(kind(b"{\n  \"asset\": {\"version\": \"2.0\"}}"), FileKind::GltfJson);
        assert_eq!(kind(b"ply\nformat ascii 1.0\n"), FileKind::Ply);
        assert_eq!(kind(b"# a cube\nmtllib c.mtl\nv 0 0 0\nv 1 0 0\n"), FileKind::Obj);
        assert_eq!(kind(&sct_format::raw::SCT_MAGIC), FileKind::SctScene);
        assert_eq!(kind(&sct_format::raw::SAMPLES_MAGIC), FileKind::SctSamples);
        assert_eq!(kind(b"hello world"), FileKind::Unknown);
        assert_eq!(kind(b""), FileKind::Unknown);
        assert_eq!(kind(b"\x89PNG\r\n\x1a\n"), FileKind::Image);
    }
}
