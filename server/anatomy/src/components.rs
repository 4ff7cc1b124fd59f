//! Connected components of a graph given as index pairs (union–find with path halving).

/// Number of connected components among the indices `0..count` that appear in `pairs`.
pub(crate) fn count_components(
    count: usize,
    pairs: impl IntoIterator<Item = (usize, usize)>,
) -> usize {
    fn find(parent: &mut [usize], mut i: usize) -> usize {
        while parent[i] != i {
            parent[i] = parent[parent[i]];
            i = parent[i];
        }
        i
    }
    let mut parent: Vec<usize> = (0..count).collect();
    let mut used = vec![false; count];
    for (a, b) in pairs {
        used[a] = true;
        used[b] = true;
        let (ra, rb) = (find(&mut parent, a), find(&mut parent, b));
        if ra != rb {
            parent[ra] = rb;
        }
    }
    (0..count)
        .filter(|&i| used[i] && find(&mut parent, i) == i)
        .count()
}
