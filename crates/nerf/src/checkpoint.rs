//! Checkpoint files: named binary sections in one file, written atomically (temporary file in
//! the same folder, fsync, rename), so an interrupted write never damages the last checkpoint.
//!
//! A model's record is its burn module record plus its host-side tables (hash grids and their
//! sparse-Adam moments) and occupancy grid; [`write_model_parts`] and [`read_model_parts`] are the
//! one path every model (static, NSFF, a user's own field) saves and loads them through.

use std::path::Path;
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
        out
    }

    pub fn from_bytes(bytes: &[u8], path: &Path) -> Result<Self> {
        let bad = |msg: String| ModelError::checkpoint(path, msg);
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
        let count = u32_le(take(4, "the section count")?) as usize;
        let mut sections = Sections::default();
        for _ in 0..count {
            let len = u32_le(take(4, "a section name")?) as usize;
            let name = String::from_utf8_lossy(take(len, "a section name")?).into_owned();
            let len = u64_le(take(8, &name)?) as usize;
            let data = take(len, &name)?.to_vec();
            sections.push(&name, data);
        }
        Ok(sections)
    }

    pub fn write(&self, path: &Path) -> Result<()> {
        Ok(nerf_data::image::write_atomic(path, &self.to_bytes())?)
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

/// Adds a module's record, its host tables and an occupancy grid as the "model" sections.
pub fn write_model_parts<M: Module>(
    s: &mut Sections,
    module: &M,
    host: &[Arc<HashGrid>],
    occupancy: Option<&OccupancyGrid>,
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
    if let Some(o) = occupancy {
        s.push(&format!("{MODEL}.occupancy"), f32_bytes(o.values()));
        s.push(
            &format!("{MODEL}.carved"),
            o.carved().iter().map(|&c| u8::from(c)).collect(),
        );
    }
    Ok(())
}

/// Loads what [`write_model_parts`] wrote into a freshly built `module` (whose host tables are
/// `host(&module)`) and `occupancy`.
pub fn read_model_parts<M: Module>(
    s: &Sections,
    module: M,
    host: impl Fn(&M) -> Vec<Arc<HashGrid>>,
    occupancy: Option<&mut OccupancyGrid>,
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
    if let Some(o) = occupancy {
        let values = bytes_f32(s.require(&format!("{MODEL}.occupancy"), path)?);
        let carved = s.require(&format!("{MODEL}.carved"), path)?;
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
        write_model_parts(s, &self.fields, &host, self.occupancy.as_ref(), path)
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
        model.fields = read_model_parts(s, model.fields, host, model.occupancy.as_mut(), path)?;
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
