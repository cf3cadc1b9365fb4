//! 2D keypoint references in the loop: the keypoint clip resampled to the policy's ticks
//! ([`KeypointReference`], beside the joint reference), and per tick ([`KeypointTrack`]) the
//! robot's keypoints — forward kinematics of the measured joints, placed by the base estimate —
//! projected through the same cameras for the `keypoints` observation term, and measured against
//! the references: reprojection error per view (mean, max, mean offset), the paper's failure
//! criterion, and with two views or more the references triangulated against the robot's
//! keypoints. Every buffer is sized when the run starts.

use robots::spatial;

use super::camera::{Camera, triangulate};
use super::clip::{KeypointClip, MIN_CONFIDENCE};
use super::{FAILURE_PX, KeypointError};

/// Most views a run's keypoint reference may have (tick records are sized for them).
pub const MAX_VIEWS: usize = 4;

/// A keypoint clip ready for a run: resampled to the policy's ticks, the camera of each view.
#[derive(Debug, Clone, PartialEq)]
pub struct KeypointReference {
    /// The camera of each view, in the clip's view order.
    pub cameras: Vec<Camera>,
    /// The keypoints' names.
    pub names: Vec<String>,
    /// Ticks.
    pub ticks: usize,
    /// `(u, v, confidence)` px at `(tick · views + view) · names + keypoint`.
    pub points: Vec<[f64; 3]>,
}

impl KeypointReference {
    /// `clip` at `rate_hz` for `ticks` ticks (tick `k` at `k / rate_hz` s from the clip's first
    /// frame; held at its ends), each view's camera found by name in `cameras`. Between two
    /// frames a keypoint seen in both is interpolated, else the nearer frame's is taken.
    pub fn new(
        clip: &KeypointClip,
        cameras: &[Camera],
        rate_hz: f64,
        ticks: usize,
    ) -> Result<Self, KeypointError> {
        if clip.views.len() > MAX_VIEWS {
            return Err(KeypointError::TooManyViews(clip.views.len()));
        }
        if clip.is_empty() {
            return Err(KeypointError::NoFrames);
        }
        let view_cameras: Vec<Camera> = super::cameras_of(&clip.views, cameras)?
            .into_iter()
            .cloned()
            .collect();
        let (views, n) = (clip.views.len(), clip.names.len());
        let t0 = clip.times.first().copied().unwrap_or(0.0);
        let mut points = Vec::with_capacity(ticks * views * n);
        let last = clip.len().saturating_sub(1);
        let mut i = 0;
        for k in 0..ticks {
            let t = t0 + k as f64 / rate_hz;
            while i < last && clip.times[i + 1] <= t {
                i += 1;
            }
            let j = (i + 1).min(last);
            let span = clip.times[j] - clip.times[i];
            let s = if span > 0.0 {
                ((t - clip.times[i]) / span).clamp(0.0, 1.0)
            } else {
                0.0
            };
            for v in 0..views {
                let (a, b) = (clip.at(i, v), clip.at(j, v));
                for (p, q) in a.iter().zip(b) {
                    points.push(if p[2] > MIN_CONFIDENCE && q[2] > MIN_CONFIDENCE {
                        [0, 1, 2].map(|c| p[c] + (q[c] - p[c]) * s)
                    } else if s < 0.5 {
                        *p
                    } else {
                        *q
                    });
                }
            }
        }
        Ok(Self {
            cameras: view_cameras,
            names: clip.names.clone(),
            ticks,
            points,
        })
    }

    /// The keypoints of `view` at `tick` (held at the last tick).
    pub fn at(&self, tick: usize, view: usize) -> &[[f64; 3]] {
        let n = self.names.len();
        let start = (tick.min(self.ticks.saturating_sub(1)) * self.cameras.len() + view) * n;
        &self.points[start..start + n]
    }

