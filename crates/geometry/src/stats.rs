//! Small sample statistics shared by the crates, their tests and the bench
//! lab: the median in its three flavours and the mean with the population
//! variance.
//!
//! NaN: the medians order values with [`f64::total_cmp`], which puts a
//! positive NaN after `+inf` and a negative NaN before `-inf`; a NaN in the
//! sample can therefore be (or enter) the median. [`median_finite`] skips NaN
//! and infinities first; the others leave filtering to the caller. Every
//! function returns `None` for an empty sample.

/// Median of `v`: the middle value for an odd count, the mean of the two
/// middle values for an even count. Sorts `v` ascending (by
/// [`f64::total_cmp`]) in place, so that after the call `v[0]` and
/// `v[v.len() - 1]` are its minimum and maximum. `None` when `v` is empty.
pub fn median_in_place(v: &mut [f64]) -> Option<f64> {
    v.sort_unstable_by(f64::total_cmp);
    let n = v.len();
    let hi = *v.get(n / 2)?;
    if n % 2 == 1 {
        return Some(hi);
    }
    // n is even and >= 2 here, so n / 2 - 1 is a valid index.
    Some(0.5 * (v[n / 2 - 1] + hi))
}

/// Median (as [`median_in_place`]) of the finite values of `v`, ignoring NaN
/// and infinities; `None` when there is no finite value. `v` is not changed.
/// The mean of two huge middle values can still overflow to infinity.
pub fn median_finite(v: &[f64]) -> Option<f64> {
    let mut finite: Vec<f64> = v.iter().copied().filter(|x| x.is_finite()).collect();
    median_in_place(&mut finite)
}

/// Upper median of `v`: the value that would stand at index `v.len() / 2`
/// once sorted by [`f64::total_cmp`] (the median for an odd count, the
/// larger of the two middle values for an even count; never an average, so
/// always one of the samples). Found by selection in linear time; reorders
/// `v` partially. `None` when `v` is empty.
pub fn upper_median_in_place(v: &mut [f64]) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    let mid = v.len() / 2;
    let (_, m, _) = v.select_nth_unstable_by(mid, f64::total_cmp);
    Some(*m)
}

/// Arithmetic mean and population variance (divided by the count, not the
/// count minus one) of `v`, in two passes; `None` when `v` is empty. A NaN or
/// infinite value makes both NaN or infinite.
pub fn mean_and_variance(v: &[f64]) -> Option<(f64, f64)> {
    if v.is_empty() {
        return None;
    }
    let n = v.len() as f64;
    let mean = v.iter().sum::<f64>() / n;
    let var = v
        .iter()
        .map(|x| {
            let d = x - mean;
            d * d
        })
        .sum::<f64>()
        / n;
    Some((mean, var))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn median_odd_even_and_empty() {
        let mut odd = [3.0, 1.0, 2.0];
        assert_eq!(median_in_place(&mut odd), Some(2.0));
        assert_eq!(odd, [1.0, 2.0, 3.0], "sorted in place");
        assert_eq!(median_in_place(&mut [4.0, 1.0]), Some(2.5));
        assert_eq!(median_in_place(&mut [4.0, 1.0, 8.0, 2.0]), Some(3.0));
        assert_eq!(median_in_place(&mut [7.5]), Some(7.5));
        assert_eq!(median_in_place(&mut []), None);
    }

    #[test]
    fn median_nan_is_ordered_not_skipped() {
        // total_cmp: 1 < 2 < 3 < NaN, so the middle two of four are 2 and 3;
        // with NaN in the middle the median is NaN; a negative NaN sorts first.
        assert_eq!(median_in_place(&mut [3.0, f64::NAN, 1.0, 2.0]), Some(2.5));
        assert!(median_in_place(&mut [f64::NAN, 1.0, f64::NAN]).is_some_and(f64::is_nan));
        assert_eq!(median_in_place(&mut [-f64::NAN, 1.0, 2.0]), Some(1.0));
    }

    #[test]
    fn median_of_finite_values() {
        assert_eq!(median_finite(&[3.0, f64::NAN, 1.0, 2.0]), Some(2.0));
        assert_eq!(median_finite(&[4.0, f64::INFINITY, 1.0, f64::NEG_INFINITY]), Some(2.5));
        assert_eq!(median_finite(&[f64::INFINITY, f64::NAN]), None);
        assert_eq!(median_finite(&[]), None);
        let v = [2.0, 1.0];
        assert_eq!(median_finite(&v), Some(1.5));
        assert_eq!(v, [2.0, 1.0], "input unchanged");
    }

    #[test]
    fn upper_median() {
        assert_eq!(upper_median_in_place(&mut [3.0, 1.0, 2.0]), Some(2.0));
        assert_eq!(upper_median_in_place(&mut [4.0, 1.0, 3.0, 2.0]), Some(3.0));
        assert_eq!(upper_median_in_place(&mut [5.0]), Some(5.0));
        assert_eq!(upper_median_in_place(&mut []), None);
        // NaN sorts last under total_cmp.
        assert_eq!(upper_median_in_place(&mut [f64::NAN, 1.0, 2.0]), Some(2.0));
        // Same value as sorting and indexing len / 2, on a larger sample.
        let mut v: Vec<f64> = (0..101).map(|i| f64::from((i * 37) % 101) - 50.0).collect();
        let mut sorted = v.clone();
        sorted.sort_by(f64::total_cmp);
        assert_eq!(upper_median_in_place(&mut v), Some(sorted[50]));
    }

    #[test]
    fn mean_and_population_variance() {
        assert_eq!(mean_and_variance(&[1.0, 2.0, 3.0, 4.0]), Some((2.5, 1.25)));
        assert_eq!(mean_and_variance(&[5.0]), Some((5.0, 0.0)));
        assert_eq!(mean_and_variance(&[]), None);
        let (m, v) = mean_and_variance(&[1.0, f64::NAN]).unwrap();
        assert!(m.is_nan() && v.is_nan());
    }
}
