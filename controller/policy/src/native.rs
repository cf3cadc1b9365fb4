//! Finds the pinned ONNX Runtime library without any variable set by the user.
//!
//! `scripts/setup` copies `libonnxruntime.so.1.31.1` out of the `onnxruntime==1.31.1` wheel into the
//! workspace's `.local/lib`. A binary looks for it, in order:
//! 1. `lib/` beside the executable or one level up (an installed deployment: `bin/` + `lib/`);
//! 2. the `.local/lib` of the checkout the binary sits in (`target/…`), found from its own place.

use std::path::{Path, PathBuf};

/// File name of the pinned ONNX Runtime (ort 2.0.0-rc.15 with `api-31`).
pub const ONNXRUNTIME_FILE: &str = "libonnxruntime.so.1.31.1";

/// Where a library file is looked for, most specific first (found from the executable's place:
/// no path of the build machine is compiled in).
pub fn search_dirs() -> Vec<PathBuf> {
    robots::locate::library_dirs()
}

/// The version ONNX Runtime reports for itself (`OrtGetApiBase()->GetVersionString()`), read from the
/// library file at `path` without initialising it. Used to refuse a mislabelled or wrong library
/// before ort binds to it.
pub fn onnxruntime_version(path: &Path) -> Result<String, robots::FileError> {
    #[allow(unsafe_code)] // dlopen of the library ort is about to load anyway, and one C getter call
    // SAFETY: loading runs the library's initialisers, exactly as ort's own load would; the symbol
    // has the documented C signature `const OrtApiBase* OrtGetApiBase(void)`, whose
    // `GetVersionString` returns a static NUL-terminated string.
    unsafe {
        let lib = libloading::Library::new(path)
            .map_err(|e| robots::FileError::new(path, format!("cannot load: {e}")))?;
        let get_base: libloading::Symbol<'_, unsafe extern "C" fn() -> *const ort::sys::OrtApiBase> = lib
            .get(b"OrtGetApiBase\0")
            .map_err(|_| robots::FileError::new(path, "does not export OrtGetApiBase: not ONNX Runtime"))?;
        let base = get_base();
        if base.is_null() {
            return Err(robots::FileError::new(path, "OrtGetApiBase returned null"));
        }
        let version = std::ffi::CStr::from_ptr(((*base).GetVersionString)());
        Ok(version.to_string_lossy().into_owned())
    }
}

/// The pinned ONNX Runtime release.
pub const ONNXRUNTIME_VERSION: &str = "1.31.1";

/// The library could not be found where the project installs it.
#[derive(Debug, thiserror::Error)]
#[error(
    "{file} not found (looked in: {searched}). Run `scripts/setup` from the workspace root: it installs \
     the pinned native libraries into .local/lib{other}"
)]
pub struct MissingLibrary {
    /// The versioned file name that was looked for.
    pub file: &'static str,
    /// The folders searched, joined for display.
    pub searched: String,
    /// A note about other versions found instead, if any.
    pub other: String,
}

/// Finds the pinned ONNX Runtime library file.
pub fn find_onnxruntime() -> Result<PathBuf, MissingLibrary> {
    find_library(&search_dirs(), ONNXRUNTIME_FILE, "libonnxruntime.so.")
}

/// Finds `file` in the first of `dirs` that holds it; on failure, names other versions of the
/// same library (files starting with `family_prefix`) so a wrong version is told from a missing one.
pub fn find_library(
    dirs: &[PathBuf],
    file: &'static str,
    family_prefix: &str,
) -> Result<PathBuf, MissingLibrary> {
    if let Some(found) = dirs.iter().map(|d| d.join(file)).find(|p| p.is_file()) {
        return Ok(found);
    }
    let others: Vec<String> = dirs
        .iter()
        .filter_map(|d| std::fs::read_dir(d).ok())
        .flatten()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with(family_prefix) && n != file)
        .collect();
    Err(MissingLibrary {
        file,
        searched: dirs
            .iter()
            .map(|d| d.display().to_string())
            .collect::<Vec<_>>()
            .join(", "),
        other: if others.is_empty() {
            String::new()
        } else {
            format!(
                " (found other versions, which this build does not use: {})",
                others.join(", ")
            )
        },
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn temp_dir(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("robodeploy-native-{}-{name}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    #[test]
    fn missing_library_names_the_fix() {
        let dir = temp_dir("missing");
        let err =
            find_library(std::slice::from_ref(&dir), ONNXRUNTIME_FILE, "libonnxruntime.so.").unwrap_err();
        let msg = err.to_string();
        assert!(msg.contains("libonnxruntime.so.1.31.1 not found"), "{msg}");
        assert!(msg.contains("scripts/setup"), "{msg}");
        assert!(msg.contains(&dir.display().to_string()), "{msg}");
    }

    #[test]
    fn wrong_version_is_named() {
        let dir = temp_dir("wrong");
        std::fs::write(dir.join("libonnxruntime.so.1.20.0"), b"").unwrap();
        let err =
            find_library(std::slice::from_ref(&dir), ONNXRUNTIME_FILE, "libonnxruntime.so.").unwrap_err();
        assert!(
            err.to_string()
                .contains("found other versions, which this build does not use: libonnxruntime.so.1.20.0")
        );
    }

    #[test]
    fn first_directory_holding_the_file_wins() {
        let (a, b) = (temp_dir("a"), temp_dir("b"));
        std::fs::write(b.join(ONNXRUNTIME_FILE), b"").unwrap();
        let found = find_library(&[a, b.clone()], ONNXRUNTIME_FILE, "libonnxruntime.so.").unwrap();
        assert_eq!(found, b.join(ONNXRUNTIME_FILE));
    }

    #[test]
    fn workspace_install_is_found_and_is_the_pinned_release() {
        let found = find_onnxruntime().expect("scripts/setup installs the library");
        assert!(found.ends_with(ONNXRUNTIME_FILE));
        assert_eq!(onnxruntime_version(&found).unwrap(), ONNXRUNTIME_VERSION);
    }

    #[test]
    fn a_file_that_is_not_onnxruntime_is_refused() {
        let dir = temp_dir("fake");
        let fake = dir.join(ONNXRUNTIME_FILE);
        std::fs::write(&fake, b"not an ELF file").unwrap();
        let err = onnxruntime_version(&fake).unwrap_err().to_string();
        assert!(err.contains(&fake.display().to_string()), "{err}");
    }
}
