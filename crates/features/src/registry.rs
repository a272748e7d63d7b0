//! Making extractors and matchers by name, so front ends can be chosen from
//! the command line or a config file and learned ones (XFeat, ...) can be
//! added beside ORB.

use crate::FeatureError;
use crate::matcher::{NnMatcher, NnMatcherOptions};
use crate::orb::{OrbExtractor, OrbOptions};
use crate::types::{FeatureExtractor, Matcher};

/// Names accepted by [`extractor_by_name`].
pub const EXTRACTOR_NAMES: &[&str] = &["orb"];
/// Names accepted by [`matcher_by_name`].
pub const MATCHER_NAMES: &[&str] = &["nn"];

/// Options of every extractor; only the one named is used.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ExtractorOptions {
    /// Options for "orb".
    pub orb: OrbOptions,
}

/// Options of every matcher; only the one named is used.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct MatcherOptions {
    /// Options for "nn".
    pub nn: NnMatcherOptions,
}

/// Makes the extractor called `name` (case-insensitive; see [`EXTRACTOR_NAMES`]).
pub fn extractor_by_name(name: &str, opts: &ExtractorOptions) -> Result<Box<dyn FeatureExtractor>, FeatureError> {
    match name.to_ascii_lowercase().as_str() {
        "orb" => Ok(Box::new(OrbExtractor::new(opts.orb.clone())?)),
        _ => Err(FeatureError::UnknownName {
            kind: "extractor",
            name: name.to_string(),
            known: EXTRACTOR_NAMES.join(", "),
        }),
    }
}

/// Makes the matcher called `name` (case-insensitive; see [`MATCHER_NAMES`]).
pub fn matcher_by_name(name: &str, opts: &MatcherOptions) -> Result<Box<dyn Matcher>, FeatureError> {
    match name.to_ascii_lowercase().as_str() {
        "nn" => Ok(Box::new(NnMatcher::new(opts.nn.clone())?)),
        _ => {
            Err(FeatureError::UnknownName { kind: "matcher", name: name.to_string(), known: MATCHER_NAMES.join(", ") })
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_resolve() {
        assert_eq!(extractor_by_name("ORB", &ExtractorOptions::default()).unwrap().name(), "orb");
        assert_eq!(matcher_by_name("nn", &MatcherOptions::default()).unwrap().name(), "nn");
        let e = extractor_by_name("sift", &ExtractorOptions::default()).err().unwrap().to_string();
        assert!(e.contains("sift") && e.contains("orb"), "{e}");
        assert!(matcher_by_name("superglue", &MatcherOptions::default()).is_err());
        let mut bad = ExtractorOptions::default();
        bad.orb.n_levels = 0;
        assert!(extractor_by_name("orb", &bad).is_err());
    }
}
