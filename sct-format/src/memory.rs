//! Process-wide allocator settings for the command-line tools.

/// Allocations this large or larger get a mapping of their own (see
/// [`map_large_allocations`]).
pub const MAPPED_BYTES: usize = 1 << 20;

/// Has glibc serve every allocation of [`MAPPED_BYTES`] or more by a mapping of its own,
/// returned to the system when freed; nothing on other C libraries. Call once, first thing
/// in `main`.
///
/// By default glibc starts at 128 KiB and raises that threshold to the size of each such
/// block freed (up to 32 MiB). After a tool has freed its first large buffers, blocks of up
/// to that size come from glibc's arenas, which keep the memory when they are freed and
/// fragment as vectors grow: the freed memory stays in the process's peak. Measured with
/// `sct-voxelize` (peak RSS, medians of 3–7 interleaved runs, 2 threads, same times): a
/// coarse dry run of the 4.4 M-triangle subdivided bunny as OBJ (`--dry-run --screen-error
/// 60`) 390 → 330 MB, the Stanford bunny 42 → 37 MB, the dragon 40 → 35 MB. Lower thresholds
/// save a little more but map and zero buffers that are allocated over and over:
/// `sct-build-tree`'s encoder took 6–9 % longer at 128–256 KiB, and 3–4 % at 1 MiB, which is
/// why it keeps glibc's default.
pub fn map_large_allocations() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    #[allow(unsafe_code)]
    // SAFETY: `mallopt` takes no pointers; it sets one parameter of the allocator.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, MAPPED_BYTES as libc::c_int);
    }
}
