//! NumPy `.npy` reading and writing (format versions 1-3, little- and big-endian f4/f8/i4/i8/u1/b1,
//! C order). Arrays come back as f64 or f32 with their shape.

use std::path::Path;

use crate::error::{DataError, Result};

/// A decoded array: values converted to f64, C order.
#[derive(Clone, Debug, PartialEq)]
pub struct NpyArray {
    pub shape: Vec<usize>,
    pub data: Vec<f64>,
    /// The stored dtype descriptor, e.g. `<f4`.
    pub dtype: String,
}

impl NpyArray {
    pub fn to_f32(&self) -> Vec<f32> {
        self.data.iter().map(|&v| v as f32).collect()
    }
}

const MAGIC: &[u8] = b"\x93NUMPY";

/// Reads an `.npy` file.
pub fn read_npy(path: &Path) -> Result<NpyArray> {
    parse_npy(&crate::error::read_file(path)?, path)
}

/// Parses `.npy` bytes; `origin` names the file (or `archive.npz:entry.npy`) in errors.
pub fn parse_npy(bytes: &[u8], origin: &Path) -> Result<NpyArray> {
    let bad = |msg: String| DataError::invalid(origin, msg);
    if bytes.len() < 10 || &bytes[..6] != MAGIC {
        return Err(bad("not a NumPy .npy file (missing \\x93NUMPY magic)".into()));
    }
    let major = bytes[6];
    let (header_len, start) = match major {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10),
        2 | 3 => {
            if bytes.len() < 12 {
                return Err(bad("truncated .npy header".into()));
            }
            (
                u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize,
                12,
            )
        }
        v => return Err(bad(format!("unsupported .npy format version {v}"))),
    };
    let end = start + header_len;
    if bytes.len() < end {
        return Err(bad(format!(
            "truncated .npy header: {} of {end} bytes",
            bytes.len()
        )));
    }
    let header = std::str::from_utf8(&bytes[start..end]).map_err(|_| bad("header is not text".into()))?;
    let dtype =
        header_field(header, "descr").ok_or_else(|| bad(format!("header has no 'descr': {header}")))?;
    let dtype = dtype.trim_matches(|c| c == '\'' || c == '"').to_string();
    if header_field(header, "fortran_order").is_some_and(|v| v.starts_with("True")) {
        return Err(bad("Fortran-order arrays are not supported".into()));
    }
    let shape_text =
        header_field(header, "shape").ok_or_else(|| bad(format!("header has no 'shape': {header}")))?;
    let shape: Vec<usize> = shape_text
        .trim_matches(|c| c == '(' || c == ')')
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| {
            s.parse::<usize>()
                .map_err(|_| bad(format!("bad shape {shape_text}")))
        })
        .collect::<Result<_>>()?;
    let count: usize = shape.iter().product();
    let (little, kind, size) =
        parse_dtype(&dtype).ok_or_else(|| bad(format!("unsupported dtype {dtype}")))?;
    let payload = &bytes[end..];
    let need = count * size;
    if payload.len() < need {
        return Err(bad(format!(
            "truncated .npy data: shape {shape:?} of {dtype} needs {need} bytes, file has {}",
            payload.len()
        )));
    }
    let data = payload[..need]
        .chunks_exact(size)
        .map(|c| decode(c, little, kind))
        .collect();
    Ok(NpyArray { shape, data, dtype })
}

fn header_field<'a>(header: &'a str, key: &str) -> Option<&'a str> {
    let pos = header
        .find(&format!("'{key}'"))
        .or_else(|| header.find(&format!("\"{key}\"")))?;
    let rest = header[pos + key.len() + 2..].trim_start();
    let rest = rest.strip_prefix(':')?.trim_start();
    if rest.starts_with('(') {
        rest.find(')').map(|e| &rest[..=e])
    } else {
        let e = rest.find([',', '}']).unwrap_or(rest.len());
        Some(rest[..e].trim())
    }
}

fn parse_dtype(d: &str) -> Option<(bool, char, usize)> {
    let mut chars = d.chars();
    let order = chars.next()?;
    let little = match order {
        '<' | '|' | '=' => true,
        '>' => false,
        _ => return None,
    };
    let kind = chars.next()?;
    let size: usize = chars.as_str().parse().ok()?;
    match (kind, size) {
        ('f', 4 | 8) | ('i', 1 | 2 | 4 | 8) | ('u', 1 | 2 | 4 | 8) | ('b', 1) => Some((little, kind, size)),
        _ => None,
    }
}

fn decode(c: &[u8], little: bool, kind: char) -> f64 {
    let mut b = [0u8; 8];
    b[..c.len()].copy_from_slice(c);
    if !little {
        b[..c.len()].reverse();
    }
    match (kind, c.len()) {
        ('f', 4) => f32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
        ('f', 8) => f64::from_le_bytes(b),
        ('i', 1) => b[0] as i8 as f64,
        ('i', 2) => i16::from_le_bytes([b[0], b[1]]) as f64,
        ('i', 4) => i32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
        ('i', 8) => i64::from_le_bytes(b) as f64,
        ('u', _) | ('b', _) => u64::from_le_bytes(b) as f64,
        _ => f64::NAN,
    }
}

/// Encodes a little-endian f64 (`<f8`) or f32 (`<f4`) array as `.npy` version 1.0 bytes.
pub fn encode_npy(shape: &[usize], data: &[f64], f32_storage: bool) -> Vec<u8> {
    let shape_text = match shape.len() {
        1 => format!("({},)", shape[0]),
        _ => format!(
            "({})",
            shape.iter().map(|s| s.to_string()).collect::<Vec<_>>().join(", ")
        ),
    };
    let descr = if f32_storage { "<f4" } else { "<f8" };
    let mut header = format!("{{'descr': '{descr}', 'fortran_order': False, 'shape': {shape_text}, }}");
    // Pad so the data starts on a 64-byte boundary, header ends with '\n'.
    while (10 + header.len() + 1) % 64 != 0 {
        header.push(' ');
    }
    header.push('\n');
    let mut out = Vec::with_capacity(10 + header.len() + data.len() * 8);
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&[1, 0]);
    out.extend_from_slice(&(header.len() as u16).to_le_bytes());
    out.extend_from_slice(header.as_bytes());
    for &v in data {
        if f32_storage {
            out.extend_from_slice(&(v as f32).to_le_bytes());
        } else {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
    out
}

/// Writes an f64 `.npy` file atomically.
pub fn write_npy(path: &Path, shape: &[usize], data: &[f64]) -> Result<()> {
    crate::image::write_atomic(path, &encode_npy(shape, data, false))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_truncation() {
        let data: Vec<f64> = (0..12).map(|v| v as f64 * 0.5).collect();
        let bytes = encode_npy(&[3, 4], &data, false);
        let arr = parse_npy(&bytes, Path::new("a.npy")).unwrap();
        assert_eq!(arr.shape, vec![3, 4]);
        assert_eq!(arr.data, data);
        let f32bytes = encode_npy(&[12], &data, true);
        assert_eq!(parse_npy(&f32bytes, Path::new("b.npy")).unwrap().data, data);
        let err = parse_npy(&bytes[..bytes.len() - 3], Path::new("a.npy"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("a.npy") && err.contains("truncated"), "{err}");
        let err = parse_npy(b"hello world", Path::new("c.npy"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("c.npy") && err.contains("magic"), "{err}");
    }
}
