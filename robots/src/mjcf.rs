//! The robot's MJCF as MuJoCo compiles it: `<include>`s, default classes, `meshdir`/`assetdir`,
//! the compiler's angle units and frames are MuJoCo's own business, so the robot description reads
//! the compiled model — joints with their ranges in radians, bodies, sites, actuators by kind,
//! sensors, keyframes and the floor — instead of re-implementing a part of the XML format.
//!
//! Before MuJoCo sees the files, the model and everything it includes or loads are checked to be
//! regular files of bounded size: MuJoCo reads what a path names to its end, so `/dev/zero` or a
//! FIFO would hang it.

use std::path::{Path, PathBuf};

use mujoco_rs::mujoco_c::{_mjtGeomBase, mjtBias, mjtGain, mjtJoint, mjtSensor};
use mujoco_rs::prelude::MjModel;
use mujoco_rs::wrappers::mj_model::MjtObjBase;

use crate::FileError;

/// The MuJoCo release mujoco-rs 7.0.0+mj-3.17.0 is written against, as `mj_version()` reports it.
pub const PINNED_MUJOCO_VERSION: i32 = 3_017_000;

/// What can go wrong before a model is compiled.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum MujocoError {
    /// The loaded `libmujoco` is not the pinned release.
    #[error(
        "libmujoco reports version {found} but this build needs {PINNED_MUJOCO_VERSION} (3.17.0); \
         run `scripts/setup` to reinstall the pinned library into .local/lib"
    )]
    WrongVersion {
        /// `mj_version()` of the loaded library.
        found: i32,
    },
    /// MuJoCo refused the model, or a file it would read is not one.
    #[error("cannot load MJCF model {path}: {reason}")]
    Model {
        /// The file, or `<inline>` for a string.
        path: String,
        /// MuJoCo's own message, or what is wrong with a file.
        reason: String,
    },
    /// robot.toml maps a joint to an MJCF joint the model lacks.
    #[error("joint {joint}: the model has no joint {mjcf_joint:?}")]
    MissingJoint {
        /// The joint in robot.toml.
        joint: String,
        /// The MJCF joint it names.
        mjcf_joint: String,
    },
}

/// `mj_version()` of the loaded library (3017000 for 3.17.0).
pub fn loaded_version() -> i32 {
    #[allow(unsafe_code)] // plain C getter with no arguments and no preconditions
    // SAFETY: mj_version reads a compile-time constant of the loaded library.
    unsafe {
        mujoco_rs::mujoco_c::mj_version()
    }
}

/// `mj_versionString()` of the loaded library, e.g. `3.17.0`.
pub fn loaded_version_string() -> String {
    #[allow(unsafe_code)] // C getter returning a pointer to a static, NUL-terminated string
    // SAFETY: mj_versionString returns a non-null pointer to a static C string owned by the library.
    let s = unsafe { std::ffi::CStr::from_ptr(mujoco_rs::mujoco_c::mj_versionString()) };
    s.to_string_lossy().into_owned()
}

/// Fails unless the loaded `libmujoco` is the pinned 3.17.0.
pub fn check_version() -> Result<(), MujocoError> {
    match loaded_version() {
        PINNED_MUJOCO_VERSION => Ok(()),
        found => Err(MujocoError::WrongVersion { found }),
    }
}

/// Loads and compiles an MJCF file after checking the library version and the files it reads.
pub fn load_model(path: &Path) -> Result<MjModel, MujocoError> {
    check_version()?;
    let model_error = |reason: String| MujocoError::Model {
        path: path.display().to_string(),
        reason,
    };
    check_files(path)?;
    MjModel::from_xml(path).map_err(|e| model_error(e.to_string()))
}

