//! What reads a run after it ran: replay through the same loop, observation-contract comparison,
//! run reports, batch runs and soaks on the mirror, and the motion checker for clips.

pub mod batch;
pub mod compare;
pub mod error;
pub mod motion_check;
pub mod recording;
pub mod replay;
pub mod report;
pub mod soak;

pub use error::AnalysisError;
