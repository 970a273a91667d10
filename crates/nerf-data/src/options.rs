//! Options shared by all parsers.

/// What the user asked of the loader. Every parser reads the fields that apply to its format and
/// ignores the rest.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct LoadOptions {
    /// Integer downscale factor of the images (1 = full resolution).
    pub downscale: u32,
    /// Background colour for RGBA images; `None` means the format's default
    /// (white for Blender/D-NeRF, black for the tiny npz, none for real captures).
    pub background: Option<[f32; 3]>,
    /// Hold out every `holdout`-th view for testing; `None` means the format's default
    /// (LLFF every 8th; Blender uses its test json, or every 10th view when it has none).
    pub holdout: Option<usize>,
    /// Forward-facing scenes: warp rays to NDC (default true for LLFF/COLMAP/NSFF video).
    pub ndc: bool,
    /// 360° LLFF/COLMAP captures: spherify poses instead of NDC.
    pub spherify: bool,
}

impl Default for LoadOptions {
    fn default() -> Self {
        LoadOptions {
            downscale: 1,
            background: None,
            holdout: None,
            ndc: true,
            spherify: false,
        }
    }
}
