//! `robodeploy bundle`: what a run needs, in one tarball for another machine: of this machine's
//! architecture, or a 64-bit ARM robot computer (`--target aarch64-unknown-linux-gnu`).
//!
//! ```text
//! robodeploy-ROBOT/
//!   bin/robodeploy                 this binary (its run path looks in ../lib first)
//!   lib/libmujoco.so.3.17.0        the native libraries it loads
//!   lib/libonnxruntime.so.1.31.1
//!   robot/                         the robot's folder: robot.toml, MJCF, meshes, calibration.toml
//!   policy/                        the policy's folder: manifest(s) and ONNX files
//!   clips/                         the clips asked for
//!   bundle.toml                    what bin/robodeploy runs given no --robot, --policy, --clip
//!   README.txt                     how to run it
//! ```
//!
//! The binary packed is the one running, or with `--target` the checkout's cross build for that
//! architecture: a bundle build either way (`scripts/dev bundle [--target …]`: release, no
//! symbols, no folder of the build machine in it, its libraries found beside it). A development
//! build is refused unless asked for (`--allow-dev-build`, for trying a bundle on this machine).
//! A cross build and its libraries are checked to be ELF files for the target's processor.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use clap::Args;

/// The libraries the binary loads, by the file names it asks for.
const LIBRARIES: [&str; 2] = ["libmujoco.so.3.17.0", "libonnxruntime.so.1.31.1"];

/// Largest folder packed whole, bytes: a robot or policy folder is descriptions and models.
const MAX_FOLDER_BYTES: u64 = 512 * 1024 * 1024;

/// Arguments of `bundle`.
#[derive(Debug, Args)]
pub struct BundleArgs {
    /// The robot description; its whole folder is packed.
    #[arg(long, default_value_os_t = robots::locate::default_robot())]
    robot: PathBuf,
    /// The policy (manifest or ONNX export); its whole folder is packed.
    /// Default: the policy robot.toml names (`policy = "policies/…"`).
    #[arg(long)]
    policy: Option<PathBuf>,
    /// Clips to pack (repeat or list).
    #[arg(long, num_args = 0..)]
    clip: Vec<PathBuf>,
    /// The tarball to write (gzipped); outside the folders it packs, and not over an existing
    /// file unless --overwrite.
    #[arg(long, default_value = "out/robodeploy-bundle.tar.gz")]
    out: PathBuf,
    /// Replace an existing --out.
    #[arg(long)]
    overwrite: bool,
    /// Pack the build for another kind of computer instead of this binary: this checkout's
    /// cross build `target/TRIPLE/bundle/robodeploy` with that architecture's libraries from
    /// `.local/TRIPLE/lib`. `scripts/dev bundle --target aarch64-unknown-linux-gnu …` builds both
    /// and packs them (a 64-bit ARM robot computer: Jetson Orin, Raspberry Pi 5, RK3588 boards).
    #[arg(long, value_name = "TRIPLE")]
    target: Option<Target>,
    /// Pack this binary even if it is a development build (debug checks on, symbols, folders of
    /// this machine inside): a bundle to try on this machine. Bundles for a robot come from
    /// `scripts/dev bundle`.
    #[arg(long)]
    allow_dev_build: bool,
}

/// A computer a bundle is cross-built for, by its Rust target triple.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Target {
    /// 64-bit ARM Linux: Jetson Orin (inside a Unitree G1), Raspberry Pi 5, Rockchip boards.
    #[value(name = "aarch64-unknown-linux-gnu")]
    Aarch64Linux,
}

impl Target {
    fn triple(self) -> &'static str {
        match self {
            Self::Aarch64Linux => "aarch64-unknown-linux-gnu",
        }
    }

    fn arch(self) -> &'static str {
        match self {
            Self::Aarch64Linux => "aarch64",
        }
    }

    /// The ELF header's `e_machine` of its binaries.
    fn elf_machine(self) -> u16 {
        match self {
            Self::Aarch64Linux => object::elf::EM_AARCH64,
        }
    }
}

/// What an ELF file says of itself, as far as packing needs.
struct ElfFacts {
    /// The processor it is for (`e_machine`).
    machine: u16,
    /// It still carries a symbol table (not stripped).
    symbols: bool,
    /// The newest glibc symbol version it needs (`GLIBC_2.35` → (2, 35)): the oldest C library
    /// it starts with.
    glibc: Option<(u32, u32)>,
}

