//! 2D keypoint inputs: any text as a camera file, as the project's keypoint CSV (checked against
//! the shipped cameras, then resampled to a run's ticks) and as a pose estimator's COCO JSON (by
//! person and without). Whatever is
//! accepted is whole: every frame has every view's keypoints, confidences within [0, 1], and every
//! keypoint seen lies on its camera's image.

use controller::keypoints::camera::{Camera, cameras_from_str};
use controller::keypoints::clip::{CocoOptions, KeypointClip, coco_from_str};

fn shipped_cameras() -> &'static [Camera] {
    static CAMERAS: std::sync::OnceLock<Vec<Camera>> = std::sync::OnceLock::new();
    CAMERAS.get_or_init(|| {
        let path = robots::reference_robot_path().with_file_name("cameras.toml");
        controller::keypoints::camera::load_cameras(&path).expect("the shipped cameras load")
    })
}

fn whole(clip: &KeypointClip, cameras: &[&Camera]) {
    assert_eq!(
        clip.points.len(),
        clip.len() * clip.views.len() * clip.names.len()
    );
    for f in 0..clip.len() {
        for (v, camera) in cameras.iter().enumerate() {
            for p in clip.at(f, v) {
                assert!((0.0..=1.0).contains(&p[2]), "{p:?}");
                if p[2] > 0.0 {
                    assert!(camera.sees([p[0], p[1]]), "{p:?} off {}", camera.name);
                }
            }
        }
    }
}

/// One input.
pub fn run(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let path = std::path::Path::new("fuzz");
    if let Ok(cameras) = cameras_from_str(path, text) {
        for c in &cameras {
            assert!(c.fx > 0.0 && c.fy > 0.0 && c.width > 0 && c.height > 0);
            let _ = c.project([0.1, 0.2, 0.3]);
        }
    }
    let cameras = shipped_cameras();
    if let Ok(clip) = KeypointClip::from_csv_str(path, text, cameras) {
        let by_view = controller::keypoints::cameras_of(&clip.views, cameras).expect("a view has its camera");
        whole(&clip, &by_view);
        // Resampled to a run's ticks: every tick whole, nothing off the images.
        let Ok(reference) = controller::keypoints::track::KeypointReference::new(&clip, cameras, 50.0, 64)
        else {
            assert!(
                clip.is_empty(),
                "a clip with frames whose views have cameras resamples"
            );
            return;
        };
        assert_eq!(reference.points.len(), 64 * clip.views.len() * clip.names.len());
        for t in 0..64 {
            for (v, camera) in by_view.iter().enumerate() {
                for p in reference.at(t, v) {
                    assert!((0.0..=1.0).contains(&p[2]), "{p:?}");
                    if p[2] > 0.0 {
                        assert!(camera.sees([p[0], p[1]]), "{p:?} off {}", camera.name);
                    }
                }
            }
        }
    }
    for person in [None, Some(7)] {
        let options = CocoOptions {
            view: "front".into(),
            person,
            fps: 30.0,
        };
        if let Ok(clip) = coco_from_str(path, text, &options, Some(&cameras[0])) {
            whole(&clip, &[&cameras[0]]);
        }
    }
}
