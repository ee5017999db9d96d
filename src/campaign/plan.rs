//! A campaign expanded into its ordered measurements: plans as data. The plan is a pure
//! function of the campaign file, so a resumed campaign regenerates the same plan and skips the
//! targets already stored.
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::spec::{AxisPlan, Campaign};
use crate::sampling::{Design, DesignKind};
use crate::types::{AxisId, Direction, Phase, RunKey, Target};

pub mod map;

/// A monotonic sweep of one run: approached from its direction, targets in visiting order.
#[derive(Debug, Clone)]
pub struct Batch {
    pub run: RunKey,
    /// Batch number within the run (adaptive runs have several).
    pub index: usize,
    pub targets: Vec<Target>,
    /// Adaptive: after this batch, stop the run once the CV error estimate is at most this.
    pub target_error_um: Option<f64>,
}

#[derive(Debug, Clone)]
pub struct Plan {
    pub batches: Vec<Batch>,
}

impl Plan {
    pub fn total(&self) -> usize {
        self.batches.iter().map(|b| b.targets.len()).sum()
    }

    /// Batches of one run, in order.
    pub fn run_batches(&self, run: RunKey) -> impl Iterator<Item = &Batch> {
        self.batches.iter().filter(move |b| b.run == run)
    }

    pub fn runs(&self) -> Vec<RunKey> {
        let mut v: Vec<RunKey> = Vec::new();
        for b in &self.batches {
            if v.last() != Some(&b.run) {
                v.push(b.run);
            }
        }
        v
    }
}

/// Seed of an axis's design: the same targets for every cycle and both directions, so that
/// repeated approaches give ISO 230-2 repeatability and reversal at the same targets.
fn axis_seed(seed: u64, axis: AxisId) -> u64 {
    seed.wrapping_mul(0x9E37_79B9_7F4A_7C15)
        .wrapping_add(match axis {
            AxisId::X => 1,
            AxisId::Y => 2,
        })
}

/// Expands a validated campaign.
pub fn plan(c: &Campaign) -> Plan {
    let s = &c.spec().sampling;
    let a = &c.spec().acquisition;
    let mut batches = Vec::new();
    let mut seq = 0u64;
    let mut phases = vec![Phase::Cs];
    if s.design == DesignKind::Full {
        phases = vec![Phase::Full];
    } else if s.full_scan {
        phases.push(Phase::Full);
    }
    for ax in c.axes() {
        let n = ax.grid.n;
        for &phase in &phases {
            let (designs, chunks): (Vec<Vec<usize>>, Vec<usize>) = match phase {
                Phase::Full => (vec![(0..n).collect()], vec![n]),
                Phase::Cs | Phase::Map => {
                    cs_design(ax, s.design, s.seed, s.batch, a.directions.len())
                }
            };
            for cycle in 0..a.cycles {
                for (di, &direction) in a.directions.iter().enumerate() {
                    let idx = &designs[di % designs.len()];
                    let run = RunKey {
                        phase,
                        axis: ax.axis,
                        direction,
                        cycle,
                    };
                    let mut start = 0;
                    for (bi, &len) in chunks.iter().enumerate() {
                        let mut chunk: Vec<usize> = idx[start..start + len].to_vec();
                        start += len;
                        chunk.sort_unstable();
                        if direction == Direction::Backward {
                            chunk.reverse();
                        }
                        let targets = chunk
                            .into_iter()
                            .map(|i| {
                                let p = ax.grid.position(i);
                                let (tx, ty) = match ax.axis {
                                    AxisId::X => (p, ax.other_at_um),
                                    AxisId::Y => (ax.other_at_um, p),
                                };
                                let t = Target {
                                    seq,
                                    run,
                                    grid_index: i,
                                    target_x_um: tx,
                                    target_y_um: ty,
                                };
                                seq += 1;
                                t
                            })
                            .collect();
                        batches.push(Batch {
                            run,
                            index: bi,
                            targets,
                            target_error_um: if phase == Phase::Cs {
                                ax.target_error_um
                            } else {
                                None
                            },
                        });
                    }
                }
            }
        }
    }
    // `[map]`: its runs come after the lines'.
    if let Some(mp) = c.map() {
        batches.extend(map::batches(mp, &mut seq));
    }
    Plan { batches }
}

