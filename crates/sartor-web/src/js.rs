//! The JavaScript API (wasm-bindgen): thin conversions around [`crate::TryOn`]. Every fault
//! comes back as a JavaScript `Error` whose message names it (the page shows it); none panics.
//!
//! ```js
//! const files = new AssetFiles();
//! files.add("model/model.json", bytes); // … every name of MODEL_FILES and BODY_FILES
//! const tryOn = TryOn.load(files, "f32", true, JSON.stringify(manifest.arm_clearance));
//! tryOn.setPhenotype(0.0, 1.70, 0.75, 0.5, 25); // female, 1.70 m, heavy
//! tryOn.playProcedural("dance_disco");
//! tryOn.step();
//! const garment = tryOn.garmentVertices(); // Float32Array, x y z …
//! ```

use sartor_runtime::Precision;
use wasm_bindgen::prelude::{JsError, wasm_bindgen};

use crate::files::FileSet;
use crate::limbs::LimbsWorker;
use crate::post::PostWorker;
use crate::session::{PhenotypeSliders, TryOn, TryOnOptions, procedural_clip_names};
use sartor_motion::ClearanceOptions;

fn js(e: crate::Error) -> JsError {
    JsError::new(&e.to_string())
}

/// The page's slider values (gender 0–1, height in metres, weight 0–1, muscle 0–1, age in
/// years).
fn sliders(
    gender: f64,
    height_m: f64,
    weight: f64,
    muscle: f64,
    age_years: f64,
) -> PhenotypeSliders {
    PhenotypeSliders {
        gender,
        height_m,
        weight,
        muscle,
        age_years,
    }
}

/// The arm clearance options' JSON (`manifest.json`'s `arm_clearance`).
fn clearance_options(json: &str) -> Result<ClearanceOptions, JsError> {
    serde_json::from_str(json)
        .map_err(|e| JsError::new(&format!("arm clearance options {json:?}: {e}")))
}

/// The precision named `f32`, `f16` or `int8`.
fn precision_of(name: &str) -> Result<Precision, JsError> {
    match name {
        "f32" => Ok(Precision::F32),
        "f16" => Ok(Precision::F16),
        "int8" => Ok(Precision::Int8),
        other => Err(JsError::new(&format!(
            "precision {other:?}: expected f32, f16 or int8"
        ))),
    }
}

/// Files fetched by the page, by name (`model/model.json`, `body/tpose.json`, …).
#[wasm_bindgen]
#[derive(Default)]
pub struct AssetFiles {
    inner: FileSet,
}

#[wasm_bindgen]
impl AssetFiles {
    /// An empty set.
    #[wasm_bindgen(constructor)]
    pub fn new() -> Self {
        Self::default()
    }

    /// Add file `name` with its bytes.
    pub fn add(&mut self, name: &str, bytes: &[u8]) {
        self.inner.insert(name, bytes.to_vec());
    }
}

/// One avatar wearing the shipped garment (see [`crate::TryOn`]).
#[wasm_bindgen(js_name = TryOn)]
pub struct WebTryOn {
    inner: TryOn,
}

#[wasm_bindgen(js_class = TryOn)]
impl WebTryOn {
    /// Load the model and the body; `precision` is `f32`, `f16` or `int8` (weights in memory);
    /// `arm_clearance` the JSON of the arm clearance options the model was trained with
    /// (`manifest.json`'s `arm_clearance`), or none: motions played as they come.
    pub fn load(
        files: AssetFiles,
        precision: &str,
        post_process: bool,
        arm_clearance: Option<String>,
    ) -> Result<WebTryOn, JsError> {
        let precision = precision_of(precision)?;
        let arm_clearance = arm_clearance
            .map(|json| clearance_options(&json))
            .transpose()?;
        let options = TryOnOptions {
            precision,
            post_process,
            clock: Some(crate::clock::now_ms),
            arm_clearance,
        };
        Ok(Self {
            inner: TryOn::load(files.inner, options).map_err(js)?,
        })
    }

    /// Shape from the phenotype sliders (gender 0–1, height in metres, weight 0–1, muscle 0–1,
    /// age in years); returns β.
    #[wasm_bindgen(js_name = setPhenotype)]
    pub fn set_phenotype(
        &mut self,
        gender: f64,
        height_m: f64,
        weight: f64,
        muscle: f64,
        age_years: f64,
    ) -> Result<Vec<f64>, JsError> {
        let sliders = sliders(gender, height_m, weight, muscle, age_years);
        self.inner.set_phenotype(&sliders).map_err(js)
    }