    /// The index of the view filmed by camera `name`.
    pub fn view(&self, name: &str) -> Option<usize> {
        self.cameras.iter().position(|c| c.name == name)
    }
}

/// `(u, v)` px to [−1, 1] across `camera`'s image.
fn normalised(camera: &Camera, uv: [f64; 2]) -> [f64; 2] {
    [
        2.0 * uv[0] / f64::from(camera.width) - 1.0,
        2.0 * uv[1] / f64::from(camera.height) - 1.0,
    ]
}

/// One view's reprojection error at one tick.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ViewTick {
    /// Mean and largest distance over the keypoints seen in both, px.
    pub mean_px: f64,
    /// (See `mean_px`.)
    pub max_px: f64,
    /// Mean offset robot − reference, px (a camera's bias shows here).
    pub mean_du_px: f64,
    /// (See `mean_du_px`.)
    pub mean_dv_px: f64,
    /// Keypoints compared.
    pub compared: u32,
}

/// A view's errors over a run.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ViewSummary {
    /// The camera.
    pub view: String,
    /// Mean over the compared keypoints of every tick, px.
    pub mean_px: f64,
    /// Largest, px.
    pub max_px: f64,
    /// Ticks compared, and those whose largest error was over [`FAILURE_PX`].
    pub ticks: u64,
    /// (See `ticks`.)
    pub failed_ticks: u64,
}

/// The keypoints' errors over a run.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct KeypointSummary {
    /// Per view.
    pub views: Vec<ViewSummary>,
    /// With two views or more: the references triangulated against the robot's keypoints, mean
    /// and largest, mm.
    pub triangulated_mm: Option<(f64, f64)>,
}

impl std::fmt::Display for KeypointSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "2D keypoints (the robot's, projected, against the references):"
        )?;
        for v in &self.views {
            writeln!(
                f,
                "  {:<10} reprojection mean {:.1} px, max {:.1} px; {} of {} ticks over {FAILURE_PX} px",
                v.view, v.mean_px, v.max_px, v.failed_ticks, v.ticks
            )?;
        }
        if let Some((mean, max)) = self.triangulated_mm {
            writeln!(
                f,
                "  triangulated from the views: mean {mean:.1} mm, max {max:.1} mm"
            )?;
        }
        Ok(())
    }
}

#[derive(Debug, Clone, Copy, Default)]
struct Totals {
    sum_px: f64,
    max_px: f64,
    compared: u64,
    ticks: u64,
    failed: u64,
}

/// The run's keypoints, tick by tick.
#[derive(Debug)]
pub struct KeypointTrack {
    reference: KeypointReference,
    /// The reference keypoint of each tracked keypoint (the kinematics tracks them in this order).
    pairs: Vec<usize>,
    /// Tracked keypoints' names.
    names: Vec<String>,
    /// The observation terms' views and keypoints (indices into the reference's views and the
    /// tracked keypoints).
    obs_views: Vec<usize>,
    obs_keypoints: Vec<usize>,
    /// The `ref_keypoints` values of every tick, `obs_width` each.
    ref_obs: Vec<f64>,
    obs_width: usize,
    /// This tick: the robot's keypoints for the observation and for the errors, world.
    observed: Vec<[f64; 3]>,
    measured: Vec<[f64; 3]>,
    robot_obs: Vec<f64>,
    errors: [ViewTick; MAX_VIEWS],
    triangulated_mm: Option<f64>,
    totals: [Totals; MAX_VIEWS],
    tri: (f64, f64, u64),
}

