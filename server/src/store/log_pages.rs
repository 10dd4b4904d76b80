//! The sled edit log's records. A commit writes its entries as one page:
//! key = first seq then last seq (big-endian, [`PAGE_KEY_LEN`] bytes), value
//! = each entry's log record (`record::encode_log_record`) after its length
//! (u32 little-endian). Format-2 stores hold one entry per record, keyed by
//! its seq alone ([`SEQ_KEY_LEN`] bytes); both sort by first seq, as a
//! seq key is a prefix of the page keys that start with it.

use super::keys::{seq_from_key, SEQ_KEY_LEN};

/// Length of a page key: first and last seq.
pub const PAGE_KEY_LEN: usize = 2 * SEQ_KEY_LEN;

/// Key of the page holding seqs `first..=last`.
pub fn page_key(first: u64, last: u64) -> [u8; PAGE_KEY_LEN] {
    let mut k = [0u8; PAGE_KEY_LEN];
    k[..SEQ_KEY_LEN].copy_from_slice(&first.to_be_bytes());
    k[SEQ_KEY_LEN..].copy_from_slice(&last.to_be_bytes());
    k
}

/// The last key a record holding `seq` can have: a backward search from it
/// finds that record first.
pub fn search_key(seq: u64) -> [u8; PAGE_KEY_LEN] {
    page_key(seq, u64::MAX)
}

/// A page's value from its entries' records, in seq order.
pub fn encode_page(records: &[Vec<u8>]) -> Vec<u8> {
    let len = records.iter().map(|r| 4 + r.len()).sum();
    let mut out = Vec::with_capacity(len);
    for r in records {
        // A record is at most `MAX_LOG_RECORD_BYTES` (1 MiB).
        out.extend_from_slice(&(r.len() as u32).to_le_bytes());
        out.extend_from_slice(r);
    }
    out
}

/// Why a log record could not be split into entries.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum BadRecord {
    /// The key is neither a seq nor a page key.
    Key,
    /// The page starting at this seq does not hold what its key says.
    Page { first: u64, reason: String },
}

/// The entries of one log tree record: (seq, its log record bytes), in seq
/// order.
pub fn record_entries<'a>(key: &[u8], value: &'a [u8]) -> Result<Vec<(u64, &'a [u8])>, BadRecord> {
    if key.len() == SEQ_KEY_LEN {
        let seq = seq_from_key(key).ok_or(BadRecord::Key)?;
        return Ok(vec![(seq, value)]);
    }
    if key.len() != PAGE_KEY_LEN {
        return Err(BadRecord::Key);
    }
    let first = seq_from_key(&key[..SEQ_KEY_LEN]).ok_or(BadRecord::Key)?;
    let last = seq_from_key(&key[SEQ_KEY_LEN..]).ok_or(BadRecord::Key)?;
    let bad = |reason: String| BadRecord::Page { first, reason };
    if last < first {
        return Err(bad(format!("last seq {last} is below the first")));
    }
    let mut entries = Vec::new();
    let mut rest = value;
    let mut seq = first;
    while !rest.is_empty() {
        if seq > last {
            return Err(bad(format!("more entries than seqs {first}..={last}")));
        }
        let Some((len, tail)) = rest.split_first_chunk::<4>() else {
            return Err(bad(format!("entry {seq}: truncated length")));
        };
        let len = u32::from_le_bytes(*len) as usize;
        if tail.len() < len {
            return Err(bad(format!(
                "entry {seq}: {len} bytes, {} left",
                tail.len()
            )));
        }
        let (record, tail) = tail.split_at(len);
        entries.push((seq, record));
        rest = tail;
        // A damaged key may name the last seq there is: no entry follows it.
        seq = match seq.checked_add(1) {
            Some(next) => next,
            None if rest.is_empty() => break,
            None => return Err(bad(format!("entries past seq {seq}"))),
        };
    }
    if entries.last().map(|e| e.0) != Some(last) {
        return Err(bad(format!(
            "{} entries for seqs {first}..={last}",
            entries.len()
        )));
    }
    Ok(entries)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::store::keys::seq_key;

    #[test]
    fn pages_split_into_their_entries_and_sort_by_first_seq() {
        let records = vec![b"a".to_vec(), Vec::new(), b"ccc".to_vec()];
        let v = encode_page(&records);
        let got = record_entries(&page_key(7, 9), &v).unwrap();
        assert_eq!(got, [(7, &b"a"[..]), (8, &b""[..]), (9, &b"ccc"[..])]);
        assert_eq!(record_entries(&seq_key(4), b"x").unwrap(), [(4, &b"x"[..])]);
        // Seq keys and page keys interleave by first seq.
        let mut keys = [
            page_key(7, 9).to_vec(),
            seq_key(6).to_vec(),
            page_key(10, 10).to_vec(),
            seq_key(7).to_vec(),
        ];
        keys.sort();
        assert_eq!(keys[0], seq_key(6));
        assert_eq!(keys[1], seq_key(7));
        assert_eq!(keys[2], page_key(7, 9));
        assert!(search_key(9).as_slice() >= page_key(7, 9).as_slice());
        assert!(search_key(9).as_slice() < page_key(10, 10).as_slice());
    }

    #[test]
    fn a_page_ending_at_the_last_seq_there_is_reads_or_is_refused_without_a_panic() {
        let two = encode_page(&[b"a".to_vec(), b"b".to_vec()]);
        let got = record_entries(&page_key(u64::MAX - 1, u64::MAX), &two).unwrap();
        assert_eq!(got, [(u64::MAX - 1, &b"a"[..]), (u64::MAX, &b"b"[..])]);
        let three = encode_page(&[b"a".to_vec(), b"b".to_vec(), b"c".to_vec()]);
        match record_entries(&page_key(u64::MAX - 1, u64::MAX), &three) {
            Err(BadRecord::Page { reason, .. }) => {
                assert!(reason.contains("entries past seq"), "{reason}")
            }
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn malformed_pages_are_refused_with_a_reason() {
        let v = encode_page(&[b"a".to_vec(), b"b".to_vec()]);
        let page = |r: Result<_, BadRecord>| match r {
            Err(BadRecord::Page { first, reason }) => (first, reason),
            other => panic!("{other:?}"),
        };
        assert!(page(record_entries(&page_key(1, 3), &v))
            .1
            .contains("2 entries"));
        assert!(page(record_entries(&page_key(1, 1), &v))
            .1
            .contains("more entries"));
        assert!(page(record_entries(&page_key(1, 2), &v[..v.len() - 1]))
            .1
            .contains("left"));
        assert!(page(record_entries(&page_key(1, 2), &v[..7]))
            .1
            .contains("truncated"));
        assert!(page(record_entries(&page_key(5, 4), &v))
            .1
            .contains("below"));
        assert_eq!(record_entries(&[0u8; 5], &v), Err(BadRecord::Key));
    }
}