/// Parses an MJCF file into an editable specification (after the same checks as [`load_model`]),
/// for callers that add to the model before compiling it.
pub fn load_spec(path: &Path) -> Result<mujoco_rs::prelude::MjSpec, MujocoError> {
    check_version()?;
    let model_error = |reason: String| MujocoError::Model {
        path: path.display().to_string(),
        reason,
    };
    check_files(path)?;
    mujoco_rs::prelude::MjSpec::from_xml(path).map_err(|e| model_error(e.to_string()))
}

/// Applies what robot.toml says of the trainer's simulation to `spec`: `[[joint_dynamics]]`
/// (armature, friction loss, damping per joint) and `[sim]` (step, integrator, iterations).
/// `Err` names the MJCF joint robot.toml maps that the model lacks.
pub fn apply_trainer_settings(
    spec: &mut mujoco_rs::prelude::MjSpec,
    config: &crate::RobotConfig,
) -> Result<(), MujocoError> {
    for j in &config.joints {
        let d = config.joint_dynamics_of(&j.name);
        if d == crate::JointDynamicsOf::default() {
            continue;
        }
        let joint = spec
            .joint_mut(&j.mjcf_joint)
            .ok_or_else(|| MujocoError::MissingJoint {
                joint: j.name.clone(),
                mjcf_joint: j.mjcf_joint.clone(),
            })?;
        if let Some(a) = d.armature {
            joint.set_armature(a);
        }
        if let Some(f) = d.frictionloss {
            joint.set_frictionloss(f);
        }
        if let Some(c) = d.damping {
            // The linear coefficient; MuJoCo's higher-order terms stay as the model has them.
            joint.damping_mut()[0] = c;
        }
    }
    let sim = &config.sim;
    let option = spec.option_mut();
    if let Some(t) = sim.timestep {
        option.timestep = t;
    }
    if let Some(i) = sim.integrator {
        option.integrator = i.mujoco();
    }
    if let Some(n) = sim.iterations {
        option.iterations = n as i32;
    }
    if let Some(solver) = sim.solver {
        use mujoco_rs::mujoco_c::mjtSolver as S;
        option.solver = (match solver {
            crate::Solver::Pgs => S::mjSOL_PGS,
            crate::Solver::Cg => S::mjSOL_CG,
            crate::Solver::Newton => S::mjSOL_NEWTON,
        }) as i32;
    }
    if let Some(cone) = sim.cone {
        use mujoco_rs::mujoco_c::mjtCone as C;
        option.cone = (match cone {
            crate::FrictionCone::Pyramidal => C::mjCONE_PYRAMIDAL,
            crate::FrictionCone::Elliptic => C::mjCONE_ELLIPTIC,
        }) as i32;
    }
    if let Some(r) = sim.impratio {
        option.impratio = r;
    }
    Ok(())
}

impl crate::Integrator {
    const ALL: [Self; 4] = [Self::Euler, Self::Rk4, Self::Implicit, Self::Implicitfast];

    /// MuJoCo's `mjtIntegrator` value.
    pub fn mujoco(self) -> i32 {
        use mujoco_rs::mujoco_c::mjtIntegrator as I;
        (match self {
            Self::Euler => I::mjINT_EULER,
            Self::Rk4 => I::mjINT_RK4,
            Self::Implicit => I::mjINT_IMPLICIT,
            Self::Implicitfast => I::mjINT_IMPLICITFAST,
        }) as i32
    }

    /// The integrator of MuJoCo's `mjtIntegrator` value `code`, if it is one of these.
    pub fn of_mujoco(code: i32) -> Option<Self> {
        Self::ALL.into_iter().find(|i| i.mujoco() == code)
    }

    /// Its name in robot.toml.
    pub fn name(self) -> &'static str {
        match self {
            Self::Euler => "euler",
            Self::Rk4 => "rk4",
            Self::Implicit => "implicit",
            Self::Implicitfast => "implicitfast",
        }
    }
}