/// CS targets of an axis in measuring order (one list for every direction, or one per
/// direction) and the batch sizes: one batch of m, or for adaptive runs the design's points in
/// the farthest-point order cut into batches. An adaptive axis measured in `dirs` > 1 directions
/// draws dirs·m points when the grid has room and deals the order out in turn, so each direction
/// measures other positions and every prefix of the union still covers the stroke evenly: the
/// curves pool the other direction's samples (`recon::joint`), which the same positions would
/// not add to.
fn cs_design(
    ax: &AxisPlan,
    kind: DesignKind,
    seed: u64,
    batch: usize,
    dirs: usize,
) -> (Vec<Vec<usize>>, Vec<usize>) {
    let n = ax.grid.n;
    let seed = axis_seed(seed, ax.axis);
    let deal = ax.target_error_um.is_some() && dirs > 1 && dirs * ax.m <= n;
    let mut idx = Design::new(kind, if deal { dirs * ax.m } else { ax.m }, seed)
        .indices(n)
        .expect("m validated against the grid");
    with_ends(&mut idx, n);
    match ax.target_error_um {
        None => {
            let m = idx.len();
            (vec![idx], vec![m])
        }
        Some(_) => {
            // The ends first, in every direction: a run stopped early still covers the span.
            let ends = [0, n - 1];
            let inner: Vec<usize> = idx.iter().copied().filter(|i| !ends.contains(i)).collect();
            let order = spread_order(&inner, n, seed ^ 0xADA9);
            let designs: Vec<Vec<usize>> = if deal {
                (0..dirs)
                    .map(|d| {
                        // m each: the last dealt points (the least spread) make room.
                        ends.iter()
                            .copied()
                            .chain(order.iter().copied().skip(d).step_by(dirs))
                            .take(ax.m)
                            .collect()
                    })
                    .collect()
            } else {
                vec![ends.iter().copied().chain(order).collect()]
            };
            let m = designs[0].len();
            let mut chunks = Vec::new();
            let mut left = m;
            while left > 0 {
                let take = batch.min(left);
                chunks.push(take);
                left -= take;
            }
            (designs, chunks)
        }
    }
}

/// Puts both grid ends into a design of sorted distinct indices, in place of its first and last
/// points (m unchanged; a jittered design keeps one point per stratum): a curve is trusted, and
/// compensated and verified, up to the ends of its grid, where a design without them would
/// extrapolate (the demo's Y verification failed there at 0 forward and 4200 backward).
fn with_ends(idx: &mut [usize], n: usize) {
    if let (Some(first), true) = (idx.first_mut(), n > 0) {
        *first = 0;
    }
    if let Some(last) = idx.last_mut() {
        *last = n.saturating_sub(1);
    }
}