impl KeypointTrack {
    /// The track of `reference` for a robot mapping `mapped` keypoints (robot.toml order), with
    /// observation terms over `obs_views` × `obs_keypoints` (by name; empty without such terms).
    pub fn new(
        reference: KeypointReference,
        mapped: &[String],
        obs_views: &[String],
        obs_keypoints: &[String],
    ) -> Result<Self, KeypointError> {
        let (pairs, names): (Vec<usize>, Vec<String>) = reference
            .names
            .iter()
            .enumerate()
            .filter(|(_, n)| mapped.contains(n))
            .map(|(i, n)| (i, n.clone()))
            .unzip();
        if names.is_empty() {
            return Err(KeypointError::NoCommonKeypoint(reference.names.join(", ")));
        }
        let obs_views = super::cameras_of(obs_views, &reference.cameras)?
            .into_iter()
            .map(|c| reference.view(&c.name).expect("found by name"))
            .collect::<Vec<_>>();
        let obs_keypoints = obs_keypoints
            .iter()
            .map(|k| {
                names
                    .iter()
                    .position(|n| n == k)
                    .ok_or_else(|| KeypointError::Unmapped(k.clone()))
            })
            .collect::<Result<Vec<_>, _>>()?;
        let obs_width = 3 * obs_views.len() * obs_keypoints.len();
        let mut ref_obs = Vec::with_capacity(reference.ticks * obs_width);
        for tick in 0..reference.ticks {
            for &v in &obs_views {
                let seen = reference.at(tick, v);
                for &k in &obs_keypoints {
                    let p = seen[pairs[k]];
                    if p[2] > MIN_CONFIDENCE {
                        let [u, w] = normalised(&reference.cameras[v], [p[0], p[1]]);
                        ref_obs.extend_from_slice(&[u, w, p[2]]);
                    } else {
                        ref_obs.extend_from_slice(&[0.0; 3]);
                    }
                }
            }
        }
        Ok(Self {
            observed: vec![[0.0; 3]; names.len()],
            measured: vec![[0.0; 3]; names.len()],
            robot_obs: vec![0.0; obs_width],
            errors: [ViewTick::default(); MAX_VIEWS],
            triangulated_mm: None,
            totals: [Totals::default(); MAX_VIEWS],
            tri: (0.0, 0.0, 0),
            reference,
            pairs,
            names,
            obs_views,
            obs_keypoints,
            ref_obs,
            obs_width,
        })
    }

    /// The tracked keypoints (the reference's the robot maps), in the order
    /// [`Self::set_positions`] takes them.
    pub fn names(&self) -> &[String] {
        &self.names
    }

    /// The views (camera names).
    pub fn views(&self) -> Vec<String> {
        self.reference.cameras.iter().map(|c| c.name.clone()).collect()
    }

    /// Ticks of the reference.
    pub fn ticks(&self) -> usize {
        self.reference.ticks
    }

    /// The `ref_keypoints` values at `tick` (held at the last).
    pub fn reference_obs(&self, tick: usize) -> &[f64] {
        let t = tick.min(self.reference.ticks.saturating_sub(1));
        &self.ref_obs[t * self.obs_width..(t + 1) * self.obs_width]
    }

    /// The `ref_keypoints` values of every tick, [`Self::obs_width`] each.
    pub fn reference_obs_all(&self) -> &[f64] {
        &self.ref_obs
    }

    /// Values per tick of the `ref_keypoints` term (one frame), and of the `keypoints` term.
    pub fn obs_width(&self) -> usize {
        self.obs_width
    }

    /// Sets this tick's robot keypoints in the reference's frame: `position(k)` for tracked
    /// keypoint `k` as the observation places it (the base estimate) and as the errors measure
    /// it (the simulation's truth where there is one).
    pub fn set_positions(
        &mut self,
        observed: impl Fn(usize) -> [f64; 3],
        measured: impl Fn(usize) -> [f64; 3],
    ) {
        for k in 0..self.names.len() {
            self.observed[k] = observed(k);
            self.measured[k] = measured(k);
        }
        let cams = &self.reference.cameras;
        let mut i = 0;
        for &v in &self.obs_views {
            for &k in &self.obs_keypoints {
                let seen = cams[v].project(self.observed[k]).filter(|uv| cams[v].sees(*uv));
                let out = match seen {
                    Some(uv) => {
                        let [u, w] = normalised(&cams[v], uv);
                        [u, w, 1.0]
                    }
                    None => [0.0; 3],
                };
                self.robot_obs[i..i + 3].copy_from_slice(&out);
                i += 3;
            }
        }
    }

