//! NumPy `.npz` archives: a zip of `.npy` entries, stored or DEFLATE-compressed.
//!
//! A minimal zip reader (central directory, stored and deflate entries, CRC-32 check), so a
//! truncated or corrupt archive is reported with the entry and the byte offset at fault.

use std::collections::BTreeMap;
use std::path::Path;

use crate::error::{DataError, Result};
use crate::npy::{NpyArray, parse_npy};

/// Reads every `.npy` entry of an `.npz` file, keyed by name without the `.npy` suffix.
pub fn read_npz(path: &Path) -> Result<BTreeMap<String, NpyArray>> {
    let bytes = crate::error::read_file(path)?;
    let mut out = BTreeMap::new();
    for (name, data) in read_zip(&bytes, path)? {
        let key = name.strip_suffix(".npy").unwrap_or(&name).to_string();
        let origin = Path::new(path).join(&name);
        out.insert(key, parse_npy(&data, &origin)?);
    }
    Ok(out)
}

fn u16_at(b: &[u8], o: usize) -> Option<u16> {
    Some(u16::from_le_bytes(b.get(o..o + 2)?.try_into().ok()?))
}

fn u32_at(b: &[u8], o: usize) -> Option<u32> {
    Some(u32::from_le_bytes(b.get(o..o + 4)?.try_into().ok()?))
}

/// All file entries of a zip archive as (name, uncompressed bytes).
pub fn read_zip(bytes: &[u8], path: &Path) -> Result<Vec<(String, Vec<u8>)>> {
    let bad = |msg: String| DataError::invalid(path, msg);
    // The end-of-central-directory record sits in the last 22..65557 bytes.
    let eocd = (0..bytes.len().saturating_sub(21))
        .rev()
        .take(65_557)
        .find(|&o| u32_at(bytes, o) == Some(0x0605_4b50))
        .ok_or_else(|| {
            bad("not a zip/npz archive, or truncated: end-of-central-directory record missing".into())
        })?;
    let count = u16_at(bytes, eocd + 10).unwrap_or(0) as usize;
    let cd_offset = u32_at(bytes, eocd + 16).unwrap_or(0) as usize;
    let mut entries = Vec::with_capacity(count);
    let mut o = cd_offset;
    for k in 0..count {
        let trunc = || {
            bad(format!(
                "truncated central directory at byte {o} (entry {k} of {count})"
            ))
        };
        if u32_at(bytes, o).ok_or_else(trunc)? != 0x0201_4b50 {
            return Err(bad(format!("corrupt central directory entry at byte {o}")));
        }
        let method = u16_at(bytes, o + 10).ok_or_else(trunc)?;
        let crc = u32_at(bytes, o + 16).ok_or_else(trunc)?;
        let csize = u32_at(bytes, o + 20).ok_or_else(trunc)? as usize;
        let usize_ = u32_at(bytes, o + 24).ok_or_else(trunc)? as usize;
        let name_len = u16_at(bytes, o + 28).ok_or_else(trunc)? as usize;
        let extra_len = u16_at(bytes, o + 30).ok_or_else(trunc)? as usize;
        let comment_len = u16_at(bytes, o + 32).ok_or_else(trunc)? as usize;
        let local = u32_at(bytes, o + 42).ok_or_else(trunc)? as usize;
        let name = bytes.get(o + 46..o + 46 + name_len).ok_or_else(trunc)?;
        let name = String::from_utf8_lossy(name).into_owned();
        o += 46 + name_len + extra_len + comment_len;
        if csize == 0xFFFF_FFFF || usize_ == 0xFFFF_FFFF {
            return Err(bad(format!("entry {name}: zip64 archives are not supported")));
        }
        // Local header: its own name/extra lengths decide where the data starts.
        if u32_at(bytes, local) != Some(0x0403_4b50) {
            return Err(bad(format!("entry {name}: local header missing at byte {local}")));
        }
        let lname = u16_at(bytes, local + 26).unwrap_or(0) as usize;
        let lextra = u16_at(bytes, local + 28).unwrap_or(0) as usize;
        let start = local + 30 + lname + lextra;
        let raw = bytes.get(start..start + csize).ok_or_else(|| {
            bad(format!(
                "entry {name}: truncated, data needs bytes {start}..{} of {}",
                start + csize,
                bytes.len()
            ))
        })?;
        let data = match method {
            0 => raw.to_vec(),
            8 => miniz_oxide::inflate::decompress_to_vec_with_limit(raw, usize_.max(1))
                .map_err(|e| bad(format!("entry {name}: corrupt deflate stream ({:?})", e.status)))?,
            m => return Err(bad(format!("entry {name}: unsupported compression method {m}"))),
        };
        if data.len() != usize_ {
            return Err(bad(format!(
                "entry {name}: expected {usize_} bytes, got {}",
                data.len()
            )));
        }
        if crc32(&data) != crc {
            return Err(bad(format!("entry {name}: CRC mismatch, the archive is corrupt")));
        }
        entries.push((name, data));
    }
    Ok(entries)
}

