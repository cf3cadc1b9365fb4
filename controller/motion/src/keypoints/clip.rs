//! Keypoint clips: per frame and per view (camera), named 2D keypoints `(u, v, confidence)` in
//! pixels. Read from the project's compact CSV (what `robodeploy project` writes) or from the COCO
//! keypoint JSON that 2D pose estimators write.
//!
//! CSV: a header `time_s,VIEW/KEYPOINT/u,VIEW/KEYPOINT/v,VIEW/KEYPOINT/confidence,…`, then one row
//! per frame; confidence 0 marks a keypoint not seen (its u, v are then ignored).

use std::collections::BTreeMap;
use std::path::Path;

use robots::FileError;

use super::camera::Camera;

/// The 17 keypoints of the COCO layout, in its order.
pub const COCO_KEYPOINTS: [&str; 17] = [
    "nose",
    "left_eye",
    "right_eye",
    "left_ear",
    "right_ear",
    "left_shoulder",
    "right_shoulder",
    "left_elbow",
    "right_elbow",
    "left_wrist",
    "right_wrist",
    "left_hip",
    "right_hip",
    "left_knee",
    "right_knee",
    "left_ankle",
    "right_ankle",
];

/// Keypoints at or under this confidence count as not seen.
pub const MIN_CONFIDENCE: f64 = 0.05;

/// 2D keypoints per frame and view.
#[derive(Debug, Clone, PartialEq)]
pub struct KeypointClip {
    /// The views (camera names).
    pub views: Vec<String>,
    /// The keypoints' names.
    pub names: Vec<String>,
    /// Frame times, s.
    pub times: Vec<f64>,
    /// `(u, v, confidence)` at `(frame · views + view) · names + keypoint`.
    pub points: Vec<[f64; 3]>,
}

impl KeypointClip {
    /// Frames.
    pub fn len(&self) -> usize {
        self.times.len()
    }

    /// Whether there are no frames.
    pub fn is_empty(&self) -> bool {
        self.times.is_empty()
    }

    /// The keypoints of `view` at `frame`.
    pub fn at(&self, frame: usize, view: usize) -> &[[f64; 3]] {
        let n = self.names.len();
        let start = (frame * self.views.len() + view) * n;
        &self.points[start..start + n]
    }

    /// Writes the clip as the project's CSV.
    pub fn write_csv(&self, path: &Path) -> Result<(), FileError> {
        let mut out = String::from("time_s");
        for view in &self.views {
            for name in &self.names {
                for field in ["u", "v", "confidence"] {
                    out.push_str(&format!(",{view}/{name}/{field}"));
                }
            }
        }
        out.push('\n');
        for (k, t) in self.times.iter().enumerate() {
            out.push_str(&format!("{t}"));
            for v in 0..self.views.len() {
                for p in self.at(k, v) {
                    out.push_str(&format!(",{},{},{}", p[0], p[1], p[2]));
                }
            }
            out.push('\n');
        }
        std::fs::write(path, out).map_err(|e| FileError::new(path, format!("cannot write: {e}")))
    }

    /// Refuses references in which no keypoint is ever seen: zero measurements give no error to
    /// report, not an error of 0 px. `person`: the COCO person asked for.
    pub fn require_seen(&self, path: &Path, person: Option<u64>) -> Result<(), FileError> {
        if self.points.iter().any(|p| p[2] > 0.0) {
            return Ok(());
        }
        let why = match person {
            Some(p) => {
                format!("every confidence is 0, person {p} (--person) is in no annotation, or there are none")
            }
            None => "every confidence is 0, or there are no annotations".to_owned(),
        };
        Err(FileError::new(
            path,
            format!(
                "no keypoint is seen in any of its {} frames ({why}): nothing to compare against",
                self.len()
            ),
        ))
    }

    /// Reads the project's CSV; every keypoint seen must lie on its camera's image when
    /// `cameras` are given.
    pub fn load_csv(path: &Path, cameras: &[Camera]) -> Result<Self, FileError> {
        let text = robots::read_text(path).map_err(|m| FileError::new(path, m))?;
        Self::from_csv_str(path, &text, cameras)
    }

