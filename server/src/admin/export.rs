//! Mesh export formats shared by the admin commands: which format a path asks
//! for, a borrowed view of the mesh to write, and an owned mesh read back.

use std::path::Path;

use thiserror::Error;

/// File formats `strata-admin` can write meshes in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ExportFormat {
    /// Binary little-endian PLY with normals and a per-vertex material.
    Ply,
    /// Wavefront OBJ text (positions, normals, faces; no materials).
    Obj,
    /// glTF 2.0 binary: positions, normals, material colours and ids.
    Glb,
}

/// Why a mesh could not be exported or read back.
#[derive(Debug, Error)]
pub enum ExportError {
    #[error("output file {path:?} has no extension; use .ply, .obj or .glb")]
    NoExtension { path: String },
    #[error("output file {path:?} has unknown extension {ext:?}; use .ply, .obj or .glb")]
    UnknownExtension { path: String, ext: String },
    #[error(
        "mesh arrays disagree: {positions} positions, {normals} normals, {materials} materials"
    )]
    VertexArrays {
        positions: usize,
        normals: usize,
        materials: usize,
    },
    #[error("index count {0} is not a multiple of 3")]
    PartialTriangle(usize),
    #[error("triangle index {index} is out of range for {vertices} vertices")]
    IndexOutOfRange { index: u32, vertices: usize },
    #[error("{count} vertices exceed the format limit of {limit}")]
    TooManyVertices { count: usize, limit: usize },
    #[error("malformed {format} data: {reason}")]
    Malformed {
        format: &'static str,
        reason: String,
    },
    #[error("I/O error while exporting: {0}")]
    Io(#[from] std::io::Error),
}

impl ExportError {
    /// Bytes that are not in the layout `format`'s reader expects.
    pub fn malformed(format: &'static str, reason: impl Into<String>) -> Self {
        ExportError::Malformed {
            format,
            reason: reason.into(),
        }
    }
}

impl ExportFormat {
    /// Picks the format from the file extension (case-insensitive).
    pub fn from_path(path: &Path) -> Result<Self, ExportError> {
        let shown = path.display().to_string();
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .ok_or(ExportError::NoExtension {
                path: shown.clone(),
            })?;
        match ext.to_ascii_lowercase().as_str() {
            "ply" => Ok(ExportFormat::Ply),
            "obj" => Ok(ExportFormat::Obj),
            "glb" => Ok(ExportFormat::Glb),
            _ => Err(ExportError::UnknownExtension {
                path: shown,
                ext: ext.to_string(),
            }),
        }
    }
}

/// A borrowed, format-neutral view of an indexed triangle mesh.
#[derive(Debug, Clone, Copy)]
pub struct MeshRef<'a> {
    pub positions: &'a [[f32; 3]],
    pub normals: &'a [[f32; 3]],
    pub materials: &'a [u8],
    /// Triangles, three vertex indices each.
    pub indices: &'a [u32],
}

impl<'a> From<&'a strata_terrain::mesh::Mesh> for MeshRef<'a> {
    fn from(m: &'a strata_terrain::mesh::Mesh) -> Self {
        MeshRef {
            positions: &m.positions,
            normals: &m.normals,
            materials: &m.materials,
            indices: &m.indices,
        }
    }
}

impl MeshRef<'_> {
    /// Checks the arrays agree and every index is in range, so writers never
    /// emit a file that references a missing vertex.
    pub fn validate(&self) -> Result<(), ExportError> {
        let n = self.positions.len();
        if self.normals.len() != n || self.materials.len() != n {
            return Err(ExportError::VertexArrays {
                positions: n,
                normals: self.normals.len(),
                materials: self.materials.len(),
            });
        }
        if self.indices.len() % 3 != 0 {
            return Err(ExportError::PartialTriangle(self.indices.len()));
        }
        if let Some(&index) = self.indices.iter().find(|&&i| i as usize >= n) {
            return Err(ExportError::IndexOutOfRange { index, vertices: n });
        }
        Ok(())
    }

    pub fn triangle_count(&self) -> usize {
        self.indices.len() / 3
    }
}

/// An owned mesh, as read back from an exported file.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ExportMesh {
    pub positions: Vec<[f32; 3]>,
    pub normals: Vec<[f32; 3]>,
    pub materials: Vec<u8>,
    pub indices: Vec<u32>,
}

impl ExportMesh {
    pub fn as_ref(&self) -> MeshRef<'_> {
        MeshRef {
            positions: &self.positions,
            normals: &self.normals,
            materials: &self.materials,
            indices: &self.indices,
        }
    }
}

/// Writes `mesh` in `format`.
pub fn write_mesh(
    format: ExportFormat,
    mesh: MeshRef<'_>,
    out: &mut impl std::io::Write,
) -> Result<(), ExportError> {
    match format {
        ExportFormat::Ply => super::ply::write_ply(mesh, out),
        ExportFormat::Obj => super::obj::write_obj(mesh, out),
        ExportFormat::Glb => super::glb::write_glb(mesh, out),
    }
}

/// Mode of exported files: readable by everyone, like any file a user saves
/// (temporary files start private).
pub const OUTPUT_MODE: u32 = 0o644;

/// A temporary file next to `out` (same directory, so it can be renamed
/// onto `out` once complete): outputs never appear half-written. It is
/// held (`stale_outputs::hold`) while written, and those a killed run
/// left, which nobody holds, are removed first.
pub fn stage_output(out: &Path) -> std::io::Result<tempfile::NamedTempFile> {
    super::stale_outputs::clear_for(out);
    let dir = super::stale_outputs::dir_of(out);
    let prefix = format!(
        "{}{}-",
        super::stale_outputs::STAGED_PREFIX,
        std::process::id()
    );
    let tmp = tempfile::Builder::new().prefix(&prefix).tempfile_in(dir)?;
    // Held until renamed into place: no other run takes it for a stale one.
    super::stale_outputs::hold(tmp.as_file())?;
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        tmp.as_file()
            .set_permissions(std::fs::Permissions::from_mode(OUTPUT_MODE))?;
    }
    Ok(tmp)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn format_from_extension() {
        assert_eq!(
            ExportFormat::from_path(Path::new("a/b.ply")).unwrap(),
            ExportFormat::Ply
        );
        assert_eq!(
            ExportFormat::from_path(Path::new("B.OBJ")).unwrap(),
            ExportFormat::Obj
        );
        assert!(matches!(
            ExportFormat::from_path(Path::new("mesh.stl")),
            Err(ExportError::UnknownExtension { ext, .. }) if ext == "stl"
        ));
        assert!(matches!(
            ExportFormat::from_path(Path::new("mesh")),
            Err(ExportError::NoExtension { .. })
        ));
    }

    #[test]
    fn validate_rejects_inconsistent_meshes() {
        let p = [[0.0f32; 3]; 3];
        let ok = MeshRef {
            positions: &p,
            normals: &p,
            materials: &[1, 2, 3],
            indices: &[0, 1, 2],
        };
        ok.validate().unwrap();
        let short = MeshRef {
            materials: &[1],
            ..ok
        };
        assert!(matches!(
            short.validate(),
            Err(ExportError::VertexArrays { .. })
        ));
        let partial = MeshRef {
            indices: &[0, 1],
            ..ok
        };
        assert!(matches!(
            partial.validate(),
            Err(ExportError::PartialTriangle(2))
        ));
        let oob = MeshRef {
            indices: &[0, 1, 3],
            ..ok
        };
        assert!(matches!(
            oob.validate(),
            Err(ExportError::IndexOutOfRange { index: 3, .. })
        ));
    }
}