/// CRC-32 (IEEE, as zip uses).
pub fn crc32(data: &[u8]) -> u32 {
    crc32fast::hash(data)
}

/// Builds a zip archive (stored or deflated entries). Used to write `.npz` files and test fixtures.
pub fn write_zip(entries: &[(&str, &[u8])], deflate: bool) -> Vec<u8> {
    let mut out = Vec::new();
    let mut central = Vec::new();
    for (name, data) in entries {
        let offset = out.len() as u32;
        let (method, payload) = if deflate {
            (8u16, miniz_oxide::deflate::compress_to_vec(data, 6))
        } else {
            (0u16, data.to_vec())
        };
        let crc = crc32(data);
        let header = |sig: u32, central: bool| {
            let mut h = Vec::new();
            h.extend(sig.to_le_bytes());
            if central {
                h.extend(20u16.to_le_bytes());
            }
            h.extend(20u16.to_le_bytes());
            h.extend(0u16.to_le_bytes());
            h.extend(method.to_le_bytes());
            h.extend([0u8; 4]);
            h.extend(crc.to_le_bytes());
            h.extend((payload.len() as u32).to_le_bytes());
            h.extend((data.len() as u32).to_le_bytes());
            h.extend((name.len() as u16).to_le_bytes());
            h.extend(0u16.to_le_bytes());
            if central {
                // comment length, disk number, internal and external attributes
                h.extend([0u8; 10]);
                h.extend(offset.to_le_bytes());
            }
            h.extend(name.as_bytes());
            h
        };
        out.extend(header(0x0403_4b50, false));
        out.extend(&payload);
        central.extend(header(0x0201_4b50, true));
    }
    let cd_offset = out.len() as u32;
    out.extend(&central);
    out.extend(0x0605_4b50u32.to_le_bytes());
    out.extend([0u8; 4]);
    out.extend((entries.len() as u16).to_le_bytes());
    out.extend((entries.len() as u16).to_le_bytes());
    out.extend((central.len() as u32).to_le_bytes());
    out.extend(cd_offset.to_le_bytes());
    out.extend(0u16.to_le_bytes());
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crc_matches_known_value() {
        assert_eq!(crc32(b"123456789"), 0xCBF4_3926);
    }

    #[test]
    fn zip_round_trip_stored_and_deflated() {
        let a = crate::npy::encode_npy(&[2, 2], &[1.0, 2.0, 3.0, 4.0], true);
        for deflate in [false, true] {
            let zip = write_zip(&[("a.npy", &a)], deflate);
            let entries = read_zip(&zip, Path::new("x.npz")).unwrap();
            assert_eq!(entries, vec![("a.npy".to_string(), a.clone())]);
            let err = read_zip(&zip[..zip.len() / 2], Path::new("x.npz"))
                .unwrap_err()
                .to_string();
            assert!(err.contains("x.npz") && err.contains("truncated"), "{err}");
        }
    }
}
