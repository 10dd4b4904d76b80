//! The few integer query parameters the console's GET requests take
//! (`?tx=1&tz=-2`), parsed by hand: the names are known, and anything
//! else is refused.

use thiserror::Error;

/// Most parameters one request may carry.
pub const MAX_PARAMS: usize = 16;

/// Why a query string was refused.
#[derive(Debug, Error, PartialEq, Eq)]
pub enum QueryError {
    #[error("too many query parameters (at most {MAX_PARAMS})")]
    TooMany,
    #[error("unknown query parameter {0:?}")]
    Unknown(String),
    #[error("query parameter {0} is missing")]
    Missing(&'static str),
    #[error("query parameter {name} must be an integer within {min}..={max}")]
    Bad {
        name: &'static str,
        min: i64,
        max: i64,
    },
}

/// Parsed `name=value` pairs, each name one of `known`.
#[derive(Debug)]
pub struct Query<'a> {
    pairs: Vec<(&'a str, &'a str)>,
}

impl<'a> Query<'a> {
    pub fn parse(raw: Option<&'a str>, known: &[&str]) -> Result<Self, QueryError> {
        let mut pairs = Vec::new();
        for part in raw.unwrap_or("").split('&').filter(|p| !p.is_empty()) {
            if pairs.len() == MAX_PARAMS {
                return Err(QueryError::TooMany);
            }
            let (k, v) = part.split_once('=').unwrap_or((part, ""));
            if !known.contains(&k) {
                return Err(QueryError::Unknown(k.chars().take(32).collect()));
            }
            pairs.push((k, v));
        }
        Ok(Self { pairs })
    }

    fn raw(&self, name: &str) -> Option<&'a str> {
        self.pairs
            .iter()
            .rev()
            .find(|(k, _)| *k == name)
            .map(|(_, v)| *v)
    }

    /// An optional integer within `min..=max`.
    pub fn int_opt(
        &self,
        name: &'static str,
        min: i64,
        max: i64,
    ) -> Result<Option<i64>, QueryError> {
        let Some(v) = self.raw(name) else {
            return Ok(None);
        };
        match v.parse::<i64>() {
            Ok(n) if (min..=max).contains(&n) => Ok(Some(n)),
            _ => Err(QueryError::Bad { name, min, max }),
        }
    }

    /// A required integer within `min..=max`.
    pub fn int(&self, name: &'static str, min: i64, max: i64) -> Result<i64, QueryError> {
        self.int_opt(name, min, max)?
            .ok_or(QueryError::Missing(name))
    }

    /// The raw text of a parameter.
    pub fn text(&self, name: &str) -> Option<&'a str> {
        self.raw(name)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_known_integers_and_refuses_the_rest() {
        let q = Query::parse(Some("tx=3&tz=-2&view=top"), &["tx", "tz", "view"]).unwrap();
        assert_eq!(q.int("tx", -5, 5), Ok(3));
        assert_eq!(q.int("tz", -5, 5), Ok(-2));
        assert_eq!(q.text("view"), Some("top"));
        assert!(matches!(q.int("tx", 4, 5), Err(QueryError::Bad { .. })));
        assert_eq!(q.int_opt("y", 0, 1), Ok(None));
        assert!(matches!(
            Query::parse(Some("evil=1"), &["tx"]),
            Err(QueryError::Unknown(_))
        ));
        let many = vec!["tx=1"; MAX_PARAMS + 1].join("&");
        assert_eq!(
            Query::parse(Some(&many), &["tx"]).unwrap_err(),
            QueryError::TooMany
        );
        assert!(matches!(
            Query::parse(Some("tx=99999999999999999999"), &["tx"])
                .unwrap()
                .int("tx", 0, 9),
            Err(QueryError::Bad { .. })
        ));
    }
}
