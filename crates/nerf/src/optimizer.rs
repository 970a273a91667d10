//! The one optimiser step every model takes: burn's Adam on the module's parameters, and the
//! sparse Adam of each host-side table (hash grids), at the step's learning rate.

use std::sync::Arc;

use burn::module::Module;
use burn::optim::decay::WeightDecayConfig;
use burn::optim::{AdamConfig, GradientsParams, ModuleOptimizer};
use burn::tensor::{Bytes, Tensor};
use nerf_core::encoding::HashGrid;
use nerf_core::optim::AdamParams;
use nerf_core::profile::span;

use crate::config::TrainConfig;

pub struct Optimizer {
    module: ModuleOptimizer,
    host: AdamParams,
    weight_decay: f64,
}

impl Optimizer {
    pub fn new(cfg: &TrainConfig) -> Self {
        let host = AdamParams {
            beta1: cfg.adam_beta1,
            beta2: cfg.adam_beta2,
            epsilon: cfg.adam_eps,
        };
        Optimizer {
            module: module_adam(&host, cfg.weight_decay),
            host,
            weight_decay: cfg.weight_decay,
        }
    }

    /// Back-propagates `loss` and updates `module` and `host` (the module's host tables).
    pub fn step<M: Module>(&mut self, loss: Tensor<1>, lr: f64, module: M, host: &[Arc<HashGrid>]) -> M {
        let grads = span("backward", || loss.backward());
        let grads = GradientsParams::from_grads(grads, &module);
        self.update(module, [(grads, lr)], [(host, lr)])
    }

    /// Adam on each group of the module's gradients and of the host tables, at its rate.
    fn update<M: Module, const N: usize>(
        &mut self,
        module: M,
        grads: [(GradientsParams, f64); N],
        host: [(&[Arc<HashGrid>], f64); N],
    ) -> M {
        let module = span("adam_mlp", || {
            grads
                .into_iter()
                .fold(module, |m, (g, lr)| self.module.step(lr, m, g))
        });
        span("adam_grid", || {
            for (grids, lr) in host {
                for g in grids {
                    g.adam_step(&self.host, lr);
                }
            }
        });
        module
    }

    /// Drops what a skipped step accumulated in the host tables.
    pub fn skip(&self, host: &[Arc<HashGrid>]) {
        for g in host {
            g.zero_grad();
        }
    }

    /// The module optimiser's state (the host tables' moments are saved with the tables).
    pub fn to_bytes(&self) -> Result<Vec<u8>, String> {
        self.module
            .into_bytes()
            .map(|b| b.to_vec())
            .map_err(|e| format!("{e:?}"))
    }

    pub fn load_bytes(&mut self, bytes: &[u8]) -> Result<(), String> {
        self.module = module_adam(&self.host, self.weight_decay)
            .from_bytes(Bytes::from_bytes_vec(bytes.to_vec()))
            .map_err(|e| format!("{e:?}"))?;
        Ok(())
    }
}

fn module_adam(p: &AdamParams, weight_decay: f64) -> ModuleOptimizer {
    let mut adam = AdamConfig::new()
        .with_beta_1(p.beta1 as f32)
        .with_beta_2(p.beta2 as f32)
        .with_epsilon(p.epsilon as f32);
    if weight_decay > 0.0 {
        adam = adam.with_weight_decay(Some(WeightDecayConfig::new(weight_decay as f32)));
    }
    adam.init()
}
