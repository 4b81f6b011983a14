//! The initial scales' neighbour distances: for each point, the mean
//! squared distance to its 3 nearest others, exact, through a k-d tree.
//!
//! A uniform grid (what this was) assumes the points fill their bounding
//! box. The random initialisation does not: 100k points in the scene's
//! cube and 200k far-field points out to 30 units (the paper preset) put
//! thousands of points in each grid cell of the cube, and the search went
//! quadratic (143 s before the first iteration on an H100 machine's CPU,
//! perf/RESULTS.md, twenty-second session). A k-d tree splits where the
//! points are.

/// Points per leaf.
const LEAF: usize = 16;

struct Node {
    /// The node's points: `order[lo..hi]`.
    lo: usize,
    hi: usize,
    /// Inner nodes: the split axis and value (left: coordinate <= split,
    /// right: >= split) and the children's indices; leaves: `left` = 0.
    axis: usize,
    split: f32,
    left: usize,
    right: usize,
}

struct Tree<'a> {
    pts: &'a [[f32; 3]],
    order: Vec<u32>,
    nodes: Vec<Node>,
}

impl<'a> Tree<'a> {
    fn new(pts: &'a [[f32; 3]]) -> Tree<'a> {
        let mut t = Tree { pts, order: (0..pts.len() as u32).collect(), nodes: Vec::new() };
        t.build(0, pts.len());
        t
    }

    /// Build the node of `order[lo..hi]`; returns its index.
    fn build(&mut self, lo: usize, hi: usize) -> usize {
        let id = self.nodes.len();
        self.nodes.push(Node { lo, hi, axis: 0, split: 0.0, left: 0, right: 0 });
        if hi - lo <= LEAF {
            return id;
        }
        // Split the widest extent at its median.
        let (mut min, mut max) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
        for &i in &self.order[lo..hi] {
            let p = self.pts[i as usize];
            for k in 0..3 {
                min[k] = min[k].min(p[k]);
                max[k] = max[k].max(p[k]);
            }
        }
        let axis = (0..3).max_by(|&a, &b| (max[a] - min[a]).total_cmp(&(max[b] - min[b]))).unwrap_or(0);
        if !(max[axis] > min[axis]) {
            // Every point the same (or non-finite): nothing to split.
            return id;
        }
        let mid = (lo + hi) / 2;
        let pts = self.pts;
        self.order[lo..hi].select_nth_unstable_by(mid - lo, |&a, &b| pts[a as usize][axis].total_cmp(&pts[b as usize][axis]).then(a.cmp(&b)));
        let split = pts[self.order[mid] as usize][axis];
        let left = self.build(lo, mid);
        let right = self.build(mid, hi);
        self.nodes[id] = Node { lo, hi, axis, split, left, right };
        id
    }

    /// The 3 smallest squared distances from point `i` to the others of
    /// node `n` (infinity where there are fewer), merged into `best`.
    fn nearest(&self, n: usize, i: usize, best: &mut [f32; 3]) {
        let node = &self.nodes[n];
        let p = self.pts[i];
        if node.left == 0 {
            for &j in &self.order[node.lo..node.hi] {
                if j as usize == i {
                    continue;
                }
                let q = self.pts[j as usize];
                let d = (p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2);
                if d < best[2] {
                    best[2] = d;
                    best.sort_by(|a, b| a.total_cmp(b));
                }
            }
            return;
        }
        let diff = p[node.axis] - node.split;
        let (near, far) = if diff < 0.0 { (node.left, node.right) } else { (node.right, node.left) };
        self.nearest(near, i, best);
        // Every point on the far side is at least |diff| away along the axis.
        if !(diff * diff >= best[2]) {
            self.nearest(far, i, best);
        }
    }
}

/// Mean squared distance of each point to its 3 nearest others (fewer
/// when there are fewer others; 1e-7 when there are none).
pub fn knn3_mean_sq(pts: &[[f32; 3]]) -> Vec<f32> {
    if pts.len() < 2 {
        return vec![1e-7; pts.len()];
    }
    let tree = Tree::new(pts);
    (0..pts.len())
        .map(|i| {
            let mut best = [f32::INFINITY; 3];
            tree.nearest(0, i, &mut best);
            let found: Vec<f32> = best.iter().copied().filter(|d| d.is_finite()).collect();
            if found.is_empty() {
                1e-7
            } else {
                found.iter().sum::<f32>() / found.len() as f32
            }
        })
        .collect()
}
