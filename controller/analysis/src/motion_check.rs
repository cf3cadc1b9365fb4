//! Motion quality of a reference on the robot model, before anything moves: ground penetration,
//! foot sliding and floating, joint limit and speed margins, and the joint torques the motion
//! needs against each motor's limit (the retargeting metrics of the research this project
//! follows; see `../shared/reference/seeds.md`).
//!
//! Torques come from inverse dynamics of the motion on the free-floating model (MuJoCo's RNE at
//! the motion's finite-difference accelerations), less the ground forces: the wrench the floating
//! base needs is split over the sole points within [`CONTACT_HEIGHT`] of the floor, inside their
//! friction cones ([`contact_forces`]), and each joint carries what is left. Feet are measured by
//! their real collision geometry (box, capsule, sphere, cylinder, ellipsoid, mesh).

pub mod contact_forces;

use mujoco_rs::prelude::MjData;
use mujoco_rs::wrappers::mj_model::MjtObjBase;
use mujoco_rs::wrappers::mj_model::traits::ModelType;
use robots::{Robot, spatial};
use sim2real::model_index::ModelIndex;
use sim2real::placement;

use controller::clip::Reference;

/// Penetration deeper than this counts, m.
pub const PENETRATION: f64 = 0.01;
/// A sole point lower than this is taken to be in contact, m.
pub const CONTACT_HEIGHT: f64 = 0.02;
/// A frame whose base force the feet cannot carry by more than this share of the robot's weight
/// is unsupported.
pub const UNSUPPORTED_SHARE: f64 = 0.2;
/// Unsupported frames in a row that make a problem, s (a single frame is a finite-difference
/// spike at an impact).
pub const UNSUPPORTED_S: f64 = 0.1;
/// Torque beyond a joint's limit for this long in a row makes a problem, s; shorter bursts (a
/// landing's impact, a finite-difference spike of a noisy clip) are reported, not refused: a
/// motor saturating for a tick or two still tracks.
pub const SATURATION_S: f64 = 0.1;
/// Friction coefficient between sole and floor when the model gives none.
const DEFAULT_FRICTION: f64 = 1.0;
/// How far out of straight down the directions that find a sole's corners lean.
const CORNER_LEAN: f64 = 0.3;

/// One torque finding.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct TorqueUse {
    /// Joint name.
    pub joint: String,
    /// Largest |τ| the motion needs, N·m.
    pub peak: f64,
    /// Tick of the peak.
    pub peak_tick: usize,
    /// The joint's torque limit, N·m.
    pub limit: f64,
    /// First tick beyond the limit.
    pub first_saturated: Option<usize>,
    /// Ticks beyond the limit.
    pub saturated_ticks: usize,
    /// Runs of ticks beyond the limit, first and last tick of each.
    pub saturated_spans: Vec<(usize, usize)>,
}

/// What [`analyze`] found.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct MotionQuality {
    /// Ticks analysed.
    pub ticks: usize,
    /// Control rate, Hz.
    pub rate_hz: f64,
    /// Ticks with a contact deeper than [`PENETRATION`].
    pub penetration_ticks: usize,
    /// Mean depth over those ticks, m.
    pub penetration_mean: f64,
    /// Deepest penetration: depth, tick, geom name.
    pub deepest: Option<(f64, usize, String)>,
    /// First tick deeper than the threshold, and the geom.
    pub first_penetration: Option<(usize, String)>,
    /// Ticks where two bodies of different chains overlap by more than [`PENETRATION`].
    pub self_penetration_ticks: usize,
    /// Deepest self-penetration: depth, tick, "geom/geom".
    pub deepest_self: Option<(f64, usize, String)>,
    /// Mean horizontal foot speed while in contact, m/s.
    pub foot_sliding: f64,
    /// Median of it over the feet's ticks in contact, m/s (a swing foot skimming the floor for a
    /// tick moves the mean, not this).
    pub foot_sliding_median: f64,
    /// Mean foot height above the floor while in contact, m.
    pub foot_floating: f64,
    /// Smallest distance to a position limit: rad, joint, tick.
    pub limit_margin: (f64, String, usize),
    /// Largest fraction of a joint's speed limit used: fraction, joint, tick.
    pub speed_use: (f64, String, usize),
    /// Per joint torque use, saturating joints first.
    pub torques: Vec<TorqueUse>,
    /// Ticks with some sole point in contact.
    pub support_ticks: usize,
    /// Ticks whose base force the feet cannot carry (beyond [`UNSUPPORTED_SHARE`] of the weight).
    pub unsupported_ticks: usize,
    /// The longest run of unsupported ticks: first tick, ticks.
    pub longest_unsupported: Option<(usize, usize)>,
    /// The largest force the feet could not carry: N, tick.
    pub worst_unsupported: Option<(f64, usize)>,
    /// The robot's weight, N.
    pub weight: f64,
    /// Joint torques the motion needs per tick, robot order (`ticks × joints`), N·m.
    #[serde(skip)]
    pub torque: Vec<f64>,
}

