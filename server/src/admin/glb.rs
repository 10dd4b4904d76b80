//! glTF 2.0 binary (`.glb`) export: one mesh, one node, one scene, opened by
//! Blender, MeshLab and any glTF viewer.
//!
//! The single primitive (triangles) has `POSITION` (float VEC3, with the
//! `min`/`max` the spec requires), `NORMAL` (float VEC3, unit length),
//! `COLOR_0` (normalised u8 VEC4: the material table's colour, opaque) and
//! `_MATERIAL` (u8 SCALAR material id, an application-specific attribute;
//! its buffer view has a 4-byte stride because vertex attribute elements
//! must start on 4-byte boundaries), indexed by u32 `indices`. Each
//! attribute has its own buffer view in one buffer, the GLB `BIN` chunk. An
//! empty mesh is written as a scene with one node and no mesh (accessors
//! may not be empty).

use std::io::Write;

use serde_json::{json, Value};
use strata_terrain::MaterialTable;

use super::export::{ExportError, ExportMesh, MeshRef};

const MAGIC: u32 = 0x4654_6C67; // "glTF"
const VERSION: u32 = 2;
const CHUNK_JSON: u32 = 0x4E4F_534A; // "JSON"
const CHUNK_BIN: u32 = 0x004E_4942; // "BIN\0"
const ARRAY_BUFFER: u32 = 34962;
const ELEMENT_ARRAY_BUFFER: u32 = 34963;
const FLOAT: u32 = 5126;
const UNSIGNED_BYTE: u32 = 5121;
const UNSIGNED_INT: u32 = 5125;
const TRIANGLES: u32 = 4;
/// Stride of the `_MATERIAL` buffer view (one id byte, three padding).
const MATERIAL_STRIDE: usize = 4;
/// Bytes per vertex across all attribute buffers.
const VERTEX_BYTES: usize = 12 + 12 + 4 + MATERIAL_STRIDE;
/// GLB lengths are u32: the whole file must stay under this.
pub const GLB_MAX_BYTES: u64 = u32::MAX as u64;

const FORMAT: &str = "GLB";

fn pad4(n: usize) -> usize {
    n.div_ceil(4) * 4
}

fn bounds(positions: &[[f32; 3]]) -> ([f32; 3], [f32; 3]) {
    positions.iter().fold(
        ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]),
        |(lo, hi), p| {
            (
                std::array::from_fn(|i| lo[i].min(p[i])),
                std::array::from_fn(|i| hi[i].max(p[i])),
            )
        },
    )
}

/// The glTF JSON and the binary buffer for `mesh`.
fn document(mesh: MeshRef<'_>) -> (Value, Vec<u8>) {
    let n = mesh.positions.len();
    let asset = json!({"version": "2.0", "generator": "strata-admin"});
    if n == 0 || mesh.indices.is_empty() {
        let doc = json!({
            "asset": asset,
            "scene": 0,
            "scenes": [{"nodes": [0]}],
            "nodes": [{"name": "strata (empty)"}],
        });
        return (doc, Vec::new());
    }
    let table = MaterialTable::default();
    let mut bin = Vec::with_capacity(n * VERTEX_BYTES + mesh.indices.len() * 4);
    let mut views = Vec::new();
    let mut view = |bin: &mut Vec<u8>, start: usize, target: u32, stride: Option<usize>| {
        let mut v = json!({
            "buffer": 0,
            "byteOffset": start,
            "byteLength": bin.len() - start,
            "target": target,
        });
        if let Some(s) = stride {
            v["byteStride"] = json!(s);
        }
        views.push(v);
    };
    let start = bin.len();
    for c in mesh.positions.iter().flatten() {
        bin.extend_from_slice(&c.to_le_bytes());
    }
    view(&mut bin, start, ARRAY_BUFFER, None);
    let start = bin.len();
    for c in mesh.normals.iter().flatten() {
        bin.extend_from_slice(&c.to_le_bytes());
    }
    view(&mut bin, start, ARRAY_BUFFER, None);
    let start = bin.len();
    for &m in mesh.materials {
        let [r, g, b, _] = table.rgba(m);
        bin.extend_from_slice(&[r, g, b, 255]);
    }
    view(&mut bin, start, ARRAY_BUFFER, None);
    let start = bin.len();
    for &m in mesh.materials {
        bin.extend_from_slice(&[m, 0, 0, 0]);
    }
    view(&mut bin, start, ARRAY_BUFFER, Some(MATERIAL_STRIDE));
    let start = bin.len();
    for i in mesh.indices {
        bin.extend_from_slice(&i.to_le_bytes());
    }
    view(&mut bin, start, ELEMENT_ARRAY_BUFFER, None);

    let (min, max) = bounds(mesh.positions);
    let doc = json!({
        "asset": asset,
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, "name": "strata"}],
        "meshes": [{"name": "terrain", "primitives": [{
            "attributes": {"POSITION": 0, "NORMAL": 1, "COLOR_0": 2, "_MATERIAL": 3},
            "indices": 4,
            "mode": TRIANGLES,
        }]}],
        "buffers": [{"byteLength": bin.len()}],
        "bufferViews": views,
        "accessors": [
            {"bufferView": 0, "componentType": FLOAT, "count": n, "type": "VEC3",
             "min": min, "max": max},
            {"bufferView": 1, "componentType": FLOAT, "count": n, "type": "VEC3"},
            {"bufferView": 2, "componentType": UNSIGNED_BYTE, "normalized": true,
             "count": n, "type": "VEC4"},
            {"bufferView": 3, "componentType": UNSIGNED_BYTE, "count": n, "type": "SCALAR"},
            {"bufferView": 4, "componentType": UNSIGNED_INT, "count": mesh.indices.len(),
             "type": "SCALAR"},
        ],
    });
    (doc, bin)
}

