//! Natural ("human") ordering of file names: digit runs compare by value, so
//! `frame2 < frame10`.

use std::cmp::Ordering;

/// Compares two names naturally: runs of ASCII digits compare as numbers
/// (ties broken by fewer leading zeros first), everything else byte by byte.
/// A total order, so it can sort file lists deterministically.
pub fn natural_cmp(a: &str, b: &str) -> Ordering {
    let (a, b) = (a.as_bytes(), b.as_bytes());
    let (mut i, mut j) = (0, 0);
    while i < a.len() && j < b.len() {
        let (ca, cb) = (a[i], b[j]);
        if ca.is_ascii_digit() && cb.is_ascii_digit() {
            let ea = i + a[i..].iter().take_while(|c| c.is_ascii_digit()).count();
            let eb = j + b[j..].iter().take_while(|c| c.is_ascii_digit()).count();
            let (da, db) = (&a[i..ea], &b[j..eb]);
            // Strip leading zeros; then a longer run is a larger number, and
            // equal-length runs compare lexicographically (= numerically).
            let za = da.iter().take_while(|&&c| c == b'0').count();
            let zb = db.iter().take_while(|&&c| c == b'0').count();
            let (na, nb) = (&da[za..], &db[zb..]);
            let ord = na.len().cmp(&nb.len()).then_with(|| na.cmp(nb)).then_with(|| za.cmp(&zb));
            if ord != Ordering::Equal {
                return ord;
            }
            i = ea;
            j = eb;
        } else {
            if ca != cb {
                return ca.cmp(&cb);
            }
            i += 1;
            j += 1;
        }
    }
    (a.len() - i).cmp(&(b.len() - j))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn digits_compare_by_value() {
        let mut v = vec![
            "frame10.png",
            "frame2.png",
            "frame1.png",
            "frame02.png",
            "a.png",
            "frame100.png",
            "frame9b.png",
            "frame9a.png",
        ];
        v.sort_by(|a, b| natural_cmp(a, b));
        assert_eq!(
            v,
            [
                "a.png",
                "frame1.png",
                "frame2.png",
                "frame02.png",
                "frame9a.png",
                "frame9b.png",
                "frame10.png",
                "frame100.png"
            ]
        );
    }

    #[test]
    fn huge_numbers_and_prefixes() {
        assert_eq!(natural_cmp("x99999999999999999999999", "x100000000000000000000000"), Ordering::Less);
        assert_eq!(natural_cmp("abc", "abcd"), Ordering::Less);
        assert_eq!(natural_cmp("abc1", "abc1"), Ordering::Equal);
        assert_eq!(natural_cmp("1305031229.528748.png", "1305031229.596600.png"), Ordering::Less);
    }
}
