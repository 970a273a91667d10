//! Checkpoint files: named binary sections in one file, written atomically (temporary file in
//! the same folder, fsync, rename), so an interrupted write never damages the last checkpoint.
//! A CRC-32 of the content closes the file and is checked on every read: a damaged checkpoint is
//! refused with an error naming it rather than loaded. A run keeps the checkpoint before its last
//! one (`checkpoint.prev.bin`), which `--resume` falls back to when the last one is damaged.
//!
//! A model's record is its burn module record plus its host-side tables (hash grids and their
//! sparse-Adam moments) and occupancy grid; [`write_model_parts`] and [`read_model_parts`] are the
//! one path every model (static, NSFF, a user's own field) saves and loads them through.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use burn::module::Module;
use burn::tensor::{Bytes, Device};
use nerf_core::encoding::HashGrid;
use nerf_core::occupancy::OccupancyGrid;

use crate::config::TrainConfig;
use crate::error::{ModelError, Result};
use crate::field::{BaseField, FieldModule};
use crate::model::{FieldBuilder, StaticFields, StaticModel, preset_field};
use crate::renderer::SceneBounds;

/// What a static run's checkpoint records besides the model.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct TrainState {
    pub config: TrainConfig,
    pub step: usize,
    /// Seconds of training so far (evaluation pauses excluded).
    pub elapsed: f64,
    /// Current ray count of the adaptive batch (fast preset).
    pub n_rays: usize,
}

/// A trained static model for inference, on a plain (no autodiff) device: no dataset, no
/// optimiser.
pub struct TrainedModel<F: Module = BaseField> {
    pub state: TrainState,
    pub model: StaticModel<F>,
    pub device: Device,
}

/// Loads `run_dir/checkpoint.bin` written by `nerf train`.
pub fn load_trained(run_dir: &Path) -> Result<TrainedModel> {
    load_trained_with_field(run_dir, preset_field)
}

/// [`load_trained`] for a run whose fields `build` makes.
pub fn load_trained_with_field<F: FieldModule>(
    run_dir: &Path,
    build: FieldBuilder<F>,
) -> Result<TrainedModel<F>> {
    let path = run_dir.join(crate::train_loop::CHECKPOINT);
    let s = Sections::read(&path)?;
    let state: TrainState = s.json("state", &path)?;
    let device = crate::trainer::device(&state.config, false)?;
    let model = StaticModel::from_sections(&state.config, &s, &path, &device, build)?;
    Ok(TrainedModel { state, model, device })
}

/// Format 2: header, sections, CRC-32 of everything before it (little-endian u32).
const MAGIC: &[u8] = b"NERFRS-CKPT-2\n";
/// Format 1 had no checksum; still read so older runs load.
const MAGIC_V1: &[u8] = b"NERFRS-CKPT-1\n";

/// Where a run keeps the checkpoint that its last save replaced.
pub fn previous_path(path: &Path) -> PathBuf {
    let stem = path
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    path.with_file_name(format!("{stem}.prev.bin"))
}