impl MotionQuality {
    /// Problems that should stop a deployment, one line each (empty: none).
    pub fn problems(&self) -> Vec<String> {
        let mut out = Vec::new();
        if let (Some((depth, _, _)), Some((first, geom))) = (&self.deepest, &self.first_penetration) {
            out.push(format!(
                "ground penetration: {} of {} ticks deeper than {:.0} cm, first at t = {:.3} s (tick {first}, {geom}); deepest {:.1} cm",
                self.penetration_ticks,
                self.ticks,
                PENETRATION * 100.0,
                *first as f64 / self.rate_hz,
                depth * 100.0
            ));
        }
        if let Some((depth, tick, pair)) = &self.deepest_self {
            out.push(format!(
                "self-penetration: {} ticks with limbs overlapping more than {:.0} cm (deepest {:.1} cm, {pair}, t = {:.3} s, tick {tick})",
                self.self_penetration_ticks,
                PENETRATION * 100.0,
                depth * 100.0,
                *tick as f64 / self.rate_hz
            ));
        }
        if let Some((first, ticks)) = self.longest_unsupported
            && ticks as f64 / self.rate_hz >= UNSUPPORTED_S
        {
            let (worst, at) = self.worst_unsupported.unwrap_or((0.0, first));
            out.push(format!(
                "the feet cannot carry the motion in {} of {} ticks (longest {:.2} s from t = {:.3} s, tick {first}): up to {:.0} N ({:.0} % of the weight) left unsupported at t = {:.3} s — the body floats, leans beyond its feet or is pulled",
                self.unsupported_ticks,
                self.ticks,
                ticks as f64 / self.rate_hz,
                first as f64 / self.rate_hz,
                worst,
                100.0 * worst / self.weight.max(f64::MIN_POSITIVE),
                at as f64 / self.rate_hz
            ));
        }
        for t in self.torques.iter().filter(|t| self.sustained(t)) {
            out.push(format!(
                "{} needs up to {:.1} N·m ({:.0} % of its {:.1} N·m limit, t = {:.3} s) in {} ticks ({}): the motor would saturate",
                t.joint,
                t.peak,
                100.0 * t.peak / t.limit,
                t.limit,
                t.peak_tick as f64 / self.rate_hz,
                t.saturated_ticks,
                spans_text(&t.saturated_spans, self.rate_hz)
            ));
        }
        out
    }

    /// Whether `t` stays beyond its limit for [`SATURATION_S`] or longer at a time.
    pub fn sustained(&self, t: &TorqueUse) -> bool {
        let longest = t
            .saturated_spans
            .iter()
            .map(|(a, b)| b - a + 1)
            .max()
            .unwrap_or(0);
        longest as f64 / self.rate_hz >= SATURATION_S
    }
}

/// "t 1.20–1.44 s, 3.02 s, … and 4 more" for runs of ticks.
fn spans_text(spans: &[(usize, usize)], rate_hz: f64) -> String {
    const SHOWN: usize = 3;
    let mut parts: Vec<String> = spans
        .iter()
        .take(SHOWN)
        .map(|&(a, b)| {
            if a == b {
                format!("{:.2} s", a as f64 / rate_hz)
            } else {
                format!("{:.2}–{:.2} s", a as f64 / rate_hz, b as f64 / rate_hz)
            }
        })
        .collect();
    if spans.len() > SHOWN {
        parts.push(format!("and {} more", spans.len() - SHOWN));
    }
    format!("t {}", parts.join(", "))
}