    /// [`Self::set_phenotype`] as a preview while a slider moves: body and garment in the new
    /// shape, the arms held as for the shape last set (see `TryOn::preview_betas`); once the
    /// slider settles, hold the arms for it with `settle` (or set the shape with
    /// `setPhenotype`). Returns β.
    #[wasm_bindgen(js_name = previewPhenotype)]
    pub fn preview_phenotype(
        &mut self,
        gender: f64,
        height_m: f64,
        weight: f64,
        muscle: f64,
        age_years: f64,
    ) -> Result<Vec<f64>, JsError> {
        let sliders = sliders(gender, height_m, weight, muscle, age_years);
        self.inner.preview_phenotype(&sliders).map_err(js)
    }

    /// After a preview or a `play…`, hold the arms out for the shape in use and the motion
    /// begun, at most `maxLooks` looks of the body this call (about 1 to 2 ms each; see
    /// `TryOn::settle`); `true` once they are held (the motion begun then plays from its first
    /// frame, and the frame shown is the one `setPhenotype` gives), `false` while there is more
    /// to do.
    pub fn settle(&mut self, max_looks: usize) -> Result<bool, JsError> {
        self.inner.settle(max_looks).map_err(js)
    }

    /// Compute, at most `maxLooks` looks of the body this call, the held arms a jump to `frame`
    /// needs (see `TryOn::prepare_seek`); `true` once `seek(frame)` would compute none of them.
    #[wasm_bindgen(js_name = prepareSeek)]
    pub fn prepare_seek(&mut self, frame: usize, max_looks: usize) -> Result<bool, JsError> {
        self.inner.prepare_seek(frame, max_looks).map_err(js)
    }

    /// The held-limb work the page waits on (a clip begun, else a jump to `seek`, else the
    /// frames shown held for the shape in use), as bytes for a `LimbsWorker`, or `undefined`
    /// when it waits on none (see `TryOn::arms_job`).
    #[wasm_bindgen(js_name = armsJob)]
    pub fn arms_job(&mut self, seek: Option<usize>) -> Result<Option<Vec<u8>>, JsError> {
        self.inner.arms_job(seek).map_err(js)
    }

    /// The held limbs the motion playing needs next where a frame among the next `minFrames`
    /// lacks them: the job of the next `maxFrames` for a `LimbsWorker`, or `undefined` (see
    /// `TryOn::arms_ahead_job`).
    #[wasm_bindgen(js_name = armsAheadJob)]
    pub fn arms_ahead_job(
        &mut self,
        min_frames: usize,
        max_frames: usize,
    ) -> Result<Option<Vec<u8>>, JsError> {
        self.inner
            .arms_ahead_job(min_frames, max_frames)
            .map_err(js)
    }

    /// Take up a `LimbsWorker`'s answer: `true` where it is still of use (see
    /// `TryOn::absorb_arms`); `settle` and `prepareSeek` then find that work done.
    #[wasm_bindgen(js_name = absorbArms)]
    pub fn absorb_arms(&mut self, progress: &[u8]) -> Result<bool, JsError> {
        self.inner.absorb_arms(progress).map_err(js)
    }

    /// Shape from a phenotype text such as `female, 1.70 m, heavy`; returns β.
    #[wasm_bindgen(js_name = setPhenotypeText)]
    pub fn set_phenotype_text(&mut self, text: &str) -> Result<Vec<f64>, JsError> {
        self.inner.set_phenotype_text(text).map_err(js)
    }

    /// [`Self::set_phenotype_text`] as a preview (see `previewPhenotype`); returns β.
    #[wasm_bindgen(js_name = previewPhenotypeText)]
    pub fn preview_phenotype_text(&mut self, text: &str) -> Result<Vec<f64>, JsError> {
        self.inner.preview_phenotype_text(text).map_err(js)
    }

    /// Shape from β; returns the β in use.
    #[wasm_bindgen(js_name = setBetas)]
    pub fn set_betas(&mut self, betas: &[f64]) -> Result<Vec<f64>, JsError> {
        self.inner.set_betas(betas).map_err(js)
    }

    /// [`Self::set_betas`] as a preview (see `previewPhenotype`); returns the β in use.
    #[wasm_bindgen(js_name = previewBetas)]
    pub fn preview_betas(&mut self, betas: &[f64]) -> Result<Vec<f64>, JsError> {
        self.inner.preview_betas(betas).map_err(js)
    }

    /// Play a procedural clip once `settle` returns `true` (see `TryOn::begin_motion`; so do
    /// the other `play…` calls).
    #[wasm_bindgen(js_name = playProcedural)]
    pub fn play_procedural(&mut self, name: &str) -> Result<(), JsError> {
        let motion = TryOn::motion_procedural(name).map_err(js)?;
        self.inner.begin_motion(motion).map_err(js)
    }

