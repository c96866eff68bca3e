//! Item 9 of the hostile-input list: a binary PLY of many tiny (3-byte `uchar`) vertices
//! must load in memory about the size of its arrays. The ply-rs payload reader kept a hash
//! map per vertex (≈ 190 bytes for 3 bytes of file: 5.6 GB for a 30 MB file). The counting
//! allocator below measures the load's peak heap; it is this test binary's only test, so no
//! other test allocates meanwhile.

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering};

struct Counting;

static NOW: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);

// SAFETY: forwards to the system allocator unchanged; only counts bytes.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        let p = unsafe { System.alloc(l) };
        if !p.is_null() {
            let now = NOW.fetch_add(l.size(), Ordering::Relaxed) + l.size();
            PEAK.fetch_max(now, Ordering::Relaxed);
        }
        p
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        unsafe { System.dealloc(p, l) };
        NOW.fetch_sub(l.size(), Ordering::Relaxed);
    }
}

#[global_allocator]
static A: Counting = Counting;

#[test]
fn uchar_vertices_load_in_memory_near_their_arrays() {
    const N: usize = 1_000_000;
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("cloud.ply");
    let mut bytes = format!("ply\nformat binary_little_endian 1.0\nelement vertex {N}\nproperty uchar x\nproperty uchar y\nproperty uchar z\nend_header\n").into_bytes();
    bytes.extend((0..N).flat_map(|i| [(i % 251) as u8, (i / 251 % 253) as u8, (i / 63_503) as u8]));
    std::fs::write(&path, &bytes).expect("write");
    drop(bytes);

    let base = NOW.load(Ordering::Relaxed);
    PEAK.store(base, Ordering::Relaxed);
    let scene = voxelize::load(&path, &voxelize::LoadOptions::default()).expect("loads");
    let peak = PEAK.load(Ordering::Relaxed) - base;
    let points = scene.points.as_ref().expect("a point cloud");
    assert_eq!(points.positions.len(), N);
    assert_eq!(points.positions[N - 1], [((N - 1) % 251) as f32, ((N - 1) / 251 % 253) as f32, ((N - 1) / 63_503) as f32]);
    // The file (3 MB) plus the positions (12 MB), with room for the reader's buffers: far
    // below the ≈ 190 MB a map per vertex costs.
    assert!(peak < 40 << 20, "peak heap {} MB for a {} MB file", peak >> 20, (3 * N) >> 20);
}
