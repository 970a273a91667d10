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
    /// LLFF/COLMAP/NSFF-video captures: whether rays are warped to NDC.
    pub ndc: NdcMode,
    /// 360° LLFF/COLMAP captures: spherify poses instead of NDC.
    pub spherify: bool,
}

impl Default for LoadOptions {
    fn default() -> Self {
        LoadOptions {
            downscale: 1,
            background: None,
            holdout: None,
            ndc: NdcMode::Auto,
            spherify: false,
        }
    }
}

/// Whether a capture's rays are warped to normalised device coordinates (method.md §1.6).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum NdcMode {
    /// NDC when the capture is forward-facing: every camera looks within
    /// [`NDC_MAX_VIEW_ANGLE_DEG`] of the average camera's direction. NDC cannot represent what a
    /// camera turned further sideways sees (it leaves the reference frustum), so such captures
    /// keep Euclidean rays inside the cameras' frustum box.
    #[default]
    Auto,
    /// Always NDC (nerf-pytorch's LLFF default).
    On,
    /// Never NDC.
    Off,
}

/// The largest angle between a camera's viewing axis and the average one for which
/// [`NdcMode::Auto`] picks NDC. LLFF's forward-facing scenes stay well below it (their cameras
/// turn by a few degrees); a capture walking an arc around an object exceeds it.
pub const NDC_MAX_VIEW_ANGLE_DEG: f64 = 30.0;

impl std::str::FromStr for NdcMode {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s {
            "auto" => Ok(NdcMode::Auto),
            "on" => Ok(NdcMode::On),
            "off" => Ok(NdcMode::Off),
            _ => Err(format!("'{s}': expected auto, on or off")),
        }
    }
}
