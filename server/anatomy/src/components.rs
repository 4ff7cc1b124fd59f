//! Connected components of a graph given as index pairs (union–find with path halving).

/// Disjoint sets over the indices `0..count`.
pub struct UnionFind(Vec<usize>);

impl UnionFind {
    /// Every index in its own set.
    pub fn new(count: usize) -> Self {
        Self((0..count).collect())
    }

    /// The representative of `i`'s set.
    pub fn find(&mut self, mut i: usize) -> usize {
        while self.0[i] != i {
            self.0[i] = self.0[self.0[i]];
            i = self.0[i];
        }
        i
    }

    /// Joins the sets of `a` and `b`.
    pub fn union(&mut self, a: usize, b: usize) {
        let (ra, rb) = (self.find(a), self.find(b));
        if ra != rb {
            self.0[ra] = rb;
        }
    }
}

/// Number of connected components among the indices `0..count` that appear in `pairs`.
pub(crate) fn count_components(
    count: usize,
    pairs: impl IntoIterator<Item = (usize, usize)>,
) -> usize {
    let mut sets = UnionFind::new(count);
    let mut used = vec![false; count];
    for (a, b) in pairs {
        used[a] = true;
        used[b] = true;
        sets.union(a, b);
    }
    (0..count).filter(|&i| used[i] && sets.find(i) == i).count()
}