/// Whether `run_dir` holds a checkpoint to resume from (the last one or the one before it).
pub fn has_checkpoint(run_dir: &Path) -> bool {
    let path = run_dir.join(crate::train_loop::CHECKPOINT);
    path.exists() || previous_path(&path).exists()
}

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
            .ok_or_else(|| ModelError::checkpoint(path, format!("checkpoint has no '{name}' section")))
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
        let crc = nerf_data::npz::crc32(&out);
        out.extend(crc.to_le_bytes());
        out
    }

    pub fn from_bytes(bytes: &[u8], path: &Path) -> Result<Self> {
        let bad = |msg: String| ModelError::checkpoint(path, msg);
        let body = if bytes.starts_with(MAGIC) {
            if bytes.len() < MAGIC.len() + 4 {
                return Err(bad(format!("truncated: {} bytes", bytes.len())));
            }
            let (content, stored) = bytes.split_at(bytes.len() - 4);
            let (stored, computed) = (u32_le(stored), nerf_data::npz::crc32(content));
            if stored != computed {
                return Err(bad(format!(
                    "damaged: checksum mismatch (stored {stored:08x}, content {computed:08x}); \
                     the file is truncated or corrupt"
                )));
            }
            &content[MAGIC.len()..]
        } else if bytes.starts_with(MAGIC_V1) {
            &bytes[MAGIC_V1.len()..]
        } else {
            return Err(bad("not a checkpoint of this program (bad header)".into()));
        };
        let mut at = 0usize;
        let mut take = |n: u64, what: &str| -> Result<&[u8]> {
            let s = usize::try_from(n)
                .ok()
                .and_then(|n| at.checked_add(n))
                .and_then(|end| body.get(at..end))
                .ok_or_else(|| bad(format!("truncated while reading {what}")))?;
            at += s.len();
            Ok(s)
        };
        let count = u32_le(take(4, "the section count")?);
        let mut sections = Sections::default();
        for _ in 0..count {
            let len = u32_le(take(4, "a section name")?);
            let name = String::from_utf8_lossy(take(len.into(), "a section name")?).into_owned();
            let len = u64_le(take(8, &name)?);
            let data = take(len, &name)?.to_vec();
            sections.push(&name, data);
        }
        if at != body.len() {
            return Err(bad(format!(
                "{} unexpected bytes after the last section",
                body.len() - at
            )));
        }
        Ok(sections)
    }

    pub fn write(&self, path: &Path) -> Result<()> {
        Ok(nerf_data::image::write_atomic(path, &self.to_bytes())?)
    }

    /// Writes a run's checkpoint atomically and keeps the one it replaces at
    /// [`previous_path`] (a hard link where the file system allows, else a copy).
    pub fn write_keeping_previous(&self, path: &Path) -> Result<()> {
        if path.exists() {
            let prev = previous_path(path);
            let _ = std::fs::remove_file(&prev);
            if std::fs::hard_link(path, &prev).is_err() {
                std::fs::copy(path, &prev).map_err(|e| {
                    ModelError::checkpoint(&prev, format!("cannot keep the previous checkpoint: {e}"))
                })?;
            }
        }
        self.write(path)
    }

    /// The checkpoint to resume `run_dir` from: `checkpoint.bin`, or, when that is missing or
    /// damaged and the previous one reads, the previous one (said on stderr; the damaged file is
    /// moved aside to `checkpoint.bin.damaged` so the next save does not keep it as previous).
    /// Returns the sections and the file they came from.
    pub fn read_for_resume(run_dir: &Path) -> Result<(Self, PathBuf)> {
        let path = run_dir.join(crate::train_loop::CHECKPOINT);
        let err = match Self::read(&path) {
            Ok(s) => return Ok((s, path)),
            Err(e) => e,
        };
        let prev = previous_path(&path);
        if !prev.exists() {
            return Err(err);
        }
        let s = Self::read(&prev).map_err(|prev_err| {
            ModelError::checkpoint(
                &path,
                format!("{err}; the previous checkpoint is no better: {prev_err}"),
            )
        })?;
        if path.exists() {
            let aside = path.with_extension("bin.damaged");
            if std::fs::rename(&path, &aside).is_ok() {
                eprintln!("warning: {err}; moved it to {}", aside.display());
            }
        }
        eprintln!(
            "warning: resuming from the previous checkpoint {}",
            prev.display()
        );
        Ok((s, prev))
    }

    pub fn read(path: &Path) -> Result<Self> {
        Self::from_bytes(&nerf_data::error::read_file(path)?, path)
    }

    /// A JSON section.
    pub fn push_json<T: serde::Serialize>(&mut self, name: &str, value: &T, path: &Path) -> Result<()> {
        let bytes =
            serde_json::to_vec_pretty(value).map_err(|e| ModelError::checkpoint(path, e.to_string()))?;
        self.push(name, bytes);
        Ok(())
    }

    pub fn json<T: serde::de::DeserializeOwned>(&self, name: &str, path: &Path) -> Result<T> {
        serde_json::from_slice(self.require(name, path)?)
            .map_err(|e| ModelError::checkpoint(path, format!("bad '{name}' section: {e}")))
    }
}

/// Little-endian integers from slices whose length the caller has checked.
fn u32_le(b: &[u8]) -> u32 {
    u32::from_le_bytes([b[0], b[1], b[2], b[3]])
}

