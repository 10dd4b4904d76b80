//! Binary little-endian PLY: the compact export every mesh viewer reads
//! (MeshLab, Blender, ParaView), and it keeps the per-vertex material.
//!
//! Layout: `vertex` records of `float x y z, float nx ny nz, uchar material`
//! (25 bytes) and `face` records of `list uchar int vertex_indices` (always 3
//! indices, 13 bytes).

use std::io::Write;

use super::export::{ExportError, ExportMesh, MeshRef};

/// PLY `int` indices are signed 32-bit, so this is the largest vertex count.
pub const PLY_MAX_VERTICES: usize = i32::MAX as usize;
/// Bytes of one vertex record.
pub const PLY_VERTEX_BYTES: usize = 6 * 4 + 1;
/// Bytes of one triangle record.
pub const PLY_FACE_BYTES: usize = 1 + 3 * 4;
/// Records encoded per buffered write.
const BATCH: usize = 4096;

const FORMAT: &str = "PLY";

fn header(vertices: usize, faces: usize) -> String {
    format!(
        "ply\nformat binary_little_endian 1.0\ncomment written by strata-admin\n\
         element vertex {vertices}\nproperty float x\nproperty float y\nproperty float z\n\
         property float nx\nproperty float ny\nproperty float nz\nproperty uchar material\n\
         element face {faces}\nproperty list uchar int vertex_indices\nend_header\n"
    )
}

/// Writes `mesh` as binary little-endian PLY.
pub fn write_ply(mesh: MeshRef<'_>, out: &mut impl Write) -> Result<(), ExportError> {
    mesh.validate()?;
    let n = mesh.positions.len();
    if n > PLY_MAX_VERTICES {
        return Err(ExportError::TooManyVertices {
            count: n,
            limit: PLY_MAX_VERTICES,
        });
    }
    out.write_all(header(n, mesh.triangle_count()).as_bytes())?;

    let mut buf = Vec::with_capacity(BATCH * PLY_VERTEX_BYTES);
    for start in (0..n).step_by(BATCH) {
        buf.clear();
        for i in start..(start + BATCH).min(n) {
            for c in mesh.positions[i].iter().chain(&mesh.normals[i]) {
                buf.extend_from_slice(&c.to_le_bytes());
            }
            buf.push(mesh.materials[i]);
        }
        out.write_all(&buf)?;
    }
    for tris in mesh.indices.chunks(3 * BATCH) {
        buf.clear();
        for tri in tris.chunks_exact(3) {
            buf.push(3);
            for &i in tri {
                // In range of i32: validated above (i < n <= PLY_MAX_VERTICES).
                buf.extend_from_slice(&(i as i32).to_le_bytes());
            }
        }
        out.write_all(&buf)?;
    }
    out.flush()?;
    Ok(())
}

fn malformed(reason: impl Into<String>) -> ExportError {
    ExportError::malformed(FORMAT, reason)
}

