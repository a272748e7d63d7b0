//! Number formatting as COLMAP's text writers produce it: a C++ stream with
//! `precision(17)` and the default float field, i.e. C's `%.17g` (17
//! significant digits, trailing zeros removed, exponent form when the decimal
//! exponent is below -4 or at least 17).

/// Significant digits COLMAP writes (enough to round-trip any f64).
const SIGNIFICANT_DIGITS: i32 = 17;

/// `%g` switches to exponent form below this decimal exponent.
const MIN_FIXED_EXPONENT: i32 = -4;

/// Formats `x` like C's `printf("%.17g", x)` (glibc spelling of the special
/// values: `nan`, `-nan`, `inf`, `-inf`).
pub fn format_g17(x: f64) -> String {
    let mut s = String::new();
    push_g17(&mut s, x);
    s
}

/// Appends `x` formatted like `%.17g`.
pub(crate) fn push_g17(out: &mut String, x: f64) {
    if x.is_nan() {
        out.push_str(if x.is_sign_negative() { "-nan" } else { "nan" });
        return;
    }
    if x.is_infinite() {
        out.push_str(if x < 0.0 { "-inf" } else { "inf" });
        return;
    }
    if x == 0.0 {
        out.push_str(if x.is_sign_negative() { "-0" } else { "0" });
        return;
    }
    // Exactly rounded scientific form with 17 significant digits, e.g.
    // "-1.2345678901234567e-5".
    let sci = format!("{:.*e}", (SIGNIFICANT_DIGITS - 1) as usize, x);
    let (mantissa, exp) = sci.split_once('e').unwrap_or((&sci, "0"));
    let exp: i32 = exp.parse().unwrap_or(0);
    let negative = mantissa.starts_with('-');
    let digits: Vec<u8> = mantissa.bytes().filter(u8::is_ascii_digit).collect();
    if negative {
        out.push('-');
    }
    // Digits without trailing zeros (at least one remains: x != 0).
    let sig_len = digits.iter().rposition(|&d| d != b'0').map_or(1, |p| p + 1);
    let sig = digits.get(..sig_len).unwrap_or(&digits);
    let push_digits = |out: &mut String, d: &[u8]| d.iter().for_each(|&c| out.push(char::from(c)));
    if !(MIN_FIXED_EXPONENT..SIGNIFICANT_DIGITS).contains(&exp) {
        let (first, rest) = sig.split_at(1.min(sig.len()));
        push_digits(out, first);
        if !rest.is_empty() {
            out.push('.');
            push_digits(out, rest);
        }
        out.push('e');
        out.push(if exp < 0 { '-' } else { '+' });
        let e = exp.unsigned_abs();
        if e < 10 {
            out.push('0');
        }
        out.push_str(&e.to_string());
    } else if exp >= 0 {
        // exp + 1 integer digits (exp < 17 = digits.len()).
        let int_len = (exp + 1) as usize;
        let int_part = digits.get(..int_len).unwrap_or(&digits);
        push_digits(out, int_part);
        if sig_len > int_len {
            out.push('.');
            push_digits(out, sig.get(int_len..).unwrap_or(&[]));
        }
    } else {
        out.push_str("0.");
        for _ in 0..(-exp - 1) {
            out.push('0');
        }
        push_digits(out, sig);
    }
}

#[cfg(test)]
mod tests {
    use super::format_g17;

    #[test]
    #[allow(clippy::excessive_precision)] // literals copied from COLMAP output on purpose
    fn matches_printf_g17() {
        // Reference strings from C's printf("%.17g") (and COLMAP's files).
        let cases: &[(f64, &str)] = &[
            (500.0, "500"),
            (0.1, "0.10000000000000001"),
            (-0.01, "-0.01"),
            (0.002, "0.002"),
            (1.0, "1"),
            (-1.0, "-1"),
            (0.5, "0.5"),
            (2688.6363636363635, "2688.6363636363635"),
            (1e-5, "1.0000000000000001e-05"),
            (1.5e-4, "0.00014999999999999999"),
            (1e17, "1e+17"),
            (1.2345e20, "1.2345e+20"),
            (123456789012345678.0, "1.2345678901234568e+17"),
            (12345678901234567.0, "12345678901234568"),
            (1e-300, "1e-300"),
            (f64::MAX, "1.7976931348623157e+308"),
            (-0.0, "-0"),
            (0.0, "0"),
            (f64::INFINITY, "inf"),
            (1.340_780_792_994_259_6e154, "1.3407807929942596e+154"),
            (0.92338051687663869, "0.92338051687663869"),
            (-0.0072437568218800454, "-0.0072437568218800454"),
            (0.0009220983015007986, "0.0009220983015007986"),
        ];
        for &(x, want) in cases {
            assert_eq!(format_g17(x), want, "{x:e}");
        }
    }

    #[test]
    fn round_trips_through_parse() {
        let mut rng = colslam_geometry::SplitMix64::new(7);
        for _ in 0..10_000 {
            let bits = rng.next_u64();
            let x = f64::from_bits(bits);
            if !x.is_finite() {
                continue;
            }
            let s = format_g17(x);
            let back: f64 = s.parse().unwrap();
            assert_eq!(back.to_bits(), x.to_bits(), "{s}");
        }
    }
}
