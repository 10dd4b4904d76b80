//! Wavefront OBJ text export: the lowest common denominator for tools that
//! do not read PLY. OBJ has no per-vertex attribute slot for materials, so
//! they are dropped. Floats are printed in Rust's shortest round-trip form,
//! so reading a file back gives the exact `f32` values.

use std::io::Write;

use super::export::{ExportError, MeshRef};

const FORMAT: &str = "OBJ";

/// Writes `mesh` as OBJ: `v`, `vn` (one per vertex) and `f a//a b//b c//c`
/// faces with 1-based indices.
pub fn write_obj(mesh: MeshRef<'_>, out: &mut impl Write) -> Result<(), ExportError> {
    mesh.validate()?;
    writeln!(out, "# written by strata-admin")?;
    writeln!(
        out,
        "# {} vertices, {} triangles",
        mesh.positions.len(),
        mesh.triangle_count()
    )?;
    for [x, y, z] in mesh.positions {
        writeln!(out, "v {x} {y} {z}")?;
    }
    for [x, y, z] in mesh.normals {
        writeln!(out, "vn {x} {y} {z}")?;
    }
    for tri in mesh.indices.chunks_exact(3) {
        let [a, b, c] = [tri[0] as u64 + 1, tri[1] as u64 + 1, tri[2] as u64 + 1];
        writeln!(out, "f {a}//{a} {b}//{b} {c}//{c}")?;
    }
    out.flush()?;
    Ok(())
}

/// An OBJ file read back: what the format can carry.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ObjMesh {
    pub positions: Vec<[f32; 3]>,
    pub normals: Vec<[f32; 3]>,
    /// Triangles as 0-based vertex indices.
    pub triangles: Vec<[u32; 3]>,
}

fn malformed(line: usize, reason: impl std::fmt::Display) -> ExportError {
    ExportError::Malformed {
        format: FORMAT,
        reason: format!("line {line}: {reason}"),
    }
}

/// Reads an OBJ file of triangles whose corners are `v//vn` with equal
/// indices, as [`write_obj`] writes; anything else is rejected with the line.
pub fn read_obj(text: &str) -> Result<ObjMesh, ExportError> {
    let mut mesh = ObjMesh::default();
    for (n, line) in text.lines().enumerate() {
        let n = n + 1;
        let mut parts = line.split_whitespace();
        let vec3 = |parts: std::str::SplitWhitespace<'_>| -> Result<[f32; 3], ExportError> {
            let v: Vec<f32> = parts
                .map(|p| p.parse::<f32>().map_err(|e| malformed(n, e)))
                .collect::<Result<_, _>>()?;
            v.try_into().map_err(|_| malformed(n, "expected 3 numbers"))
        };
        match parts.next() {
            None => {}
            Some(t) if t.starts_with('#') => {}
            Some("v") => mesh.positions.push(vec3(parts)?),
            Some("vn") => mesh.normals.push(vec3(parts)?),
            Some("f") => {
                let mut tri = [0u32; 3];
                let corners: Vec<&str> = parts.collect();
                if corners.len() != 3 {
                    return Err(malformed(n, "face is not a triangle"));
                }
                for (slot, corner) in tri.iter_mut().zip(corners) {
                    let (v, vn) = corner
                        .split_once("//")
                        .ok_or_else(|| malformed(n, "not v//vn"))?;
                    if v != vn {
                        return Err(malformed(n, "position and normal index differ"));
                    }
                    let i: u32 = v.parse().map_err(|e| malformed(n, e))?;
                    *slot = i.checked_sub(1).ok_or_else(|| malformed(n, "index 0"))?;
                }
                mesh.triangles.push(tri);
            }
            Some(other) => return Err(malformed(n, format!("unsupported statement {other:?}"))),
        }
    }
    let vertices = mesh.positions.len();
    if mesh.normals.len() != vertices {
        return Err(ExportError::Malformed {
            format: FORMAT,
            reason: format!("{vertices} positions but {} normals", mesh.normals.len()),
        });
    }
    if let Some(&index) = mesh
        .triangles
        .iter()
        .flatten()
        .find(|&&i| i as usize >= vertices)
    {
        return Err(ExportError::IndexOutOfRange { index, vertices });
    }
    Ok(mesh)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::admin::export::ExportMesh;

    fn quad() -> ExportMesh {
        ExportMesh {
            positions: vec![
                [0.0, 0.0, 0.0],
                [1.0, 0.0, 0.0],
                [1.0, 0.1, 1.0],
                [0.0, 0.0, 1e-5],
            ],
            normals: vec![
                [0.0, 1.0, 0.0],
                [0.0, 1.0, 0.0],
                [0.6, 0.8, 0.0],
                [0.0, -1.0, 0.0],
            ],
            materials: vec![3, 3, 3, 3],
            indices: vec![0, 2, 1, 0, 3, 2],
        }
    }

    #[test]
    fn round_trip_counts_and_values() {
        let m = quad();
        let mut out = Vec::new();
        write_obj(m.as_ref(), &mut out).unwrap();
        let text = String::from_utf8(out).unwrap();
        assert_eq!(text.lines().filter(|l| l.starts_with("v ")).count(), 4);
        assert_eq!(text.lines().filter(|l| l.starts_with("vn ")).count(), 4);
        assert_eq!(text.lines().filter(|l| l.starts_with("f ")).count(), 2);
        assert!(text.contains("\nf 1//1 3//3 2//2\n"));
        let back = read_obj(&text).unwrap();
        assert_eq!(
            back.positions, m.positions,
            "shortest round-trip floats are exact"
        );
        assert_eq!(back.normals, m.normals);
        assert_eq!(back.triangles, vec![[0, 2, 1], [0, 3, 2]]);
    }

    #[test]
    fn reader_rejects_bad_faces() {
        let base = "v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1\nvn 0 0 1\nvn 0 0 1\n";
        assert!(read_obj(&format!("{base}f 1//1 2//2 3//3\n")).is_ok());
        for bad in [
            "f 1//2 2//2 3//3",
            "f 1 2 3",
            "f 1//1 2//2",
            "f 1//1 2//2 4//4",
            "f 0//0 1//1 2//2",
        ] {
            assert!(read_obj(&format!("{base}{bad}\n")).is_err(), "{bad}");
        }
        assert!(read_obj("v 1 2\n").is_err());
    }
}