fn u64_le(b: &[u8]) -> u64 {
    u64::from_le_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]])
}

/// Sections of the model parts are named after this.
const MODEL: &str = "model";

/// Adds a module's record, its host tables and its occupancy grids (none, one, or one per time
/// bin) as the "model" sections.
pub fn write_model_parts<M: Module>(
    s: &mut Sections,
    module: &M,
    host: &[Arc<HashGrid>],
    occupancy: &[OccupancyGrid],
    path: &Path,
) -> Result<()> {
    let bytes = module
        .clone()
        .into_record()
        .into_bytes()
        .map_err(|e| ModelError::checkpoint(path, format!("cannot save model: {e:?}")))?;
    s.push(MODEL, bytes.to_vec());
    for (k, grid) in host.iter().enumerate() {
        s.push(&format!("{MODEL}.grid{k}"), f32_bytes(&grid.table()));
        let (step, m, v) = grid.adam_state();
        let mut adam = step.to_le_bytes().to_vec();
        adam.extend(f32_bytes(&m));
        adam.extend(f32_bytes(&v));
        s.push(&format!("{MODEL}.grid{k}_adam"), adam);
    }
    for (k, o) in occupancy.iter().enumerate() {
        let (values, carved) = occupancy_sections(k);
        s.push(&values, f32_bytes(o.values()));
        s.push(&carved, o.carved().iter().map(|&c| u8::from(c)).collect());
    }
    Ok(())
}

/// Section names of the k-th occupancy grid (the first keeps the single grid's names).
fn occupancy_sections(k: usize) -> (String, String) {
    if k == 0 {
        (format!("{MODEL}.occupancy"), format!("{MODEL}.carved"))
    } else {
        (format!("{MODEL}.occupancy{k}"), format!("{MODEL}.carved{k}"))
    }
}

/// Loads what [`write_model_parts`] wrote into a freshly built `module` (whose host tables are
/// `host(&module)`) and `occupancy`.
pub fn read_model_parts<M: Module>(
    s: &Sections,
    module: M,
    host: impl Fn(&M) -> Vec<Arc<HashGrid>>,
    occupancy: &mut [OccupancyGrid],
    path: &Path,
) -> Result<M> {
    let record =
        burn::store::ModuleRecord::from_bytes(Bytes::from_bytes_vec(s.require(MODEL, path)?.to_vec()))
            .map_err(|e| ModelError::checkpoint(path, format!("cannot read model: {e:?}")))?;
    let module = module
        .try_load_record(record)
        .map_err(|e| ModelError::checkpoint(path, format!("model does not match its config: {e:?}")))?;
    for (k, grid) in host(&module).iter().enumerate() {
        let table = bytes_f32(s.require(&format!("{MODEL}.grid{k}"), path)?);
        let n = grid.num_params();
        grid.set_table(table).map_err(|want| {
            ModelError::checkpoint(
                path,
                format!("hash table {k} has the wrong size (config needs {want})"),
            )
        })?;
        let adam = s.require(&format!("{MODEL}.grid{k}_adam"), path)?;
        if adam.len() != 8 + 8 * n {
            return Err(ModelError::checkpoint(
                path,
                format!("hash-grid {k} optimiser state has the wrong size"),
            ));
        }
        grid.set_adam_state(
            u64_le(&adam[..8]),
            bytes_f32(&adam[8..8 + 4 * n]),
            bytes_f32(&adam[8 + 4 * n..]),
        );
    }
    for (k, o) in occupancy.iter_mut().enumerate() {
        let (values, carved) = occupancy_sections(k);
        let values = bytes_f32(s.require(&values, path)?);
        let carved = s.require(&carved, path)?;
        if values.len() != o.num_cells() || carved.len() != o.num_cells() {
            return Err(ModelError::checkpoint(path, "occupancy grid has the wrong size"));
        }
        o.set_values(values);
        o.set_carved(carved.iter().map(|&c| c != 0).collect());
    }
    Ok(module)
}

