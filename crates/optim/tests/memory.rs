//! Memory of the bundle adjuster is linear in the number of observations.
//!
//! A counting global allocator (this test binary only) records the bytes in
//! use and their peak. Each case builds a 500-pose synthetic scene, then
//! measures the peak of the bytes the solver allocates on top of the problem
//! (Jacobians, per-point blocks, the reduced camera system and its
//! factorisation, the thread pool). Two sizes with the same poses and twice
//! the points must cost about the same bytes per observation, and below
//! [`MAX_BYTES_PER_OBSERVATION`].

use colslam_optim::synthetic::{SyntheticOptions, perturb, synthetic_scene};
use colslam_optim::{BaOptions, BundleAdjuster, LossFunction};
use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};

/// Bytes currently allocated through the global allocator.
static CURRENT: AtomicUsize = AtomicUsize::new(0);
/// Largest value `CURRENT` reached since the last reset.
static PEAK: AtomicUsize = AtomicUsize::new(0);
/// The allocator counters are process-wide: the cases must not overlap.
static SERIAL: Mutex<()> = Mutex::new(());

/// Bound on the marginal bytes the solver needs per extra observation
/// (measured: about 530 B).
const MAX_MARGINAL_BYTES_PER_OBSERVATION: f64 = 800.0;
/// Bound on the solver's total peak extra bytes per observation at the
/// largest measured size, intercept included (the per-pose part is about
/// 0.25 GB at 500 poses, so small problems pay more per observation).
const MAX_BYTES_PER_OBSERVATION: f64 = 1500.0;
/// The marginal bytes per observation between the two larger sizes may
/// exceed those between the two smaller by at most this factor (a term
/// quadratic in points or observations would double it).
const MAX_GROWTH: f64 = 1.25;
/// Poses of every case.
const NUM_POSES: usize = 500;
/// LM iterations per measured solve: every buffer is allocated in the first
/// iteration, so a few suffice and keep the test fast.
const ITERATIONS: usize = 2;

struct Counting;

// SAFETY: every call is forwarded unchanged to `System`; the counters only
// observe sizes.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        // SAFETY: same contract as the caller's.
        let p = unsafe { System.alloc(layout) };
        if !p.is_null() {
            let now = CURRENT.fetch_add(layout.size(), Ordering::Relaxed) + layout.size();
            PEAK.fetch_max(now, Ordering::Relaxed);
        }
        p
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        // SAFETY: same contract as the caller's.
        let p = unsafe { System.alloc_zeroed(layout) };
        if !p.is_null() {
            let now = CURRENT.fetch_add(layout.size(), Ordering::Relaxed) + layout.size();
            PEAK.fetch_max(now, Ordering::Relaxed);
        }
        p
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: same contract as the caller's.
        unsafe { System.dealloc(ptr, layout) };
        CURRENT.fetch_sub(layout.size(), Ordering::Relaxed);
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        // SAFETY: same contract as the caller's.
        let p = unsafe { System.realloc(ptr, layout, new_size) };
        if !p.is_null() {
            if new_size >= layout.size() {
                let now = CURRENT.fetch_add(new_size - layout.size(), Ordering::Relaxed) + new_size - layout.size();
                PEAK.fetch_max(now, Ordering::Relaxed);
            } else {
                CURRENT.fetch_sub(layout.size() - new_size, Ordering::Relaxed);
            }
        }
        p
    }
}

#[global_allocator]
static ALLOCATOR: Counting = Counting;

/// Observations and the solver's peak extra bytes on a 500-pose scene.
fn measure(num_points: usize, max_iterations: usize) -> (usize, usize) {
    let scene = synthetic_scene(&SyntheticOptions {
        num_poses: NUM_POSES,
        num_points,
        step: 0.6,
        pixel_noise: 0.5,
        outlier_ratio: 0.02,
        seed: 7,
        ..Default::default()
    })
    .unwrap();
    let mut problem = scene.problem;
    problem.fix_gauge(0, 1);
    perturb(&mut problem, 0.002, 0.01, 0.05, 8);
    let options = BaOptions { loss: LossFunction::Cauchy(1.0), max_iterations, num_threads: 2, ..Default::default() };
    let base = CURRENT.load(Ordering::Relaxed);
    PEAK.store(base, Ordering::Relaxed);
    let report = BundleAdjuster::solve(&mut problem, &options).unwrap();
    let extra = PEAK.load(Ordering::Relaxed).saturating_sub(base);
    assert!(report.final_cost < report.initial_cost, "the solve made no progress: {report:?}");
    (report.num_observations, extra)
}

#[test]
fn memory_is_linear_in_observations() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let sizes = [3_000, 6_000, 12_000].map(|n| measure(n, ITERATIONS));
    for (obs, bytes) in sizes {
        eprintln!("{NUM_POSES} poses, {obs} observations: {bytes} B ({:.0} B/obs)", bytes as f64 / obs as f64);
    }
    let [(o1, b1), (o2, b2), (o3, b3)] = sizes.map(|(o, b)| (o as f64, b as f64));
    assert!(o3 > 3.6 * o1, "four times the points should give about four times the observations");
    // Affine in observations: the two marginal costs agree, so there is no
    // super-linear term; the intercept is the per-pose part, which does not
    // grow with points.
    let m12 = (b2 - b1) / (o2 - o1);
    let m23 = (b3 - b2) / (o3 - o2);
    let intercept = b3 - m23 * o3;
    eprintln!("marginal {m12:.0} and {m23:.0} B/obs; intercept {:.1} MB at {NUM_POSES} poses", intercept / 1e6);
    assert!(
        m12 < MAX_MARGINAL_BYTES_PER_OBSERVATION && m23 < MAX_MARGINAL_BYTES_PER_OBSERVATION,
        "{m12:.0}, {m23:.0} B/obs"
    );
    assert!(m12 > 0.0 && m23 > 0.0, "memory must grow with observations: {m12:.0}, {m23:.0} B/obs");
    assert!(m23 < MAX_GROWTH * m12, "marginal bytes per observation grew from {m12:.0} to {m23:.0}");
    assert!(b3 / o3 < MAX_BYTES_PER_OBSERVATION, "{:.0} B/obs at {o3} observations", b3 / o3);
}

#[test]
#[ignore = "about 2.7 M observations (1.7 GB), a full solve: about 60 CPU-seconds"]
fn memory_bound_holds_at_a_million_observations() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let (obs, bytes) = measure(100_000, 100);
    let per = bytes as f64 / obs as f64;
    eprintln!("{NUM_POSES} poses: {obs} observations -> {bytes} B ({per:.0} B/obs)");
    assert!(obs > 1_000_000, "{obs} observations");
    assert!(per < MAX_BYTES_PER_OBSERVATION, "{per:.0} B/obs at {obs} observations");
}