impl std::fmt::Display for MotionQuality {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "  ground penetration > {:.0} cm: {} of {} ticks ({:.1} %), mean depth {:.2} cm",
            PENETRATION * 100.0,
            self.penetration_ticks,
            self.ticks,
            100.0 * self.penetration_ticks as f64 / self.ticks.max(1) as f64,
            self.penetration_mean * 100.0
        )?;
        writeln!(
            f,
            "  self-penetration > {:.0} cm (different chains): {} ticks",
            PENETRATION * 100.0,
            self.self_penetration_ticks
        )?;
        writeln!(
            f,
            "  soles within {:.0} cm of the floor (swinging feet skimming it included): moving {:.1} cm/s median, {:.1} cm/s mean; {:.2} cm above it on average",
            CONTACT_HEIGHT * 100.0,
            self.foot_sliding_median * 100.0,
            self.foot_sliding * 100.0,
            self.foot_floating * 100.0
        )?;
        let (m, j, k) = &self.limit_margin;
        writeln!(
            f,
            "  closest to a position limit: {j} {:.3} rad away (tick {k})",
            m
        )?;
        let (u, j, k) = &self.speed_use;
        writeln!(
            f,
            "  highest speed: {j} at {:.0} % of its limit (tick {k})",
            u * 100.0
        )?;
        for t in self.torques.iter().take(3) {
            writeln!(
                f,
                "  torque: {} peaks at {:.1} of {:.1} N·m ({:.0} %, t = {:.3} s)",
                t.joint,
                t.peak,
                t.limit,
                100.0 * t.peak / t.limit,
                t.peak_tick as f64 / self.rate_hz
            )?;
        }
        let mut brief: Vec<&TorqueUse> = self
            .torques
            .iter()
            .filter(|t| t.saturated_ticks > 0 && !self.sustained(t))
            .collect();
        if !brief.is_empty() {
            const SHOWN: usize = 4;
            brief.sort_by_key(|t| std::cmp::Reverse(t.saturated_ticks));
            let mut parts: Vec<String> = brief
                .iter()
                .take(SHOWN)
                .map(|t| {
                    format!(
                        "{} {} ticks (peak {:.0} of {:.0} N·m)",
                        t.joint, t.saturated_ticks, t.peak, t.limit
                    )
                })
                .collect();
            if brief.len() > SHOWN {
                parts.push(format!("{} more joints", brief.len() - SHOWN));
            }
            writeln!(
                f,
                "  brief saturation, under {:.0} ms at a time: {}",
                SATURATION_S * 1000.0,
                parts.join(", ")
            )?;
        }
        writeln!(
            f,
            "  ground support: feet in contact in {} of {} ticks; unsupported (> {:.0} % of the {:.0} N weight left over) in {}",
            self.support_ticks,
            self.ticks,
            UNSUPPORTED_SHARE * 100.0,
            self.weight,
            self.unsupported_ticks
        )?;
        writeln!(
            f,
            "  (torques: inverse dynamics with the ground forces split over the soles in contact, inside friction cones)"
        )?;
        Ok(())
    }
}

