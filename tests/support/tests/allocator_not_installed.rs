//! Without `#[global_allocator]`, a measurement must refuse to run instead of reading zero.

#[test]
#[should_panic(expected = "CountingAllocator is not the global allocator")]
fn refuses_to_measure_when_not_installed() {
    let _ = test_support::alloc::count_allocations(|| ());
}
