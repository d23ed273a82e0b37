//! Allan deviation (IEEE Std 952 / NIST SP 1065), used to verify the inertial noise models of
//! docs/REFERENCES.md A2.1 against their white-noise (`σ_v/√τ`) and random-walk (`σ_u·√(τ/3)`)
//! signatures.

/// One Allan-deviation estimate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AllanPoint {
    /// Allan deviation, in the units of the samples.
    pub adev: f64,
    /// Number of clusters `n` the estimate used (it averages `n − 1` differences).
    pub clusters: usize,
}

/// Non-overlapping Allan deviation of a rate series at clusters of `cluster_len` samples
/// (τ = `cluster_len`·Δt): `σ_A² = Σ (ȳ_{j+1} − ȳ_j)² / (2(n − 1))` over the `n` full clusters.
///
/// `None` if `cluster_len` is zero or fewer than two clusters fit.
pub fn allan_deviation(samples: &[f64], cluster_len: usize) -> Option<AllanPoint> {
    if cluster_len == 0 {
        return None;
    }
    let n = samples.len() / cluster_len;
    if n < 2 {
        return None;
    }
    let inv_len = 1.0 / cluster_len as f64;
    let mut means = samples
        .chunks_exact(cluster_len)
        .map(|c| c.iter().sum::<f64>() * inv_len);
    let mut prev = means.next()?;
    let mut sum_sq = 0.0;
    for mean in means {
        sum_sq += (mean - prev).powi(2);
        prev = mean;
    }
    Some(AllanPoint {
        adev: (sum_sq / (2.0 * (n - 1) as f64)).sqrt(),
        clusters: n,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hand_computed_series() {
        // Clusters of 2: means 1, 3, 2 → differences 2, −1 → σ² = (4 + 1)/(2·2) = 1.25.
        let y = [0.0, 2.0, 3.0, 3.0, 1.0, 3.0, 99.0];
        let p = allan_deviation(&y, 2).unwrap();
        assert_eq!(p.clusters, 3);
        assert!((p.adev - 1.25_f64.sqrt()).abs() < 1e-15);
        // A constant has zero Allan deviation; a ramp of slope a has σ_A = a·τ/√2.
        assert_eq!(allan_deviation(&[5.0; 10], 3).unwrap().adev, 0.0);
        let ramp: Vec<f64> = (0..100).map(|k| 0.5 * k as f64).collect();
        let p = allan_deviation(&ramp, 10).unwrap();
        assert!((p.adev - 0.5 * 10.0 / 2.0_f64.sqrt()).abs() < 1e-12);
    }

    #[test]
    fn degenerate_inputs() {
        assert!(allan_deviation(&[1.0, 2.0, 3.0], 0).is_none());
        assert!(allan_deviation(&[1.0, 2.0, 3.0], 2).is_none());
        assert!(allan_deviation(&[], 1).is_none());
        assert!(allan_deviation(&[f64::NAN, 1.0], 1).unwrap().adev.is_nan());
    }
}
