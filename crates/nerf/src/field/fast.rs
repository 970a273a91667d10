//! The fast field (Instant-NGP recipe): multiresolution hash grid → tiny density MLP → log
//! density and geometry features; spherical-harmonics view encoding + features → colour MLP.
//!
//! The hash table lives on the host (see `nerf_core::encoding::hash_grid`) and is shared by
//! clones of the module (`valid()` copies for inference see the same table). Positions are
//! normalised to [0, 1]^3 over the field's box; a time input becomes the grid's fourth axis, or,
//! with `time_planes`, the time axis of three space-time planes that multiply a space grid
//! (`nerf_core::encoding::planes`).

use std::sync::Arc;

use burn::config::Config;
use burn::module::Module;
use burn::nn::{Linear, LinearConfig};
use burn::tensor::activation::sigmoid;
use burn::tensor::{Device, Tensor};
use nerf_core::encoding::spherical_harmonics;
use nerf_core::encoding::{GridEncoding, HashGrid, HashGridConfig, SpaceTimePlanes};
use nerf_core::field::{Density, Extras, Field, FieldOutputs, FieldQuery, rows3, select_rows};
use nerf_core::mlp::{Mlp, MlpConfig};

use super::grid_coords;

#[derive(Config, Debug)]
pub struct FastFieldConfig {
    pub grid: HashGridConfig,
    /// The box the grid covers, `[min, max]` corners in scene coordinates.
    pub aabb: [[f32; 3]; 2],
    /// Width of the density MLP's hidden layer.
    #[config(default = 64)]
    pub hidden: usize,
    /// Outputs of the density MLP: log density plus geometry features.
    #[config(default = 16)]
    pub geo_features: usize,
    #[config(default = 64)]
    pub color_hidden: usize,
    #[config(default = 2)]
    pub color_layers: usize,
    #[config(default = 4)]
    pub sh_degree: usize,
    /// Extra raw outputs from a linear head on the geometry features (view independent).
    #[config(default = 0)]
    pub extra_outputs: usize,
    /// Upper clamp of the log density (σ ≤ e^11 ≈ 6e4) so one bad step cannot overflow.
    #[config(default = 11.0)]
    pub max_log_density: f32,
    /// For a 4-D `grid`: encode with a 3-D grid times (x, t), (y, t), (z, t) planes instead of
    /// one 4-D hash grid.
    #[config(default = false)]
    pub time_planes: bool,
}

impl FastFieldConfig {
    pub fn init(&self, device: &Device, seed: u64) -> FastField {
        let encoding = if self.time_planes && self.grid.dims == 4 {
            GridEncoding::Planes(Arc::new(SpaceTimePlanes::new(&self.grid, seed)))
        } else {
            GridEncoding::Hash(HashGrid::new(self.grid.clone(), seed))
        };
        let sh = self.sh_degree * self.sh_degree;
        FastField {
            density: MlpConfig::new(encoding.output_dim(), self.hidden, 1, self.geo_features).init(device),
            color: MlpConfig::new(self.geo_features + sh, self.color_hidden, self.color_layers, 3)
                .init(device),
            extra: (self.extra_outputs > 0)
                .then(|| LinearConfig::new(self.geo_features, self.extra_outputs).init(device)),
            encoding,
            aabb: self.aabb,
            sh_degree: self.sh_degree,
            max_log_density: self.max_log_density,
        }
    }
}

#[derive(Module, Debug)]
pub struct FastField {
    pub density: Mlp,
    pub color: Mlp,
    pub extra: Option<Linear>,
    #[module(skip)]
    pub encoding: GridEncoding,
    #[module(skip)]
    pub aabb: [[f32; 3]; 2],
    pub sh_degree: usize,
    pub max_log_density: f32,
}

impl FastField {
    /// Geometry features `[S, G]` for grid coordinates in [0, 1]^D.
    fn geometry(&self, normalized: Tensor<2>) -> Tensor<2> {
        let enc = nerf_core::profile::span("fwd.hash_encode", || self.encoding.encode(normalized));
        nerf_core::profile::span("fwd.density_mlp", || self.density.forward(enc))
    }

    fn sigma(&self, geo: &Tensor<2>) -> Tensor<2> {
        let n = geo.dims()[0];
        geo.clone()
            .slice([0..n, 0..1])
            .clamp_max(self.max_log_density)
            .exp()
    }

    fn extras(&self, features: Tensor<2>) -> Extras {
        super::raw_extras(self.extra.as_ref(), features)
    }

    /// Density, colour and extras from geometry features `[S, G]` and `S·3` view directions.
    fn outputs(&self, geo: Tensor<2>, dirs: &[f32]) -> FieldOutputs {
        let n = geo.dims()[0];
        let sh = Tensor::<2>::from_data(
            burn::tensor::TensorData::new(
                spherical_harmonics::encode(dirs, self.sh_degree),
                [n, self.sh_degree * self.sh_degree],
            ),
            &geo.device(),
        );
        let rgb = nerf_core::profile::span("fwd.color_mlp", || {
            sigmoid(self.color.forward(Tensor::cat(vec![geo.clone(), sh], 1)))
        });
        FieldOutputs {
            sigma: self.sigma(&geo),
            rgb,
            extras: self.extras(geo),
        }
    }
}

impl Field for FastField {
    fn density(&self, positions: Tensor<2>, time: Option<Tensor<2>>) -> Density {
        let geo = self.geometry(grid_coords(positions, time, self.aabb));
        Density {
            sigma: self.sigma(&geo),
            extras: self.extras(geo),
        }
    }

    fn query(&self, query: FieldQuery<'_>) -> FieldOutputs {
        let geo = self.geometry(grid_coords(query.positions, query.time, self.aabb));
        self.outputs(geo, query.dirs)
    }

    /// The density pass's features at the kept samples feed the colour network directly: the
    /// grid and density network run once per sample, not twice.
    fn query_kept(
        &self,
        query: FieldQuery<'_>,
        keep: &mut dyn FnMut(Tensor<2>) -> Vec<usize>,
    ) -> (Vec<usize>, FieldOutputs) {
        let geo = self.geometry(grid_coords(
            query.positions.clone(),
            query.time.clone(),
            self.aabb,
        ));
        let rows = keep(self.sigma(&geo));
        let outputs = self.outputs(select_rows(geo, &rows), &rows3(query.dirs, &rows));
        (rows, outputs)
    }

    fn host_params(&self) -> Vec<Arc<HashGrid>> {
        self.encoding.grids()
    }
}
