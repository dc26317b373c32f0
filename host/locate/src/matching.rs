//! Descriptor matching against the viewpoint database (docs/notes/issue15-cold-start.md §3):
//! nearest neighbour by Hamming distance, Lowe's ratio test against the nearest neighbour of
//! *another* model point (the database holds each point once per view that saw it, so the
//! runner-up is often the same point), and a mutual check.

use super::index::Index;
use super::orb::{Descriptor, hamming};

/// Matching settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MatchConfig {
    /// Largest accepted ratio best / runner-up (of another point).
    pub ratio: f32,
    /// Largest accepted Hamming distance of 256 bits.
    pub max_distance: u32,
    /// Entries whose model points lie closer than this are one point [m].
    pub same_point_m: f32,
    /// Entries compared per query through the index (the nearest branches first).
    pub checks: usize,
}

impl Default for MatchConfig {
    fn default() -> Self {
        Self {
            ratio: 0.85,
            max_distance: 80,
            same_point_m: 0.003,
            checks: 3000,
        }
    }
}

/// A live keypoint matched to a database entry.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Match {
    /// Index of the live keypoint.
    pub query: usize,
    /// Index of the database entry.
    pub entry: usize,
    /// Hamming distance.
    pub distance: u32,
}

/// Candidates kept per query while scanning, to find the runner-up of another point.
const KEEP: usize = 8;

/// Matches `query` descriptors against the database's (`train`, with each entry's model
/// point `points`), through `index` (built over `train`) with [`MatchConfig::checks`]
/// comparisons per query, or by a scan of all entries without one. Where the CPU has the
/// `popcnt` instruction (chosen at run time: a release build runs on any x86-64), the
/// distances are counted with it; the matches are the same either way.
pub fn match_descriptors(
    query: &[Descriptor],
    train: &[Descriptor],
    points: &[[f32; 3]],
    index: Option<&Index>,
    config: &MatchConfig,
) -> Vec<Match> {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("popcnt") {
        // SAFETY: the CPU has `popcnt` (checked just above), the only feature the function
        // enables.
        #[allow(unsafe_code)]
        return unsafe { match_with_popcnt(query, train, points, index, config) };
    }
    match_all(query, train, points, index, config)
}

/// [`match_all`] compiled with `popcnt`: each `count_ones` in it (the index's search and the
/// closures included, all inlined) is one instruction instead of the baseline's shifts and
/// adds.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "popcnt")]
fn match_with_popcnt(
    query: &[Descriptor],
    train: &[Descriptor],
    points: &[[f32; 3]],
    index: Option<&Index>,
    config: &MatchConfig,
) -> Vec<Match> {
    match_all(query, train, points, index, config)
}

/// The matching ([`match_descriptors`]), inlined into each instruction set's function.
#[inline(always)]
fn match_all(
    query: &[Descriptor],
    train: &[Descriptor],
    points: &[[f32; 3]],
    index: Option<&Index>,
    config: &MatchConfig,
) -> Vec<Match> {
    if train.len() != points.len() || index.is_some_and(|i| i.len() != train.len()) {
        return Vec::new();
    }
    let mut candidates = Vec::with_capacity(query.len());
    // The KEEP nearest, sorted by distance.
    let mut near: Vec<(u32, usize)> = Vec::with_capacity(KEEP + 1);
    for (qi, q) in query.iter().enumerate() {
        near.clear();
        let mut consider = |ti: usize, t: &Descriptor| {
            let d = hamming(q, t);
            if near.len() < KEEP || d < near[near.len() - 1].0 {
                let at = near.partition_point(|&(e, _)| e <= d);
                near.insert(at, (d, ti));
                near.truncate(KEEP);
            }
        };
        match index {
            Some(index) => index.search(q, config.checks, &mut consider),
            None => train.iter().enumerate().for_each(|(ti, t)| consider(ti, t)),
        }
        let Some(&(d0, t0)) = near.first() else {
            continue;
        };
        let p0 = points[t0];
        let far = |ti: usize| {
            let p = points[ti];
            let d2: f32 = (0..3).map(|k| (p[k] - p0[k]).powi(2)).sum();
            d2 > config.same_point_m * config.same_point_m
        };
        // Without a runner-up of another point among the nearest, the match is unambiguous
        // as far as the list reaches: compare with the farthest kept.
        let runner_up = near
            .iter()
            .skip(1)
            .find(|&&(_, ti)| far(ti))
            .or(near.last())
            .map_or(u32::MAX, |&(d, _)| d);
        if d0 <= config.max_distance && (d0 as f32) < config.ratio * runner_up as f32 {
            candidates.push(Match {
                query: qi,
                entry: t0,
                distance: d0,
            });
        }
    }
    // Mutual check: the entry's nearest query (the first of equals) must be this one.
    candidates.retain(|m| {
        let t = &train[m.entry];
        let best = query
            .iter()
            .enumerate()
            .min_by_key(|&(_, q)| hamming(q, t))
            .map(|(i, _)| i);
        best == Some(m.query)
    });
    candidates
}

#[cfg(test)]
mod tests {
    use super::*;

    fn desc(seed: u64) -> Descriptor {
        let mut s = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
        let mut next = || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            s
        };
        [next(), next(), next(), next()]
    }

    fn flip(mut d: Descriptor, bits: usize) -> Descriptor {
        for b in 0..bits {
            d[b % 4] ^= 1 << (b * 7 % 64);
        }
        d
    }

    #[test]
    fn near_copies_match_and_ambiguity_is_refused() {
        let train: Vec<Descriptor> = (0..200).map(desc).collect();
        let mut points: Vec<[f32; 3]> = (0..200).map(|i| [i as f32 * 0.01, 0.0, 0.0]).collect();
        // Entry 7 seen twice (two views of one point): the nearer copy matches, and the other
        // is no runner-up.
        let mut train = train;
        train.push(flip(train[7], 3));
        points.push(points[7]);
        let query = vec![flip(train[5], 10), flip(train[7], 8), desc(9999)];
        let m = match_descriptors(&query, &train, &points, None, &MatchConfig::default());
        assert_eq!(
            m.iter().map(|m| (m.query, m.entry)).collect::<Vec<_>>(),
            vec![(0, 5), (1, 200)]
        );
        // Two different points with the same descriptor: ambiguous, refused.
        let mut train2 = train.clone();
        train2[6] = flip(train[5], 1);
        let m = match_descriptors(&query[..1], &train2, &points, None, &MatchConfig::default());
        assert!(m.is_empty(), "{m:?}");
        // Mismatched lengths: nothing.
        let cfg = MatchConfig::default();
        assert!(match_descriptors(&query, &train, &points[..3], None, &cfg).is_empty());
        // Through the index: the same matches here.
        let index = Index::new(&train);
        assert_eq!(
            match_descriptors(&query, &train, &points, Some(&index), &cfg),
            match_descriptors(&query, &train, &points, None, &cfg)
        );
    }
}
