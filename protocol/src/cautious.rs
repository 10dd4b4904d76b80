//! Decoding a list without trusting its length prefix. serde reserves room
//! for as many elements as the prefix claims (up to 1 MiB) before any is
//! read, so a 10-byte frame claiming 2^32 chunks would cost a megabyte.
//! Here at most `MAX_FORGET_CHUNKS` are reserved; more grow only as they
//! actually decode, each from bytes the frame cap bounds.

use std::fmt;
use std::marker::PhantomData;

use serde::de::{Deserialize, Deserializer, SeqAccess, Visitor};

use crate::limits::MAX_FORGET_CHUNKS;

/// `deserialize_with` for a `Vec` a client sends.
pub fn vec<'de, D, T>(d: D) -> Result<Vec<T>, D::Error>
where
    D: Deserializer<'de>,
    T: Deserialize<'de>,
{
    struct Cautious<T>(PhantomData<T>);

    impl<'de, T: Deserialize<'de>> Visitor<'de> for Cautious<T> {
        type Value = Vec<T>;

        fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
            f.write_str("a sequence")
        }

        fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<Vec<T>, A::Error> {
            let room = seq.size_hint().unwrap_or(0).min(MAX_FORGET_CHUNKS);
            let mut out = Vec::with_capacity(room);
            while let Some(x) = seq.next_element()? {
                out.push(x);
            }
            Ok(out)
        }
    }

    d.deserialize_seq(Cautious(PhantomData))
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde::de::value::{Error, SeqAccessDeserializer, U32Deserializer};
    use serde::de::{DeserializeSeed, IntoDeserializer};

    /// A sequence that claims `claimed` elements and has `real`.
    struct Claims {
        claimed: usize,
        real: u32,
    }

    impl<'de> SeqAccess<'de> for Claims {
        type Error = Error;

        fn next_element_seed<S: DeserializeSeed<'de>>(
            &mut self,
            seed: S,
        ) -> Result<Option<S::Value>, Error> {
            if self.real == 0 {
                return Ok(None);
            }
            self.real -= 1;
            let d: U32Deserializer<Error> = self.real.into_deserializer();
            seed.deserialize(d).map(Some)
        }

        fn size_hint(&self) -> Option<usize> {
            Some(self.claimed)
        }
    }

    #[test]
    fn a_length_prefix_reserves_at_most_the_forget_cap() {
        let lying = Claims {
            claimed: usize::MAX,
            real: 2,
        };
        let v: Vec<u32> = vec(SeqAccessDeserializer::new(lying)).unwrap();
        assert_eq!(v, [1, 0]);
        assert!(v.capacity() <= MAX_FORGET_CHUNKS, "{}", v.capacity());
        // More than the cap still decodes, growing as elements arrive.
        let many = Claims {
            claimed: 5000,
            real: 5000,
        };
        let v: Vec<u32> = vec(SeqAccessDeserializer::new(many)).unwrap();
        assert_eq!(v.len(), 5000);
    }
}
