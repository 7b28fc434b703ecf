//! Stamps of real recordings: which to trust, how to repair the others, how to sort.
//!
//! Real logs carry zero, repeated, rounded and wild stamps while their file order is the order
//! of events. `repair_in_file_order` keeps the longest run of plausible stamps that increase
//! in file order (when it holds at least half of them) and places every other record between
//! its trusted neighbours, so no record is lost and the order of the file is kept.

use pfslam::sensors::ScanSet;

/// Stamps made from a clock without trusted stamps: one per second.
pub const SYNTHETIC_PERIOD_NS: i64 = 1_000_000_000;

/// Indices of a longest subsequence of strictly increasing values (of equal values the first
/// is kept), in order. O(n log n).
pub(crate) fn longest_increasing(stamps: &[i64]) -> Vec<usize> {
    // tails[k] = index of the smallest tail of an increasing run of length k + 1
    let mut tails: Vec<usize> = Vec::new();
    let mut prev: Vec<usize> = vec![usize::MAX; stamps.len()];
    for (i, &s) in stamps.iter().enumerate() {
        let k = tails.partition_point(|&j| stamps[j] < s);
        if k > 0 {
            prev[i] = tails[k - 1];
        }
        if k == tails.len() {
            tails.push(i);
        } else if stamps[tails[k]] > s {
            tails[k] = i;
        }
    }
    let mut out = Vec::with_capacity(tails.len());
    let mut cur = tails.last().copied().unwrap_or(usize::MAX);
    while cur != usize::MAX {
        out.push(cur);
        cur = prev[cur];
    }
    out.reverse();
    out
}

/// A clock over records in file order.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct RepairedClock {
    /// One strictly increasing stamp per record (ns).
    pub stamps_ns: Vec<i64>,
    /// Records whose stamp was replaced.
    pub repaired: usize,
    /// The typical interval between consecutive records (ns, at least 1).
    pub period_ns: i64,
}

/// Repairs the stamps of records in file order (`None` = no parsable stamp). A stamp is
/// plausible when it is above 0; the longest strictly increasing subsequence of plausible
/// stamps is trusted when it holds at least half of the records, else `None` is returned
/// (the stamps say nothing). Untrusted records get stamps spread evenly between their trusted
/// neighbours, or extrapolated by the median interval past the first and last.
pub(crate) fn repair_in_file_order(stamps: &[Option<i64>]) -> Option<RepairedClock> {
    let plausible: Vec<usize> = (0..stamps.len())
        .filter(|&i| stamps[i].is_some_and(|s| s > 0))
        .collect();
    let values: Vec<i64> = plausible.iter().filter_map(|&i| stamps[i]).collect();
    let anchors: Vec<usize> = longest_increasing(&values)
        .into_iter()
        .map(|k| plausible[k])
        .collect();
    if anchors.is_empty() || anchors.len() * 2 < stamps.len() {
        return None;
    }
    let at = |i: usize| stamps[i].unwrap_or(0);
    let period_ns = median_period(&anchors, &at);
    let mut out = vec![0i64; stamps.len()];
    let (first, last) = (anchors[0], anchors[anchors.len() - 1]);
    // Extrapolated stamps beyond the range of i64 (wild stamps, a wild period) make the
    // clock useless, not a wrapped one.
    let step = |k: usize| i64::try_from(k).ok()?.checked_mul(period_ns);
    for (i, o) in out.iter_mut().enumerate().take(first) {
        *o = at(first).checked_sub(step(first - i)?)?;
    }
    for w in anchors.windows(2) {
        let (a, b) = (w[0], w[1]);
        let (sa, sb) = (i128::from(at(a)), i128::from(at(b)));
        for (i, o) in out.iter_mut().enumerate().take(b).skip(a) {
            *o = (sa + (sb - sa) * (i - a) as i128 / (b - a) as i128) as i64;
        }
    }
    for (i, o) in out.iter_mut().enumerate().skip(last) {
        *o = at(last).checked_add(step(i - last)?)?;
    }
    make_strictly_increasing(&mut out);
    Some(RepairedClock {
        repaired: stamps.len() - anchors.len(),
        stamps_ns: out,
        period_ns,
    })
}

/// The median interval per record between consecutive anchors (ns, at least 1; one second
/// with a single anchor).
fn median_period(anchors: &[usize], at: &impl Fn(usize) -> i64) -> i64 {
    let mut per: Vec<i64> = anchors
        .windows(2)
        .map(|w| (at(w[1]) - at(w[0])) / (w[1] - w[0]) as i64)
        .collect();
    if per.is_empty() {
        return SYNTHETIC_PERIOD_NS;
    }
    let mid = per.len() / 2;
    (*per.select_nth_unstable(mid).1).max(1)
}

/// Raises each stamp to at least one nanosecond above the previous one.
pub(crate) fn make_strictly_increasing(stamps: &mut [i64]) {
    for i in 1..stamps.len() {
        if stamps[i] <= stamps[i - 1] {
            stamps[i] = stamps[i - 1].saturating_add(1);
        }
    }
}