/// Reads a 64-bit ELF file's header, section table and version needs.
fn elf_facts(path: &Path, bytes: &[u8]) -> Result<ElfFacts> {
    use object::read::elf::{FileHeader, SectionHeader};
    let unreadable = |e: object::read::Error| {
        anyhow::Error::new(robots::FileError::new(
            path,
            format!("not a readable 64-bit ELF file: {e}"),
        ))
    };
    let header = object::elf::FileHeader64::<object::Endianness>::parse(bytes).map_err(unreadable)?;
    let endian = header.endian().map_err(unreadable)?;
    let sections = header.sections(endian, bytes).map_err(unreadable)?;
    let symbols = sections
        .iter()
        .any(|s| s.sh_type(endian) == object::elf::SHT_SYMTAB);
    let mut glibc = None;
    if let Some((mut needs, names_at)) = sections.gnu_verneed(endian, bytes).map_err(unreadable)? {
        let names = sections.strings(endian, bytes, names_at).map_err(unreadable)?;
        while let Some((_, mut versions)) = needs.next().map_err(unreadable)? {
            while let Some(version) = versions.next().map_err(unreadable)? {
                let name = version.name(endian, names).map_err(unreadable)?;
                glibc = glibc.max(glibc_version(name));
            }
        }
    }
    Ok(ElfFacts {
        machine: header.e_machine(endian),
        symbols,
        glibc,
    })
}

/// `GLIBC_2.35` → (2, 35); `GLIBC_2.2.5` → (2, 2); other version names → `None`.
fn glibc_version(name: &[u8]) -> Option<(u32, u32)> {
    let rest = std::str::from_utf8(name).ok()?.strip_prefix("GLIBC_")?;
    let (major, minor) = rest.split_once('.')?;
    Some((major.parse().ok()?, minor.split('.').next()?.parse().ok()?))
}

/// The oldest glibc every file of a build starts with: the newest version any of them needs.
fn glibc_floor(build: &Build) -> Result<Option<(u32, u32)>> {
    let mut floor = None;
    for path in std::iter::once(&build.exe).chain(build.libraries.iter().map(|(_, p)| p)) {
        let bytes = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
        floor = floor.max(elf_facts(path, &bytes)?.glibc);
    }
    Ok(floor)
}

/// What goes into `bin/` and `lib/`: a binary, the libraries it loads, the processor it runs on.
struct Build {
    exe: PathBuf,
    libraries: Vec<(&'static str, PathBuf)>,
    arch: &'static str,
    /// Debug checks compiled in (known for the running binary only; a cross build is taken from
    /// the bundle profile's folder).
    debug_checks: bool,
}

impl Build {
    /// The running binary and the libraries it found.
    fn this_binary() -> Result<Self> {
        let exe = std::env::current_exe().context("cannot find this binary")?;
        let mut libraries = Vec::new();
        for name in LIBRARIES {
            let found = policy::native::search_dirs()
                .into_iter()
                .map(|d| d.join(name))
                .find(|p| p.is_file())
                .with_context(|| {
                    format!("{name} is not beside the binary nor in .local/lib: run scripts/setup")
                })?;
            libraries.push((name, found));
        }
        Ok(Self {
            exe,
            libraries,
            arch: std::env::consts::ARCH,
            debug_checks: cfg!(debug_assertions),
        })
    }

