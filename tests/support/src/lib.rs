//! Helpers shared by the tests and benches of every crate in the workspace.
//!
//! - [`alloc`]: a counting global allocator, so a test can prove a code path makes no heap allocation.
//! - [`bin`]: the `robodeploy` binary, for tests that run it as a user does.
//! - [`fixtures`]: where the generated fixtures and the project's Python environment live.
//! - [`netns`]: a network namespace of the test's own (loopback only) for what crosses a network.
//! - [`stats`]: latency summaries (p50/p99/max) for bench binaries.
//! - [`starvation`]: how starved the host is while a real-time test runs, and runs judged only
//!   when unstarved.
//!
//! This crate is a dev-dependency only; nothing here ships in the controller.

pub mod alloc;
pub mod bin;
pub mod fixtures;
pub mod netns;
pub mod starvation;
pub mod stats;
pub mod zoo;
