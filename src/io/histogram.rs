//! A fixed-memory latency histogram of nanosecond values: O(1), allocation-free recording on the
//! tick path, percentiles and bucket lists for reports and plots afterwards.
//!
//! Buckets are log-linear (HDR style): values below 256 ns have a bucket each (exact); above, every
//! power-of-two range [2^m, 2^(m+1)) is split into 128 equal buckets, so a bucket is at most 1/128
//! of its lower bound wide and its midpoint is within 0.4 % of any value in it. The top range ends
//! at 2^36 ns (about 68.7 s); larger values are counted in the top bucket (and still set the exact
//! maximum). The 3840 counters (30 KiB) are allocated once, in [`Histogram::new`].

/// Values below this have a bucket of their own (ns).
const EXACT_LIMIT: u64 = 256;
/// log2 of the sub-buckets per power-of-two range.
const SUB_BITS: u32 = 7;
/// Sub-buckets per power-of-two range.
const SUB_COUNT: usize = 1 << SUB_BITS;
/// The highest power-of-two range covered is [2^MAX_MAGNITUDE, 2^(MAX_MAGNITUDE+1)).
const MAX_MAGNITUDE: u32 = 35;
/// Number of buckets.
const BUCKETS: usize = (MAX_MAGNITUDE as usize - SUB_BITS as usize) * SUB_COUNT + EXACT_LIMIT as usize;

/// The bucket holding `v` (ns). Tick-path safe.
#[inline]
fn bucket_index(v: u64) -> usize {
    if v < EXACT_LIMIT {
        return v as usize;
    }
    let magnitude = 63 - v.leading_zeros(); // >= 8
    if magnitude > MAX_MAGNITUDE {
        return BUCKETS - 1;
    }
    let shift = magnitude - SUB_BITS;
    // (v >> shift) is in [128, 256): the sub-bucket plus 128.
    (shift as usize + 1) * SUB_COUNT + ((v >> shift) as usize - SUB_COUNT)
}

/// The inclusive value range (ns) of bucket `i`.
fn bucket_bounds(i: usize) -> (u64, u64) {
    if i < EXACT_LIMIT as usize {
        return (i as u64, i as u64);
    }
    let shift = (i / SUB_COUNT - 1) as u32;
    let lower = ((i % SUB_COUNT + SUB_COUNT) as u64) << shift;
    (lower, lower + (1u64 << shift) - 1)
}

/// A histogram of u64 nanosecond values (latencies, lateness, durations) with fixed memory.
/// `min`, `max`, `count` and `mean` are exact; percentiles are within 0.4 % (bucket midpoints),
/// clamped to the exact min and max.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Histogram {
    counts: Box<[u64]>,
    count: u64,
    sum: u128,
    min: u64,
    max: u64,
}

impl Default for Histogram {
    fn default() -> Self {
        Self::new()
    }
}

impl Histogram {
    /// An empty histogram; allocates its buckets (30 KiB) once, here.
    pub fn new() -> Self {
        Histogram { counts: vec![0; BUCKETS].into_boxed_slice(), count: 0, sum: 0, min: u64::MAX, max: 0 }
    }

    /// Records one value (ns). Tick-path safe: O(1), no allocation.
    #[inline]
    pub fn record(&mut self, v: u64) {
        self.counts[bucket_index(v)] += 1;
        self.count += 1;
        self.sum += v as u128;
        self.min = self.min.min(v);
        self.max = self.max.max(v);
    }

    /// Number of values recorded.
    pub fn count(&self) -> u64 {
        self.count
    }

    /// The smallest value recorded (ns, exact); 0 when empty.
    pub fn min(&self) -> u64 {
        if self.count == 0 { 0 } else { self.min }
    }

    /// The largest value recorded (ns, exact); 0 when empty.
    pub fn max(&self) -> u64 {
        self.max
    }

    /// The mean of the values recorded (ns, exact up to f64 rounding); 0 when empty.
    pub fn mean(&self) -> f64 {
        if self.count == 0 { 0.0 } else { self.sum as f64 / self.count as f64 }
    }

    /// The `p`-th percentile (ns), `p` in [0, 100] (clamped; NaN reads as 0): the nearest-rank value,
    /// i.e. the ⌈p/100 · count⌉-th smallest, reported as its bucket's midpoint and clamped to the
    /// exact min and max (so rank 1 is `min()` and rank `count` is `max()`). 0 when empty.
    pub fn percentile(&self, p: f64) -> u64 {
        if self.count == 0 {
            return 0;
        }
        let p = if p.is_nan() { 0.0 } else { p.clamp(0.0, 100.0) };
        let rank = ((p / 100.0 * self.count as f64).ceil() as u64).clamp(1, self.count);
        if rank == 1 {
            return self.min;
        }
        if rank == self.count {
            return self.max;
        }
        let mut seen = 0u64;
        for (i, &c) in self.counts.iter().enumerate() {
            seen += c;
            if seen >= rank {
                let (lower, upper) = bucket_bounds(i);
                let mid = lower + (upper - lower) / 2;
                return mid.clamp(self.min, self.max);
            }
        }
        self.max
    }

    /// Adds every value of `other` to this histogram.
    pub fn merge(&mut self, other: &Histogram) {
        for (a, b) in self.counts.iter_mut().zip(other.counts.iter()) {
            *a += b;
        }
        self.count += other.count;
        self.sum += other.sum;
        self.min = self.min.min(other.min);
        self.max = self.max.max(other.max);
    }

    /// Forgets every value, keeping the buckets' memory. Tick-path safe (no allocation; touches 30 KiB).
    pub fn reset(&mut self) {
        self.counts.fill(0);
        self.count = 0;
        self.sum = 0;
        self.min = u64::MAX;
        self.max = 0;
    }

