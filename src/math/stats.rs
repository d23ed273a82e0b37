//! Order statistics shared by the estimators (the robust scales of the VNS's pose optimisation
//! and its initialisation's disparity and depth tests).

/// The median of `values` (the mean of the two middle values for an even count; NaN sorts
/// last); `None` when empty.
pub fn median(mut values: Vec<f64>) -> Option<f64> {
    if values.is_empty() {
        return None;
    }
    values.sort_by(f64::total_cmp);
    let n = values.len();
    Some(if n % 2 == 1 {
        values[n / 2]
    } else {
        0.5 * (values[n / 2 - 1] + values[n / 2])
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn odd_even_and_empty() {
        assert_eq!(median(vec![3.0, -1.0, 2.0]), Some(2.0));
        assert_eq!(median(vec![4.0, 1.0, 3.0, 2.0]), Some(2.5));
        assert_eq!(median(vec![7.0]), Some(7.0));
        assert_eq!(median(Vec::new()), None);
        // NaN sorts after every number: one NaN among three finite values leaves the middle.
        assert_eq!(median(vec![f64::NAN, 1.0, 5.0, 3.0, 2.0]), Some(3.0));
    }
}