    /// [`Self::load_csv`] from text already read (`path` names it in errors).
    pub fn from_csv_str(path: &Path, text: &str, cameras: &[Camera]) -> Result<Self, FileError> {
        let bad = |line: usize, m: String| FileError::new(path, format!("line {line}: {m}"));
        let mut lines = text.lines().enumerate().filter(|(_, l)| !l.trim().is_empty());
        let (_, header) = lines.next().ok_or_else(|| FileError::new(path, "empty"))?;
        let columns: Vec<&str> = header.split(',').map(str::trim).collect();
        if columns.first() != Some(&"time_s") {
            return Err(bad(1, "the header starts with time_s".into()));
        }
        let (mut views, mut names) = (Vec::<String>::new(), Vec::<String>::new());
        for (c, triple) in columns[1..].chunks(3).enumerate() {
            let parse = |i: usize, field: &str| -> Result<(String, String), FileError> {
                let col = triple.get(i).copied().unwrap_or("");
                let mut parts = col.split('/');
                match (parts.next(), parts.next(), parts.next(), parts.next()) {
                    (Some(v), Some(n), Some(f), None) if f == field && !v.is_empty() && !n.is_empty() => {
                        Ok((v.to_owned(), n.to_owned()))
                    }
                    _ => Err(bad(
                        1,
                        format!("column {}: {col:?} is not VIEW/KEYPOINT/{field}", 2 + 3 * c + i),
                    )),
                }
            };
            let (view, name) = parse(0, "u")?;
            for (i, field) in [(1, "v"), (2, "confidence")] {
                if parse(i, field)? != (view.clone(), name.clone()) {
                    return Err(bad(
                        1,
                        format!("column {}: not {view}/{name}/{field}", 2 + 3 * c + i),
                    ));
                }
            }
            if !views.contains(&view) {
                views.push(view.clone());
            }
            if !names.contains(&name) && views.len() == 1 {
                names.push(name.clone());
            }
        }
        // Every view has every keypoint, in the same order.
        let want: Vec<String> = views
            .iter()
            .flat_map(|v| names.iter().map(move |n| format!("{v}/{n}")))
            .collect();
        let have: Vec<String> = columns[1..]
            .chunks(3)
            .map(|t| t[0].trim_end_matches("/u").to_owned())
            .collect();
        if want != have || names.is_empty() {
            return Err(bad(
                1,
                "every view lists the same keypoints in the same order".into(),
            ));
        }
        let cams = view_cameras(path, &views, cameras)?;
        let mut clip = Self {
            views,
            names,
            times: Vec::new(),
            points: Vec::new(),
        };
        for (i, line) in lines {
            let values: Vec<f64> = line
                .split(',')
                .map(|v| {
                    v.trim()
                        .parse::<f64>()
                        .map_err(|_| bad(i + 1, format!("{v:?} is not a number")))
                })
                .collect::<Result<_, _>>()?;
            if values.len() != columns.len() {
                return Err(bad(
                    i + 1,
                    format!("{} values, the header has {}", values.len(), columns.len()),
                ));
            }
            let t = values[0];
            if !t.is_finite() || clip.times.last().is_some_and(|&p| t <= p) {
                return Err(bad(
                    i + 1,
                    format!("time {t} s does not follow the previous frame's"),
                ));
            }
            clip.times.push(t);
            for (j, p) in values[1..].chunks(3).enumerate() {
                let (view, key) = (j / clip.names.len(), j % clip.names.len());
                let point = checked([p[0], p[1], p[2]], cams.get(view).copied().flatten(), || {
                    format!("line {}, {}/{}", i + 1, clip.views[view], clip.names[key])
                })
                .map_err(|m| FileError::new(path, m))?;
                clip.points.push(point);
            }
        }
        if clip.is_empty() {
            return Err(FileError::new(path, "no frames"));
        }
        Ok(clip)
    }
}

