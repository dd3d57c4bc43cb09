//! DDS domain ids for tests that talk over loopback.
//!
//! A domain's RTPS ports are 7400 + 250 × domain + a few per participant. Domains 101–214 put
//! them inside Linux's ephemeral port range (32768–60999), where any outgoing socket on the
//! host may hold one, and discovery then fails now and then (ROS 2's own CI moved its tests off
//! those domains for the same flakes). Tests here take domains from 1–100 and 215–232 only.

/// Domains whose ports stay out of the ephemeral range (0 is left to the user's own nodes).
const SAFE: [std::ops::RangeInclusive<u16>; 2] = [1..=100, 215..=232];

/// A domain of this test process's own: `salt` tells apart the tests of one process (distinct
/// salts below 118 give distinct domains) and the process id spreads parallel test runs.
pub fn test_domain(salt: u32) -> u16 {
    let count: u32 = SAFE.iter().map(|r| r.clone().count() as u32).sum();
    let mut k = std::process::id().wrapping_add(salt) % count;
    for range in SAFE {
        let len = range.clone().count() as u32;
        if k < len {
            return *range.start() + k as u16;
        }
        k -= len;
    }
    unreachable!("k < count")
}
