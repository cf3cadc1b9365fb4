//! Just enough of NumPy's `.npy` format (and `.npz`, a zip of them) to read clips: little-endian
//! float and integer arrays, and unicode string arrays, in C order.

use std::collections::BTreeMap;
use std::io::Read;
use std::path::Path;

/// One array from an `.npz` file.
#[derive(Debug, Clone, PartialEq)]
pub enum NpyArray {
    /// Numbers (floats or integers), widened to f64, with their shape.
    Numbers {
        /// Dimensions.
        shape: Vec<usize>,
        /// Values in C order.
        data: Vec<f64>,
    },
    /// Strings (`<U` dtype), with their shape.
    Strings {
        /// Dimensions.
        shape: Vec<usize>,
        /// Values in C order.
        data: Vec<String>,
    },
}

/// Why a NumPy file cannot be read: the file (`None` for bytes in memory) and what is wrong.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{}{message}", file.as_ref().map(|f| format!("{}: ", f.display())).unwrap_or_default())]
pub struct NpyError {
    /// The file.
    pub file: Option<std::path::PathBuf>,
    /// What is wrong.
    pub message: String,
}

impl From<String> for NpyError {
    fn from(message: String) -> Self {
        Self { file: None, message }
    }
}

impl From<&str> for NpyError {
    fn from(message: &str) -> Self {
        message.to_owned().into()
    }
}

/// Reads every array of an `.npz` file by name (without the `.npy` suffix).
pub fn read_npz(path: &Path) -> Result<BTreeMap<String, NpyArray>, NpyError> {
    read_npz_entries(path).map_err(|e| NpyError {
        file: Some(path.to_path_buf()),
        message: e.message,
    })
}

fn read_npz_entries(path: &Path) -> Result<BTreeMap<String, NpyArray>, NpyError> {
    robots::check_regular_file(path).map_err(|e| e.to_string())?;
    let file = std::fs::File::open(path).map_err(|e| format!("cannot open: {e}"))?;
    let mut zip = zip::ZipArchive::new(file).map_err(|e| format!("not an .npz (zip) file: {e}"))?;
    let mut out = BTreeMap::new();
    for i in 0..zip.len() {
        let mut entry = zip.by_index(i).map_err(|e| format!("entry {i}: {e}"))?;
        let name = entry.name().trim_end_matches(".npy").to_owned();
        let mut bytes = Vec::with_capacity(entry.size() as usize);
        entry
            .read_to_end(&mut bytes)
            .map_err(|e| format!("{name}: {e}"))?;
        out.insert(
            name.clone(),
            parse_npy(&bytes).map_err(|e| format!("array {name:?}: {e}"))?,
        );
    }
    Ok(out)
}

/// Parses one `.npy` document.
pub fn parse_npy(bytes: &[u8]) -> Result<NpyArray, NpyError> {
    if bytes.len() < 10 || &bytes[..6] != b"\x93NUMPY" {
        return Err("not an .npy array (bad magic)".into());
    }
    let (header_len, start) = match bytes[6] {
        1 => (usize::from(u16::from_le_bytes([bytes[8], bytes[9]])), 10),
        2 | 3 if bytes.len() >= 12 => (
            u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize,
            12,
        ),
        v => return Err(format!("unsupported .npy version {v}").into()),
    };
    let header = bytes
        .get(start..start + header_len)
        .and_then(|h| std::str::from_utf8(h).ok())
        .ok_or("truncated or non-text header")?;
    let descr = field(header, "descr").ok_or("header has no 'descr'")?;
    let quote = descr
        .chars()
        .next()
        .filter(|c| *c == '\'' || *c == '"')
        .ok_or("malformed 'descr'")?;
    let descr = &descr[1..];
    let descr = &descr[..descr.find(quote).ok_or("malformed 'descr'")?];
    if field(header, "fortran_order").is_some_and(|f| f.starts_with("True")) {
        return Err("Fortran-order arrays are not supported".into());
    }
    let shape_text = field(header, "shape").ok_or("header has no 'shape'")?;
    let inner = shape_text.trim().trim_start_matches('(');
    let inner = &inner[..inner.find(')').ok_or("malformed shape")?];
    let shape: Vec<usize> = inner
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| {
            s.parse::<usize>()
                .map_err(|_| format!("malformed shape {shape_text:?}"))
        })
        .collect::<Result<_, _>>()?;
    let count = shape
        .iter()
        .try_fold(1usize, |n, &d| n.checked_mul(d))
        .ok_or_else(|| format!("shape {shape:?} is too large"))?;
    let data = &bytes[start + header_len..];
    let unsupported = || format!("unsupported dtype {descr:?} (need <f4, <f8, <i4, <i8 or <U)");
    if !descr.is_char_boundary(2.min(descr.len())) || descr.len() < 3 {
        return Err(unsupported().into());
    }
    let (kind, size) = descr.split_at(2);
    let size: usize = size.parse().map_err(|_| NpyError::from(unsupported()))?;
    if size == 0 {
        return Err(unsupported().into());
    }
    // A `<U` item is `size` UTF-32 characters; the fuzzer found `<U` sizes whose byte count overflows.
    let item_bytes = if kind.ends_with('U') {
        size.checked_mul(4)
    } else {
        Some(size)
    };
    let need = item_bytes
        .and_then(|b| count.checked_mul(b))
        .ok_or("array too large")?;
    if data.len() < need {
        return Err(format!("{} data bytes for shape {shape:?} of {descr}", data.len()).into());
    }
    let numbers = |f: &dyn Fn(&[u8]) -> f64| NpyArray::Numbers {
        shape: shape.clone(),
        data: data[..need].chunks_exact(size).map(f).collect(),
    };
    Ok(match (kind, size) {
        ("<f" | "|f", 8) => numbers(&|c| f64::from_le_bytes(c.try_into().expect("8 bytes"))),
        ("<f" | "|f", 4) => numbers(&|c| f64::from(f32::from_le_bytes(c.try_into().expect("4 bytes")))),
        ("<i", 8) => numbers(&|c| i64::from_le_bytes(c.try_into().expect("8 bytes")) as f64),
        ("<i", 4) => numbers(&|c| f64::from(i32::from_le_bytes(c.try_into().expect("4 bytes")))),
        ("<U", n) => NpyArray::Strings {
            shape,
            data: data[..need]
                .chunks_exact(4 * n)
                .map(|c| {
                    c.chunks_exact(4)
                        .map(|u| u32::from_le_bytes(u.try_into().expect("4 bytes")))
                        .take_while(|&u| u != 0)
                        .filter_map(char::from_u32)
                        .collect()
                })
                .collect(),
        },
        _ => {
            return Err(format!("unsupported dtype {descr:?} (need <f4, <f8, <i4, <i8 or <U)").into());
        }
    })
}