/// The camera of each view, when cameras are given (each view must have one).
fn view_cameras<'a>(
    path: &Path,
    views: &[String],
    cameras: &'a [Camera],
) -> Result<Vec<Option<&'a Camera>>, FileError> {
    if cameras.is_empty() {
        return Ok(vec![None; views.len()]);
    }
    views
        .iter()
        .map(|v| {
            cameras.iter().find(|c| &c.name == v).map(Some).ok_or_else(|| {
                let known: Vec<&str> = cameras.iter().map(|c| c.name.as_str()).collect();
                FileError::new(
                    path,
                    format!("view {v:?} has no camera (cameras: {})", known.join(", ")),
                )
            })
        })
        .collect()
}

/// A keypoint checked: confidence within [0, 1] (COCO's visibility flags 1 and 2 count as 1), and
/// when seen, finite and on the camera's image. `place` names it in the error.
fn checked(
    p: [f64; 3],
    camera: Option<&Camera>,
    place: impl Fn() -> String,
) -> Result<[f64; 3], BadKeypoint> {
    let confidence = p[2];
    if !confidence.is_finite() || confidence < 0.0 {
        return Err(BadKeypoint::Confidence {
            place: place(),
            confidence,
        });
    }
    let confidence = confidence.min(1.0);
    if confidence <= MIN_CONFIDENCE {
        return Ok([f64::NAN, f64::NAN, 0.0]);
    }
    if !(p[0].is_finite() && p[1].is_finite()) {
        return Err(BadKeypoint::NotAPixel {
            place: place(),
            at: [p[0], p[1]],
        });
    }
    if let Some(c) = camera
        && !c.sees([p[0], p[1]])
    {
        return Err(BadKeypoint::OffImage {
            place: place(),
            at: [p[0], p[1]],
            camera: c.name.clone(),
            size: [c.width, c.height],
        });
    }
    Ok([p[0], p[1], confidence])
}

/// A keypoint that is not one, named by its place in the file.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
enum BadKeypoint {
    #[error("{place}: confidence {confidence} is not within [0, 1]")]
    Confidence { place: String, confidence: f64 },
    #[error("{place}: ({}, {}) is not a pixel", at[0], at[1])]
    NotAPixel { place: String, at: [f64; 2] },
    #[error("{place}: ({}, {}) is outside camera {camera}'s {}×{} image", at[0], at[1], size[0], size[1])]
    OffImage {
        place: String,
        at: [f64; 2],
        camera: String,
        size: [u32; 2],
    },
}

/// Where a run's 2D keypoint references come from (what `play --keypoints` was given, and what
/// its recording keeps for a replay).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct KeypointSource {
    /// The references: the project's CSV, or a pose estimator's COCO JSON (`.json`).
    pub keypoints: std::path::PathBuf,
    /// Their cameras.
    pub cameras: std::path::PathBuf,
    /// COCO: the camera that filmed them (default: the only camera).
    #[serde(default)]
    pub view: Option<String>,
    /// COCO: the person to follow, by track_id.
    #[serde(default)]
    pub person: Option<u64>,
    /// COCO: the video's frames per second.
    pub fps: f64,
}

impl KeypointSource {
    /// The same with both files' paths passed through `f` (made absolute, relative, resolved).
    pub fn map_paths(&self, f: impl Fn(&std::path::PathBuf) -> std::path::PathBuf) -> Self {
        Self {
            keypoints: f(&self.keypoints),
            cameras: f(&self.cameras),
            ..self.clone()
        }
    }

    /// Reads the cameras and the references (checked against them).
    pub fn load(&self) -> Result<(Vec<Camera>, KeypointClip), FileError> {
        let cameras = super::camera::load_cameras(&self.cameras)?;
        let path = &self.keypoints;
        if !path.extension().is_some_and(|e| e.eq_ignore_ascii_case("json")) {
            let clip = KeypointClip::load_csv(path, &cameras)?;
            clip.require_seen(path, None)?;
            return Ok((cameras, clip));
        }
        let view = match (&self.view, cameras.as_slice()) {
            (Some(v), _) => v.clone(),
            (None, [only]) => only.name.clone(),
            (None, _) => {
                return Err(FileError::new(
                    path,
                    "a COCO file is one view: name its camera (--view)",
                ));
            }
        };
        let camera = cameras.iter().find(|c| c.name == view).ok_or_else(|| {
            FileError::new(
                &self.cameras,
                format!("view {view:?} (--view) is not one of its cameras"),
            )
        })?;
        let options = CocoOptions {
            view,
            person: self.person,
            fps: self.fps,
        };
        let clip = load_coco(path, &options, Some(camera))?;
        clip.require_seen(path, self.person)?;
        Ok((cameras, clip))
    }
}