/// The name of MuJoCo's constraint solver `code` (`mjtSolver`), as robot.toml `[sim] solver` says it.
pub fn solver_name(code: i32) -> &'static str {
    use mujoco_rs::mujoco_c::mjtSolver as S;
    match code {
        c if c == S::mjSOL_PGS as i32 => "pgs",
        c if c == S::mjSOL_CG as i32 => "cg",
        c if c == S::mjSOL_NEWTON as i32 => "newton",
        _ => "another solver",
    }
}

/// The name of MuJoCo's friction cone `code` (`mjtCone`), as robot.toml `[sim] cone` says it.
pub fn cone_name(code: i32) -> &'static str {
    use mujoco_rs::mujoco_c::mjtCone as C;
    match code {
        c if c == C::mjCONE_PYRAMIDAL as i32 => "pyramidal",
        c if c == C::mjCONE_ELLIPTIC as i32 => "elliptic",
        _ => "another cone",
    }
}

/// Loads an MJCF document from a string after checking the library version.
pub fn load_model_str(xml: &str) -> Result<MjModel, MujocoError> {
    check_version()?;
    MjModel::from_xml_string(xml).map_err(|e| MujocoError::Model {
        path: "<inline>".into(),
        reason: e.to_string(),
    })
}

/// Deepest `<include>` nesting followed.
const MAX_INCLUDE_DEPTH: usize = 16;

/// Checks that `main` and every file it includes or names as an asset are regular files of at
/// most [`crate::MAX_TEXT_FILE_BYTES`]. Paths resolve as MuJoCo resolves them: includes against the main file's
/// folder, assets against `meshdir`/`texturedir` (else `assetdir`, else the main file's folder).
fn check_files(main: &Path) -> Result<(), MujocoError> {
    let refused = |reason: String| MujocoError::Model {
        path: main.display().to_string(),
        reason,
    };
    let folder = main.parent().unwrap_or(Path::new("."));
    let mut xml = vec![(main.to_path_buf(), 0usize)];
    let mut assets: Vec<(PathBuf, &'static str)> = Vec::new();
    let (mut meshdir, mut texturedir, mut assetdir) = (None, None, None);
    while let Some((file, depth)) = xml.pop() {
        // Errors in an included file name it; the caller names the main one.
        let within = |e: String| match depth {
            0 => e,
            _ => format!("included {}: {e}", file.display()),
        };
        let text = crate::read_text(&file).map_err(|e| refused(within(e.to_string())))?;
        let doc =
            roxmltree::Document::parse(&text).map_err(|e| refused(within(format!("not valid XML: {e}"))))?;
        for node in doc.descendants().filter(roxmltree::Node::is_element) {
            let attr = |a: &str| node.attribute(a).map(PathBuf::from);
            match node.tag_name().name() {
                "include" => {
                    let Some(f) = attr("file") else { continue };
                    if depth + 1 > MAX_INCLUDE_DEPTH {
                        return Err(refused(within(format!(
                            "includes nest deeper than {MAX_INCLUDE_DEPTH}"
                        ))));
                    }
                    xml.push((folder.join(f), depth + 1));
                }
                "compiler" => {
                    meshdir = meshdir.or(attr("meshdir"));
                    texturedir = texturedir.or(attr("texturedir"));
                    assetdir = assetdir.or(attr("assetdir"));
                }
                "mesh" | "skin" => assets.extend(attr("file").map(|f| (f, "mesh"))),
                "hfield" => assets.extend(attr("file").map(|f| (f, "asset"))),
                "texture" => assets.extend(attr("file").map(|f| (f, "texture"))),
                _ => {}
            }
        }
    }
    for (file, kind) in assets {
        let dir = match kind {
            "mesh" => meshdir.as_ref().or(assetdir.as_ref()),
            "texture" => texturedir.as_ref().or(assetdir.as_ref()),
            _ => assetdir.as_ref(),
        };
        let path = match dir {
            Some(d) => folder.join(d).join(&file),
            None => folder.join(&file),
        };
        crate::check_regular_file(&path)
            .map_err(|e| refused(format!("{kind} file {}: {e}", path.display())))?;
    }
    Ok(())
}

/// The kind of a joint.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum JointKind {
    /// A floating base.
    Free,
    /// A ball joint.
    Ball,
    /// A prismatic joint.
    Slide,
    /// A revolute joint.
    Hinge,
}