/// The text after `'key':` in a header dict, up to the end of the header.
fn field<'a>(header: &'a str, key: &str) -> Option<&'a str> {
    let at = header.find(&format!("'{key}'"))?;
    let rest = &header[at + key.len() + 2..];
    Some(rest.trim_start().strip_prefix(':')?.trim_start())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn npy(descr: &str, shape: &str, data: &[u8]) -> Vec<u8> {
        let mut header = format!("{{'descr': '{descr}', 'fortran_order': False, 'shape': {shape}, }}");
        while (10 + header.len() + 1) % 64 != 0 {
            header.push(' ');
        }
        header.push('\n');
        let mut out = b"\x93NUMPY\x01\x00".to_vec();
        out.extend_from_slice(&(header.len() as u16).to_le_bytes());
        out.extend_from_slice(header.as_bytes());
        out.extend_from_slice(data);
        out
    }

    #[test]
    fn a_string_item_size_whose_bytes_overflow_is_refused() {
        // Found by the npy_array fuzz target: 4 × size overflowed (a panic in checked builds).
        let e = parse_npy(&npy("<U4611686018427387904", "(2, 3)", &[])).unwrap_err();
        assert!(e.to_string().contains("too large"), "{e}");
    }

    #[test]
    fn floats_and_strings_parse_as_numpy_writes_them() {
        let data: Vec<u8> = [1.5f64, -2.0, 3.25, 4.0]
            .iter()
            .flat_map(|x| x.to_le_bytes())
            .collect();
        let a = parse_npy(&npy("<f8", "(2, 2)", &data)).unwrap();
        assert_eq!(
            a,
            NpyArray::Numbers {
                shape: vec![2, 2],
                data: vec![1.5, -2.0, 3.25, 4.0]
            }
        );
        let mut s = Vec::new();
        for name in ["knee", "hip"] {
            let mut units: Vec<u32> = name.chars().map(u32::from).collect();
            units.resize(4, 0);
            s.extend(units.iter().flat_map(|u| u.to_le_bytes()));
        }
        let b = parse_npy(&npy("<U4", "(2,)", &s)).unwrap();
        assert_eq!(
            b,
            NpyArray::Strings {
                shape: vec![2],
                data: vec!["knee".into(), "hip".into()]
            }
        );
    }

    #[test]
    fn broken_arrays_are_refused_with_a_reason() {
        assert!(parse_npy(b"garbage!!!!!").unwrap_err().message.contains("magic"));
        let short = npy("<f8", "(3,)", &[0; 8]);
        assert!(parse_npy(&short).unwrap_err().message.contains("data bytes"));
        assert!(
            parse_npy(&npy("<c16", "(1,)", &[0; 16]))
                .unwrap_err()
                .message
                .contains("dtype")
        );
    }
}
