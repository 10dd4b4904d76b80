//! Loading structure templates from a directory: `<id>.strs` or
//! `<id>-<name>.strs`, in the format of `strata_terrain::edit::structure`.

use std::path::Path;

use anyhow::Context;
use strata_terrain::edit::{Structure, StructureLibrary};

/// Largest template file accepted, in bytes.
pub const MAX_STRUCTURE_FILE: u64 = 8 * 1024 * 1024;

/// Every template in `dir`, keyed by the number its file name starts with.
pub fn load_structures(dir: &Path) -> anyhow::Result<StructureLibrary> {
    let mut lib = StructureLibrary::default();
    let entries = std::fs::read_dir(dir)
        .with_context(|| format!("reading structures dir {}", dir.display()))?;
    for entry in entries {
        let path = entry?.path();
        if path.extension().and_then(|e| e.to_str()) != Some("strs") {
            continue;
        }
        let stem = path
            .file_stem()
            .and_then(|s| s.to_str())
            .unwrap_or_default();
        let id: u32 = stem
            .split('-')
            .next()
            .and_then(|n| n.parse().ok())
            .with_context(|| format!("{}: name must start with a numeric id", path.display()))?;
        let len = std::fs::metadata(&path)?.len();
        anyhow::ensure!(
            len <= MAX_STRUCTURE_FILE,
            "{}: {len} bytes is over the {MAX_STRUCTURE_FILE}-byte cap",
            path.display()
        );
        let bytes = std::fs::read(&path)?;
        let s = Structure::from_bytes(&bytes).with_context(|| format!("{}", path.display()))?;
        anyhow::ensure!(
            lib.get(id).is_none(),
            "{}: structure id {id} is defined twice",
            path.display()
        );
        lib.insert(id, s);
    }
    Ok(lib)
}

#[cfg(test)]
mod tests {
    use super::*;
    use strata_terrain::Voxel;

    #[test]
    fn loads_by_id_and_refuses_bad_files() {
        let dir = tempfile::tempdir().unwrap();
        let s = Structure::from_fn("post", [1, 3, 1], |_, _, _| Voxel::solid(7)).unwrap();
        std::fs::write(dir.path().join("12-post.strs"), s.to_bytes()).unwrap();
        std::fs::write(dir.path().join("notes.txt"), b"ignored").unwrap();
        let lib = load_structures(dir.path()).unwrap();
        assert_eq!(lib.len(), 1);
        assert_eq!(lib.get(12).unwrap().name, "post");
        std::fs::write(dir.path().join("12.strs"), s.to_bytes()).unwrap();
        assert!(load_structures(dir.path())
            .unwrap_err()
            .to_string()
            .contains("twice"));
        std::fs::remove_file(dir.path().join("12.strs")).unwrap();
        std::fs::write(dir.path().join("x-bad.strs"), s.to_bytes()).unwrap();
        assert!(load_structures(dir.path()).is_err());
        std::fs::remove_file(dir.path().join("x-bad.strs")).unwrap();
        std::fs::write(dir.path().join("3.strs"), b"STRS junk").unwrap();
        assert!(load_structures(dir.path()).is_err());
    }
}