impl JointKind {
    /// The MJCF `type` attribute's value.
    pub fn name(self) -> &'static str {
        match self {
            Self::Free => "free",
            Self::Ball => "ball",
            Self::Slide => "slide",
            Self::Hinge => "hinge",
        }
    }
}

/// A joint of the compiled model.
#[derive(Debug, Clone, PartialEq)]
pub struct MjcfJoint {
    /// Its kind.
    pub kind: JointKind,
    /// Its range when limited: rad for hinges (whatever the compiler's angle unit), m for slides.
    pub range: Option<(f64, f64)>,
    /// Address of its position in `qpos`.
    pub qpos: usize,
}

/// How an actuator turns its control into force, as MJCF's shortcuts name the common kinds.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ActuatorKind {
    /// `<position>`: force = kp (ctrl − length) − kv · velocity.
    Position {
        /// Stiffness.
        kp: f64,
        /// Damping.
        kv: f64,
    },
    /// `<velocity>`: force = kv (ctrl − velocity).
    Velocity {
        /// Gain.
        kv: f64,
    },
    /// `<motor>`: force = gear-free ctrl.
    Motor,
    /// Anything else (`<general>` with other gains, muscles, PID, DC motors, …).
    Other,
}

impl ActuatorKind {
    /// The MJCF element the kind corresponds to.
    pub fn name(self) -> &'static str {
        match self {
            Self::Position { .. } => "position",
            Self::Velocity { .. } => "velocity",
            Self::Motor => "motor",
            Self::Other => "general",
        }
    }
}

/// An actuator of the compiled model.
#[derive(Debug, Clone, PartialEq)]
pub struct MjcfActuator {
    /// Its name (`actuator<id>` when unnamed).
    pub name: String,
    /// The joint it drives, for joint transmissions.
    pub joint: Option<String>,
    /// What it is.
    pub kind: ActuatorKind,
    /// Its force range, when limited.
    pub force_range: Option<(f64, f64)>,
}

/// A sensor of the compiled model.
#[derive(Debug, Clone, PartialEq)]
pub struct MjcfSensor {
    /// Its name (`sensor<id>` when unnamed).
    pub name: String,
    /// Its type, as the MJCF element names it (`gyro`, `accelerometer`, `framequat`, `touch`, …).
    pub kind: &'static str,
    /// The name of the object it is attached to (a site for IMU sensors), if named.
    pub object: Option<String>,
    /// Address of its values in `sensordata`.
    pub address: usize,
}

/// A keyframe of the compiled model.
#[derive(Debug, Clone, PartialEq)]
pub struct MjcfKeyframe {
    /// Its name (`key<id>` when unnamed).
    pub name: String,
    /// Its `qpos`, the whole model's.
    pub qpos: Vec<f64>,
}

/// What a robot description needs of its compiled model.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct MjcfSummary {
    /// Joints by name.
    pub joints: std::collections::BTreeMap<String, MjcfJoint>,
    /// Body names (the world body left out).
    pub bodies: Vec<String>,
    /// Site names.
    pub sites: Vec<String>,
    /// Actuators, in model order.
    pub actuators: Vec<MjcfActuator>,
    /// Sensors, in model order.
    pub sensors: Vec<MjcfSensor>,
    /// Keyframes, in model order.
    pub keyframes: Vec<MjcfKeyframe>,
    /// The world's planes (the floor), its own or its static bodies', by name (`plane<id>` when
    /// unnamed).
    pub floor: Vec<String>,
    /// Whether the model has a free joint (a floating base).
    pub floating: bool,
    /// Generalised coordinates.
    pub nq: usize,
    /// Meshes the model loaded.
    pub meshes: usize,
}