/// Analyses `reference` on `robot`'s model.
pub fn analyze(robot: &Robot, reference: &Reference) -> Result<MotionQuality, world::KinematicsError> {
    let model = robot.model()?;
    let index = ModelIndex::of_robot(&model, robot)?;
    let (root_q, root_v) = (index.root.qpos, index.root.dof);
    let joints = &robot.config.joints;
    let adr: Vec<(usize, usize)> = index.joints.iter().map(|j| (j.qpos, j.dof)).collect();
    let feet = index.feet.clone();
    let ngeom = model.ffi().ngeom as usize;
    let body_of = |g: usize| model.geom_bodyid()[g] as usize;
    let soles: Vec<Vec<usize>> = feet
        .iter()
        .map(|&b| {
            (0..ngeom)
                .filter(|&g| body_of(g) == b && placement::collides(&model, g))
                .collect()
        })
        .collect();
    let friction = soles
        .iter()
        .flatten()
        .map(|&g| model.geom_friction()[g][0])
        .fold(None, |lowest: Option<f64>, mu| {
            Some(lowest.map_or(mu, |l| l.min(mu)))
        })
        .filter(|mu| *mu > 0.0)
        .unwrap_or(DEFAULT_FRICTION);
    let weight = model.body_subtreemass()[index.root_body] * -model.opt().gravity[2];
    // Geom pairs of different kinematic chains (neither body an ancestor of the other).
    let ancestor = |a: usize, b: usize| b != 0 && placement::in_tree(&model, b, a);
    let cross_pairs: Vec<(usize, usize)> = (0..ngeom)
        .flat_map(|a| (a + 1..ngeom).map(move |b| (a, b)))
        .filter(|&(a, b)| {
            let (ba, bb) = (body_of(a), body_of(b));
            ba != 0 && bb != 0 && !ancestor(ba, bb) && !ancestor(bb, ba)
        })
        .collect();
    let geom_name = |g: usize| {
        model.id_to_name(MjtObjBase::mjOBJ_GEOM, g).map_or_else(
            || {
                format!(
                    "geom {g} ({})",
                    model
                        .id_to_name(MjtObjBase::mjOBJ_BODY, body_of(g))
                        .unwrap_or("?")
                )
            },
            str::to_owned,
        )
    };
    let nv = model.ffi().nv as usize;
    let n = reference.len();
    let dt = 1.0 / reference.rate_hz;
    let (qvel, qacc) = generalised_motion(reference, &adr, root_v, nv);
    let mut data = model.make_data();
    let mut q = MotionQuality {
        ticks: n,
        rate_hz: reference.rate_hz,
        penetration_ticks: 0,
        penetration_mean: 0.0,
        deepest: None,
        first_penetration: None,
        self_penetration_ticks: 0,
        deepest_self: None,
        foot_sliding: 0.0,
        foot_sliding_median: 0.0,
        foot_floating: 0.0,
        limit_margin: (f64::INFINITY, String::new(), 0),
        speed_use: (0.0, String::new(), 0),
        torques: joints
            .iter()
            .map(|j| TorqueUse {
                joint: j.name.clone(),
                peak: 0.0,
                peak_tick: 0,
                limit: j.torque_limit,
                first_saturated: None,
                saturated_ticks: 0,
                saturated_spans: Vec::new(),
            })
            .collect(),
        support_ticks: 0,
        unsupported_ticks: 0,
        longest_unsupported: None,
        worst_unsupported: None,
        weight,
        torque: Vec::with_capacity(n * joints.len()),
    };
    let (mut slides, mut float_sum, mut contact_samples) = (Vec::new(), 0.0, 0usize);
    // Each foot's pose the tick before: (origin, rotation, row major).
    let mut previous_feet: Vec<([f64; 3], [f64; 9])> = Vec::new();
    let mut unsupported_run: Option<(usize, usize)> = None;
    let mut needed = vec![0.0; nv];
    for k in 0..n {
        let r = reference.root[k];
        data.qpos_mut()[root_q..root_q + 7].copy_from_slice(&r);
        for (i, &(qa, _)) in adr.iter().enumerate() {
            data.qpos_mut()[qa] = reference.q_at(k)[i];
        }
        data.qvel_mut().copy_from_slice(&qvel[k * nv..(k + 1) * nv]);
        data.forward();
        // Ground penetration: contacts deeper than the threshold.
        let deepest_now = data
            .contact()
            .iter()
            .map(|c| (-c.dist, c.geom))
            .fold((0.0, [0, 0]), |acc, x| if x.0 > acc.0 { x } else { acc });
        if deepest_now.0 > PENETRATION {
            q.penetration_ticks += 1;
            q.penetration_mean += deepest_now.0;
            let g = deepest_now
                .1
                .iter()
                .copied()
                .find(|&g| g >= 0 && model.geom_bodyid()[g as usize] != 0)
                .unwrap_or(0);
            let name = model
                .id_to_name(MjtObjBase::mjOBJ_GEOM, g as usize)
                .unwrap_or("geom")
                .to_owned();
            q.first_penetration.get_or_insert_with(|| (k, name.clone()));
            if q.deepest.as_ref().is_none_or(|d| deepest_now.0 > d.0) {
                q.deepest = Some((deepest_now.0, k, name));
            }
        }
        // Self-penetration between different chains.
        let mut worst = (0.0, 0, 0);
        for &(a, b) in &cross_pairs {
            // Bounding spheres apart: they cannot overlap (saves GJK on meshes).
            let (pa, pb) = (data.geom_xpos()[a], data.geom_xpos()[b]);
            if spatial::norm(spatial::sub(pa, pb)) > model.geom_rbound()[a] + model.geom_rbound()[b] {
                continue;
            }
            let depth = -data.geom_distance(a, b, 0.05, None);
            if depth > worst.0 {
                worst = (depth, a, b);
            }
        }
        if worst.0 > PENETRATION {
            q.self_penetration_ticks += 1;
            if q.deepest_self.as_ref().is_none_or(|d| worst.0 > d.0) {
                q.deepest_self = Some((
                    worst.0,
                    k,
                    format!("{}/{}", geom_name(worst.1), geom_name(worst.2)),
                ));
            }
        }
        // Feet: the lowest point of each sole by its real shape, its horizontal speed, and the
        // corners of the soles in contact.
        let mut now_feet = Vec::with_capacity(feet.len());
        let mut contacts: Vec<([f64; 3], usize)> = Vec::new();
        for (f, &body) in feet.iter().enumerate() {
            let footprint = sole_footprint(&data, body, &soles[f]);
            let height = footprint.lowest;
            let (p, r) = (data.xpos()[body], data.xmat()[body]);
            now_feet.push((p, r));
            if height < CONTACT_HEIGHT {
                float_sum += height.max(0.0);
                // Sliding: how fast the sole's points on the floor move, as points of the foot
                // (where each was the tick before), so a foot rolling over its toe or heel does
                // not slide while its ankle moves.
                if let Some(&(p0, r0)) = previous_feet.get(f) {
                    let touching: Vec<[f64; 3]> = footprint
                        .corners
                        .iter()
                        .copied()
                        .filter(|c| c[2] < CONTACT_HEIGHT)
                        .collect();
                    let points: &[[f64; 3]] = if touching.is_empty() {
                        &footprint.corners
                    } else {
                        &touching
                    };
                    let speed = points
                        .iter()
                        .map(|c| {
                            let d = spatial::sub(*c, p);
                            // In the foot's frame now, then where the foot was.
                            let local = [0, 1, 2].map(|i| r[i] * d[0] + r[3 + i] * d[1] + r[6 + i] * d[2]);
                            let was = [0, 1, 2].map(|i| {
                                p0[i]
                                    + r0[3 * i] * local[0]
                                    + r0[3 * i + 1] * local[1]
                                    + r0[3 * i + 2] * local[2]
                            });
                            ((c[0] - was[0]).powi(2) + (c[1] - was[1]).powi(2)).sqrt() / dt
                        })
                        .sum::<f64>()
                        / points.len().max(1) as f64;
                    slides.push(speed);
                }
                contact_samples += 1;
                contacts.extend(
                    footprint
                        .corners
                        .iter()
                        .filter(|c| c[2] < CONTACT_HEIGHT)
                        .map(|&c| (c, body)),
                );
            }
        }
        previous_feet = now_feet;
        // Margins.
        for (i, j) in joints.iter().enumerate() {
            let x = reference.q_at(k)[i];
            let margin = (x - j.position_limits[0]).min(j.position_limits[1] - x);
            if margin < q.limit_margin.0 {
                q.limit_margin = (margin, j.name.clone(), k);
            }
            let use_ = reference.qd_at(k)[i].abs() / j.velocity_limit;
            if use_ > q.speed_use.0 {
                q.speed_use = (use_, j.name.clone(), k);
            }
        }
        // The generalised forces the motion needs (forward dynamics above overwrote qacc).
        data.qacc_mut().copy_from_slice(&qacc[k * nv..(k + 1) * nv]);
        required_forces(&mut data, &mut needed);
        // The ground's share, over the sole corners in contact.
        let jacobians: Vec<Vec<f64>> = contacts
            .iter()
            .map(|(p, body)| data.jac(true, false, p, *body).0)
            .collect();
        let columns: Vec<[f64; 6]> = jacobians
            .iter()
            .flat_map(|jac| (0..3).map(move |axis| [0, 1, 2, 3, 4, 5].map(|r| jac[axis * nv + root_v + r])))
            .collect();
        let mut wrench = [0.0; 6];
        wrench.copy_from_slice(&needed[root_v..root_v + 6]);
        let split = contact_forces::split(&columns, wrench, friction);
        if !contacts.is_empty() {
            q.support_ticks += 1;
        }
        let left_over = spatial::norm([split.residual[0], split.residual[1], split.residual[2]]);
        if left_over > UNSUPPORTED_SHARE * weight {
            q.unsupported_ticks += 1;
            if q.worst_unsupported.is_none_or(|(w, _)| left_over > w) {
                q.worst_unsupported = Some((left_over, k));
            }
            let run = match unsupported_run {
                Some((first, len)) if first + len == k => (first, len + 1),
                _ => (k, 1),
            };
            unsupported_run = Some(run);
            if q.longest_unsupported.is_none_or(|(_, len)| run.1 > len) {
                q.longest_unsupported = Some(run);
            }
        }
        for (i, &(_, dof)) in adr.iter().enumerate() {
            let ground: f64 = jacobians
                .iter()
                .zip(&split.forces)
                .map(|(jac, f)| (0..3).map(|axis| jac[axis * nv + dof] * f[axis]).sum::<f64>())
                .sum();
            let tau = needed[dof] - ground;
            q.torque.push(tau);
            let t = &mut q.torques[i];
            if tau.abs() > t.peak {
                (t.peak, t.peak_tick) = (tau.abs(), k);
            }
            if tau.abs() > t.limit {
                t.first_saturated.get_or_insert(k);
                t.saturated_ticks += 1;
                match t.saturated_spans.last_mut() {
                    Some(last) if last.1 + 1 == k => last.1 = k,
                    _ => t.saturated_spans.push((k, k)),
                }
            }
        }
    }
    if q.penetration_ticks > 0 {
        q.penetration_mean /= q.penetration_ticks as f64;
    }
    if contact_samples > 0 {
        q.foot_sliding = slides.iter().sum::<f64>() / contact_samples as f64;
        q.foot_floating = float_sum / contact_samples as f64;
    }
    if !slides.is_empty() {
        slides.sort_by(f64::total_cmp);
        q.foot_sliding_median = slides[slides.len() / 2];
    }
    q.torques
        .sort_by(|a, b| (b.peak / b.limit).total_cmp(&(a.peak / a.limit)));
    Ok(q)
}

