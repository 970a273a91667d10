//! Backend selection at run time: burn 0.22 picks the backend from a `Device` value.

use std::sync::Mutex;

use burn::module::{Module, ModuleVisitor, Param};
use burn::tensor::{Bool, Device, Int, Tensor};

/// Backends this build can run on, as accepted by `--device`.
pub fn available() -> Vec<&'static str> {
    let mut v = Vec::new();
    if cfg!(feature = "flex") {
        v.push("flex");
    }
    if cfg!(feature = "ndarray") {
        v.push("ndarray");
    }
    if cfg!(feature = "wgpu") {
        v.push("wgpu");
    }
    if cfg!(feature = "cuda") {
        v.push("cuda");
    }
    v
}

/// The device named by `--device` (`auto` picks the first available: GPU backends first).
pub fn parse(name: &str) -> Result<Device, String> {
    let missing = || {
        format!(
            "device '{name}' is not compiled in; this build has: {}",
            available().join(", ")
        )
    };
    match name {
        "auto" => {
            let order = ["cuda", "wgpu", "flex", "ndarray"];
            let pick = order
                .iter()
                .find(|n| available().contains(n))
                .ok_or_else(missing)?;
            parse(pick)
        }
        #[cfg(feature = "flex")]
        "flex" | "cpu" => Ok(Device::flex()),
        #[cfg(feature = "ndarray")]
        #[allow(deprecated)]
        "ndarray" => Ok(Device::ndarray()),
        #[cfg(feature = "wgpu")]
        "wgpu" => Ok(Device::wgpu(Default::default())),
        #[cfg(feature = "cuda")]
        "cuda" => Ok(Device::cuda(0)),
        _ => Err(missing()),
    }
}

/// Seeds `device`'s random generator, builds a module with `build` and draws all its parameters,
/// holding a process-wide lock throughout. burn's seeded generator is shared by the whole process
/// and burn initialises a parameter lazily, on its first use: without the lock two models built at
/// once (tests run in parallel, say) would reseed it under each other, and without the draw a
/// model's weights would come from whatever the generator held at its first forward pass. Either
/// way a seed would not fix an initialisation.
pub fn seeded<M: Module>(device: &Device, seed: u64, build: impl FnOnce() -> M) -> M {
    static SEEDED: Mutex<()> = Mutex::new(());
    // A build that panicked holding the lock leaves nothing half-written behind it.
    let _guard = SEEDED.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
    device.seed(seed);
    let module = build();
    module.visit(&mut Initialise);
    module
}

/// Initialises every lazily initialised parameter it visits.
struct Initialise;

impl ModuleVisitor for Initialise {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        let _ = param.base();
    }

    fn visit_int<const D: usize>(&mut self, param: &Param<Tensor<D, Int>>) {
        let _ = param.base();
    }

    fn visit_bool<const D: usize>(&mut self, param: &Param<Tensor<D, Bool>>) {
        let _ = param.base();
    }
}

#[cfg(all(test, feature = "flex"))]
mod tests {
    use super::*;
    use burn::nn::LinearConfig;

    /// Weights of a small layer built from `seed` under [`seeded`], read after the lock is gone.
    fn weights(device: &Device, seed: u64) -> Vec<f32> {
        crate::readback::host(
            seeded(device, seed, || LinearConfig::new(16, 16).init(device))
                .weight
                .val(),
        )
    }

    /// Layers built from two seeds on eight threads at once each equal the layer built from
    /// their seed alone: no build reseeds or draws from the generator under another, and no
    /// weight is drawn after its build.
    #[test]
    fn concurrent_seeded_builds_get_their_own_seed_s_weights() {
        let device = Device::flex();
        let reference = [weights(&device, 1), weights(&device, 2)];
        assert_ne!(reference[0], reference[1], "the two seeds must differ");
        std::thread::scope(|scope| {
            for thread in 0..8u64 {
                let (device, reference) = (&device, &reference);
                scope.spawn(move || {
                    for round in 0..25u64 {
                        let seed = 1 + (thread + round) % 2;
                        assert_eq!(
                            weights(device, seed),
                            reference[seed as usize - 1],
                            "thread {thread}, round {round}, seed {seed}"
                        );
                    }
                });
            }
        });
    }
}