/// Reads back a PLY file in exactly the layout [`write_ply`] produces. Other
/// PLY layouts are rejected with a reason rather than misread.
pub fn read_ply(bytes: &[u8]) -> Result<ExportMesh, ExportError> {
    const END: &[u8] = b"end_header\n";
    let end = bytes
        .windows(END.len())
        .position(|w| w == END)
        .ok_or_else(|| malformed("no end_header line"))?;
    let head =
        std::str::from_utf8(&bytes[..end]).map_err(|_| malformed("header is not UTF-8 text"))?;
    let body = &bytes[end + END.len()..];

    let count = |element: &str| -> Result<usize, ExportError> {
        head.lines()
            .find_map(|l| {
                l.strip_prefix("element ")?
                    .strip_prefix(element)?
                    .strip_prefix(' ')
            })
            .ok_or_else(|| malformed(format!("no element {element}")))?
            .trim()
            .parse()
            .map_err(|_| malformed(format!("bad element {element} count")))
    };
    let (nv, nf) = (count("vertex")?, count("face")?);
    if header(nv, nf).as_bytes() != &bytes[..end + END.len()] {
        return Err(malformed(
            "header layout differs from the strata-admin PLY layout",
        ));
    }
    let vbytes = nv
        .checked_mul(PLY_VERTEX_BYTES)
        .ok_or_else(|| malformed("vertex count"))?;
    let fbytes = nf
        .checked_mul(PLY_FACE_BYTES)
        .ok_or_else(|| malformed("face count"))?;
    if vbytes.checked_add(fbytes) != Some(body.len()) {
        return Err(malformed(format!(
            "body is {} bytes, header implies {} vertices and {} faces",
            body.len(),
            nv,
            nf
        )));
    }

    let f32_at = |b: &[u8], o: usize| f32::from_le_bytes([b[o], b[o + 1], b[o + 2], b[o + 3]]);
    let mut mesh = ExportMesh::default();
    for rec in body[..vbytes].chunks_exact(PLY_VERTEX_BYTES) {
        mesh.positions
            .push([f32_at(rec, 0), f32_at(rec, 4), f32_at(rec, 8)]);
        mesh.normals
            .push([f32_at(rec, 12), f32_at(rec, 16), f32_at(rec, 20)]);
        mesh.materials.push(rec[24]);
    }
    for rec in body[vbytes..].chunks_exact(PLY_FACE_BYTES) {
        if rec[0] != 3 {
            return Err(malformed(format!("face with {} vertices", rec[0])));
        }
        for k in 0..3 {
            let o = 1 + 4 * k;
            let i = i32::from_le_bytes([rec[o], rec[o + 1], rec[o + 2], rec[o + 3]]);
            let i = u32::try_from(i).map_err(|_| malformed("negative vertex index"))?;
            mesh.indices.push(i);
        }
    }
    mesh.as_ref().validate()?;
    Ok(mesh)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tetra() -> ExportMesh {
        ExportMesh {
            positions: vec![
                [0.0, 0.0, 0.0],
                [1.5, 0.0, 0.0],
                [0.0, 2.25, 0.0],
                [0.0, 0.0, -3.0],
            ],
            normals: vec![
                [0.0, 0.0, 1.0],
                [1.0, 0.0, 0.0],
                [0.0, 1.0, 0.0],
                [0.0, -1.0, 0.0],
            ],
            materials: vec![1, 2, 3, 255],
            indices: vec![0, 2, 1, 0, 1, 3, 0, 3, 2, 1, 2, 3],
        }
    }

    #[test]
    fn header_and_body_layout() {
        let m = tetra();
        let mut out = Vec::new();
        write_ply(m.as_ref(), &mut out).unwrap();
        let text_end = out.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
        let head = std::str::from_utf8(&out[..text_end]).unwrap();
        assert!(head.starts_with("ply\nformat binary_little_endian 1.0\n"));
        assert!(head.contains("element vertex 4\n"));
        assert!(head.contains("property uchar material\n"));
        assert!(head.contains("element face 4\nproperty list uchar int vertex_indices\n"));
        let body = &out[text_end..];
        assert_eq!(body.len(), 4 * PLY_VERTEX_BYTES + 4 * PLY_FACE_BYTES);
        // Second vertex: x = 1.5 little-endian, material byte 2 at the end.
        let v1 = &body[PLY_VERTEX_BYTES..2 * PLY_VERTEX_BYTES];
        assert_eq!(&v1[0..4], &1.5f32.to_le_bytes());
        assert_eq!(v1[24], 2);
        // First face: count 3 then indices 0, 2, 1.
        let f0 = &body[4 * PLY_VERTEX_BYTES..][..PLY_FACE_BYTES];
        assert_eq!(f0[0], 3);
        assert_eq!(&f0[5..9], &2i32.to_le_bytes());
    }

    #[test]
    fn round_trip_is_exact() {
        let m = tetra();
        let mut out = Vec::new();
        write_ply(m.as_ref(), &mut out).unwrap();
        assert_eq!(read_ply(&out).unwrap(), m);
    }

    #[test]
    fn empty_mesh_round_trips() {
        let m = ExportMesh::default();
        let mut out = Vec::new();
        write_ply(m.as_ref(), &mut out).unwrap();
        assert_eq!(read_ply(&out).unwrap(), m);
    }

    #[test]
    fn reader_rejects_truncated_and_foreign_files() {
        let mut out = Vec::new();
        write_ply(tetra().as_ref(), &mut out).unwrap();
        assert!(matches!(
            read_ply(&out[..out.len() - 1]),
            Err(ExportError::Malformed { .. })
        ));
        assert!(matches!(
            read_ply(b"ply\nformat ascii 1.0\n"),
            Err(ExportError::Malformed { .. })
        ));
        let ascii = b"ply\nformat ascii 1.0\nelement vertex 0\nelement face 0\nend_header\n";
        assert!(matches!(
            read_ply(ascii),
            Err(ExportError::Malformed { .. })
        ));
    }

    #[test]
    fn writer_rejects_bad_mesh_before_writing() {
        let mut m = tetra();
        m.indices.push(9);
        m.indices.extend([0, 1]);
        let mut out = Vec::new();
        assert!(write_ply(m.as_ref(), &mut out).is_err());
        assert!(out.is_empty(), "nothing written for a bad mesh");
    }
}