    /// The checkout's cross build for `target` and that architecture's libraries, each checked
    /// to be an ELF file for the target's processor.
    fn cross(target: Target) -> Result<Self> {
        let triple = target.triple();
        let how = format!("`scripts/dev bundle --target {triple} …` cross-builds it and packs it");
        let checkout = robots::locate::checkout().ok_or_else(|| {
            crate::args::FlagError::new(
                "target",
                format!(
                    " {triple}: this robodeploy is not in a checkout, where cross builds are made; {how}"
                ),
            )
        })?;
        let exe = checkout.join("target").join(triple).join("bundle/robodeploy");
        let local = checkout.join(".local").join(triple).join("lib");
        let wanted = std::iter::once(("robodeploy", exe.clone()))
            .chain(LIBRARIES.iter().map(|name| (*name, local.join(name))));
        let mut libraries = Vec::new();
        for (name, path) in wanted {
            if !path.is_file() {
                bail!(crate::args::FlagError::new(
                    "target",
                    format!(" {triple}: {} is not there; {how}", path.display())
                ));
            }
            let bytes = std::fs::read(&path).with_context(|| format!("cannot read {}", path.display()))?;
            let machine = elf_facts(&path, &bytes)?.machine;
            if machine != target.elf_machine() {
                bail!(robots::FileError::new(
                    &path,
                    format!(
                        "an ELF file for machine {machine}, not for {} ({}): rebuild it with {how}",
                        target.arch(),
                        target.elf_machine()
                    )
                ));
            }
            if name != "robodeploy" {
                libraries.push((name, path));
            }
        }
        Ok(Self {
            exe,
            libraries,
            arch: target.arch(),
            debug_checks: false,
        })
    }
}

/// Why a binary is no bundle build, or `None` when it is one: debug checks compiled in, a symbol
/// table, or folders of this machine named in its bytes (the checkout it was built in, the cargo
/// registry its dependencies came from: panic messages and run paths carry them).
fn dev_build_reasons(build: &Build) -> Result<Option<String>> {
    let exe = &build.exe;
    let mut why = Vec::new();
    if build.debug_checks {
        why.push("debug checks are compiled in".to_owned());
    }
    let bytes = std::fs::read(exe).with_context(|| format!("cannot read {}", exe.display()))?;
    if elf_facts(exe, &bytes)?.symbols {
        why.push("it carries a symbol table".to_owned());
    }
    let cargo_home = std::env::var_os("CARGO_HOME")
        .map(PathBuf::from)
        .or_else(|| std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".cargo")));
    for folder in robots::locate::checkout().into_iter().chain(cargo_home) {
        let needle = folder.to_string_lossy().into_owned();
        let count = bytes
            .windows(needle.len())
            .filter(|w| *w == needle.as_bytes())
            .count();
        if count > 0 {
            why.push(format!("it names {needle} {count} times"));
        }
    }
    Ok((!why.is_empty()).then(|| why.join(", ")))
}

