//! Strata's terrain core: pure, deterministic, and free of I/O.
//!
//! Everything here gives the same bytes on every run, thread count and
//! platform: chunks, world generation, edits, the delta codec, meshing and
//! hashing. The server and the client simulator both build on it.

pub mod chunk;
pub mod chunk_codec;
pub mod contour;
pub mod delta;
pub mod edit;
pub mod gen;
pub mod hash;
pub mod material;
pub mod mesh;
pub mod pos;
pub mod world;
mod zstd_ctx;

pub use chunk::{Chunk, DenseChunk, Voxel, SOLID_THRESHOLD};
pub use edit::{Edit, EditContext, EditError, EditKind, EditOutcome, Fixed, FixedVec3};
pub use material::{MaterialId, MaterialTable};
pub use pos::{ChunkPos, VoxelBox, VoxelPos, CHUNK_SIZE, CHUNK_VOLUME};
pub use world::{ChunkGenerator, ChunkRead, VersionedChunk, VoxelRead, World};
