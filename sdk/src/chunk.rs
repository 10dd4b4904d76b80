//! Reading chunks: voxels, the chunk holding a point, meshes.

use strata_client::coords::chunk_at;
use strata_client::glam::DVec3;
use strata_client::terrain::{ChunkPos, CHUNK_VOLUME};
use strata_client::ChunkMesh;

use crate::ptr::{shared, writable};
use crate::session::{session, StrataSession};
use crate::status::{call, call_quiet, Failure, StrataStatus};
use crate::types::StrataMeshData;

/// Voxels per chunk: 32 × 32 × 32.
pub const STRATA_CHUNK_VOLUME: usize = 32768;
const _: () = assert!(STRATA_CHUNK_VOLUME == CHUNK_VOLUME);

fn not_held(pos: ChunkPos) -> Failure {
    Failure::new(
        StrataStatus::NotHeld,
        format!("chunk ({}, {}, {}) is not held", pos.x, pos.y, pos.z),
    )
}

/// Copies a held chunk as the player sees it: `density` and `material`
/// (each may be null to skip it) receive STRATA_CHUNK_VOLUME bytes, index
/// x + 32 * (y + 32 * z); a density of 128 or more is solid. `*out_version`
/// (may be null) receives the server's version of the chunk.
/// STRATA_STATUS_NOT_HELD when the chunk has not arrived or left the view.
///
/// # Safety
/// `s` is a live session; non-null `density` and `material` point to `len`
/// writable bytes; a non-null `out_version` is writable.
#[no_mangle]
pub unsafe extern "C" fn strata_chunk_read(
    s: *const StrataSession,
    cx: i32,
    cy: i32,
    cz: i32,
    density: *mut u8,
    material: *mut u8,
    len: usize,
    out_version: *mut u64,
) -> StrataStatus {
    call(|| {
        // SAFETY: the caller's contract above; a null `out_version` is
        // skipped, a misaligned one refused.
        let (session, version) = unsafe {
            let session = session(s)?;
            if out_version.is_null() {
                (session, None)
            } else {
                (session, Some(writable(out_version, "out_version")?))
            }
        };
        if len < CHUNK_VOLUME && !(density.is_null() && material.is_null()) {
            return Err(Failure::invalid(format!(
                "buffers of {len} bytes; a chunk needs {CHUNK_VOLUME}"
            )));
        }
        let pos = ChunkPos::new(cx, cy, cz);
        let data = session.chunk(pos).ok_or_else(|| not_held(pos))?;
        for (dst, src) in [(density, &data.density), (material, &data.material)] {
            if !dst.is_null() {
                // SAFETY: `dst` has `len >= CHUNK_VOLUME` writable bytes
                // (caller's contract) and does not overlap our own copy.
                unsafe { dst.copy_from_nonoverlapping(src.as_ptr(), CHUNK_VOLUME) };
            }
        }
        if let Some(v) = version {
            v.write(data.version);
        }
        Ok(())
    })
}

/// The chunk holding point (`x`, `y`, `z`) (in voxels), into `out_chunk[3]`.
///
/// # Safety
/// `out_chunk` points to 3 writable `int32_t`.
#[no_mangle]
pub unsafe extern "C" fn strata_chunk_of(
    x: f64,
    y: f64,
    z: f64,
    out_chunk: *mut i32,
) -> StrataStatus {
    call(|| {
        // SAFETY: the caller's contract above; `[i32; 3]` has the
        // alignment of `i32`.
        let dst = unsafe { writable(out_chunk.cast::<[i32; 3]>(), "out_chunk") }?;
        let c = chunk_at(DVec3::new(x, y, z))
            .ok_or_else(|| Failure::invalid("the point is not finite or out of range"))?;
        dst.write([c.x, c.y, c.z]);
        Ok(())
    })
}

/// A chunk's mesh. Opaque: made by `strata_mesh`, read with
/// `strata_mesh_data`, freed by `strata_mesh_free`. It does not depend on
/// the session and may outlive it.
#[derive(Debug)]
pub struct StrataMesh(ChunkMesh);

// A mesh may move to another thread (an engine's render thread).
const _: () = {
    const fn shareable<T: Send + Sync>() {}
    shareable::<StrataMesh>();
};

/// Meshes a held chunk as the player sees it, at `lod` (0..=3), with
/// transition cells on the faces set in `transition_faces` (bits -X, +X,
/// -Y, +Y, -Z, +Z from bit 0: faces bordering a chunk one LOD finer; 0 at
/// LOD 0). On success `*out_mesh` is a new mesh the caller owns; on any
/// other status it is NULL (when `out_mesh` itself is not), which
/// `strata_mesh_free` ignores. STRATA_STATUS_NOT_HELD when the chunk is not
/// held.
///
/// # Safety
/// `s` is a live session; `out_mesh` is writable.
#[no_mangle]
pub unsafe extern "C" fn strata_mesh(
    s: *const StrataSession,
    cx: i32,
    cy: i32,
    cz: i32,
    lod: u8,
    transition_faces: u8,
    out_mesh: *mut *mut StrataMesh,
) -> StrataStatus {
    call(|| {
        // SAFETY: the caller's contract above.
        let dst = unsafe { writable(out_mesh, "out_mesh") }?;
        dst.write(std::ptr::null_mut());
        // SAFETY: the caller's contract above.
        let session = unsafe { session(s) }?;
        let pos = ChunkPos::new(cx, cy, cz);
        let mesh = session
            .mesh(pos, lod, transition_faces)?
            .ok_or_else(|| not_held(pos))?;
        dst.write(Box::into_raw(Box::new(StrataMesh(mesh))));
        Ok(())
    })
}

/// The mesh's arrays and counts; the pointers stay valid until
/// `strata_mesh_free(mesh)`.
///
/// # Safety
/// `mesh` is a live mesh; `out_data` is writable.
#[no_mangle]
pub unsafe extern "C" fn strata_mesh_data(
    mesh: *const StrataMesh,
    out_data: *mut StrataMeshData,
) -> StrataStatus {
    call(|| {
        // SAFETY: the caller's contract above.
        let (StrataMesh(m), dst) =
            unsafe { (shared(mesh, "mesh")?, writable(out_data, "out_data")?) };
        let data = StrataMeshData {
            positions: m.positions_flat().as_ptr(),
            normals: m.normals_flat().as_ptr(),
            materials: m.materials.as_ptr(),
            indices: m.indices.as_ptr(),
            vertex_count: m.vertex_count(),
            index_count: m.indices.len(),
            origin: m.origin.to_array(),
            lod: m.lod,
            complete: u8::from(m.complete),
            hash: m.hash,
        };
        dst.write(data);
        Ok(())
    })
}

/// Frees a mesh. Null is ignored.
///
/// # Safety
/// `mesh` is null or a live mesh from `strata_mesh`, not used again.
#[no_mangle]
pub unsafe extern "C" fn strata_mesh_free(mesh: *mut StrataMesh) {
    if mesh.is_null() {
        return;
    }
    call_quiet(|| {
        // SAFETY: a live mesh from `Box::into_raw`, given back once.
        drop(unsafe { Box::from_raw(mesh) });
    });
}