/// Runs `bundle`.
pub fn run(args: &BundleArgs) -> Result<()> {
    // Load both as a run would: a bundle of files that do not load helps nobody.
    let robot = robots::Robot::load(&args.robot)?;
    let policy = crate::args::policy_of(args.policy.as_deref(), &robot)?;
    let layout = policy::PolicyLayout::load(&policy, &robot)?;
    let robot_dir = folder_of(&args.robot)?;
    let policy_dir = folder_of(&policy)?;
    // Compared resolved, as the folders are (a relative --policy names the same files).
    let onnx = std::fs::canonicalize(&layout.onnx_path).unwrap_or_else(|_| layout.onnx_path.clone());
    if !onnx.starts_with(&policy_dir) {
        bail!(
            "--policy {}: its ONNX file {} lies outside the policy's folder, which is what is packed",
            policy.display(),
            layout.onnx_path.display()
        );
    }
    let mjcf = std::fs::canonicalize(&robot.mjcf_path).unwrap_or_else(|_| robot.mjcf_path.clone());
    if !mjcf.starts_with(&robot_dir) {
        bail!(
            "--robot {}: its MJCF {} lies outside the robot's folder, which is what is packed",
            args.robot.display(),
            mjcf.display()
        );
    }
    for dir in [&robot_dir, &policy_dir] {
        let size = folder_bytes(dir)?;
        if size > MAX_FOLDER_BYTES {
            bail!(
                "{}: {} MB is more than a robot or policy folder should hold (at most {} MB)",
                dir.display(),
                size / 1_000_000,
                MAX_FOLDER_BYTES / 1_000_000
            );
        }
    }
    let build = match args.target {
        None => Build::this_binary()?,
        Some(target) => Build::cross(target)?,
    };
    let exe = &build.exe;
    let dev_build = dev_build_reasons(&build)?;
    let glibc = glibc_floor(&build)?;
    match (&dev_build, args.allow_dev_build) {
        (Some(why), false) => bail!(crate::args::FlagError::new(
            "allow-dev-build",
            format!(
                " is not given, and the robodeploy to pack ({}, {:.0} MB) is a development build: {why}. \
                 Bundle a release build: `scripts/dev bundle [--target …] --robot … --out …` builds \
                 one without symbols or this machine's folders and packs it",
                exe.display(),
                std::fs::metadata(exe).map_or(0.0, |m| m.len() as f64 / 1e6)
            )
        )),
        (Some(why), true) => eprintln!("bundle: packing a development build ({why}): for this machine only"),
        (None, _) => {}
    }
    check_out(&args.out, args.overwrite, &[&robot_dir, &policy_dir])?;
    let mut seen_names: Vec<(String, &Path)> = Vec::new();
    for c in &args.clip {
        if !c.is_file() {
            bail!(robots::FileError::new(c, "--clip: not a file"));
        }
        // A clip is packed only if it reads as one.
        controller::clip::Clip::load(c)?;
        let name = file_name(c);
        if let Some((_, other)) = seen_names.iter().find(|(n, _)| *n == name) {
            bail!(robots::FileError::new(
                c,
                format!(
                    "--clip: its name {name:?} is also {}'s: both would be clips/{name} in the bundle",
                    other.display()
                )
            ));
        }
        seen_names.push((name, c));
    }

    let top = format!("robodeploy-{}", robot.config.name);
    if let Some(dir) = args.out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    }
    let file =
        std::fs::File::create(&args.out).with_context(|| format!("cannot create {}", args.out.display()))?;
    let mut tar = tar::Builder::new(flate2::write::GzEncoder::new(
        file,
        flate2::Compression::default(),
    ));
    // Symbolic links inside the folders are packed as the files they point to.
    tar.follow_symlinks(true);
    let add = |tar: &mut tar::Builder<_>, from: &Path, to: String| -> Result<()> {
        tar.append_path_with_name(from, &to)
            .with_context(|| format!("cannot pack {}", from.display()))
    };
    add(&mut tar, exe, format!("{top}/bin/robodeploy"))?;
    for (name, path) in &build.libraries {
        add(&mut tar, path, format!("{top}/lib/{name}"))?;
    }
    tar.append_dir_all(format!("{top}/robot"), &robot_dir)
        .with_context(|| format!("cannot pack {}", robot_dir.display()))?;
    tar.append_dir_all(format!("{top}/policy"), &policy_dir)
        .with_context(|| format!("cannot pack {}", policy_dir.display()))?;
    let mut clip_names = Vec::new();
    for c in &args.clip {
        let name = c
            .file_name()
            .map_or_else(|| "clip".into(), |n| n.to_string_lossy().into_owned());
        add(&mut tar, c, format!("{top}/clips/{name}"))?;
        // A clip's motion sidecar travels with it.
        let sidecar = c.with_file_name(format!("{name}.motion.toml"));
        if sidecar.is_file() {
            add(&mut tar, &sidecar, format!("{top}/clips/{name}.motion.toml"))?;
        }
        clip_names.push(name);
    }
    let robot_file = file_name(&args.robot);
    let policy_file = file_name(&policy);
    let clip_arg = clip_names
        .first()
        .map_or_else(String::new, |c| format!(" and clips/{c}"));
    let defaults = robots::locate::BundleDefaults {
        robot: PathBuf::from(format!("robot/{robot_file}")),
        policy: PathBuf::from(format!("policy/{policy_file}")),
        clip: clip_names.first().map(|c| PathBuf::from(format!("clips/{c}"))),
    };
    let defaults_toml = format!(
        "# Written by robodeploy bundle: what bin/robodeploy runs when given no --robot, --policy or\n\
         # --clip (paths relative to this folder).\n{}",
        toml::to_string(&defaults).context("writing bundle.toml")?
    );
    let mut header = tar::Header::new_gnu();
    header.set_size(defaults_toml.len() as u64);
    header.set_mode(0o644);
    header.set_cksum();
    tar.append_data(
        &mut header,
        format!("{top}/{}", robots::locate::BUNDLE_FILE),
        defaults_toml.as_bytes(),
    )
    .context("cannot pack bundle.toml")?;
    let readme = format!(
        "robodeploy bundle: {robot_name}, policy {policy_file}\n\
         Built for {arch} Linux. Unpack anywhere; nothing else is needed (no environment variable,\n\
         no checkout). bin/robodeploy runs robot/{robot_file} with policy/{policy_file}{clip_arg}\n\
         when given no --robot, --policy or --clip (bundle.toml says so):\n\n  \
         ./bin/robodeploy doctor --mjcf robot/{mjcf} --onnx policy/{onnx}\n  \
         ./bin/robodeploy doctor --realtime    # can this computer hold the loop? (10 s)\n  \
         ./bin/robodeploy check\n  \
         ./bin/robodeploy play                 # on the mirror, lockstep\n  \
         ./bin/robodeploy play --hardware      # on the robot's buses from robot/{robot_file}\n\n\
         bin/robodeploy loads lib/libmujoco.so.3.17.0 and lib/libonnxruntime.so.1.31.1 from beside it.\n\
         {needs}",
        robot_name = robot.config.name,
        arch = build.arch,
        needs = glibc.map_or_else(String::new, |(major, minor)| format!(
            "It needs glibc {major}.{minor} or newer on that computer (`ldd --version` shows its own).\n"
        )),
        mjcf = mjcf.strip_prefix(&robot_dir).unwrap_or(&mjcf).display(),
        onnx = layout
            .onnx_path
            .strip_prefix(&policy_dir)
            .unwrap_or(&layout.onnx_path)
            .display(),
    );
    let mut header = tar::Header::new_gnu();
    header.set_size(readme.len() as u64);
    header.set_mode(0o644);
    header.set_cksum();
    tar.append_data(&mut header, format!("{top}/README.txt"), readme.as_bytes())
        .context("cannot pack README.txt")?;
    let gz = tar.into_inner().context("cannot finish the tarball")?;
    gz.finish().context("cannot finish the tarball")?;
    let size = std::fs::metadata(&args.out).map_or(0, |m| m.len());
    println!(
        "bundle: {} ({:.1} MB, for {} Linux): {top}/ with bin/, lib/, robot/, policy/{}",
        args.out.display(),
        size as f64 / 1e6,
        build.arch,
        if clip_names.is_empty() { "" } else { ", clips/" }
    );
    print!("{readme}");
    Ok(())
}