/// Generalised velocities and accelerations of the reference, each `ticks × nv`: velocities by
/// central differences, accelerations by second differences over the neighbouring ticks (the
/// root's linear part in the world frame, its angular part in the body frame, as MuJoCo's free
/// joint has them).
fn generalised_motion(
    reference: &Reference,
    adr: &[(usize, usize)],
    root_v: usize,
    nv: usize,
) -> (Vec<f64>, Vec<f64>) {
    let n = reference.len();
    let dt = 1.0 / reference.rate_hz;
    // Velocity over each step k → k + 1.
    let mut step = vec![0.0; n.saturating_sub(1).max(1) * nv];
    for k in 0..n.saturating_sub(1) {
        let (ra, rb) = (reference.root[k], reference.root[k + 1]);
        let v = &mut step[k * nv..(k + 1) * nv];
        for i in 0..3 {
            v[root_v + i] = (rb[i] - ra[i]) / dt;
        }
        let w = angular_velocity([ra[3], ra[4], ra[5], ra[6]], [rb[3], rb[4], rb[5], rb[6]], dt);
        v[root_v + 3..root_v + 6].copy_from_slice(&w);
        for (i, &(_, dof)) in adr.iter().enumerate() {
            v[dof] = (reference.q_at(k + 1)[i] - reference.q_at(k)[i]) / dt;
        }
    }
    let steps = n.saturating_sub(1);
    let (mut qvel, mut qacc) = (vec![0.0; n * nv], vec![0.0; n * nv]);
    if steps == 0 {
        return (qvel, qacc);
    }
    for k in 0..n {
        let (before, after) = (k.saturating_sub(1).min(steps - 1), k.min(steps - 1));
        for v in 0..nv {
            let (a, b) = (step[before * nv + v], step[after * nv + v]);
            qvel[k * nv + v] = 0.5 * (a + b);
            if before != after {
                qacc[k * nv + v] = (b - a) / dt;
            }
        }
    }
    (qvel, qacc)
}