    /// Play a saved JSON motion (the walk cycle).
    #[wasm_bindgen(js_name = playJson)]
    pub fn play_json(&mut self, name: &str, bytes: &[u8]) -> Result<(), JsError> {
        let motion = TryOn::motion_json(name, bytes).map_err(js)?;
        self.inner.begin_motion(motion).map_err(js)
    }

    /// Play a stored mocap clip (`cmu/05_06`: its JSON and safetensors bytes).
    #[wasm_bindgen(js_name = playStored)]
    pub fn play_stored(&mut self, name: &str, json: &[u8], tensors: &[u8]) -> Result<(), JsError> {
        let motion = self
            .inner
            .motion_stored(name, json, tensors.to_vec())
            .map_err(js)?;
        self.inner.begin_motion(motion).map_err(js)
    }

    /// Play a BVH file's text (`name`: its file name).
    #[wasm_bindgen(js_name = playBvh)]
    pub fn play_bvh(&mut self, name: &str, text: &str) -> Result<(), JsError> {
        let motion = self.inner.motion_bvh(name, text).map_err(js)?;
        self.inner.begin_motion(motion).map_err(js)
    }

    /// Wear another garment model (`files`: the four `model/…` files of MODEL_FILES, taken
    /// over), on the shape, motion and frame shown (see `TryOn::set_garment`).
    #[wasm_bindgen(js_name = setGarment)]
    pub fn set_garment(&mut self, files: AssetFiles) -> Result<(), JsError> {
        self.inner.set_garment(files.inner).map_err(js)
    }

    /// Show frame `frame` (scrubbing).
    pub fn seek(&mut self, frame: usize) -> Result<(), JsError> {
        self.inner.seek(frame).map_err(js)
    }

    /// Advance one frame (looping); returns the frame shown.
    pub fn step(&mut self) -> Result<usize, JsError> {
        self.inner.step().map_err(js)
    }

    /// `step` with the garment's post-process left to a `PostWorker`: the job's bytes, or
    /// `undefined` where the frame was shown whole (see `TryOn::step_deferred`); the frame is
    /// shown once `absorbPost` takes up the answer.
    #[wasm_bindgen(js_name = stepDeferred)]
    pub fn step_deferred(&mut self) -> Result<Option<Vec<u8>>, JsError> {
        self.inner.step_deferred().map_err(js)
    }

    /// Take up a `PostWorker`'s answer (its bytes): `true` where it makes the frame shown,
    /// `false` where it is stale (see `TryOn::absorb_post`).
    #[wasm_bindgen(js_name = absorbPost)]
    pub fn absorb_post(&mut self, answer: &[u8]) -> Result<bool, JsError> {
        self.inner.absorb_post(answer).map_err(js)
    }

    /// The frame shown.
    #[wasm_bindgen(getter)]
    pub fn frame(&self) -> usize {
        self.inner.frame()
    }

    /// Frames of the motion.
    #[wasm_bindgen(getter, js_name = nFrames)]
    pub fn n_frames(&self) -> usize {
        self.inner.n_frames()
    }

    /// The motion's name.
    #[wasm_bindgen(getter, js_name = motionName)]
    pub fn motion_name(&self) -> String {
        self.inner.motion_name().to_string()
    }

    /// β in use.
    pub fn betas(&self) -> Vec<f64> {
        self.inner.betas().to_vec()
    }

    /// The body's size-chart measurements: `[height m, chest m, waist m, hips m, mass kg]`
    /// (`sartor_core::BodyMeasurer`).
    pub fn measurements(&self) -> Result<Vec<f64>, JsError> {
        let m = self.inner.measurements().map_err(js)?;
        Ok(vec![m.height_m, m.chest_m, m.waist_m, m.hips_m, m.mass_kg])
    }

    /// Standing height of the body, metres.
    #[wasm_bindgen(js_name = heightM)]
    pub fn height_m(&self) -> Result<f64, JsError> {
        self.inner.height_m().map_err(js)
    }

    /// Garment vertices of the frame shown (x, y, z, …; metres).
    #[wasm_bindgen(js_name = garmentVertices)]
    pub fn garment_vertices(&self) -> Vec<f32> {
        self.inner.garment_vertices()
    }

    /// Body vertices of the frame shown.
    #[wasm_bindgen(js_name = bodyVertices)]
    pub fn body_vertices(&self) -> Vec<f32> {
        self.inner.body_vertices()
    }

