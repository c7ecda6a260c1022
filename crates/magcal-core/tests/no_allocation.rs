//! The fitness evaluations in the optimisers' inner loops make no heap allocation: every criterion
//! of `DesignProblem::fitness`, the 8-lane D of the PSO, and the value and gradient of the optimum
//! optimiser's objective. Counted by a global allocator that tallies this thread's allocations.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

use magcal_core::attitude::AttitudeBox;
use magcal_core::design::lanes::LANES;
use magcal_core::design::optimum::ln_det_and_gradient;
use magcal_core::design::{DesignCriterion, DesignProblem, sources, to_vector};
use magcal_core::paper;
use magcal_core::rng::stream_rng;

struct Counting;

thread_local! {
    static ALLOCATIONS: Cell<usize> = const { Cell::new(0) };
}

// SAFETY: every call goes unchanged to the system allocator; the counter is a const-initialised
// thread-local `Cell`, which never allocates itself.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        ALLOCATIONS.with(|n| n.set(n.get() + 1));
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        ALLOCATIONS.with(|n| n.set(n.get() + 1));
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

/// Allocations this thread made while running `f`.
fn allocations_in(f: impl FnOnce()) -> usize {
    let before = ALLOCATIONS.with(Cell::get);
    f();
    ALLOCATIONS.with(Cell::get) - before
}

#[test]
fn fitness_evaluations_do_not_allocate() {
    // The counter sees an allocation.
    assert_eq!(allocations_in(|| drop(std::hint::black_box(vec![0u8; 16]))), 1);
    for (bounds, m) in [(paper::auv_box(), 9), (AttitudeBox::full(), 12)] {
        let p = DesignProblem::new(paper::changsha_field(), paper::true_error_model(), bounds, m).unwrap();
        let mut rng = stream_rng(4, m as u64);
        let designs: Vec<Vec<f64>> = (0..LANES)
            .map(|_| to_vector(&sources::random(&bounds, m, &mut rng)))
            .collect();
        let xs = std::array::from_fn(|l| designs[l].as_slice());
        let mut gradient = vec![0.0; 3 * m];
        let mut sum = 0.0;
        let n = allocations_in(|| {
            for x in &designs {
                for criterion in [DesignCriterion::D, DesignCriterion::A, DesignCriterion::E] {
                    sum += p.fitness(criterion, x);
                }
                sum += ln_det_and_gradient(&p, x, &mut gradient);
            }
            sum += p.ln_det_lanes(xs).iter().sum::<f64>();
        });
        assert_eq!(n, 0, "m = {m}: {n} allocations");
        assert!(sum.is_finite());
    }
}
