//! [`load_motion`]: a motion from a command-line or config spec — a file (BVH, AMASS `.npz`,
//! saved JSON), the imported walk cycle, or a procedural clip — resampled to [`FPS`].

use std::path::{Path, PathBuf};

use sartor_core::FPS;

use crate::amass::UpAxis;
use crate::bvh::{BvhRetargetOptions, load_bvh_motion, retarget_bvh};
use crate::motion_library::{MotionWindow, is_stored_clip, load_stored_clip};
use crate::retarget::RetargetBody;
use crate::{Error, Motion, Result};

/// What [`load_motion`] needs besides the name.
#[derive(Clone, Debug, Default)]
pub struct MotionSourceOptions {
    /// Folder of imported motions (holding `walk.json`), e.g. `datasets/motions`.
    pub motions_dir: PathBuf,
    /// The body BVH and AMASS files are retargeted onto; required for those two.
    pub body: Option<RetargetBody>,
    /// BVH: see [`crate::BvhRetargetOptions::lenient`].
    pub lenient: bool,
    /// AMASS: the file's up axis.
    pub up_axis: UpAxis,
    /// BVH: keep frame 0 even when it is a T-pose added by the converter (dropped by default,
    /// see [`crate::detect_tpose_frame`]).
    pub keep_tpose_frame: bool,
}

/// Name of the imported walk cycle, as [`load_motion`] understands it.
pub const WALK_NAME: &str = "walk";

/// Load a motion from a command-line spec, resampled to [`FPS`]:
///
/// - a path ending in `.bvh` (CMU-style BVH, retargeted onto `options.body`);
/// - a path ending in `.npz` (AMASS-style, retargeted onto `options.body`);
/// - a path ending in `.json` (a saved [`Motion`]);
/// - `walk`: `<motions_dir>/walk.json`, the imported MakeHuman walk cycle;
/// - a stored clip such as `cmu/05_02` (`<motions_dir>/cmu/05_02.json`, imported by
///   `cargo xtask import-motions`, retargeted onto `options.body` at load; see
///   [`crate::StoredClip`]);
/// - any name in [`crate::procedural::clip_names`];
/// - any of these followed by a window `@<start>+<frames>` (frames at 30 fps, e.g.
///   `cmu/05_02@120+90`): exactly those frames of the whole motion ([`MotionWindow`]).
///
/// A set such as `cmu/*` is several motions: expand it first with
/// [`crate::expand_motion_set`].
pub fn load_motion(spec: &str, options: &MotionSourceOptions) -> Result<Motion> {
    if let Some(window) = MotionWindow::parse(spec)? {
        let whole = load_motion(&window.motion, options)?;
        return window.cut(&whole);
    }
    if spec.ends_with("/*") {
        return Err(Error::invalid(
            "motion source",
            format!("{spec:?} is a set of motions: expand it (expand_motion_set) and load each"),
        ));
    }
    let lower = spec.to_ascii_lowercase();
    let need_body = |kind: &str| {
        options.body.as_ref().ok_or_else(|| {
            Error::invalid(
                "motion source",
                format!("{spec}: a {kind} file needs a body to retarget onto"),
            )
        })
    };
    let motion = if lower.ends_with(".bvh") {
        let body = need_body("BVH")?;
        let opts = BvhRetargetOptions {
            lenient: options.lenient,
            keep_tpose_frame: options.keep_tpose_frame,
        };
        load_bvh_motion(Path::new(spec), body, &opts)?.0
    } else if lower.ends_with(".npz") {
        load_npz(Path::new(spec), need_body("AMASS"), options.up_axis)?
    } else if lower.ends_with(".json") {
        Motion::load_json(Path::new(spec))?
    } else if spec == WALK_NAME {
        Motion::load_json(&options.motions_dir.join(format!("{WALK_NAME}.json")))?
    } else if is_stored_clip(&options.motions_dir, spec) {
        let body = need_body("stored mocap")?;
        let bvh = load_stored_clip(&options.motions_dir, spec)?;
        // The T-pose frame was dropped at import; the first stored frame is the performance's.
        let opts = BvhRetargetOptions {
            lenient: options.lenient,
            keep_tpose_frame: true,
        };
        retarget_bvh(&bvh, body, &opts)?.0.renamed(spec.to_string())
    } else {
        match crate::procedural::clip(spec) {
            Ok(m) => m,
            Err(_) => {
                return Err(Error::invalid(
                    "motion source",
                    format!(
                        "{spec:?} is not a .bvh/.npz/.json path, not {WALK_NAME:?}, not a stored \
                         clip in {} and not a procedural clip (known clips: {})",
                        options.motions_dir.display(),
                        crate::procedural::clip_names().join(", ")
                    ),
                ));
            }
        }
    };
    if (motion.fps() - FPS).abs() > 1e-9 {
        motion.resample(FPS)
    } else {
        Ok(motion)
    }
}

/// An AMASS `.npz` motion retargeted onto `body` (an error when the spec came without one).
#[cfg(feature = "npz")]
fn load_npz(path: &Path, body: Result<&RetargetBody>, up_axis: UpAxis) -> Result<Motion> {
    let body = body?;
    let options = crate::AmassOptions {
        up_axis,
        ..crate::AmassOptions::default()
    };
    crate::load_amass(path, body, &options)
}

/// Without the `npz` feature (the try-on page's build), an `.npz` path is refused.
#[cfg(not(feature = "npz"))]
fn load_npz(path: &Path, _body: Result<&RetargetBody>, _up_axis: UpAxis) -> Result<Motion> {
    Err(Error::format(
        path,
        "this build reads no .npz motions (sartor-motion's `npz` feature is off)",
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    #[cfg(not(feature = "npz"))]
    fn without_the_npz_feature_an_npz_path_is_refused_by_name() {
        let err = load_motion("clip.npz", &MotionSourceOptions::default()).expect_err("refused");
        let msg = err.to_string();
        assert!(msg.contains("clip.npz") && msg.contains("`npz`"), "{msg}");
    }

    #[test]
    fn unknown_spec_lists_clips() {
        let err =
            load_motion("no-such-clip", &MotionSourceOptions::default()).expect_err("unknown name");
        let msg = err.to_string();
        assert!(
            msg.contains("no-such-clip") && msg.contains("walk_normal"),
            "{msg}"
        );
        let err = load_motion("x.bvh", &MotionSourceOptions::default()).expect_err("no body");
        assert!(err.to_string().contains("needs a body"));
    }
}
