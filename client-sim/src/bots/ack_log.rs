//! `--ack-log FILE`: one [`AckRecord`] JSON line per accepted edit, written
//! (and flushed) as soon as the acknowledgement arrives, so the file holds
//! every acknowledged edit even if this process dies next.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::Path;
use std::sync::Mutex;

pub use strata_protocol::ack::AckRecord;
use strata_protocol::ChunkVersion;

#[derive(Debug)]
pub struct AckLog(Mutex<BufWriter<File>>);

impl AckLog {
    /// Creates (truncates) the file.
    pub fn create(path: &Path) -> std::io::Result<Self> {
        Ok(Self(Mutex::new(BufWriter::new(File::create(path)?))))
    }

    pub fn write(&self, seq: u64, changes: &[ChunkVersion]) -> std::io::Result<()> {
        let mut w = self.0.lock().expect("not poisoned");
        writeln!(w, "{}", AckRecord::new(seq, changes).to_line())?;
        w.flush()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use strata_terrain::ChunkPos;

    #[test]
    fn lines_read_back() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("acks.jsonl");
        let log = AckLog::create(&path).unwrap();
        let c = ChunkVersion {
            pos: ChunkPos::new(1, -2, 3),
            version: 9,
        };
        log.write(5, &[c]).unwrap();
        log.write(6, &[]).unwrap();
        let back = strata_server::admin::verify_acks::read_ack_log(&path).unwrap();
        assert_eq!(back, vec![AckRecord::new(5, &[c]), AckRecord::new(6, &[])]);
    }
}
