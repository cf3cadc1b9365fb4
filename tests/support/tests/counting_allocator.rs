//! The counting allocator must catch a deliberate allocation, and report none for code that has none.

use test_support::alloc::{CountingAllocator, count_allocations};

#[global_allocator]
static ALLOC: CountingAllocator = CountingAllocator;

#[test]
fn catches_a_deliberate_allocation() {
    let (v, stats) = count_allocations(|| std::hint::black_box(vec![1u8; 64]));
    assert_eq!(stats.allocations, 1, "{stats:?}");
    assert!(stats.bytes >= 64, "{stats:?}");
    drop(v);
}

#[test]
fn catches_growth_and_frees() {
    let mut v: Vec<u32> = Vec::with_capacity(1);
    let ((), stats) = count_allocations(|| {
        v.extend(0..1000);
        drop(std::hint::black_box(String::from("freed inside")));
    });
    assert!(stats.reallocations >= 1, "{stats:?}");
    assert_eq!(stats.deallocations, 1, "{stats:?}");
    assert!(!stats.is_zero());
}

#[test]
fn reports_zero_for_allocation_free_code() {
    let mut buf = [0.0f32; 96];
    let (sum, stats) = count_allocations(|| {
        for (i, x) in buf.iter_mut().enumerate() {
            *x = i as f32 * 0.5;
        }
        buf.iter().sum::<f32>()
    });
    assert!(stats.is_zero(), "{stats:?}");
    assert!(sum > 0.0);
}

#[test]
fn other_threads_do_not_disturb_a_measurement() {
    let noisy = std::thread::Builder::new()
        .name("noisy".into())
        .spawn(|| {
            for i in 0..10_000 {
                drop(std::hint::black_box(vec![i; 8]));
            }
        })
        .unwrap();
    let ((), stats) = count_allocations(|| {
        for _ in 0..1000 {
            std::hint::black_box(0u64);
        }
    });
    noisy.join().unwrap();
    assert!(stats.is_zero(), "{stats:?}");
}