    /// Garment triangles.
    #[wasm_bindgen(js_name = garmentFaces)]
    pub fn garment_faces(&self) -> Vec<u32> {
        self.inner.garment_faces()
    }

    /// Body triangles.
    #[wasm_bindgen(js_name = bodyFaces)]
    pub fn body_faces(&self) -> Vec<u32> {
        self.inner.body_faces()
    }

    /// Garment vertices the post-process moved in the frame shown.
    pub fn pushed(&self) -> usize {
        self.inner.pushed()
    }

    /// Milliseconds of the frame shown: network, skinning, post-process (the strain limit and
    /// the collisions), body posing, arm clearance.
    pub fn times(&self) -> Vec<f64> {
        let t = self.inner.times();
        vec![
            t.garment.network_ms,
            t.garment.skinning_ms,
            t.garment.strain_limit_ms + t.garment.post_process_ms,
            t.body_ms,
            t.arms_ms,
        ]
    }

    /// Looks the held limbs of the motion playing took on the page's thread so far (see
    /// `TryOn::arm_looks`).
    #[wasm_bindgen(getter, js_name = armLooks)]
    pub fn arm_looks(&self) -> usize {
        self.inner.arm_looks()
    }

    /// The largest shoulder (or, with the legs held, hip) rotation the arm clearance added to
    /// the frame shown, degrees.
    #[wasm_bindgen(getter, js_name = armTurnDeg)]
    pub fn arm_turn_deg(&self) -> f64 {
        self.inner.arm_turn_deg()
    }
}

/// The held limbs computed in a Web Worker (see [`LimbsWorker`]).
#[wasm_bindgen(js_name = LimbsWorker)]
pub struct WebLimbsWorker {
    inner: LimbsWorker,
}

#[wasm_bindgen(js_class = LimbsWorker)]
impl WebLimbsWorker {
    /// Load the body (`files`: the `body/…` files) with the page's arm clearance options'
    /// JSON (`manifest.json`'s `arm_clearance`).
    pub fn load(files: AssetFiles, arm_clearance: &str) -> Result<WebLimbsWorker, JsError> {
        let options = clearance_options(arm_clearance)?;
        Ok(Self {
            inner: LimbsWorker::load(files.inner, options).map_err(js)?,
        })
    }

    /// Take a job (`TryOn.armsJob`'s bytes) in place of any in hand.
    pub fn begin(&mut self, job: &[u8]) -> Result<(), JsError> {
        self.inner.begin(job).map_err(js)
    }

    /// Compute the job in hand, at most `maxLooks` looks: `true` once it is all computed.
    pub fn work(&mut self, max_looks: usize) -> Result<bool, JsError> {
        self.inner.work(max_looks).map_err(js)
    }

    /// Everything computed for the last job's motion and shape, for `TryOn.absorbArms`.
    pub fn answer(&self) -> Result<Vec<u8>, JsError> {
        self.inner.answer().map_err(js)
    }
}

/// The garment's post-process computed in a Web Worker (see [`PostWorker`]).
#[wasm_bindgen(js_name = PostWorker)]
pub struct WebPostWorker {
    inner: PostWorker,
}

#[wasm_bindgen(js_class = PostWorker)]
impl WebPostWorker {
    /// Load the garment model and the body (`files`: the `model/…` and `body/…` files) with
    /// the precision the page's `TryOn` was loaded with (`f32`, `f16` or `int8`).
    pub fn load(files: AssetFiles, precision: &str) -> Result<WebPostWorker, JsError> {
        let precision = precision_of(precision)?;
        let clock = Some(crate::clock::now_ms as fn() -> f64);
        Ok(Self {
            inner: PostWorker::load(files.inner, precision, clock).map_err(js)?,
        })
    }

    /// Post-process a job (`TryOn.stepDeferred`'s bytes): the answer's bytes, for
    /// `TryOn.absorbPost`.
    pub fn run(&mut self, job: &[u8]) -> Result<Vec<u8>, JsError> {
        self.inner.run(job).map_err(js)
    }
}

/// The procedural clips (sartor-motion's library).
#[wasm_bindgen(js_name = proceduralClips)]
pub fn procedural_clips() -> Vec<String> {
    procedural_clip_names()
}

/// The runtime's matrix kernels on fixed inputs ([`crate::kernel_probe`]): the browser test
/// compares them bit for bit with the native build's.
#[wasm_bindgen(js_name = kernelProbe)]
pub fn kernel_probe_js() -> Result<Vec<f32>, JsError> {
    crate::kernel_probe().map_err(js)
}
