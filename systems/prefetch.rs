//! Stepping the scattered rows of a table with their memory fetched ahead.
//!
//! A view reaches a few Gaussians spread over the whole table; a stage that works on those
//! alone (Adam with `visible_adam` or `deferred_adam`, the deformation backward) would wait on
//! a cache miss for each of their rows. [`RowsAhead`] holds the rows found but not yet worked
//! on, so each row's memory can be requested ([`prefetch`]) several rows before it is used.

/// How many rows are found (and prefetched) ahead of the one being worked on.
pub const ROWS_AHEAD: usize = 8;

/// The rows found but not yet worked on, oldest first: a ring of [`ROWS_AHEAD`] entries, each
/// a row index with what the stage noted about it.
#[derive(Default)]
pub struct RowsAhead<T: Copy + Default> {
    rows: [(usize, T); ROWS_AHEAD],
    first: usize,
    len: usize,
}

impl<T: Copy + Default> RowsAhead<T> {
    /// Queues `row`; once the ring is full, returns the oldest row, to work on now.
    pub fn push(&mut self, row: usize, note: T) -> Option<(usize, T)> {
        let out = if self.len == ROWS_AHEAD {
            self.pop()
        } else {
            None
        };
        self.rows[(self.first + self.len) % ROWS_AHEAD] = (row, note);
        self.len += 1;
        out
    }

    /// The oldest queued row, if any.
    pub fn pop(&mut self) -> Option<(usize, T)> {
        (self.len > 0).then(|| {
            let row = self.rows[self.first];
            self.first = (self.first + 1) % ROWS_AHEAD;
            self.len -= 1;
            row
        })
    }
}

/// Asks the CPU to bring every cache line of `values` in ahead of their use (a no-op off
/// x86-64). The rasterizer's loops use the same helper, which lives beside them.
#[inline(always)]
pub fn prefetch<T>(values: &[T]) {
    crate::raster::prefetch_lines(values);
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Rows come out in the order they went in, each once, the first only when the ring is full.
    #[test]
    fn rows_come_out_in_order_once_the_ring_is_full() {
        let mut ahead = RowsAhead::<bool>::default();
        let mut out = Vec::new();
        for row in 0..20 {
            let popped = ahead.push(row, row % 3 == 0);
            assert_eq!(popped.is_some(), row >= ROWS_AHEAD, "row {row}");
            out.extend(popped);
        }
        while let Some(row) = ahead.pop() {
            out.push(row);
        }
        let expected: Vec<(usize, bool)> = (0..20).map(|r| (r, r % 3 == 0)).collect();
        assert_eq!(out, expected);
    }
}
