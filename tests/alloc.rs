//! The splatting hot path (projection, binning, blending, loss, raster backward) makes no heap
//! allocation once its buffers are warm: a counting global allocator sees none across several
//! iterations on the benchmark scene.

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use tadgs::bench::benchmark_world;
use tadgs::metrics::loss::training_loss;
use tadgs::resources::{LossImage, SplatBuffers, ViewSample};
use tadgs::systems::{splat, training_schedule};

/// Counts allocations (from every thread) while `COUNTING` is set.
struct Counting;

static COUNTING: AtomicBool = AtomicBool::new(false);
static ALLOCATIONS: AtomicUsize = AtomicUsize::new(0);

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if COUNTING.load(Ordering::Relaxed) {
            ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        }
        unsafe { System.alloc(layout) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        if COUNTING.load(Ordering::Relaxed) {
            ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        }
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn warm_splatting_path_does_not_allocate() {
    let (w, h) = (320u32, 180u32);
    let mut world = benchmark_world(20_000, w, h, false);
    let mut train = training_schedule();
    train.run(&mut world);
    let camera = world.resource::<ViewSample>().camera;
    let mut loss = std::mem::take(&mut *world.resource_mut::<LossImage>());
    let target = loss.target.clone();
    let deformed = splat::deformed_by_slot(&mut world);
    let mut buffers = world.resource_mut::<SplatBuffers>();
    let b = &mut *buffers;

    let run = |b: &mut SplatBuffers, loss: &mut LossImage| {
        splat::project_all(&deformed, &camera, 0.01, &mut b.splats);
        b.rasterizer
            .forward(&b.splats, w as usize, h as usize, [0.0; 3], &mut b.render);
        training_loss(
            &mut loss.scratch,
            &b.render.image,
            &target,
            0.2,
            &mut loss.d_color,
        );
        b.rasterizer
            .backward(&b.splats, &loss.d_color, w as usize, &mut b.splat_grads);
    };
    // Runs on a rayon worker, as the CPU backend's work does inside the pool: calls made from
    // outside it go through rayon's injector queue, which allocates one 1.5 KB block per ~60
    // calls (rayon's bookkeeping, not this crate's buffers).
    rayon::scope(|_| {
        // Warm-up: buffers reach their size, worker threads set up their state.
        for _ in 0..3 {
            run(b, &mut loss);
        }
        COUNTING.store(true, Ordering::SeqCst);
        for _ in 0..5 {
            run(b, &mut loss);
        }
        COUNTING.store(false, Ordering::SeqCst);
    });
    assert!(
        b.rasterizer.intersections() > 10_000,
        "the scene must be drawn"
    );
    assert_eq!(
        ALLOCATIONS.load(Ordering::SeqCst),
        0,
        "heap allocations after warm-up"
    );
}
