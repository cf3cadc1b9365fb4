//! The 64-bit ARM bundle (`scripts/dev bundle --target aarch64-unknown-linux-gnu`) run on this
//! x86_64 machine under Debian's user-mode QEMU, as a user first runs it on an ARM robot computer:
//! `doctor`, `check`, a short lockstep `play` of rd-biped on its mirror, a Dynamixel scan over a
//! pseudo-terminal served by this machine's build, and the recording the ARM build wrote read and
//! replayed by this machine's build.
//!
//! The cross build takes minutes, so plain `cargo test` leaves this out: `scripts/dev test` builds
//! the bundle, names it in `ROBODEPLOY_ARM_BUNDLE` and runs this with `--run-ignored only`.

use std::path::{Path, PathBuf};
use std::time::Instant;

use test_support::bin::{Running, robodeploy, with_checkout_hidden};

/// Debian's user-mode emulator of a 64-bit ARM Linux process (package qemu-user).
const QEMU: &str = "/usr/bin/qemu-aarch64";

/// The ELF header's `e_machine` of a 64-bit ARM binary (EM_AARCH64).
const EM_AARCH64: u16 = 183;

#[test]
#[ignore = "needs the aarch64 bundle: scripts/dev test cross-builds it and runs this with ROBODEPLOY_ARM_BUNDLE set"]
fn the_arm_bundle_checks_plays_scans_and_records_under_qemu() {
    let tarball = PathBuf::from(std::env::var_os("ROBODEPLOY_ARM_BUNDLE").expect(
        "ROBODEPLOY_ARM_BUNDLE names the tarball of `scripts/dev bundle --target aarch64-unknown-linux-gnu` \
         (scripts/dev test builds it and sets this)",
    ));
    assert!(
        Path::new(QEMU).is_file(),
        "{QEMU} is missing: scripts/setup --target aarch64-unknown-linux-gnu installs it"
    );
    let dir = std::env::temp_dir().join(format!("arm-bundle-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    tar::Archive::new(flate2::read::GzDecoder::new(
        std::fs::File::open(&tarball).unwrap(),
    ))
    .unpack(&dir)
    .unwrap();
    let home = dir.join("robodeploy-rd-biped");
    let exe = home.join("bin/robodeploy");

    // A binary for 64-bit ARM, naming no folder of the machine that built it (the checkout,
    // cargo's and rustup's homes), its libraries looked for beside it only.
    let bytes = std::fs::read(&exe).unwrap();
    assert_eq!(&bytes[..4], b"\x7fELF");
    assert_eq!(u16::from_le_bytes([bytes[18], bytes[19]]), EM_AARCH64);
    let user_home = std::env::var("HOME").unwrap_or_else(|_| "/root".into());
    let build_folders = [
        test_support::fixtures::workspace_root().display().to_string(),
        std::env::var("CARGO_HOME").unwrap_or_else(|_| format!("{user_home}/.cargo")),
        std::env::var("RUSTUP_HOME").unwrap_or_else(|_| format!("{user_home}/.rustup")),
    ];
    for folder in &build_folders {
        assert!(
            !bytes.windows(folder.len()).any(|w| w == folder.as_bytes()),
            "the ARM binary names {folder}"
        );
    }
    // Its run path: beside it only (binutils' readelf reads an ELF file of any processor).
    let dynamic = std::process::Command::new("readelf")
        .arg("-d")
        .arg(&exe)
        .output()
        .unwrap();
    let dynamic = String::from_utf8_lossy(&dynamic.stdout);
    let run_paths: Vec<&str> = dynamic
        .lines()
        .filter(|l| l.contains("(RUNPATH)") || l.contains("(RPATH)"))
        .collect();
    assert_eq!(run_paths.len(), 1, "{dynamic}");
    assert!(
        run_paths[0].ends_with("[$ORIGIN/lib:$ORIGIN/../lib]"),
        "{dynamic}"
    );
    // Stripped, and the glibc its README promises is the newest version the binary or a library
    // needs (binutils' objdump, read independently of robodeploy's own ELF reader).
    let sections = std::process::Command::new("readelf")
        .arg("-S")
        .arg(&exe)
        .output()
        .unwrap();
    assert!(
        !String::from_utf8_lossy(&sections.stdout).contains(".symtab"),
        "the ARM binary carries a symbol table"
    );
    let mut floor = (0, 0);
    for file in [
        exe.clone(),
        home.join("lib/libmujoco.so.3.17.0"),
        home.join("lib/libonnxruntime.so.1.31.1"),
    ] {
        let symbols = std::process::Command::new("objdump")
            .arg("-T")
            .arg(&file)
            .output()
            .unwrap();
        for version in String::from_utf8_lossy(&symbols.stdout).split("GLIBC_").skip(1) {
            let mut parts = version
                .split(|c: char| !c.is_ascii_digit())
                .map(str::parse::<u32>);
            if let (Some(Ok(major)), Some(Ok(minor))) = (parts.next(), parts.next()) {
                floor = floor.max((major, minor));
            }
        }
    }
    let readme = std::fs::read_to_string(home.join("README.txt")).unwrap();
    assert!(
        readme.contains("Built for aarch64 Linux")
            && readme.contains(&format!("It needs glibc {}.{} or newer", floor.0, floor.1)),
        "{floor:?}\n{readme}"
    );
    eprintln!(
        "ARM binary: {:.1} MB, bundle {:.1} MB, needs glibc {}.{}",
        bytes.len() as f64 / 1e6,
        std::fs::metadata(&tarball).unwrap().len() as f64 / 1e6,
        floor.0,
        floor.1
    );

    // Each command as the ARM binary under QEMU, from the unpacked folder, the checkout hidden;
    // `preload`: a library QEMU's dynamic loader loads into the ARM process first.
    let arm_with = |preload: Option<&Path>, args: &[&str]| {
        let started = Instant::now();
        let mut command = with_checkout_hidden(&home, Path::new(QEMU));
        if let Some(library) = preload {
            command.arg("-E").arg(format!("LD_PRELOAD={}", library.display()));
        }
        let out = command.arg(&exe).args(args).output().unwrap();
        let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
        let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
        eprintln!(
            "under QEMU: {} ({:.1} s)",
            args.join(" "),
            started.elapsed().as_secs_f64()
        );
        assert!(out.status.success(), "{args:?} failed:\n{stdout}{stderr}");
        stdout
    };
    let arm = |args: &[&str]| arm_with(None, args);

    // doctor: the aarch64 libraries from the wheels load from beside the binary and run a model.
    let doctor = arm(&[
        "doctor",
        "--mjcf",
        "robot/biped.xml",
        "--onnx",
        "policy/reference_follower.onnx",
    ]);
    let libs = home.join("lib");
    assert!(
        doctor.contains(&format!("loaded {}/libmujoco.so.3.17.0", libs.display()))
            && doctor.contains(&format!("loaded {}/libonnxruntime.so.1.31.1", libs.display()))
            && doctor.contains("all checks passed"),
        "{doctor}"
    );

    // check: the bundle's robot, policy and clip, with no flag.
    let check = arm(&["check"]);
    assert!(check.contains("squat"), "{check}");

    // A short lockstep play on the mirror, recorded.
    let play = arm(&["play", "--max-seconds", "2", "--record", "out/arm.mcap"]);
    assert!(play.contains("result: finished"), "{play}");
    let recording = home.join("out/arm.mcap");
    assert!(recording.is_file(), "{play}");

    // The recording the ARM build wrote, replayed by this machine's build through the same
    // controller code: every tick's bus readings decoded and every command compared.
    let replay = robodeploy().arg("replay").arg(&recording).output().unwrap();
    let replayed = String::from_utf8_lossy(&replay.stdout);
    assert!(
        replay.status.success(),
        "{replayed}{}",
        String::from_utf8_lossy(&replay.stderr)
    );
    assert!(
        replayed.contains("every command matches the recording bit for bit"),
        "{replayed}"
    );
    eprintln!("replayed on x86_64: {replayed}");

    // A Dynamixel bus served on a pseudo-terminal by this machine's build, scanned by the ARM one.
    let mut emulate = Running::start(&[
        "dxl",
        "emulate",
        "--servo",
        "1:XM430-W350",
        "--servo",
        "3:XL430-W250",
        "--baud",
        "1000000",
        "--seconds",
        "120",
    ]);
    let pty = emulate.wait_for_pty();
    // QEMU 10.0 does not translate the termios2 ioctls serial2 sets the bit rate with (a real ARM
    // kernel has them): tests/qemu/termios2_shim.c serves them with plain termios for the scan.
    let shim = dir.join("termios2_shim.so");
    let built = std::process::Command::new("aarch64-linux-gnu-gcc")
        .args(["-Wall", "-Werror", "-shared", "-fPIC", "-O2", "-o"])
        .arg(&shim)
        .arg(test_support::fixtures::workspace_root().join("tests/qemu/termios2_shim.c"))
        .status()
        .unwrap();
    assert!(built.success(), "the termios2 shim did not build");
    let scan = arm_with(
        Some(&shim),
        &["dxl", "scan", "--port", &pty, "--baud", "1000000", "--ids", "1-4"],
    );
    emulate.kill();
    assert!(scan.contains("2 servo(s) answered out of 4 asked"), "{scan}");
    assert!(
        scan.contains("   1   XM430-W350") && scan.contains("   3   XL430-W250"),
        "{scan}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}