    /// The `keypoints` term's values this tick.
    pub fn robot_obs(&self) -> &[f64] {
        &self.robot_obs
    }

    /// Measures this tick's robot keypoints against the references of `tick`, and adds them to
    /// the run's totals.
    pub fn measure(&mut self, tick: usize) {
        let views = self.reference.cameras.len();
        for v in 0..views {
            let camera = &self.reference.cameras[v];
            let seen = self.reference.at(tick, v);
            let mut e = ViewTick::default();
            for (k, &r) in self.pairs.iter().enumerate() {
                let p = seen[r];
                let Some(uv) = (p[2] > MIN_CONFIDENCE)
                    .then_some(())
                    .and(camera.project(self.measured[k]))
                else {
                    continue;
                };
                let (du, dv) = (uv[0] - p[0], uv[1] - p[1]);
                let d = du.hypot(dv);
                e.mean_px += d;
                e.max_px = e.max_px.max(d);
                e.mean_du_px += du;
                e.mean_dv_px += dv;
                e.compared += 1;
            }
            if e.compared > 0 {
                let n = f64::from(e.compared);
                let t = &mut self.totals[v];
                t.sum_px += e.mean_px;
                t.compared += u64::from(e.compared);
                t.max_px = t.max_px.max(e.max_px);
                t.ticks += 1;
                t.failed += u64::from(e.max_px > FAILURE_PX);
                (e.mean_px, e.mean_du_px, e.mean_dv_px) = (e.mean_px / n, e.mean_du_px / n, e.mean_dv_px / n);
            }
            self.errors[v] = e;
        }
        self.triangulated_mm = None;
        if views >= 2 {
            let (mut sum, mut count) = (0.0, 0u32);
            for (k, &r) in self.pairs.iter().enumerate() {
                let mut rays: [(&Camera, [f64; 2]); MAX_VIEWS] =
                    [(&self.reference.cameras[0], [0.0; 2]); MAX_VIEWS];
                let mut n = 0;
                for (v, camera) in self.reference.cameras.iter().enumerate() {
                    let p = self.reference.at(tick, v)[r];
                    if p[2] > MIN_CONFIDENCE {
                        rays[n] = (camera, [p[0], p[1]]);
                        n += 1;
                    }
                }
                if let Some(x) = triangulate(&rays[..n]) {
                    let d = 1000.0 * spatial::norm(spatial::sub(x, self.measured[k]));
                    sum += d;
                    count += 1;
                    self.tri.1 = self.tri.1.max(d);
                }
            }
            if count > 0 {
                self.tri.0 += sum;
                self.tri.2 += u64::from(count);
                self.triangulated_mm = Some(sum / f64::from(count));
            }
        }
    }

    /// This tick's errors per view (the reference's view order).
    pub fn errors(&self) -> &[ViewTick] {
        &self.errors[..self.reference.cameras.len()]
    }

    /// This tick's triangulated error, mean over keypoints, mm (two views or more).
    pub fn triangulated_mm(&self) -> Option<f64> {
        self.triangulated_mm
    }

    /// The run's errors so far.
    pub fn summary(&self) -> KeypointSummary {
        KeypointSummary {
            views: self
                .reference
                .cameras
                .iter()
                .zip(&self.totals)
                .map(|(c, t)| ViewSummary {
                    view: c.name.clone(),
                    mean_px: t.sum_px / t.compared.max(1) as f64,
                    max_px: t.max_px,
                    ticks: t.ticks,
                    failed_ticks: t.failed,
                })
                .collect(),
            triangulated_mm: (self.tri.2 > 0).then(|| (self.tri.0 / self.tri.2 as f64, self.tri.1)),
        }
    }
}
