//! A hierarchical clustering index over binary descriptors (docs/notes/issue15-cold-start.md
//! §3), after Muja and Lowe ("Fast matching of binary features", CRV 2012): the entries are
//! split around `BRANCHING` centres picked among them, recursively, down to small leaves. A
//! query descends to the nearest leaf and then visits the other branches in the order of
//! their centres' distance, until it has compared `checks` entries. A brute-force scan of the
//! whole database is the limit of many checks. Each leaf holds its entries' descriptors
//! beside their indices, so that a search reads them in order instead of one by one from
//! across the database (cache misses were most of the matching's time).

use std::cmp::Reverse;
use std::collections::BinaryHeap;

use rand::SeedableRng;
use rand::rngs::StdRng;
use rand::seq::index::sample;

use super::orb::{Descriptor, hamming};

/// Children per node.
const BRANCHING: usize = 16;
/// Largest leaf.
const LEAF: usize = 64;
/// Seed of the centres' choice (the index is deterministic).
const SEED: u64 = 0x1dec_5eed;

#[derive(Debug, Clone)]
enum Node {
    /// Entry indices, each with its descriptor.
    Leaf(Vec<(u32, Descriptor)>),
    /// Children with their centres (an entry's descriptor each).
    Inner(Vec<(Descriptor, Node)>),
}

/// The index over a set of descriptors.
#[derive(Debug, Clone)]
pub struct Index {
    root: Node,
    len: usize,
}

impl Index {
    /// Builds the index of `descriptors`.
    pub fn new(descriptors: &[Descriptor]) -> Self {
        let mut rng = StdRng::seed_from_u64(SEED);
        let all: Vec<u32> = (0..descriptors.len() as u32).collect();
        Self {
            root: build(descriptors, all, &mut rng),
            len: descriptors.len(),
        }
    }

    /// Entries indexed.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether the index is empty.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Calls `visit(entry, its descriptor)` for at least `checks` entries (all, if fewer) near
    /// `query`: the nearest leaf first, then the others by their centres' distance.
    /// (Inlined, so that the matching's `popcnt` build counts the centres' distances too.)
    #[inline(always)]
    pub fn search(
        &self,
        query: &Descriptor,
        checks: usize,
        visit: &mut dyn FnMut(usize, &Descriptor),
    ) {
        // Branches not taken wait in `pending`; the heap orders them by their centre's distance.
        let mut pending: Vec<&Node> = vec![&self.root];
        let mut heap: BinaryHeap<Reverse<(u32, usize)>> = BinaryHeap::new();
        heap.push(Reverse((0, 0)));
        let mut seen = 0usize;
        while let Some(Reverse((_, at))) = heap.pop() {
            let mut node = pending[at];
            loop {
                match node {
                    Node::Leaf(entries) => {
                        for (e, d) in entries {
                            visit(*e as usize, d);
                        }
                        seen += entries.len();
                        break;
                    }
                    Node::Inner(children) => {
                        let mut best = (u32::MAX, 0usize);
                        for (i, (centre, _)) in children.iter().enumerate() {
                            let d = hamming(query, centre);
                            if d < best.0 {
                                best = (d, i);
                            }
                        }
                        for (i, (centre, child)) in children.iter().enumerate() {
                            if i != best.1 {
                                pending.push(child);
                                heap.push(Reverse((hamming(query, centre), pending.len() - 1)));
                            }
                        }
                        node = &children[best.1].1;
                    }
                }
            }
            if seen >= checks {
                return;
            }
        }
    }
}

fn build(descriptors: &[Descriptor], entries: Vec<u32>, rng: &mut StdRng) -> Node {
    let leaf = |entries: Vec<u32>| {
        Node::Leaf(
            entries
                .into_iter()
                .map(|e| (e, descriptors[e as usize]))
                .collect(),
        )
    };
    if entries.len() <= LEAF {
        return leaf(entries);
    }
    let centres: Vec<Descriptor> = sample(rng, entries.len(), BRANCHING)
        .into_iter()
        .map(|i| descriptors[entries[i] as usize])
        .collect();
    let mut groups: Vec<Vec<u32>> = vec![Vec::new(); BRANCHING];
    for &e in &entries {
        let d = &descriptors[e as usize];
        let nearest = (0..BRANCHING)
            .min_by_key(|&c| hamming(d, &centres[c]))
            .unwrap_or(0);
        groups[nearest].push(e);
    }
    // Identical descriptors cannot be split by any centre: keep them as one leaf.
    if groups.iter().any(|g| g.len() == entries.len()) {
        return leaf(entries);
    }
    Node::Inner(
        centres
            .into_iter()
            .zip(groups)
            .filter(|(_, g)| !g.is_empty())
            .map(|(c, g)| (c, build(descriptors, g, rng)))
            .collect(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn random(n: usize, seed: u64) -> Vec<Descriptor> {
        use rand::RngExt;
        let mut rng = StdRng::seed_from_u64(seed);
        (0..n)
            .map(|_| [rng.random(), rng.random(), rng.random(), rng.random()])
            .collect()
    }

    #[test]
    fn every_entry_is_reachable_and_near_copies_are_found_first() {
        let db = random(5000, 1);
        let index = Index::new(&db);
        assert_eq!(index.len(), 5000);
        let mut all = Vec::new();
        index.search(&db[0], usize::MAX, &mut |e, d| {
            assert_eq!(*d, db[e]);
            all.push(e)
        });
        all.sort_unstable();
        assert_eq!(
            all,
            (0..5000).collect::<Vec<_>>(),
            "a full search visits everything once"
        );
        // Near copies (12 of 256 bits flipped) are found with a tenth of the checks.
        let mut found = 0;
        for (k, d) in db.iter().enumerate().step_by(50) {
            let mut q = *d;
            for b in 0..12 {
                q[b % 4] ^= 1 << ((b * 13 + k) % 64);
            }
            let mut hit = false;
            index.search(&q, 500, &mut |e, _| hit |= e == k);
            found += usize::from(hit);
        }
        assert!(found >= 95, "{found} of 100 near copies found");
        // Identical descriptors and an empty set.
        let same = vec![[7u64; 4]; 300];
        let mut n = 0;
        Index::new(&same).search(&same[0], 10, &mut |_, _| n += 1);
        assert_eq!(n, 300);
        assert!(Index::new(&[]).is_empty());
    }
}
