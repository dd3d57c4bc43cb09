//! The heap trimmer the live node runs ([`lhmpp::node::memory_trim`]): pages freed in the
//! middle of a thread's arena stay resident after `free` and go back to the system when
//! trimmed. In a test binary of its own, since resident memory is the whole process's.

/// Resident set size of this process, bytes (Linux).
fn rss() -> u64 {
    let statm = std::fs::read_to_string("/proc/self/statm").unwrap();
    let pages: u64 = statm.split_whitespace().nth(1).unwrap().parse().unwrap();
    pages * 4096
}

#[test]
#[cfg(all(target_os = "linux", target_env = "gnu"))]
fn freed_pages_in_the_middle_of_an_arena_go_back_to_the_system() {
    // On a thread of its own (its own arena), interleave small blocks that stay with large
    // ones that are freed: the freed pages sit below live blocks, where free() alone cannot
    // return them.
    let (held, before, after_free, after_trim) = std::thread::spawn(|| {
        let mut held = Vec::new();
        let mut freed = Vec::new();
        for _ in 0..2000 {
            freed.push(vec![1u8; 60_000]);
            held.push(vec![2u8; 64]);
        }
        let before = rss();
        drop(freed);
        let after_free = rss();
        assert!(lhmpp::node::memory_trim::trim(), "something was released");
        let after_trim = rss();
        (held.len(), before, after_free, after_trim)
    })
    .join()
    .unwrap();
    assert_eq!(held, 2000);
    let mb = |b: u64| b as f64 / 1e6;
    eprintln!(
        "RSS {:.1} MB, after free {:.1} MB, after trim {:.1} MB",
        mb(before),
        mb(after_free),
        mb(after_trim)
    );
    // 120 MB were freed: free() alone keeps most of it resident, the trim gives it back.
    assert!(
        after_free + 20_000_000 > before,
        "free() released it already"
    );
    assert!(
        after_free > after_trim + 60_000_000,
        "trim released only {:.1} MB",
        mb(after_free.saturating_sub(after_trim))
    );
}
