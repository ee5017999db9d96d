//! Samples of an error curve on a grid: what the reconstruction takes. The sample files and their
//! layout are the service's (`csmetro::samples`).

/// Samples of an error curve on a grid: grid indices (ascending) and errors (µm).
#[derive(Debug, Clone, PartialEq)]
pub struct GridSamples {
    pub idx: Vec<usize>,
    pub values: Vec<f64>,
}

impl GridSamples {
    pub fn len(&self) -> usize {
        self.idx.len()
    }
    pub fn is_empty(&self) -> bool {
        self.idx.is_empty()
    }
}

/// Grid steps from `i` to the nearest of the ascending indices `idx` (`usize::MAX` when empty).
pub fn nearest_steps(idx: &[usize], i: usize) -> usize {
    let j = idx.partition_point(|&x| x < i);
    let above = idx.get(j).map(|&x| x - i);
    let below = j.checked_sub(1).map(|j| i - idx[j]);
    above.into_iter().chain(below).min().unwrap_or(usize::MAX)
}
