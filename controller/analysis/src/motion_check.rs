//! Motion quality of a reference on the robot model, before anything moves: ground penetration,
//! foot sliding and floating, joint limit and speed margins, and the joint torques inverse
//! dynamics needs against each motor's limit (the retargeting metrics of the research this project
//! follows; see `../shared/reference/seeds.md`).

use mujoco_rs::wrappers::mj_model::MjtObjBase;
use robots::{Robot, spatial};
use sim2real::model_index::ModelIndex;

use controller::clip::Reference;

/// Penetration deeper than this counts, m.
pub const PENETRATION: f64 = 0.01;
/// A foot lower than this is taken to be in contact, m.
pub const CONTACT_HEIGHT: f64 = 0.02;

/// One torque finding.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct TorqueUse {
    /// Joint name.
    pub joint: String,
    /// Largest |τ| inverse dynamics needs, N·m.
    pub peak: f64,
    /// The joint's torque limit, N·m.
    pub limit: f64,
    /// First tick beyond the limit.
    pub first_saturated: Option<usize>,
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
    /// Mean foot height above the floor while in contact, m.
    pub foot_floating: f64,
    /// Smallest distance to a position limit: rad, joint, tick.
    pub limit_margin: (f64, String, usize),
    /// Largest fraction of a joint's speed limit used: fraction, joint, tick.
    pub speed_use: (f64, String, usize),
    /// Per joint torque use, saturating joints first.
    pub torques: Vec<TorqueUse>,
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
        for t in self.torques.iter().filter(|t| t.first_saturated.is_some()) {
            let tick = t.first_saturated.unwrap_or(0);
            out.push(format!(
                "{} needs {:.1} N·m, beyond its {:.1} N·m limit (first at t = {:.3} s, tick {tick}): the motor would saturate",
                t.joint,
                t.peak,
                t.limit,
                tick as f64 / self.rate_hz
            ));
        }
        out
    }
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
            "  foot sliding {:.3} m/s, foot floating {:.2} cm (while in contact)",
            self.foot_sliding,
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
                "  torque: {} peaks at {:.1} of {:.1} N·m ({:.0} %)",
                t.joint,
                t.peak,
                t.limit,
                100.0 * t.peak / t.limit
            )?;
        }
        writeln!(
            f,
            "  (stance-leg torques use MuJoCo's soft contacts at the clip's foot heights: weight bearing is underestimated)"
        )?;
        Ok(())
    }
}

/// Analyses `reference` on `robot`'s model.
pub fn analyze(
    robot: &Robot,
    reference: &Reference,
) -> Result<MotionQuality, controller::fk::KinematicsError> {
    let model = sim2real::mujoco::load_model(&robot.mjcf_path)?;
    let index = ModelIndex::of_robot(&model, robot)?;
    let (root_q, root_v) = (index.root.qpos, index.root.dof);
    let joints = &robot.config.joints;
    let adr: Vec<(usize, usize)> = index.joints.iter().map(|j| (j.qpos, j.dof)).collect();
    let feet = index.feet.clone();
    let ngeom = model.ffi().ngeom as usize;
    let soles: Vec<Vec<usize>> = feet
        .iter()
        .map(|&b| {
            (0..ngeom)
                .filter(|&g| model.geom_bodyid()[g] as usize == b && model.geom_contype()[g] != 0)
                .collect()
        })
        .collect();
    // Geom pairs of different kinematic chains (neither body an ancestor of the other).
    let parent = |b: usize| model.body_parentid()[b] as usize;
    let ancestor = |a: usize, mut b: usize| {
        while b != 0 {
            if b == a {
                return true;
            }
            b = parent(b);
        }
        false
    };
    let body_of = |g: usize| model.geom_bodyid()[g] as usize;
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
    // Generalised velocities by finite differences of the reference (root in the world frame for
    // the linear part, body frame for the angular part, as MuJoCo's free joint has them).
    let mut qvel = vec![0.0; n * nv];
    for k in 0..n {
        let (a, b) = (k.saturating_sub(1), (k + 1).min(n - 1));
        let span = (b - a).max(1) as f64 * dt;
        let (ra, rb) = (reference.root[a], reference.root[b]);
        for i in 0..3 {
            qvel[k * nv + root_v + i] = (rb[i] - ra[i]) / span;
        }
        let w = angular_velocity([ra[3], ra[4], ra[5], ra[6]], [rb[3], rb[4], rb[5], rb[6]], span);
        qvel[k * nv + root_v + 3..k * nv + root_v + 6].copy_from_slice(&w);
        for (i, &(_, dof)) in adr.iter().enumerate() {
            qvel[k * nv + dof] = reference.qd_at(k)[i];
        }
    }
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
        foot_floating: 0.0,
        limit_margin: (f64::INFINITY, String::new(), 0),
        speed_use: (0.0, String::new(), 0),
        torques: joints
            .iter()
            .map(|j| TorqueUse {
                joint: j.name.clone(),
                peak: 0.0,
                limit: j.torque_limit,
                first_saturated: None,
            })
            .collect(),
    };
    let (mut slide_sum, mut float_sum, mut contact_samples) = (0.0, 0.0, 0usize);
    let mut previous_feet: Vec<[f64; 3]> = Vec::new();
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
        // Feet: height of the lowest sole point, horizontal speed.
        let mut now_feet = Vec::with_capacity(feet.len());
        for (f, &body) in feet.iter().enumerate() {
            let height = soles[f]
                .iter()
                .map(|&g| data.geom_xpos()[g][2] - model.geom_size()[g][2])
                .fold(f64::INFINITY, f64::min);
            let p = data.xpos()[body];
            now_feet.push(p);
            if height < CONTACT_HEIGHT {
                float_sum += height.max(0.0);
                if let Some(prev) = previous_feet.get(f) {
                    slide_sum += ((p[0] - prev[0]).powi(2) + (p[1] - prev[1]).powi(2)).sqrt() / dt;
                }
                contact_samples += 1;
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
        // Torques inverse dynamics needs for the reference's accelerations (forward dynamics above
        // overwrote qacc; contact forces come from MuJoCo's soft contact model).
        let (a, b) = (k.saturating_sub(1), (k + 1).min(n - 1));
        let span = (b - a).max(1) as f64 * dt;
        for v in 0..nv {
            data.qacc_mut()[v] = (qvel[b * nv + v] - qvel[a * nv + v]) / span;
        }
        data.inverse();
        for (i, &(_, dof)) in adr.iter().enumerate() {
            let tau = data.qfrc_inverse()[dof].abs();
            let t = &mut q.torques[i];
            t.peak = t.peak.max(tau);
            if tau > t.limit && t.first_saturated.is_none() {
                t.first_saturated = Some(k);
            }
        }
    }
    if q.penetration_ticks > 0 {
        q.penetration_mean /= q.penetration_ticks as f64;
    }
    if contact_samples > 0 {
        q.foot_sliding = slide_sum / contact_samples as f64;
        q.foot_floating = float_sum / contact_samples as f64;
    }
    q.torques
        .sort_by(|a, b| (b.peak / b.limit).total_cmp(&(a.peak / a.limit)));
    Ok(q)
}

/// Body-frame angular velocity taking orientation `a` to `b` in `dt` (`[w, x, y, z]`).
fn angular_velocity(a: [f64; 4], b: [f64; 4], dt: f64) -> [f64; 3] {
    // q_rel = a⁻¹ ⊗ b, ω = log(q_rel)/dt.
    let rel = spatial::quat_mul(spatial::quat_conj(a), b);
    spatial::scale(spatial::quat_log(rel), 1.0 / dt)
}
