//! Snapshots of modified chunks as patches: a delta from the generated
//! chunk, which clients regenerate from the seed. An edited chunk differs
//! from its generated form in a few hundred voxels, so a patch is usually
//! tens of times smaller than the full chunk.

use strata_terrain::delta::{ChunkDelta, DeltaError};
use strata_terrain::{Chunk, ChunkPos};

/// Generated chunks kept as patch bases (at most 64 KiB each).
pub const PATCH_BASE_CHUNKS: usize = 512;

/// The patch taking the generated chunk `base` (version 0) to `chunk` at
/// `version` (above 0).
pub fn patch(
    pos: ChunkPos,
    base: &Chunk,
    chunk: &Chunk,
    version: u64,
) -> Result<ChunkDelta, DeltaError> {
    ChunkDelta::encode(pos, 0, version, base, chunk)
}

#[cfg(test)]
mod tests {
    use super::*;
    use strata_terrain::gen::{GenParams, Generator};
    use strata_terrain::{ChunkGenerator, Voxel, VoxelPos};

    #[test]
    fn patch_rebuilds_the_chunk_from_its_generated_base() {
        let g = Generator::fractal(GenParams::default()).expect("valid params");
        let pos = VoxelPos::new(0, 20, 0).chunk();
        let base = g.generate(pos);
        let mut edited = base.clone();
        for x in 3..9 {
            edited.set(x, 5, 7, Voxel::solid(2));
        }
        let d = patch(pos, &base, &edited, 4).expect("version above 0");
        assert_eq!((d.from_version, d.to_version), (0, 4));
        assert_eq!(d.apply(&g.generate(pos)).expect("applies"), edited);
        assert!(d.payload.len() < 200, "{} bytes", d.payload.len());
    }
}