    /// The non-empty buckets in increasing order, as `(lower_ns, upper_ns, count)` with both bounds
    /// inclusive (for plots). Values beyond the top range are counted in the last bucket.
    pub fn iter_buckets(&self) -> impl Iterator<Item = (u64, u64, u64)> + '_ {
        self.counts.iter().enumerate().filter(|(_, c)| **c > 0).map(|(i, &c)| {
            let (lower, upper) = bucket_bounds(i);
            (lower, upper, c)
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn within(got: u64, want: u64, rel: f64) -> bool {
        (got as f64 - want as f64).abs() <= rel * want as f64
    }

    /// Exact nearest-rank percentile of sorted values.
    fn exact(sorted: &[u64], p: f64) -> u64 {
        let rank = ((p / 100.0 * sorted.len() as f64).ceil() as usize).clamp(1, sorted.len());
        sorted[rank - 1]
    }

    #[test]
    fn buckets_tile_the_range() {
        assert_eq!(bucket_bounds(0), (0, 0));
        let mut next = 0u64;
        for i in 0..BUCKETS {
            let (lo, hi) = bucket_bounds(i);
            assert_eq!(lo, next, "bucket {i}");
            assert!(hi >= lo);
            assert_eq!(bucket_index(lo), i);
            assert_eq!(bucket_index(hi), i);
            // At most 1/128 of the lower bound wide.
            assert!((hi - lo + 1) as f64 <= (lo.max(1) as f64) / 128.0 + 1.0, "bucket {i}: {lo}..={hi}");
            next = hi + 1;
        }
        assert_eq!(next, 1u64 << (MAX_MAGNITUDE + 1));
        assert!(next > 60_000_000_000);
        assert_eq!(bucket_index(u64::MAX), BUCKETS - 1);
    }

    #[test]
    fn empty_histogram_reads_zero() {
        let h = Histogram::new();
        assert_eq!((h.count(), h.min(), h.max(), h.mean()), (0, 0, 0, 0.0));
        assert_eq!(h.percentile(50.0), 0);
        assert_eq!(h.iter_buckets().count(), 0);
    }

    #[test]
    fn uniform_percentiles() {
        let mut h = Histogram::new();
        for v in 1..=100_000u64 {
            h.record(v);
        }
        assert_eq!(h.count(), 100_000);
        assert_eq!((h.min(), h.max()), (1, 100_000));
        assert!((h.mean() - 50_000.5).abs() < 1e-9);
        assert!(within(h.percentile(50.0), 50_000, 0.01), "{}", h.percentile(50.0));
        assert!(within(h.percentile(99.0), 99_000, 0.01), "{}", h.percentile(99.0));
        assert_eq!(h.percentile(0.0), 1);
        assert_eq!(h.percentile(100.0), 100_000);
        assert_eq!(h.percentile(0.0005), 1);
        assert_eq!(h.percentile(0.0015), 2); // rank 2, an exact bucket
        assert_eq!(h.iter_buckets().map(|b| b.2).sum::<u64>(), 100_000);
    }

    #[test]
    fn constant_is_exact() {
        let mut h = Histogram::new();
        for _ in 0..1000 {
            h.record(123_456_789);
        }
        for p in [0.0, 1.0, 50.0, 99.9, 100.0] {
            assert_eq!(h.percentile(p), 123_456_789);
        }
        assert_eq!(h.mean(), 123_456_789.0);
        let buckets: Vec<_> = h.iter_buckets().collect();
        assert_eq!(buckets.len(), 1);
        assert!(buckets[0].0 <= 123_456_789 && 123_456_789 <= buckets[0].1 && buckets[0].2 == 1000);
    }

    #[test]
    fn exponential_matches_sorted_percentiles() {
        // Fixed-seed LCG (Knuth MMIX), 53-bit uniform in (0, 1), exponential with mean 200 µs.
        let mut state = 0x2545_F491_4F6C_DD1Du64;
        let mut values = Vec::with_capacity(200_000);
        let mut h = Histogram::new();
        for _ in 0..200_000 {
            state = state.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
            let u = ((state >> 11) as f64 + 0.5) / (1u64 << 53) as f64;
            let v = (-u.ln() * 200_000.0) as u64;
            values.push(v);
            h.record(v);
        }
        values.sort_unstable();
        assert_eq!(h.min(), values[0]);
        assert_eq!(h.max(), *values.last().unwrap());
        let mean = values.iter().map(|&v| v as f64).sum::<f64>() / values.len() as f64;
        assert!((h.mean() - mean).abs() < 1e-6 * mean);
        for p in [0.1, 1.0, 10.0, 25.0, 50.0, 75.0, 90.0, 99.0, 99.9, 99.99] {
            let want = exact(&values, p);
            let got = h.percentile(p);
            assert!(within(got, want, 0.01), "p{p}: {got} vs exact {want}");
        }
    }

    #[test]
    fn merge_and_reset() {
        let mut a = Histogram::new();
        let mut b = Histogram::new();
        let mut all = Histogram::new();
        for v in 0..5000u64 {
            let x = v * v % 7919 + 10;
            if v % 3 == 0 {
                a.record(x)
            } else {
                b.record(x)
            }
            all.record(x);
        }
        a.merge(&b);
        assert_eq!(a, all);
        a.merge(&Histogram::new());
        assert_eq!(a, all);
        a.reset();
        assert_eq!(a, Histogram::new());
    }

    #[test]
    fn huge_values_go_to_the_top_bucket() {
        let mut h = Histogram::new();
        h.record(u64::MAX);
        h.record(5);
        assert_eq!(h.max(), u64::MAX);
        assert_eq!(h.percentile(100.0), u64::MAX);
        assert_eq!(h.iter_buckets().last().unwrap().2, 1);
    }
}
