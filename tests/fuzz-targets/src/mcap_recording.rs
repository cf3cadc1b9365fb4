//! Recorded runs (MCAP) as `report`, `replay` and `compare` read them: any bytes through the chunk
//! check and the message walk.

/// One input.
pub fn run(data: &[u8]) {
    if analysis::recording::check_chunks(data).is_ok() {
        let mut n = 0u64;
        let _ = analysis::recording::for_each_message(data, |m| {
            n += m.data.len() as u64;
            Ok(())
        });
    }
}