impl MjcfSummary {
    /// The sensor called `name`.
    pub fn sensor(&self, name: &str) -> Option<&MjcfSensor> {
        self.sensors.iter().find(|s| s.name == name)
    }

    /// The keyframe called `name`.
    pub fn keyframe(&self, name: &str) -> Option<&MjcfKeyframe> {
        self.keyframes.iter().find(|k| k.name == name)
    }

    /// Actuators driving joint `joint` (MJCF name).
    pub fn actuators_of<'a>(&'a self, joint: &'a str) -> impl Iterator<Item = &'a MjcfActuator> + 'a {
        self.actuators
            .iter()
            .filter(move |a| a.joint.as_deref() == Some(joint))
    }

    /// Joints driven by `<position>` actuators.
    pub fn position_actuated(&self) -> impl Iterator<Item = &str> {
        self.actuators
            .iter()
            .filter(|a| matches!(a.kind, ActuatorKind::Position { .. }))
            .filter_map(|a| a.joint.as_deref())
    }
}

/// Compiles `path` with MuJoCo and reads what the robot description cross-checks. Errors name the
/// file and carry MuJoCo's message.
pub fn summarize(path: &Path) -> Result<MjcfSummary, FileError> {
    let model = load_model(path).map_err(|e| FileError {
        path: path.to_path_buf(),
        message: compile_message(e),
    })?;
    Ok(summarize_model(&model))
}

/// What went wrong compiling a model, without the path (the caller names the file).
pub fn compile_message(e: MujocoError) -> String {
    match e {
        MujocoError::Model { reason, .. } => reason,
        other => other.to_string(),
    }
}

