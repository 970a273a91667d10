//! Checkpoint files: named binary sections in one file, written atomically (temporary file in
//! the same folder, fsync, rename), so an interrupted write never damages the last checkpoint.

use std::path::Path;

use nerf_data::error::{DataError, Result};

const MAGIC: &[u8] = b"NERFRS-CKPT-1\n";

/// Named byte sections.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Sections(pub Vec<(String, Vec<u8>)>);

impl Sections {
    pub fn push(&mut self, name: &str, data: Vec<u8>) {
        self.0.push((name.to_string(), data));
    }

    pub fn get(&self, name: &str) -> Option<&[u8]> {
        self.0.iter().find(|(n, _)| n == name).map(|(_, d)| d.as_slice())
    }

    /// A required section, or an error naming the file and the section.
    pub fn require(&self, name: &str, path: &Path) -> Result<&[u8]> {
        self.get(name)
            .ok_or_else(|| DataError::invalid(path, format!("checkpoint has no '{name}' section")))
    }

    pub fn to_bytes(&self) -> Vec<u8> {
        let mut out = MAGIC.to_vec();
        out.extend((self.0.len() as u32).to_le_bytes());
        for (name, data) in &self.0 {
            out.extend((name.len() as u32).to_le_bytes());
            out.extend(name.as_bytes());
            out.extend((data.len() as u64).to_le_bytes());
            out.extend(data);
        }
        out
    }

    pub fn from_bytes(bytes: &[u8], path: &Path) -> Result<Self> {
        let bad = |msg: String| DataError::invalid(path, msg);
        if !bytes.starts_with(MAGIC) {
            return Err(bad("not a checkpoint of this program (bad header)".into()));
        }
        let mut at = MAGIC.len();
        let mut take = |n: usize, what: &str| -> Result<&[u8]> {
            let s = bytes
                .get(at..at + n)
                .ok_or_else(|| bad(format!("truncated at byte {at} while reading {what}")))?;
            at += n;
            Ok(s)
        };
        let count = u32::from_le_bytes(take(4, "the section count")?.try_into().unwrap_or_default()) as usize;
        let mut sections = Sections::default();
        for _ in 0..count {
            let len = u32::from_le_bytes(take(4, "a section name")?.try_into().unwrap_or_default()) as usize;
            let name = String::from_utf8_lossy(take(len, "a section name")?).into_owned();
            let len = u64::from_le_bytes(take(8, &name)?.try_into().unwrap_or_default()) as usize;
            let data = take(len, &name)?.to_vec();
            sections.push(&name, data);
        }
        Ok(sections)
    }

    pub fn write(&self, path: &Path) -> Result<()> {
        nerf_data::image::write_atomic(path, &self.to_bytes())
    }

    pub fn read(path: &Path) -> Result<Self> {
        Self::from_bytes(&nerf_data::error::read_file(path)?, path)
    }
}

/// f32 slice ↔ little-endian bytes.
pub fn f32_bytes(v: &[f32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

pub fn bytes_f32(b: &[u8]) -> Vec<f32> {
    b.chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_truncation() {
        let mut s = Sections::default();
        s.push("a", vec![1, 2, 3]);
        s.push("state", b"{}".to_vec());
        let bytes = s.to_bytes();
        let p = Path::new("run/checkpoint.bin");
        assert_eq!(Sections::from_bytes(&bytes, p).unwrap(), s);
        let err = Sections::from_bytes(&bytes[..bytes.len() - 1], p)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("checkpoint.bin") && err.contains("truncated"),
            "{err}"
        );
        assert!(s.require("missing", p).is_err());
    }
}