/// Writes `mesh` as a binary glTF 2.0 file.
pub fn write_glb(mesh: MeshRef<'_>, out: &mut impl Write) -> Result<(), ExportError> {
    mesh.validate()?;
    let n = mesh.positions.len();
    let estimate = (n * VERTEX_BYTES + mesh.indices.len() * 4) as u64;
    if estimate + 4096 > GLB_MAX_BYTES {
        return Err(ExportError::TooManyVertices {
            count: n,
            limit: (GLB_MAX_BYTES / VERTEX_BYTES as u64 / 4) as usize,
        });
    }
    let (doc, bin) = document(mesh);
    let mut json = serde_json::to_vec(&doc).map_err(|e| malformed(e.to_string()))?;
    json.resize(pad4(json.len()), b' ');
    let bin_len = pad4(bin.len());
    let mut total = 12 + 8 + json.len();
    if !bin.is_empty() {
        total += 8 + bin_len;
    }
    if total as u64 > GLB_MAX_BYTES {
        return Err(malformed(format!("{total} bytes exceed the GLB limit")));
    }
    for word in [MAGIC, VERSION, total as u32, json.len() as u32, CHUNK_JSON] {
        out.write_all(&word.to_le_bytes())?;
    }
    out.write_all(&json)?;
    if !bin.is_empty() {
        out.write_all(&(bin_len as u32).to_le_bytes())?;
        out.write_all(&CHUNK_BIN.to_le_bytes())?;
        out.write_all(&bin)?;
        out.write_all(&vec![0u8; bin_len - bin.len()])?;
    }
    out.flush()?;
    Ok(())
}

fn malformed(reason: impl Into<String>) -> ExportError {
    ExportError::malformed(FORMAT, reason)
}

/// A GLB file read back: the JSON document and the mesh its accessors hold.
#[derive(Debug, Clone, PartialEq)]
pub struct GlbFile {
    pub json: Value,
    pub mesh: ExportMesh,
    /// `COLOR_0`, RGBA per vertex.
    pub colors: Vec<[u8; 4]>,
}

fn le32(b: &[u8], at: usize) -> Result<u32, ExportError> {
    b.get(at..at + 4)
        .map(|s| u32::from_le_bytes([s[0], s[1], s[2], s[3]]))
        .ok_or_else(|| malformed(format!("truncated at byte {at}")))
}

/// One accessor's elements as byte slices of `size` bytes each.
fn elements<'a>(
    json: &Value,
    bin: &'a [u8],
    accessor: &Value,
    size: usize,
) -> Result<Vec<&'a [u8]>, ExportError> {
    let idx = accessor
        .as_u64()
        .ok_or_else(|| malformed("accessor index"))?;
    let acc = &json["accessors"][idx as usize];
    let count = acc["count"]
        .as_u64()
        .ok_or_else(|| malformed("accessor count"))? as usize;
    let view = &json["bufferViews"][acc["bufferView"].as_u64().unwrap_or(u64::MAX) as usize];
    let offset = view["byteOffset"].as_u64().unwrap_or(0) as usize;
    let length = view["byteLength"]
        .as_u64()
        .ok_or_else(|| malformed("buffer view length"))? as usize;
    let stride = view["byteStride"].as_u64().map_or(size, |s| s as usize);
    if offset % 4 != 0 || stride % 4 != 0 {
        return Err(malformed("misaligned buffer view"));
    }
    let data = bin
        .get(offset..offset + length)
        .ok_or_else(|| malformed("buffer view outside the BIN chunk"))?;
    (0..count)
        .map(|k| {
            data.get(k * stride..k * stride + size)
                .ok_or_else(|| malformed("accessor outside its buffer view"))
        })
        .collect()
}

fn f32s<const N: usize>(e: &[u8]) -> [f32; N] {
    std::array::from_fn(|i| {
        f32::from_le_bytes([e[4 * i], e[4 * i + 1], e[4 * i + 2], e[4 * i + 3]])
    })
}