/// Stamps for records placed among the records of another clock: `before[j]` is the number of
/// clock records that precede record `j` in the file (non-decreasing). Records in the same gap
/// are spread evenly across it; before the first and after the last clock record they step by
/// the clock's period.
pub(crate) fn place_between(clock: &RepairedClock, before: &[usize]) -> Vec<i64> {
    let c = &clock.stamps_ns;
    let mut out = Vec::with_capacity(before.len());
    let mut j = 0;
    while j < before.len() {
        let k = before[j];
        let m = before[j..].iter().take_while(|&&b| b == k).count();
        for r in 0..m {
            let frac = (r + 1) as f64 / (m + 1) as f64;
            let t = match (k.checked_sub(1).and_then(|p| c.get(p)), c.get(k)) {
                (Some(&lo), Some(&hi)) => lo as f64 + frac * (hi - lo) as f64,
                (Some(&lo), None) => lo as f64 + (r + 1) as f64 * clock.period_ns as f64,
                (None, Some(&hi)) => hi as f64 - (m - r) as f64 * clock.period_ns as f64,
                (None, None) => ((j + r) as i64 * SYNTHETIC_PERIOD_NS) as f64,
            };
            out.push(t.round() as i64);
        }
        j += m;
    }
    make_strictly_increasing(&mut out);
    out
}

/// Scans sorted by stamp (stable; of scans with equal stamps the first is kept) and the
/// number of scans whose stamp is not above the previous one's in file order.
pub(crate) fn sort_scans(scans: ScanSet) -> (ScanSet, Vec<usize>, usize) {
    let backwards = scans.stamps_ns.windows(2).filter(|w| w[1] <= w[0]).count();
    if backwards == 0 {
        let all = (0..scans.len()).collect();
        return (scans, all, 0);
    }
    let mut order: Vec<usize> = (0..scans.len()).collect();
    order.sort_by_key(|&i| scans.stamps_ns[i]);
    order.dedup_by_key(|i| scans.stamps_ns[*i]);
    (scans.select(&order), order, backwards)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lis_drops_outliers_and_duplicates() {
        let s = [1, 2, 9, 3, 4, 5, 5, 6, 0, 7];
        let keep = longest_increasing(&s);
        let kept: Vec<i64> = keep.iter().map(|&i| s[i]).collect();
        assert_eq!(kept, vec![1, 2, 3, 4, 5, 6, 7]);
        assert_eq!(keep[4], 5, "first of equal stamps kept");
        assert!(longest_increasing(&[]).is_empty());
    }

    #[test]
    fn repair_keeps_every_record_in_file_order() {
        // a zero, a repeat, a wild jump and an unparsable stamp among good ones
        let s = [
            Some(10),
            Some(20),
            Some(0),
            Some(40),
            Some(40),
            Some(9_999),
            Some(70),
            None,
            Some(90),
        ];
        let c = repair_in_file_order(&s).unwrap();
        assert_eq!(c.stamps_ns, vec![10, 20, 30, 40, 50, 60, 70, 80, 90]);
        assert_eq!(c.repaired, 4);
        assert_eq!(c.period_ns, 10);
        // untrusted ends extrapolate by the period
        let c = repair_in_file_order(&[Some(0), Some(100), Some(110), Some(120), None]).unwrap();
        assert_eq!(c.stamps_ns, vec![90, 100, 110, 120, 130]);
    }

    #[test]
    fn no_clock_from_useless_stamps() {
        assert!(repair_in_file_order(&[Some(0); 5]).is_none());
        // decreasing stamps: one trusted of five
        assert!(repair_in_file_order(&[Some(5), Some(4), Some(3), Some(2), Some(1)]).is_none());
        assert!(repair_in_file_order(&[]).is_none());
        // equal stamps (rounded): only the first is trusted
        assert!(repair_in_file_order(&[Some(7); 4]).is_none());
    }

    #[test]
    fn a_clock_that_would_run_past_i64_is_no_clock() {
        // found by fuzzing: the stamps after the last trusted one overflowed
        let near_end = i64::MAX - 10;
        let stamps = [Some(near_end - 2_000_000_000), Some(near_end), None, None];
        assert_eq!(repair_in_file_order(&stamps), None);
        // a wild period: the stamps before the first trusted one would fall below i64::MIN
        let before_start = [None, None, Some(1), Some(i64::MAX - 1)];
        assert_eq!(repair_in_file_order(&before_start), None);
        let fine = [Some(1_000), Some(2_000), None];
        assert_eq!(
            repair_in_file_order(&fine).unwrap().stamps_ns,
            vec![1_000, 2_000, 3_000]
        );
    }

    #[test]
    fn crowded_gaps_stay_strictly_increasing() {
        let c = repair_in_file_order(&[Some(10), None, None, None, Some(11), Some(12)]).unwrap();
        for w in c.stamps_ns.windows(2) {
            assert!(w[0] < w[1], "{:?}", c.stamps_ns);
        }
    }

    #[test]
    fn placing_between_another_clock() {
        let clock = RepairedClock {
            stamps_ns: vec![100, 200, 300],
            repaired: 0,
            period_ns: 100,
        };
        // two before the first record, two in the first gap, one after the last
        let p = place_between(&clock, &[0, 0, 1, 1, 3]);
        assert_eq!(p, vec![-100, 0, 133, 167, 400]);
    }
}
