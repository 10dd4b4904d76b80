//! `strata-admin inspect chunk X Y Z`: a chunk's version, hash, material
//! histogram, and whether it is as generated or modified.

use std::fmt;
use std::sync::Arc;

use anyhow::{bail, Context};
use clap::Args;
use strata_protocol::admin::{AdminRequest, AdminResponse};
use strata_terrain::chunk_codec::decode_chunk;
use strata_terrain::gen::{GenParams, Generator};
use strata_terrain::hash::chunk_hash;
use strata_terrain::{Chunk, ChunkGenerator, ChunkPos, MaterialTable, CHUNK_VOLUME};

use super::remote::{open_offline_store, request_once, Target, TargetArgs};
use crate::store::ChunkStore;

#[derive(Debug, Args)]
pub struct InspectChunkArgs {
    /// Chunk coordinates (voxel coordinates floor-divided by 32).
    #[arg(allow_negative_numbers = true)]
    pub x: i32,
    #[arg(allow_negative_numbers = true)]
    pub y: i32,
    #[arg(allow_negative_numbers = true)]
    pub z: i32,
    #[command(flatten)]
    pub target: TargetArgs,
}

/// What `inspect chunk` prints.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ChunkReport {
    pub pos: ChunkPos,
    pub version: u64,
    pub hash: u64,
    /// Version 0: the generator's output, never modified.
    pub generated: bool,
    /// Voxels below the solid threshold.
    pub air: u32,
    /// Solid voxels per material name, most first.
    pub solid: Vec<(String, u32)>,
}

impl ChunkReport {
    pub fn new(pos: ChunkPos, version: u64, chunk: &Chunk) -> Self {
        let mut counts = [0u32; 256];
        let mut air = 0u32;
        for i in 0..CHUNK_VOLUME {
            let v = chunk.get_index(i);
            if v.is_solid() {
                counts[v.material as usize] += 1;
            } else {
                air += 1;
            }
        }
        let table = MaterialTable::default();
        let mut solid: Vec<(String, u32)> = counts
            .iter()
            .enumerate()
            .filter(|(_, &n)| n > 0)
            .map(|(id, &n)| {
                let name = table
                    .get(id as u8)
                    .map_or_else(|| format!("material {id}"), |m| m.name.clone());
                (name, n)
            })
            .collect();
        solid.sort_by(|a, b| b.1.cmp(&a.1).then_with(|| a.0.cmp(&b.0)));
        Self {
            pos,
            version,
            hash: chunk_hash(chunk),
            generated: version == 0,
            air,
            solid,
        }
    }
}

impl fmt::Display for ChunkReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let p = self.pos;
        writeln!(f, "chunk: ({}, {}, {})", p.x, p.y, p.z)?;
        writeln!(f, "version: {}", self.version)?;
        writeln!(f, "hash: {:016x}", self.hash)?;
        let state = if self.generated {
            "generated"
        } else {
            "modified"
        };
        writeln!(f, "state: {state}")?;
        writeln!(f, "air: {}", self.air)?;
        for (name, n) in &self.solid {
            writeln!(f, "solid {name}: {n}")?;
        }
        Ok(())
    }
}

/// The generator a store's metadata describes (fractal worlds only).
pub fn generator_of(params: &str) -> anyhow::Result<Arc<dyn ChunkGenerator>> {
    if params.contains("# heightmap ") {
        bail!("a heightmap world: unmodified chunks need the heightmap file; inspect it online");
    }
    let p: GenParams = toml::from_str(params).context("stored generator parameters")?;
    Ok(Arc::new(Generator::fractal(p)?))
}

/// A chunk of a stopped server's store, generated if never modified.
pub fn offline(store: &dyn ChunkStore, pos: ChunkPos) -> anyhow::Result<ChunkReport> {
    let Some(meta) = store.load_meta()? else {
        bail!("the store has no world yet (start the server once)");
    };
    if let Some(s) = store.load_chunk(pos)? {
        return Ok(ChunkReport::new(pos, s.version, &s.chunk));
    }
    let chunk = generator_of(&meta.generator_params)?.generate(pos);
    Ok(ChunkReport::new(pos, 0, &chunk))
}

pub fn run(args: &InspectChunkArgs) -> anyhow::Result<ChunkReport> {
    let pos = ChunkPos::new(args.x, args.y, args.z);
    match args.target.target()? {
        Target::Offline(dir) => offline(&*open_offline_store(&dir)?, pos),
        Target::Online {
            server,
            cert,
            token,
        } => match request_once(server, &cert, &token, &AdminRequest::InspectChunk { pos })? {
            AdminResponse::Chunk { pos, version, data } => {
                let chunk = decode_chunk(&data).context("the server's chunk bytes")?;
                Ok(ChunkReport::new(pos, version, &chunk))
            }
            other => bail!("unexpected answer {other:?}"),
        },
    }
}
