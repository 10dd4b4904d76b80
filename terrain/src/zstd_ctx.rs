//! Per-thread zstd contexts. Creating a context costs more than compressing
//! a small delta, so each thread keeps one per level and one decompressor.
//! A context carries no data between calls: the output is the same as with
//! a fresh one.

use std::cell::RefCell;

use zstd::bulk::{Compressor, Decompressor};

thread_local! {
    static COMPRESSORS: RefCell<Vec<(i32, Compressor<'static>)>> = const { RefCell::new(Vec::new()) };
    static DECOMPRESSOR: RefCell<Option<Decompressor<'static>>> = const { RefCell::new(None) };
}

/// One zstd frame of `data` at `level`.
pub(crate) fn compress(data: &[u8], level: i32) -> std::io::Result<Vec<u8>> {
    COMPRESSORS.with(|cell| {
        let Ok(mut all) = cell.try_borrow_mut() else {
            return zstd::bulk::compress(data, level);
        };
        let i = match all.iter().position(|(l, _)| *l == level) {
            Some(i) => i,
            None => {
                all.push((level, Compressor::new(level)?));
                all.len() - 1
            }
        };
        all[i].1.compress(data)
    })
}

/// Decompresses `data` into at most `capacity` bytes.
pub(crate) fn decompress(data: &[u8], capacity: usize) -> std::io::Result<Vec<u8>> {
    DECOMPRESSOR.with(|cell| {
        let Ok(mut d) = cell.try_borrow_mut() else {
            return zstd::bulk::decompress(data, capacity);
        };
        if d.is_none() {
            *d = Some(Decompressor::new()?);
        }
        d.as_mut().expect("set above").decompress(data, capacity)
    })
}

#[cfg(test)]
mod tests {
    #[test]
    fn reused_contexts_give_the_bytes_of_fresh_ones() {
        let data: Vec<u8> = (0..5000u32).map(|i| (i * i / 7) as u8).collect();
        for level in [1, 3, 1] {
            let packed = super::compress(&data, level).unwrap();
            assert_eq!(packed, zstd::bulk::compress(&data, level).unwrap());
            assert_eq!(super::decompress(&packed, data.len()).unwrap(), data);
        }
        assert!(super::decompress(&[1, 2, 3], 10).is_err());
    }
}