/// The generalised forces that make `data`'s `qacc` at its `qpos` and `qvel` with no contact:
/// M·qacc + bias (MuJoCo's RNE), plus the rotors' armature, less the passive springs and dampers.
/// `data` has been through `forward`.
fn required_forces<M: ModelType>(data: &mut MjData<M>, out: &mut [f64]) {
    data.rne_into(true, out);
    let model = data.model();
    for (v, f) in out.iter_mut().enumerate() {
        *f += model.dof_armature()[v] * data.qacc()[v] - data.qfrc_passive()[v];
    }
}

/// Where a foot meets the floor: its lowest point and the corners of its sole.
struct Footprint {
    /// Height of the lowest point, m.
    lowest: f64,
    /// The sole's extreme points towards front-left, front-right, back-left and back-right (the
    /// foot body's heading), world frame.
    corners: Vec<[f64; 3]>,
}

/// The footprint of foot `body` from its collision geoms `soles`, by their real shapes: for each
/// geom its support points in directions leaning out of straight down, of which the extremes over
/// all geoms are the sole's corners.
fn sole_footprint<M: ModelType>(data: &MjData<M>, body: usize, soles: &[usize]) -> Footprint {
    let r = data.xmat()[body];
    // The body's x axis flattened onto the floor: the foot's heading.
    let heading = {
        let (x, y) = (r[0], r[3]);
        let len = (x * x + y * y).sqrt();
        if len > 1e-9 {
            [x / len, y / len]
        } else {
            [1.0, 0.0]
        }
    };
    let side = [-heading[1], heading[0]];
    let mut lowest = f64::INFINITY;
    let mut corners: [Option<([f64; 3], f64)>; 4] = [None; 4];
    for &g in soles {
        if let Some(p) = placement::world_support_point(data, g, [0.0, 0.0, -1.0]) {
            lowest = lowest.min(p[2]);
        }
        for (c, (front, left)) in [(1.0, 1.0), (1.0, -1.0), (-1.0, 1.0), (-1.0, -1.0)]
            .into_iter()
            .enumerate()
        {
            let out = [
                front * heading[0] + left * side[0],
                front * heading[1] + left * side[1],
            ];
            let lean = [CORNER_LEAN * out[0], CORNER_LEAN * out[1], -1.0];
            let d = spatial::scale(lean, 1.0 / spatial::norm(lean));
            let Some(p) = placement::world_support_point(data, g, d) else {
                continue;
            };
            let score = p[0] * d[0] + p[1] * d[1] + p[2] * d[2];
            if corners[c].is_none_or(|(_, best)| score > best) {
                corners[c] = Some((p, score));
            }
        }
    }
    if lowest.is_infinite() {
        // No collision geometry: the body's origin stands for the foot.
        let p = data.xpos()[body];
        return Footprint {
            lowest: p[2],
            corners: vec![p],
        };
    }
    Footprint {
        lowest,
        corners: corners.iter().flatten().map(|(p, _)| *p).collect(),
    }
}

/// Body-frame angular velocity taking orientation `a` to `b` in `dt` (`[w, x, y, z]`).
fn angular_velocity(a: [f64; 4], b: [f64; 4], dt: f64) -> [f64; 3] {
    // q_rel = a⁻¹ ⊗ b, ω = log(q_rel)/dt.
    let rel = spatial::quat_mul(spatial::quat_conj(a), b);
    spatial::scale(spatial::quat_log(rel), 1.0 / dt)
}
