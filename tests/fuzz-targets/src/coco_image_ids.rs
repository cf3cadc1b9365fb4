//! COCO results lists whose image ids the fuzzer chooses (numbers, and names with the number
//! inside: "cam2_frame_0012.jpg", leading zeros, several digit runs, huge numbers), the rest
//! well-formed. Whatever is accepted is timed by the ids' numbers: one frame per number from the
//! first to the last, at 1/fps apart, each id's detection in its own frame and every gap unseen.

use controller::keypoints::clip::{CocoOptions, coco_from_str};

/// An image id from three bytes: a number (12 bits: clips of up to 4096 frames keep the fuzzer
/// fast), a file name around it, or text.
fn image_id(b: [u8; 3]) -> (String, Option<u64>) {
    let n = u64::from(u16::from_le_bytes([b[1], b[2]]) & 0x0FFF);
    match b[0] % 6 {
        0 => (n.to_string(), Some(n)),
        1 => (format!("\"cam2_frame_{n:06}.jpg\""), Some(n)),
        2 => (format!("\"{n}\""), Some(n)),
        3 => (format!("\"v{}_{n}\"", b[0]), Some(n)),
        // More digits than a u64 holds: refused.
        4 => (format!("\"{n}{}\"", "9".repeat(20)), None),
        _ => (format!("\"frame_{}\"", char::from(b'a' + b[1] % 26)), None),
    }
}

/// One input.
pub fn run(data: &[u8]) {
    let mut ids = Vec::new();
    let mut list = Vec::new();
    for chunk in data.chunks_exact(3).take(64) {
        let (text, number) = image_id([chunk[0], chunk[1], chunk[2]]);
        ids.push(number);
        let keypoints = vec!["100.0, 200.0, 0.9"; 17].join(", ");
        list.push(format!(
            "{{\"image_id\": {text}, \"keypoints\": [{keypoints}], \"score\": 0.9}}"
        ));
    }
    let text = format!("[{}]", list.join(","));
    let options = CocoOptions {
        view: "front".into(),
        person: None,
        fps: 30.0,
    };
    let Ok(clip) = coco_from_str(std::path::Path::new("fuzz.json"), &text, &options, None) else {
        return;
    };
    // Accepted with every id numbered: one frame per number from the first to the last.
    if let Some(numbers) = ids.iter().copied().collect::<Option<Vec<u64>>>() {
        let (lo, hi) = (*numbers.iter().min().unwrap(), *numbers.iter().max().unwrap());
        assert_eq!(clip.len() as u64, hi - lo + 1, "{numbers:?}");
        for f in 0..clip.len() {
            assert!((clip.times[f] - f as f64 / 30.0).abs() < 1e-9);
            let seen = clip.at(f, 0).iter().any(|p| p[2] > 0.0);
            assert_eq!(
                seen,
                numbers.contains(&(lo + f as u64)),
                "frame {f} of {numbers:?}"
            );
        }
    }
}