/// What the robot description cross-checks, read from a compiled model.
pub fn summarize_model(model: &MjModel) -> MjcfSummary {
    let m = model.ffi();
    let count = |n: i64| usize::try_from(n).unwrap_or(0);
    let name = |kind: MjtObjBase, id: usize, fallback: &str| {
        model
            .id_to_name(kind, id)
            .filter(|n| !n.is_empty())
            .map_or_else(|| format!("{fallback}{id}"), str::to_owned)
    };
    let named = |kind: MjtObjBase, id: usize| {
        model
            .id_to_name(kind, id)
            .filter(|n| !n.is_empty())
            .map(str::to_owned)
    };
    let mut s = MjcfSummary {
        nq: count(m.nq),
        meshes: count(m.nmesh),
        ..MjcfSummary::default()
    };
    for j in 0..count(m.njnt) {
        let kind = match model.jnt_type()[j] {
            mjtJoint::mjJNT_FREE => JointKind::Free,
            mjtJoint::mjJNT_BALL => JointKind::Ball,
            mjtJoint::mjJNT_SLIDE => JointKind::Slide,
            mjtJoint::mjJNT_HINGE => JointKind::Hinge,
        };
        s.floating |= kind == JointKind::Free;
        let [lo, hi] = model.jnt_range()[j];
        let joint = MjcfJoint {
            kind,
            range: model.jnt_limited()[j].then_some((lo, hi)),
            qpos: usize::try_from(model.jnt_qposadr()[j]).unwrap_or(0),
        };
        if let Some(n) = named(MjtObjBase::mjOBJ_JOINT, j) {
            s.joints.insert(n, joint);
        }
    }
    s.bodies = (1..count(m.nbody))
        .filter_map(|b| named(MjtObjBase::mjOBJ_BODY, b))
        .collect();
    s.sites = (0..count(m.nsite))
        .filter_map(|k| named(MjtObjBase::mjOBJ_SITE, k))
        .collect();
    for a in 0..count(m.nu) {
        let gain = model.actuator_gainprm()[a];
        let bias = model.actuator_biasprm()[a];
        let fixed = model.actuator_gaintype()[a] == mjtGain::mjGAIN_FIXED;
        let kind = match model.actuator_biastype()[a] {
            mjtBias::mjBIAS_AFFINE if fixed && bias[1] < 0.0 && (gain[0] + bias[1]).abs() < 1e-9 => {
                ActuatorKind::Position {
                    kp: gain[0],
                    kv: -bias[2],
                }
            }
            mjtBias::mjBIAS_AFFINE if fixed && bias[1] == 0.0 && (gain[0] + bias[2]).abs() < 1e-9 => {
                ActuatorKind::Velocity { kv: gain[0] }
            }
            mjtBias::mjBIAS_NONE if fixed => ActuatorKind::Motor,
            _ => ActuatorKind::Other,
        };
        let joint = (model.actuator_trntype()[a] == mujoco_rs::mujoco_c::mjtTrn::mjTRN_JOINT)
            .then(|| usize::try_from(model.actuator_trnid()[a][0]).ok())
            .flatten()
            .and_then(|j| named(MjtObjBase::mjOBJ_JOINT, j));
        let [lo, hi] = model.actuator_forcerange()[a];
        s.actuators.push(MjcfActuator {
            name: name(MjtObjBase::mjOBJ_ACTUATOR, a, "actuator"),
            joint,
            kind,
            force_range: model.actuator_forcelimited()[a].then_some((lo, hi)),
        });
    }
    for k in 0..count(m.nsensor) {
        let object = usize::try_from(model.sensor_objid()[k])
            .ok()
            .and_then(|id| named(model.sensor_objtype()[k], id));
        s.sensors.push(MjcfSensor {
            name: name(MjtObjBase::mjOBJ_SENSOR, k, "sensor"),
            kind: sensor_kind(model.sensor_type()[k]),
            object,
            address: usize::try_from(model.sensor_adr()[k]).unwrap_or(0),
        });
    }
    // Keyframes' qpos, one row of nq values per key.
    for (k, qpos) in model
        .key_qpos()
        .chunks_exact(s.nq.max(1))
        .take(count(m.nkey))
        .enumerate()
    {
        s.keyframes.push(MjcfKeyframe {
            name: name(MjtObjBase::mjOBJ_KEY, k, "key"),
            qpos: qpos.to_vec(),
        });
    }
    for g in 0..count(m.ngeom) {
        // A plane of the world, or of a static body welded to it (a scene's `floor` body).
        let body = model.geom_bodyid()[g] as usize;
        if model.body_weldid()[body] == 0 && model.geom_type()[g] == _mjtGeomBase::mjGEOM_PLANE {
            s.floor.push(name(MjtObjBase::mjOBJ_GEOM, g, "plane"));
        }
    }
    s
}

/// The MJCF element name of a sensor type.
fn sensor_kind(t: mjtSensor) -> &'static str {
    use mjtSensor as S;
    match t {
        S::mjSENS_TOUCH => "touch",
        S::mjSENS_ACCELEROMETER => "accelerometer",
        S::mjSENS_VELOCIMETER => "velocimeter",
        S::mjSENS_GYRO => "gyro",
        S::mjSENS_FORCE => "force",
        S::mjSENS_TORQUE => "torque",
        S::mjSENS_MAGNETOMETER => "magnetometer",
        S::mjSENS_JOINTPOS => "jointpos",
        S::mjSENS_JOINTVEL => "jointvel",
        S::mjSENS_ACTUATORFRC => "actuatorfrc",
        S::mjSENS_FRAMEPOS => "framepos",
        S::mjSENS_FRAMEQUAT => "framequat",
        S::mjSENS_FRAMELINVEL => "framelinvel",
        S::mjSENS_FRAMEANGVEL => "frameangvel",
        S::mjSENS_FRAMELINACC => "framelinacc",
        S::mjSENS_CONTACT => "contact",
        _ => "other",
    }
}