/// How to read a COCO keypoint file as one view of a keypoint clip.
#[derive(Debug, Clone)]
pub struct CocoOptions {
    /// The view (camera) it was seen by.
    pub view: String,
    /// The person to follow: their `track_id` (or `idx`, `person_id`); none: the file must have
    /// one person per frame.
    pub person: Option<u64>,
    /// Frames per second of the video.
    pub fps: f64,
}

/// Reads COCO keypoints: the results list pose estimators write (`[{image_id, keypoints: [u, v,
/// c, …], score, track_id}]`) or a COCO dataset (`{images, annotations, categories}`). Frames are
/// the images in id order; a frame without the person has every keypoint unseen. Names: COCO's 17,
/// or the category's `keypoints` list.
pub fn load_coco(
    path: &Path,
    options: &CocoOptions,
    camera: Option<&Camera>,
) -> Result<KeypointClip, FileError> {
    let text = robots::read_text(path).map_err(|m| FileError::new(path, m))?;
    coco_from_str(path, &text, options, camera)
}

/// Frames a COCO file's image ids may span (about 9 h at 30 fps).
const MAX_COCO_FRAMES: u64 = 1_000_000;

/// [`load_coco`] from text already read (`path` names it in errors).
pub fn coco_from_str(
    path: &Path,
    text: &str,
    options: &CocoOptions,
    camera: Option<&Camera>,
) -> Result<KeypointClip, FileError> {
    let bad = |m: String| FileError::new(path, m);
    if !(options.fps.is_finite() && (1.0..=1000.0).contains(&options.fps)) {
        return Err(bad(format!("--fps {}: within 1–1000", options.fps)));
    }
    let json: serde_json::Value = serde_json::from_str(text).map_err(|e| bad(format!("not JSON: {e}")))?;
    let (detections, images, names): (Vec<&serde_json::Value>, Vec<String>, Vec<String>) = match &json {
        serde_json::Value::Array(list) => (list.iter().collect(), Vec::new(), Vec::new()),
        serde_json::Value::Object(o) => {
            let annotations = o
                .get("annotations")
                .and_then(|a| a.as_array())
                .ok_or_else(|| bad("neither a list of detections nor a dataset with annotations".into()))?;
            let images = o
                .get("images")
                .and_then(|i| i.as_array())
                .map(|i| i.iter().filter_map(|im| image_key(&im["id"])).collect())
                .unwrap_or_default();
            let names = o
                .get("categories")
                .and_then(|c| c.as_array())
                .and_then(|c| c.iter().find_map(|c| c["keypoints"].as_array()))
                .map(|k| k.iter().filter_map(|n| n.as_str().map(str::to_owned)).collect())
                .unwrap_or_default();
            (annotations.iter().collect(), images, names)
        }
        _ => {
            return Err(bad(
                "neither a list of detections nor a dataset with annotations".into()
            ));
        }
    };
    let names: Vec<String> = if names.is_empty() {
        COCO_KEYPOINTS.iter().map(|n| (*n).to_owned()).collect()
    } else {
        names
    };
    // Detections by frame (image), in the file's order within a frame.
    let mut frames: BTreeMap<ImageKey, Vec<&serde_json::Value>> = BTreeMap::new();
    for image in &images {
        frames.entry(ImageKey::checked(image).map_err(&bad)?).or_default();
    }
    for (i, d) in detections.iter().enumerate() {
        let image = image_key(&d["image_id"]).ok_or_else(|| bad(format!("detection {i}: no image_id")))?;
        frames
            .entry(ImageKey::checked(&image).map_err(&bad)?)
            .or_default()
            .push(d);
    }
    if frames.is_empty() {
        return Err(bad("no detections".into()));
    }
    let person_of = |d: &serde_json::Value| {
        ["track_id", "idx", "person_id"]
            .iter()
            .find_map(|k| d[*k].as_u64())
    };
    let mut clip = KeypointClip {
        views: vec![options.view.clone()],
        names: names.clone(),
        times: Vec::with_capacity(frames.len()),
        points: Vec::with_capacity(frames.len() * names.len()),
    };
    // Frames are timed by their image's number (a detector that skipped a frame leaves a gap,
    // not a shift of every later one); by their rank only when some id has no number.
    let first = frames.keys().next().and_then(|k| k.number);
    let numbered = frames.keys().all(|k| k.number.is_some());
    for (k, (image, found)) in frames.iter().enumerate() {
        let chosen: Vec<&&serde_json::Value> = match options.person {
            Some(p) => found.iter().filter(|d| person_of(d) == Some(p)).collect(),
            None => found.iter().collect(),
        };
        if chosen.len() > 1 {
            let ids: Vec<String> = chosen
                .iter()
                .map(|d| person_of(d).map_or("?".into(), |p| p.to_string()))
                .collect();
            return Err(bad(format!(
                "image {}: {} people (ids {}): pick one with --person ID (its track_id)",
                image.text,
                chosen.len(),
                ids.join(", ")
            )));
        }
        let frame = match (numbered, image.number, first) {
            (true, Some(n), Some(first)) => n - first,
            _ => k as u64,
        };
        if frame > MAX_COCO_FRAMES {
            return Err(bad(format!(
                "image {}: frame {frame} after the first: ids span more than {MAX_COCO_FRAMES} frames",
                image.text
            )));
        }
        let next = clip.times.len() as u64;
        if frame < next {
            return Err(bad(format!(
                "image {}: its frame number is another image's (ids must number the frames once each)",
                image.text
            )));
        }
        // Frames no detection mentions are unseen (not bridged by interpolation).
        for missing in next..frame {
            clip.times.push(missing as f64 / options.fps);
            clip.points
                .extend(std::iter::repeat_n([f64::NAN, f64::NAN, 0.0], names.len()));
        }
        clip.times.push(frame as f64 / options.fps);
        match chosen.first() {
            None => clip
                .points
                .extend(std::iter::repeat_n([f64::NAN, f64::NAN, 0.0], names.len())),
            Some(d) => {
                let values: Vec<f64> = d["keypoints"]
                    .as_array()
                    .map(|a| a.iter().map(|v| v.as_f64().unwrap_or(f64::NAN)).collect())
                    .unwrap_or_default();
                if values.len() != 3 * names.len() {
                    return Err(bad(format!(
                        "image {}: {} keypoint values, {} names want {}",
                        image.text,
                        values.len(),
                        names.len(),
                        3 * names.len()
                    )));
                }
                for (n, p) in values.chunks(3).enumerate() {
                    let point = checked([p[0], p[1], p[2]], camera, || {
                        format!("image {}, {}", image.text, names[n])
                    })
                    .map_err(|e| bad(e.to_string()))?;
                    clip.points.push(point);
                }
            }
        }
    }
    Ok(clip)
}