/// The static model's sections: "bounds" and the "model" parts.
impl<F: FieldModule> StaticModel<F> {
    pub fn write_sections(&self, s: &mut Sections, path: &Path) -> Result<()> {
        s.push_json("bounds", &self.bounds, path)?;
        let host = self.host_params();
        write_model_parts(s, &self.fields, &host, self.occupancy.as_slice(), path)
    }

    /// Rebuilds the model that `cfg` describes from checkpoint sections; fields made by `build`.
    pub fn from_sections(
        cfg: &TrainConfig,
        s: &Sections,
        path: &Path,
        device: &Device,
        build: FieldBuilder<F>,
    ) -> Result<Self> {
        let bounds: SceneBounds = s.json("bounds", path)?;
        let mut model = StaticModel::with_field(cfg, bounds, device, build);
        let host = StaticFields::host_params;
        model.fields = read_model_parts(s, model.fields, host, model.occupancy.as_mut_slice(), path)?;
        Ok(model)
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
        for cut in 0..bytes.len() {
            let err = Sections::from_bytes(&bytes[..cut], p).unwrap_err().to_string();
            assert!(
                err.contains("checkpoint.bin") && (err.contains("truncated") || err.contains("header")),
                "cut at {cut}: {err}"
            );
        }
        assert!(s.require("missing", p).is_err());
    }

    #[test]
    fn every_flipped_bit_is_refused() {
        let mut s = Sections::default();
        s.push("state", br#"{"step": 3}"#.to_vec());
        s.push("model", (0..64).collect());
        let bytes = s.to_bytes();
        let p = Path::new("run/checkpoint.bin");
        for bit in 0..8 * bytes.len() {
            let mut b = bytes.clone();
            b[bit / 8] ^= 1 << (bit % 8);
            let err = Sections::from_bytes(&b, p).unwrap_err().to_string();
            assert!(err.contains("checkpoint.bin"), "bit {bit}: {err}");
            if bit >= 8 * MAGIC.len() {
                assert!(err.contains("checksum mismatch"), "bit {bit}: {err}");
            }
        }
    }

    #[test]
    fn format_1_without_checksum_still_reads() {
        let mut s = Sections::default();
        s.push("state", b"{}".to_vec());
        let v2 = s.to_bytes();
        let mut v1 = MAGIC_V1.to_vec();
        v1.extend(&v2[MAGIC.len()..v2.len() - 4]);
        assert_eq!(Sections::from_bytes(&v1, Path::new("c.bin")).unwrap(), s);
    }

    #[test]
    fn resume_falls_back_to_the_previous_checkpoint() {
        let dir = std::env::temp_dir().join(format!("nerf-ckpt-prev-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join(crate::train_loop::CHECKPOINT);
        let save = |step: u8| {
            let mut s = Sections::default();
            s.push("state", vec![step]);
            s.write_keeping_previous(&path).unwrap();
            s
        };
        let first = save(1);
        let second = save(2);
        assert_eq!(Sections::read(&previous_path(&path)).unwrap(), first);
        assert_eq!(Sections::read_for_resume(&dir).unwrap().0, second);

        // Damage the last checkpoint: resume takes the previous one and moves the damaged aside.
        let mut bytes = std::fs::read(&path).unwrap();
        let mid = bytes.len() / 2;
        bytes[mid] ^= 0x10;
        std::fs::write(&path, &bytes).unwrap();
        assert!(Sections::read(&path).is_err());
        let (s, from) = Sections::read_for_resume(&dir).unwrap();
        assert_eq!((s, from), (first.clone(), previous_path(&path)));
        assert!(!path.exists() && path.with_extension("bin.damaged").exists());
        // The next save keeps the good previous checkpoint.
        let third = save(3);
        assert_eq!(Sections::read(&previous_path(&path)).unwrap(), first);
        assert_eq!(Sections::read_for_resume(&dir).unwrap().0, third);

        // Both damaged: an error naming the last checkpoint and the previous one.
        std::fs::write(&path, b"NERFRS-CKPT-2\n????").unwrap();
        std::fs::write(previous_path(&path), b"garbage").unwrap();
        let err = Sections::read_for_resume(&dir).unwrap_err().to_string();
        assert!(
            err.contains("checkpoint.bin") && err.contains("checkpoint.prev.bin"),
            "{err}"
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