/// Refuses an `out` inside a folder it packs (the tarball would pack itself as it grows, or
/// overwrite a packed file), and an existing one unless `overwrite`.
fn check_out(out: &Path, overwrite: bool, packed: &[&PathBuf]) -> Result<()> {
    let parent = out
        .parent()
        .filter(|d| !d.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    // The folder may not exist yet: resolve the deepest part that does.
    let mut existing = parent.to_path_buf();
    let mut rest = Vec::new();
    while !existing.exists() {
        match (existing.file_name().map(ToOwned::to_owned), existing.parent()) {
            (Some(name), Some(up)) => {
                rest.push(name);
                existing = up.to_path_buf();
            }
            _ => break,
        }
    }
    let mut resolved = std::fs::canonicalize(if existing.as_os_str().is_empty() {
        Path::new(".")
    } else {
        &existing
    })
    .with_context(|| format!("cannot resolve {}", parent.display()))?;
    for name in rest.into_iter().rev() {
        resolved.push(name);
    }
    if let Some(dir) = packed.iter().find(|d| resolved.starts_with(d)) {
        bail!(robots::FileError::new(
            out,
            format!(
                "--out lies inside {}, which the bundle packs: write it elsewhere",
                dir.display()
            )
        ));
    }
    if out.exists() && !overwrite {
        bail!(robots::FileError::new(
            out,
            "--out: a file is there already; give another path, or --overwrite"
        ));
    }
    Ok(())
}

/// The folder a file is in, resolved.
fn folder_of(file: &Path) -> Result<PathBuf> {
    let file = std::fs::canonicalize(file).with_context(|| format!("cannot find {}", file.display()))?;
    Ok(file
        .parent()
        .map_or_else(|| PathBuf::from("/"), Path::to_path_buf))
}

fn file_name(p: &Path) -> String {
    p.file_name()
        .map_or_else(String::new, |n| n.to_string_lossy().into_owned())
}

/// Bytes of the regular files under `dir`.
fn folder_bytes(dir: &Path) -> Result<u64> {
    let mut total = 0;
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for entry in std::fs::read_dir(&d).with_context(|| format!("cannot read {}", d.display()))? {
            let entry = entry?;
            let meta = entry.metadata()?;
            if meta.is_dir() {
                stack.push(entry.path());
            } else {
                total += meta.len();
            }
        }
    }
    Ok(total)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn glibc_versions_are_read_from_their_symbol_version_names() {
        assert_eq!(glibc_version(b"GLIBC_2.35"), Some((2, 35)));
        assert_eq!(glibc_version(b"GLIBC_2.2.5"), Some((2, 2)));
        assert_eq!(glibc_version(b"GLIBC_PRIVATE"), None);
        assert_eq!(glibc_version(b"GCC_3.0"), None);
        assert!(glibc_version(b"GLIBC_2.17") < glibc_version(b"GLIBC_2.35"));
    }

    #[test]
    fn an_elf_file_tells_its_processor_symbols_and_glibc_and_other_files_are_refused_by_name() {
        // This test binary: built here, for this processor, with symbols, against this glibc.
        let exe = std::env::current_exe().unwrap();
        let facts = elf_facts(&exe, &std::fs::read(&exe).unwrap()).unwrap();
        let this_machine = match std::env::consts::ARCH {
            "aarch64" => object::elf::EM_AARCH64,
            _ => object::elf::EM_X86_64,
        };
        assert_eq!(facts.machine, this_machine);
        assert!(facts.symbols);
        assert!(facts.glibc >= Some((2, 17)), "{:?}", facts.glibc);
        let text = Path::new("robot.toml");
        let err = elf_facts(text, b"name = \"rd-biped\"\n").err().unwrap();
        assert!(
            format!("{err:#}").contains("robot.toml") && format!("{err:#}").contains("ELF"),
            "{err:#}"
        );
    }
}