/// Adaptive measuring order of a design's points: farthest point first. Each next point is the
/// one farthest from every point before it and from the grid's ends (ties broken by a seeded
/// random key), so every prefix, and so every batch boundary where the run may stop, covers the
/// stroke without long gaps. Between samples a curve's error grows with the distance to the
/// nearest one: a random order leaves gaps several times the mean spacing, and stopped later for
/// the same error. The points stay the random design's, so no prefix is a regular lattice that
/// could alias a periodic error. Lazy greedy: a point's distance only shrinks as points are
/// chosen, so a stale heap entry is refreshed when it comes up.
fn spread_order(idx: &[usize], n: usize, seed: u64) -> Vec<usize> {
    use std::collections::{BTreeSet, BinaryHeap};
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let last = n.saturating_sub(1);
    let mut chosen: BTreeSet<usize> = BTreeSet::new();
    let dist = |chosen: &BTreeSet<usize>, i: usize| -> usize {
        let mut d = i.min(last - i);
        if let Some(&b) = chosen.range(..=i).next_back() {
            d = d.min(i - b);
        }
        if let Some(&a) = chosen.range(i..).next() {
            d = d.min(a - i);
        }
        d
    };
    let mut heap: BinaryHeap<(usize, u64, usize)> = idx
        .iter()
        .map(|&i| (dist(&chosen, i), rng.random::<u64>(), i))
        .collect();
    let mut order = Vec::with_capacity(idx.len());
    while let Some((d, key, i)) = heap.pop() {
        let now = dist(&chosen, i);
        if now < d {
            heap.push((now, key, i));
            continue;
        }
        chosen.insert(i);
        order.push(i);
    }
    order
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    fn campaign(extra: &str) -> Campaign {
        let t = format!(
            r#"
[campaign]
name = "p"
[hardware]
kind = "sim"
[axes.x]
range_um = [0.0, 1000.0]
step_um = 5.0
other_at_um = 100.0
[axes.y]
range_um = [0.0, 500.0]
step_um = 5.0
other_at_um = 200.0
m = 20
{extra}
"#
        );
        Campaign::parse(&t, "p.toml", Path::new(".")).unwrap()
    }

    #[test]
    fn runs_are_sorted_sweeps_with_unique_seqs_and_shared_targets() {
        let c = campaign("[sampling]\nm = 40\nfull_scan = true\n[acquisition]\ncycles = 2\n");
        let p = plan(&c);
        // x: cs (2 cycles x 2 dirs) + full (2 x 2); y the same.
        assert_eq!(p.runs().len(), 16);
        assert_eq!(p.total(), 2 * 2 * (40 + 201) + 2 * 2 * (20 + 101));
        let seqs: Vec<u64> = p
            .batches
            .iter()
            .flat_map(|b| b.targets.iter().map(|t| t.seq))
            .collect();
        assert!(seqs.windows(2).all(|w| w[1] == w[0] + 1) && seqs[0] == 0);
        for b in &p.batches {
            let pos: Vec<f64> = b.targets.iter().map(|t| t.target_um()).collect();
            match b.run.direction {
                Direction::Forward => assert!(pos.windows(2).all(|w| w[0] < w[1])),
                Direction::Backward => assert!(pos.windows(2).all(|w| w[0] > w[1])),
            }
            let other = if b.run.axis == AxisId::X {
                100.0
            } else {
                200.0
            };
            assert!(b.targets.iter().all(|t| match b.run.axis {
                AxisId::X => t.target_y_um == other,
                AxisId::Y => t.target_x_um == other,
            }));
        }
        // Same CS targets for both directions and both cycles of an axis.
        let set = |d: Direction, cycle: u32| {
            let mut v: Vec<usize> = p
                .batches
                .iter()
                .filter(|b| {
                    b.run.axis == AxisId::X
                        && b.run.phase == Phase::Cs
                        && b.run.direction == d
                        && b.run.cycle == cycle
                })
                .flat_map(|b| b.targets.iter().map(|t| t.grid_index))
                .collect();
            v.sort_unstable();
            v
        };
        assert_eq!(set(Direction::Forward, 0), set(Direction::Backward, 1));
        assert_eq!(set(Direction::Forward, 0).len(), 40);
        // Same file, same plan.
        let q = plan(&campaign(
            "[sampling]\nm = 40\nfull_scan = true\n[acquisition]\ncycles = 2\n",
        ));
        assert_eq!(format!("{:?}", p.batches), format!("{:?}", q.batches));
    }

    #[test]
    fn adaptive_runs_come_in_batches_of_distinct_targets() {
        let c = campaign("[sampling]\nm = 120\nbatch = 50\ntarget_error_um = 0.05\n");
        let p = plan(&c);
        let x_fwd: Vec<&Batch> = p
            .batches
            .iter()
            .filter(|b| b.run.axis == AxisId::X && b.run.direction == Direction::Forward)
            .collect();
        assert_eq!(
            x_fwd.iter().map(|b| b.targets.len()).collect::<Vec<_>>(),
            vec![50, 50, 20]
        );
        let mut all: Vec<usize> = x_fwd
            .iter()
            .flat_map(|b| b.targets.iter().map(|t| t.grid_index))
            .collect();
        all.sort_unstable();
        all.dedup();
        assert_eq!(all.len(), 120);
        assert!(x_fwd.iter().all(|b| b.target_error_um == Some(0.05)));
    }

    /// Every batch boundary of an adaptive run leaves the stroke evenly covered: no design point
    /// is farther from the points measured so far (or a grid end) than those are from each other
    /// (the farthest-point property). A random order leaves gaps several times the spacing.
    /// The farthest design point from the points so far (sorted here) and their closest spacing,
    /// in grid steps. A grid end counts as covered ground: a point by it is not a gap.
    fn cover_and_spacing(sofar: &mut [usize], design: &[usize], n: usize) -> (usize, usize) {
        sofar.sort_unstable();
        let spacing = sofar.windows(2).map(|w| w[1] - w[0]).min().unwrap();
        let near = |i: usize| sofar.iter().map(|&s| s.abs_diff(i)).min().unwrap();
        let cover = design
            .iter()
            .map(|&i| near(i).min(i).min(n - 1 - i))
            .max()
            .unwrap();
        (cover, spacing)
    }

    #[test]
    fn adaptive_directions_measure_other_positions_that_together_cover_the_stroke() {
        // 2 × 60 points fit the 201-point grid: each direction gets its own, dealt in turn.
        let c = campaign("[sampling]\nm = 60\nbatch = 20\ntarget_error_um = 0.05\n");
        let p = plan(&c);
        let n = c.axes()[0].grid.n;
        let run = |d: Direction| -> Vec<Vec<usize>> {
            p.batches
                .iter()
                .filter(|b| b.run.axis == AxisId::X && b.run.direction == d)
                .map(|b| b.targets.iter().map(|t| t.grid_index).collect())
                .collect()
        };
        let (fwd, bwd) = (run(Direction::Forward), run(Direction::Backward));
        assert_eq!((fwd.len(), bwd.len()), (3, 3));
        let all_f: Vec<usize> = fwd.concat();
        // Both directions measure the grid's ends first (the span is covered however early the
        // run stops); every other position is one direction's only.
        for run in [&fwd, &bwd] {
            assert!(run[0].contains(&0) && run[0].contains(&(n - 1)), "{run:?}");
        }
        let inner = |i: &usize| *i != 0 && *i != n - 1;
        assert!(bwd
            .concat()
            .iter()
            .filter(|i| inner(i))
            .all(|i| !all_f.contains(i)));
        // After k batches of each, the union has the farthest-point property over the whole
        // design: no design point farther from it than its closest spacing.
        let design: Vec<usize> = [fwd.concat(), bwd.concat()].concat();
        let mut sofar: Vec<usize> = Vec::new();
        for k in 0..2 {
            sofar.extend(&fwd[k]);
            sofar.extend(&bwd[k]);
            sofar.sort_unstable();
            sofar.dedup();
            let (cover, spacing) = cover_and_spacing(&mut sofar, &design, n);
            assert!(
                cover <= spacing,
                "after batch {k}: gap {cover}, spacing {spacing}"
            );
        }
    }

    #[test]
    fn adaptive_batches_fill_the_largest_gaps_first() {
        let c = campaign("[sampling]\nm = 150\nbatch = 25\ntarget_error_um = 0.05\n");
        let p = plan(&c);
        let n = c.axes()[0].grid.n;
        let x_fwd: Vec<&Batch> = p
            .batches
            .iter()
            .filter(|b| b.run.axis == AxisId::X && b.run.direction == Direction::Forward)
            .collect();
        let design: Vec<usize> = x_fwd
            .iter()
            .flat_map(|b| b.targets.iter().map(|t| t.grid_index))
            .collect();
        let mut sofar: Vec<usize> = Vec::new();
        for b in &x_fwd[..x_fwd.len() - 1] {
            sofar.extend(b.targets.iter().map(|t| t.grid_index));
            let (cover, spacing) = cover_and_spacing(&mut sofar, &design, n);
            assert!(
                cover <= spacing,
                "after {} points: a gap of {cover} steps, spacing {spacing}",
                sofar.len()
            );
        }
        // The same design as without the adaptive order, and the backward run in the same order.
        let x_bwd: Vec<usize> = p
            .batches
            .iter()
            .filter(|b| b.run.axis == AxisId::X && b.run.direction == Direction::Backward)
            .flat_map(|b| {
                let mut v: Vec<usize> = b.targets.iter().map(|t| t.grid_index).collect();
                v.reverse();
                v
            })
            .collect();
        assert_eq!(design, x_bwd);
        let mut sorted = design.clone();
        sorted.sort_unstable();
        let fixed = plan(&campaign("[sampling]\nm = 150\n"));
        let fixed_x: Vec<usize> = fixed
            .batches
            .iter()
            .filter(|b| b.run.axis == AxisId::X && b.run.direction == Direction::Forward)
            .flat_map(|b| b.targets.iter().map(|t| t.grid_index))
            .collect();
        assert_eq!(sorted, fixed_x);
    }
}
