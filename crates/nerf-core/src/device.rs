//! Backend selection at run time: burn 0.22 picks the backend from a `Device` value.

use burn::tensor::Device;

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
