//! GMR's motion pickles: any bytes through the restricted unpickler and the motion's checks, which
//! must refuse (not build) memo bombs, deep nesting and lengths beyond the data; what they accept
//! is a motion a clip can be made of.

use std::path::Path;

/// One input.
pub fn run(data: &[u8]) {
    let Ok(m) = motion::gmr::GmrMotion::from_pickle(Path::new("fuzz.pkl"), data) else {
        return;
    };
    assert!(m.frames() >= 2 && (1.0..=1000.0).contains(&m.fps));
    assert_eq!(m.dof_pos.len(), m.frames() * m.dofs);
    assert!(
        m.dof_pos
            .iter()
            .chain(m.root_pos.iter().flatten())
            .all(|x| x.is_finite())
    );
    for q in &m.root_rot {
        let norm = q.iter().map(|x| x * x).sum::<f64>().sqrt();
        assert!((norm - 1.0).abs() < 1e-9, "{q:?}");
    }
    // Every accepted motion becomes a clip, or is refused as one by name.
    let _ = m.into_clip(Path::new("fuzz.pkl"), None);
}