/// Reads back a GLB in the layout [`write_glb`] produces, checking the
/// header, chunk lengths and `POSITION` bounds.
pub fn read_glb(bytes: &[u8]) -> Result<GlbFile, ExportError> {
    if le32(bytes, 0)? != MAGIC || le32(bytes, 4)? != VERSION {
        return Err(malformed("not a glTF 2.0 binary"));
    }
    if le32(bytes, 8)? as usize != bytes.len() {
        return Err(malformed("header length differs from the file length"));
    }
    let json_len = le32(bytes, 12)? as usize;
    if le32(bytes, 16)? != CHUNK_JSON || json_len % 4 != 0 {
        return Err(malformed("first chunk is not an aligned JSON chunk"));
    }
    let json_bytes = bytes
        .get(20..20 + json_len)
        .ok_or_else(|| malformed("JSON chunk truncated"))?;
    let json: Value = serde_json::from_slice(json_bytes).map_err(|e| malformed(e.to_string()))?;
    let bin_at = 20 + json_len;
    let bin: &[u8] = if bin_at < bytes.len() {
        let len = le32(bytes, bin_at)? as usize;
        if le32(bytes, bin_at + 4)? != CHUNK_BIN || len % 4 != 0 {
            return Err(malformed("second chunk is not an aligned BIN chunk"));
        }
        bytes
            .get(bin_at + 8..bin_at + 8 + len)
            .ok_or_else(|| malformed("BIN chunk truncated"))?
    } else {
        &[]
    };
    let Some(prim) = json["meshes"][0]["primitives"].get(0) else {
        return Ok(GlbFile {
            json,
            mesh: ExportMesh::default(),
            colors: Vec::new(),
        });
    };
    let attrs = &prim["attributes"];
    let positions: Vec<[f32; 3]> = elements(&json, bin, &attrs["POSITION"], 12)?
        .into_iter()
        .map(f32s::<3>)
        .collect();
    let normals = elements(&json, bin, &attrs["NORMAL"], 12)?
        .into_iter()
        .map(f32s::<3>)
        .collect();
    let colors = elements(&json, bin, &attrs["COLOR_0"], 4)?
        .into_iter()
        .map(|e| [e[0], e[1], e[2], e[3]])
        .collect();
    let materials = elements(&json, bin, &attrs["_MATERIAL"], 1)?
        .into_iter()
        .map(|e| e[0])
        .collect();
    let indices = elements(&json, bin, &prim["indices"], 4)?
        .into_iter()
        .map(|e| u32::from_le_bytes([e[0], e[1], e[2], e[3]]))
        .collect();
    let acc = &json["accessors"][attrs["POSITION"].as_u64().unwrap_or(0) as usize];
    let (min, max) = bounds(&positions);
    let as_f32s = |v: &Value| -> Option<Vec<f32>> {
        v.as_array()?
            .iter()
            .map(|x| x.as_f64().map(|f| f as f32))
            .collect()
    };
    if as_f32s(&acc["min"]) != Some(min.to_vec()) || as_f32s(&acc["max"]) != Some(max.to_vec()) {
        return Err(malformed("POSITION min/max do not bound the positions"));
    }
    let mesh = ExportMesh {
        positions,
        normals,
        materials,
        indices,
    };
    mesh.as_ref().validate()?;
    Ok(GlbFile { json, mesh, colors })
}

#[cfg(test)]
mod tests {
    use super::*;
    use strata_terrain::material::ids;

    #[test]
    fn round_trips_with_bounds_and_colours() {
        let mesh = ExportMesh {
            positions: vec![[0.0, 1.0, 2.0], [-3.5, 4.0, 0.25], [1.0, -2.0, 9.0]],
            normals: vec![[0.0, 1.0, 0.0]; 3],
            materials: vec![ids::STONE, ids::GRASS, ids::STONE],
            indices: vec![0, 1, 2],
        };
        let mut out = Vec::new();
        write_glb(mesh.as_ref(), &mut out).unwrap();
        assert_eq!(out.len() % 4, 0);
        let back = read_glb(&out).unwrap();
        assert_eq!(back.mesh, mesh);
        assert_eq!(back.json["accessors"][0]["min"], json!([-3.5, -2.0, 0.25]));
        assert_eq!(back.json["accessors"][0]["max"], json!([1.0, 4.0, 9.0]));
        let stone = MaterialTable::default().rgba(ids::STONE);
        assert_eq!(back.colors[0], [stone[0], stone[1], stone[2], 255]);
        assert_eq!(back.json["bufferViews"][3]["byteStride"], 4);
    }

    #[test]
    fn empty_mesh_is_a_valid_scene_and_bad_bytes_are_refused() {
        let mut out = Vec::new();
        write_glb(ExportMesh::default().as_ref(), &mut out).unwrap();
        let back = read_glb(&out).unwrap();
        assert_eq!(back.mesh, ExportMesh::default());
        assert!(back.json.get("accessors").is_none());
        out[0] = b'x';
        assert!(matches!(
            read_glb(&out),
            Err(ExportError::Malformed { format: "GLB", .. })
        ));
        assert!(read_glb(&[1, 2]).is_err());
    }
}