/// An image id as text (numbers and strings alike).
fn image_key(v: &serde_json::Value) -> Option<String> {
    match v {
        serde_json::Value::Number(n) => Some(n.to_string()),
        serde_json::Value::String(s) => Some(s.clone()),
        _ => None,
    }
}

/// Images in order: by the last number in their id ("cam2_frame_012.jpg" → 12), then by the text.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord)]
struct ImageKey {
    number: Option<u64>,
    text: String,
}

impl ImageKey {
    fn of(text: &str) -> Self {
        let end = text.rfind(|c: char| c.is_ascii_digit()).map_or(0, |i| i + 1);
        let start = text[..end]
            .rfind(|c: char| !c.is_ascii_digit())
            .map_or(0, |i| i + 1);
        Self {
            number: text[start..end].parse().ok(),
            text: text.to_owned(),
        }
    }

    /// Refuses an id whose number cannot be a frame's (more digits than a u64 holds).
    fn checked(text: &str) -> Result<Self, String> {
        let key = Self::of(text);
        if key.number.is_none() && text.chars().any(|c| c.is_ascii_digit()) {
            return Err(format!(
                "image id {:?}: its number is beyond 2^64 (frames are timed by it)",
                text.chars().take(40).collect::<String>()
            ));
        }
        Ok(key)
    }
}
