//! MakeHuman's macro sliders on top of the built-in body's linear shape space.
//!
//! A [`Phenotype`] holds the eight macro sliders of MakeHuman (gender, age, muscle, weight,
//! height, proportions, cup size, firmness), each in MakeHuman's `[0, 1]` slider units.
//! MakeHuman turns sliders into a body by adding "macro targets" (sparse vertex displacements)
//! with weights that are products of piecewise-linear functions of the sliders (the rule of
//! `targets/macrodetails/macro.json`, see [`PhenotypeSpace`]). The body model's shape space is a
//! linear projection (PCA) of those bodies, so the shape vector of a phenotype is exactly
//!
//! ```text
//! β(φ) = Σ_t w_t(φ) · p_t + c,     p_t = P · Δ_t   (10 numbers per target)
//! ```
//!
//! [`PhenotypeSpace`] stores `p_t`, `c` and the weighting rule, so it needs no raw assets.
//!
//! ```no_run
//! use sartor_core::{BodyModel, PhenotypeRequest, PhenotypeSpace};
//!
//! let dir = std::path::Path::new("datasets/body/makehuman"); // the built-in body
//! let model = BodyModel::load(dir)?;
//! let space = PhenotypeSpace::load(dir)?;
//! let request: PhenotypeRequest = "female, 1.70 m, heavy".parse()?;
//! let (phenotype, betas) = space.betas_for(&model, &request)?;
//! assert!((model.height_m(&betas)? - 1.70).abs() < 0.01);
//! # let _ = phenotype;
//! # Ok::<(), sartor_core::Error>(())
//! ```

use std::collections::BTreeMap;
use std::path::Path;
use std::str::FromStr;

use serde::{Deserialize, Serialize};

use crate::asset::AssetFiles;
use crate::io::{OwnedTensor, serialize_tensors, sha256_hex};
use crate::{BodyMeasurer, BodyModel, Error, MeasurementTargets, Result};

/// File name of the phenotype space's tensors inside a model folder.
pub const PHENOTYPE_TENSORS: &str = "phenotype.safetensors";
/// File name of the phenotype space's JSON header inside a model folder.
pub const PHENOTYPE_HEADER: &str = "phenotype.json";

/// The phenotype space's file pair.
const FILES: AssetFiles = AssetFiles {
    header: PHENOTYPE_HEADER,
    tensors: PHENOTYPE_TENSORS,
    format: "sartor-phenotype",
    version: 1,
};

/// MakeHuman's age rule (`apps/human.py`, `getAgeYears`): slider 0 is 1 year, 0.5 is 25 years,
/// 1 is 90 years, linear in between.
const MIN_AGE_YEARS: f64 = 1.0;
const MID_AGE_YEARS: f64 = 25.0;
const MAX_AGE_YEARS: f64 = 90.0;

/// The macro sliders in [`Phenotype`] field order.
pub const SLIDERS: [&str; 8] = [
    "gender",
    "age",
    "muscle",
    "weight",
    "height",
    "proportions",
    "cup_size",
    "firmness",
];

/// The slider fields of `$s` in [`SLIDERS`] order, each behind `$r` (`&` or `&mut`): the one
/// place that maps slider names to fields, for [`Phenotype`] and [`PartialPhenotype`].
macro_rules! sliders {
    ($s:expr; $($r:tt)+) => {
        [
            $($r)+ $s.gender,
            $($r)+ $s.age,
            $($r)+ $s.muscle,
            $($r)+ $s.weight,
            $($r)+ $s.height,
            $($r)+ $s.proportions,
            $($r)+ $s.cup_size,
            $($r)+ $s.firmness,
        ]
    };
}

/// The position of slider `name` in [`SLIDERS`].
fn slider_index(name: &str) -> Option<usize> {
    SLIDERS.iter().position(|s| *s == name)
}

/// MakeHuman's macro sliders, each in `[0, 1]`. The default is the neutral adult (all 0.5:
/// gender halfway between female and male, 25 years, average muscle, weight and height, regular
/// proportions, average cup size and firmness).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Phenotype {
    /// 0 female, 1 male.
    pub gender: f64,
    /// 0 is 1 year, 0.1875 is 10 years, 0.5 is 25 years, 1 is 90 years (see
    /// [`Phenotype::age_years`]).
    pub age: f64,
    /// 0 minimum, 0.5 average, 1 maximum muscle.
    pub muscle: f64,
    /// 0 minimum, 0.5 average, 1 maximum weight.
    pub weight: f64,
    /// 0 minimum, 0.5 average, 1 maximum height (MakeHuman's height targets; use
    /// [`PhenotypeRequest::height_m`] to ask for metres).
    pub height: f64,
    /// 0 uncommon, 0.5 regular, 1 ideal proportions.
    pub proportions: f64,
    /// Breast size: 0 minimum, 0.5 average, 1 maximum cup (female targets only).
    pub cup_size: f64,
    /// Breast firmness: 0 minimum, 0.5 average, 1 maximum (female targets only).
    pub firmness: f64,
}

impl Default for Phenotype {
    fn default() -> Self {
        Self {
            gender: 0.5,
            age: 0.5,
            muscle: 0.5,
            weight: 0.5,
            height: 0.5,
            proportions: 0.5,
            cup_size: 0.5,
            firmness: 0.5,
        }
    }
}

impl Phenotype {
    /// The slider called `name` (one of [`SLIDERS`]).
    pub fn get(&self, name: &str) -> Option<f64> {
        let i = slider_index(name)?;
        Some(*sliders!(self; &)[i])
    }

    /// Mutable access to the slider called `name` (one of [`SLIDERS`]).
    pub fn get_mut(&mut self, name: &str) -> Option<&mut f64> {
        let i = slider_index(name)?;
        sliders!(self; &mut).into_iter().nth(i)
    }

    /// Check that every slider is finite and in `[0, 1]`.
    pub fn validate(&self) -> Result<()> {
        for name in SLIDERS {
            let v = self.get(name).unwrap_or(f64::NAN);
            if !(0.0..=1.0).contains(&v) {
                return Err(Error::invalid(
                    "phenotype",
                    format!("slider {name} is {v}, expected a value in [0, 1]"),
                ));
            }
        }
        Ok(())
    }

    /// Age in years by MakeHuman's rule (1 year at 0, 25 at 0.5, 90 at 1, linear in between).
    pub fn age_years(&self) -> f64 {
        if self.age < 0.5 {
            MIN_AGE_YEARS + (MID_AGE_YEARS - MIN_AGE_YEARS) * 2.0 * self.age
        } else {
            MID_AGE_YEARS + (MAX_AGE_YEARS - MID_AGE_YEARS) * 2.0 * (self.age - 0.5)
        }
    }

    /// The age slider for an age in years (1 to 90), the inverse of [`Self::age_years`].
    pub fn age_slider_from_years(years: f64) -> Result<f64> {
        if !(MIN_AGE_YEARS..=MAX_AGE_YEARS).contains(&years) {
            return Err(Error::invalid(
                "phenotype",
                format!("age {years} years is outside MakeHuman's range [1, 90]"),
            ));
        }
        Ok(if years < MID_AGE_YEARS {
            (years - MIN_AGE_YEARS) / ((MID_AGE_YEARS - MIN_AGE_YEARS) * 2.0)
        } else {
            0.5 + (years - MID_AGE_YEARS) / ((MAX_AGE_YEARS - MID_AGE_YEARS) * 2.0)
        })
    }
}

/// A partial description of a body: any slider may be given, and the height may be asked for in
/// metres instead of as a slider. Unset sliders take the neutral value 0.5.
///
/// Parse one from text with [`PhenotypeRequest::parse`] (or `str::parse`). Words and values are
/// separated by commas and/or spaces, case does not matter. Vocabulary:
///
/// | text | meaning |
/// | --- | --- |
/// | `female`, `male` | gender 0, 1 |
/// | `light`, `average`, `heavy` | weight 0.25, 0.5, 0.75 |
/// | `slim`, `muscular` | muscle 0.25, 0.75 |
/// | `young`, `old` | age 0.5 (25 years), 0.8846 (75 years) |
/// | `1.70 m`, `1.70m`, `170 cm`, `170cm`, `height_m=1.70` | standing height in metres |
/// | `40 years`, `age_years=40` | age in years (1 to 90, MakeHuman's rule) |
/// | `chest_cm=96` (or `bust_cm`), `waist_cm=78`, `hips_cm=102` | girths in cm |
/// | `70 kg`, `70kg`, `mass_kg=70` (or `weight_kg`) | mass ([`crate::BODY_DENSITY_KG_PER_M3`]) |
/// | `gender=0.3`, `age=…`, `muscle=…`, `weight=…`, `height=…`, `proportions=…`, `cup_size=…`, `firmness=…` | a slider, in `[0, 1]` |
///
/// Giving the same quantity twice (e.g. `female, male`, or `height=0.6, 1.80 m`) is an error.
/// Girths and mass are met by a fit of the shape ([`PhenotypeSpace::betas_for`]): a shopper's
/// size-chart figures, `"female, 1.65 m, bust_cm=94, waist_cm=76, hips_cm=102"`.
///
/// ```
/// use sartor_core::PhenotypeRequest;
/// let r: PhenotypeRequest = "male,1.90m,light,muscular,old".parse()?;
/// assert_eq!(r.sliders.gender, Some(1.0));
/// assert_eq!(r.height_m, Some(1.90));
/// assert!("female, tall".parse::<PhenotypeRequest>().is_err());
/// # Ok::<(), sartor_core::Error>(())
/// ```
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PhenotypeRequest {
    /// Sliders that were given.
    pub sliders: PartialPhenotype,
    /// Wanted standing height in metres (solved on the height slider).
    pub height_m: Option<f64>,
    /// Wanted girths and mass (its `height_m` unused: the height is the field above), met by
    /// [`PhenotypeSpace::betas_for`]'s fit.
    #[serde(default)]
    pub measurements: MeasurementTargets,
}

/// [`Phenotype`] with every slider optional.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PartialPhenotype {
    /// See [`Phenotype::gender`].
    pub gender: Option<f64>,
    /// See [`Phenotype::age`].
    pub age: Option<f64>,
    /// See [`Phenotype::muscle`].
    pub muscle: Option<f64>,
    /// See [`Phenotype::weight`].
    pub weight: Option<f64>,
    /// See [`Phenotype::height`].
    pub height: Option<f64>,
    /// See [`Phenotype::proportions`].
    pub proportions: Option<f64>,
    /// See [`Phenotype::cup_size`].
    pub cup_size: Option<f64>,
    /// See [`Phenotype::firmness`].
    pub firmness: Option<f64>,
}

impl PartialPhenotype {
    /// Whether the slider called `name` is given.
    pub fn is_given(&self, name: &str) -> bool {
        slider_index(name).is_some_and(|i| sliders!(self; &)[i].is_some())
    }

    fn slot(&mut self, name: &str) -> Option<&mut Option<f64>> {
        let i = slider_index(name)?;
        sliders!(self; &mut).into_iter().nth(i)
    }

    /// The full phenotype: given sliders, 0.5 for the others.
    pub fn or_neutral(&self) -> Phenotype {
        let d = Phenotype::default();
        Phenotype {
            gender: self.gender.unwrap_or(d.gender),
            age: self.age.unwrap_or(d.age),
            muscle: self.muscle.unwrap_or(d.muscle),
            weight: self.weight.unwrap_or(d.weight),
            height: self.height.unwrap_or(d.height),
            proportions: self.proportions.unwrap_or(d.proportions),
            cup_size: self.cup_size.unwrap_or(d.cup_size),
            firmness: self.firmness.unwrap_or(d.firmness),
        }
    }
}

/// Finite-difference step of the measurement fit over the sliders.
const SLIDER_FIT_STEP: f64 = 0.01;
/// Pull of that fit towards the start's sliders, per slider unit, against relative measurement
/// errors: it only settles the sliders the targets leave free.
const SLIDER_FIT_PRIOR: f64 = 1e-3;

/// Heights a request may ask for, in metres.
const REQUEST_HEIGHT_RANGE_M: (f64, f64) = (1.0, 2.5);

impl PhenotypeRequest {
    /// Parse a description such as `"female, 1.70 m, heavy"` (vocabulary in the type's docs).
    /// Errors name the offending word and the whole text.
    pub fn parse(text: &str) -> Result<Self> {
        let bad = |m: String| Error::invalid("phenotype request", format!("{m} in {text:?}"));
        let tokens: Vec<String> = text
            .split(|c: char| c == ',' || c.is_whitespace())
            .filter(|t| !t.is_empty())
            .map(|t| t.to_ascii_lowercase())
            .collect();
        if tokens.is_empty() {
            return Err(bad("empty description".into()));
        }
        let mut request = Self::default();
        let number = |s: &str, what: &str| -> Result<f64> {
            s.parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| bad(format!("{what} {s:?} is not a number")))
        };
        let set_slider = |request: &mut Self, name: &str, value: f64, word: &str| {
            if !(0.0..=1.0).contains(&value) {
                return Err(bad(format!(
                    "{word:?}: slider {name} must be in [0, 1], got {value}"
                )));
            }
            let slot = request
                .sliders
                .slot(name)
                .ok_or_else(|| bad(format!("unknown slider {name:?}")))?;
            if slot.is_some() {
                return Err(bad(format!("{word:?}: {name} is given twice")));
            }
            *slot = Some(value);
            Ok(())
        };
        let set_height_m = |request: &mut Self, metres: f64, word: &str| {
            let (lo, hi) = REQUEST_HEIGHT_RANGE_M;
            if !(lo..=hi).contains(&metres) {
                return Err(bad(format!(
                    "{word:?}: height {metres} m is outside [{lo}, {hi}] m"
                )));
            }
            if request.height_m.is_some() {
                return Err(bad(format!("{word:?}: the height is given twice")));
            }
            request.height_m = Some(metres);
            Ok(())
        };
        // A girth in cm or a mass in kg, stored in metres / kilograms.
        let set_measure = |request: &mut Self, key: &str, value: f64, word: &str| {
            let m = &mut request.measurements;
            let (slot, v) = match key {
                "chest_cm" => (&mut m.chest_m, value / 100.0),
                "waist_cm" => (&mut m.waist_m, value / 100.0),
                "hips_cm" => (&mut m.hips_m, value / 100.0),
                _ => (&mut m.mass_kg, value),
            };
            if slot.is_some() {
                return Err(bad(format!("{word:?}: {key} is given twice")));
            }
            *slot = Some(v);
            request
                .measurements
                .validate()
                .map_err(|e| bad(format!("{word:?}: {e}")))
        };
        fn k_of(key: &str) -> &str {
            match key {
                "bust_cm" => "chest_cm",
                "weight_kg" => "mass_kg",
                k => k,
            }
        }
        let mut i = 0;
        while i < tokens.len() {
            let tok = tokens[i].as_str();
            let next = tokens.get(i + 1).map(String::as_str);
            i += 1;
            // "<number> <unit>" as two tokens.
            if tok.parse::<f64>().is_ok() {
                let value = number(tok, "value")?;
                match next {
                    Some("m") => set_height_m(&mut request, value, tok)?,
                    Some("cm") => set_height_m(&mut request, value / 100.0, tok)?,
                    Some("kg") => set_measure(&mut request, "mass_kg", value, tok)?,
                    Some("years") | Some("year") | Some("y") => {
                        let age = Phenotype::age_slider_from_years(value)
                            .map_err(|e| bad(e.to_string()))?;
                        set_slider(&mut request, "age", age, tok)?;
                    }
                    _ => {
                        return Err(bad(format!(
                            "number {tok:?} needs a unit (m, cm, kg or years)"
                        )));
                    }
                }
                i += 1;
                continue;
            }
            if let Some(v) = tok.strip_suffix("kg").filter(|v| v.parse::<f64>().is_ok()) {
                set_measure(&mut request, "mass_kg", number(v, "mass")?, tok)?;
                continue;
            }
            if let Some(v) = tok.strip_suffix("cm").filter(|v| v.parse::<f64>().is_ok()) {
                set_height_m(&mut request, number(v, "height")? / 100.0, tok)?;
                continue;
            }
            if let Some(v) = tok.strip_suffix('m').filter(|v| v.parse::<f64>().is_ok()) {
                set_height_m(&mut request, number(v, "height")?, tok)?;
                continue;
            }
            if let Some((key, value)) = tok.split_once('=') {
                let v = number(value, key)?;
                match key {
                    "height_m" => set_height_m(&mut request, v, tok)?,
                    "chest_cm" | "bust_cm" | "waist_cm" | "hips_cm" | "mass_kg" | "weight_kg" => {
                        set_measure(&mut request, k_of(key), v, tok)?
                    }
                    "age_years" => {
                        let age =
                            Phenotype::age_slider_from_years(v).map_err(|e| bad(e.to_string()))?;
                        set_slider(&mut request, "age", age, tok)?;
                    }
                    k if SLIDERS.contains(&k) => set_slider(&mut request, k, v, tok)?,
                    k => {
                        return Err(bad(format!(
                            "unknown key {k:?} (keys: {}, height_m, age_years, chest_cm, bust_cm, \
                             waist_cm, hips_cm, mass_kg, weight_kg)",
                            SLIDERS.join(", ")
                        )));
                    }
                }
                continue;
            }
            let (slider, value) = match tok {
                "female" => ("gender", 0.0),
                "male" => ("gender", 1.0),
                "light" => ("weight", 0.25),
                "average" => ("weight", 0.5),
                "heavy" => ("weight", 0.75),
                "slim" => ("muscle", 0.25),
                "muscular" => ("muscle", 0.75),
                "young" => ("age", 0.5),
                "old" => ("age", 0.5 + 50.0 / 130.0),
                w => {
                    return Err(bad(format!(
                        "unknown word {w:?} (known: female, male, light, average, heavy, slim, \
                         muscular, young, old, <x> m, <x> cm, <n> years, key=value)"
                    )));
                }
            };
            set_slider(&mut request, slider, value, tok)?;
        }
        if request.height_m.is_some() && request.sliders.height.is_some() {
            return Err(bad(
                "both a height slider and a height in metres are given".into()
            ));
        }
        Ok(request)
    }
}

impl FromStr for PhenotypeRequest {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        Self::parse(s)
    }
}

/// One part of a macro slider's range: inside `[from, to]` the slider blends linearly from the
/// `low` label (weight 1 at `from`) to the `high` label (weight 1 at `to`). `None` is a label
/// without a target (e.g. average height).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MacroPart {
    /// Start of the part's slider range.
    pub from: f64,
    /// End of the part's slider range.
    pub to: f64,
    /// Label at `from`.
    pub low: Option<String>,
    /// Label at `to`.
    pub high: Option<String>,
}

/// A macro slider and its parts, which tile `[0, 1]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MacroVariable {
    /// One of [`SLIDERS`].
    pub name: String,
    /// Its parts, tiling `[0, 1]`.
    pub parts: Vec<MacroPart>,
}

/// A macro target: its name (path under `targets/`, no extension) and its labels, one per
/// variable of its combination (e.g. `["female", "young", "averagemuscle", "maxweight"]`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MacroTarget {
    /// Path under `targets/`, no extension.
    pub name: String,
    /// One label per variable of its combination.
    pub labels: Vec<String>,
}

/// Where a label's weight comes from.
#[derive(Clone, Copy, Debug, PartialEq)]
enum LabelSource {
    /// A fixed race weight.
    Race(f64),
    /// A slider (index into [`MacroRule::variables`]).
    Slider(usize),
}

/// MakeHuman's weighting rule: a target's weight is the product of the weights of its labels;
/// a slider label's weight is the linear blend of the part that contains the slider's value;
/// race labels have fixed weights.
#[derive(Clone, Debug, PartialEq)]
pub struct MacroRule {
    /// The sliders and their parts.
    pub variables: Vec<MacroVariable>,
    /// `(label, weight)`, e.g. `("african", 1/3)`.
    pub race_weights: Vec<(String, f64)>,
    /// Label name → source, sorted for lookups.
    labels: BTreeMap<String, LabelSource>,
}

impl MacroRule {
    /// Build and check a rule: known slider names, parts that tile `[0, 1]`, unique labels.
    pub fn new(variables: Vec<MacroVariable>, race_weights: Vec<(String, f64)>) -> Result<Self> {
        let bad = |m: String| Error::invalid("macro rule", m);
        let mut labels = BTreeMap::new();
        let mut seen_vars = Vec::new();
        for (vi, var) in variables.iter().enumerate() {
            if !SLIDERS.contains(&var.name.as_str()) || seen_vars.contains(&var.name) {
                return Err(bad(format!(
                    "variable {:?} is not a slider or appears twice",
                    var.name
                )));
            }
            seen_vars.push(var.name.clone());
            let mut at = 0.0;
            for part in &var.parts {
                if part.from != at || part.to <= part.from || part.to > 1.0 {
                    return Err(bad(format!(
                        "parts of {} do not tile [0, 1] (part [{}, {}] after {at})",
                        var.name, part.from, part.to
                    )));
                }
                at = part.to;
                for label in [&part.low, &part.high].into_iter().flatten() {
                    match labels.insert(label.clone(), LabelSource::Slider(vi)) {
                        Some(LabelSource::Slider(other)) if other != vi => {
                            return Err(bad(format!("label {label:?} is used by two variables")));
                        }
                        _ => {}
                    }
                }
            }
            if at != 1.0 {
                return Err(bad(format!("parts of {} end at {at}, not 1", var.name)));
            }
        }
        for (label, w) in &race_weights {
            if !(0.0..=1.0).contains(w) {
                return Err(bad(format!("race weight of {label:?} is {w}")));
            }
            if labels
                .insert(label.clone(), LabelSource::Race(*w))
                .is_some()
            {
                return Err(bad(format!("label {label:?} appears twice")));
            }
        }
        Ok(Self {
            variables,
            race_weights,
            labels,
        })
    }

    /// Check that every label of a target is known and that its labels name distinct
    /// variables.
    pub fn check_target(&self, target: &MacroTarget) -> Result<()> {
        let mut vars = Vec::new();
        for label in &target.labels {
            let var = match self.labels.get(label) {
                None => {
                    return Err(Error::invalid(
                        "macro target",
                        format!("{}: unknown label {label:?}", target.name),
                    ));
                }
                Some(LabelSource::Race(_)) => usize::MAX,
                Some(LabelSource::Slider(v)) => *v,
            };
            if vars.contains(&var) {
                return Err(Error::invalid(
                    "macro target",
                    format!("{}: two labels of the same variable", target.name),
                ));
            }
            vars.push(var);
        }
        Ok(())
    }

    /// Weight of every label for a phenotype (labels absent from the map weigh 0).
    fn label_weights(&self, phenotype: &Phenotype) -> BTreeMap<&str, f64> {
        let mut out: BTreeMap<&str, f64> = BTreeMap::new();
        for (label, w) in &self.race_weights {
            out.insert(label.as_str(), *w);
        }
        for var in &self.variables {
            // `variables` only holds slider names (checked in `new`).
            let x = phenotype.get(&var.name).unwrap_or(0.5);
            let part = var
                .parts
                .iter()
                .find(|p| x <= p.to)
                .or(var.parts.last())
                .filter(|_| !var.parts.is_empty());
            let Some(part) = part else { continue };
            let t = ((x - part.from) / (part.to - part.from)).clamp(0.0, 1.0);
            if let Some(low) = &part.low {
                *out.entry(low.as_str()).or_insert(0.0) += 1.0 - t;
            }
            if let Some(high) = &part.high {
                *out.entry(high.as_str()).or_insert(0.0) += t;
            }
        }
        out
    }

    /// Weight of each target for a phenotype (product of its labels' weights).
    pub fn target_weights(&self, targets: &[MacroTarget], phenotype: &Phenotype) -> Vec<f64> {
        let lw = self.label_weights(phenotype);
        targets
            .iter()
            .map(|t| {
                t.labels
                    .iter()
                    .map(|l| lw.get(l.as_str()).copied().unwrap_or(0.0))
                    .product()
            })
            .collect()
    }
}

/// Sampling settings recorded with the space (informational: how the PCA was fitted).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PhenotypeSampling {
    /// Number of phenotypes in the PCA.
    pub n_samples: usize,
    /// Seed of the sampler (ChaCha8).
    pub seed: u64,
    /// Uniform range `[lo, hi]` of each slider, in [`SLIDERS`] order.
    pub ranges: BTreeMap<String, [f64; 2]>,
}

/// JSON header of a saved phenotype space.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct Header {
    format: String,
    version: u32,
    n_betas: usize,
    variables: Vec<MacroVariable>,
    race_weights: Vec<(String, f64)>,
    targets: Vec<MacroTarget>,
    sampling: PhenotypeSampling,
    tensors_sha256: String,
}

crate::asset_header!(Header);

/// MakeHuman's macro sliders mapped exactly onto a body model's shape space (see the module
/// docs): `β(φ) = Σ_t w_t(φ) · p_t + c`, with MakeHuman's weighting rule `w_t` and the stored
/// projections `p_t` of every macro target and offset `c`. Saved next to the model as
/// `phenotype.safetensors` (`target_betas` `[T, n_betas]`, `offset` `[n_betas]`, f32) and
/// `phenotype.json` (rule, target names and labels, sampling settings).
#[derive(Clone, Debug, PartialEq)]
pub struct PhenotypeSpace {
    rule: MacroRule,
    targets: Vec<MacroTarget>,
    n_betas: usize,
    /// `T × n_betas`, row-major.
    target_betas: Vec<f64>,
    offset: Vec<f64>,
    sampling: PhenotypeSampling,
}

impl PhenotypeSpace {
    /// Build a space, checking sizes, finiteness and every target's labels.
    pub fn new(
        rule: MacroRule,
        targets: Vec<MacroTarget>,
        n_betas: usize,
        target_betas: Vec<f64>,
        offset: Vec<f64>,
        sampling: PhenotypeSampling,
    ) -> Result<Self> {
        let bad = |m: String| Error::invalid("phenotype space", m);
        if n_betas == 0 {
            return Err(bad("no shape components".into()));
        }
        if target_betas.len() != targets.len() * n_betas || offset.len() != n_betas {
            return Err(bad(format!(
                "{} target projections and {} offsets for {} targets × {n_betas} betas",
                target_betas.len(),
                offset.len(),
                targets.len()
            )));
        }
        if target_betas.iter().chain(&offset).any(|x| !x.is_finite()) {
            return Err(bad("non-finite projection".into()));
        }
        for t in &targets {
            rule.check_target(t)?;
        }
        Ok(Self {
            rule,
            targets,
            n_betas,
            target_betas,
            offset,
            sampling,
        })
    }

    /// Number of shape components.
    pub fn n_betas(&self) -> usize {
        self.n_betas
    }

    /// Names of the macro targets (paths under MakeHuman's `targets/`, no extension).
    pub fn target_names(&self) -> impl Iterator<Item = &str> {
        self.targets.iter().map(|t| t.name.as_str())
    }

    /// How the shape space was fitted.
    pub fn sampling(&self) -> &PhenotypeSampling {
        &self.sampling
    }

    /// Shape vector of a phenotype: the exact projection of MakeHuman's body for these sliders
    /// onto the model's shape space.
    pub fn betas(&self, phenotype: &Phenotype) -> Result<Vec<f64>> {
        phenotype.validate()?;
        let w = self.rule.target_weights(&self.targets, phenotype);
        let mut betas = self.offset.clone();
        for (t, wt) in w.iter().enumerate() {
            if *wt == 0.0 {
                continue;
            }
            let row = &self.target_betas[t * self.n_betas..(t + 1) * self.n_betas];
            for (b, p) in betas.iter_mut().zip(row) {
                *b += wt * p;
            }
        }
        Ok(betas)
    }

    /// Resolve a request into a phenotype and its shape vector. Unset sliders are 0.5; a height
    /// in metres is met (within 0.1 mm) by bisection on the height slider, measuring
    /// [`BodyModel::height_m`] of `model` (which must be the model this space belongs to).
    ///
    /// Girths or a mass in the request ([`PhenotypeRequest::measurements`]) are then met in two
    /// least-squares fits of the relative measurement errors (the height's weighted to be met
    /// first; a height not asked for is held at the start's): first over the sliders the request
    /// leaves free among weight, muscle, proportions and cup size (and the height slider when a
    /// height is asked for), on MakeHuman's own bodies; then, from that body, over every shape
    /// component ([`crate::fit_measurements`]), pulled towards it, for what MakeHuman's range
    /// does not reach. The phenotype returned is the first fit's, the shape the second's. A
    /// request the model's shapes cannot meet (within 2 mm of height, 1 cm of girth, and 5 % of
    /// a mass given without girths: beside girths the mass only guides the fits, see
    /// [`MeasurementTargets::misses`]) is an error naming what the nearest body reached.
    pub fn betas_for(
        &self,
        model: &BodyModel,
        request: &PhenotypeRequest,
    ) -> Result<(Phenotype, Vec<f64>)> {
        let (phenotype, start) = self.phenotype_betas(model, request)?;
        let girths = &request.measurements;
        if girths.height_m.is_some() {
            return Err(Error::invalid(
                "phenotype request",
                "the height goes in the request's height_m, not in its measurements",
            ));
        }
        if !girths.has_girth_or_mass() {
            return Ok((phenotype, start));
        }
        // A height not asked for stays the start's: a mass or girths alone would otherwise
        // change the stature too.
        let targets = MeasurementTargets {
            height_m: Some(match request.height_m {
                Some(h) => h,
                None => model.height_m(&start)?,
            }),
            ..*girths
        };
        targets.validate()?;
        let measurer = BodyMeasurer::new(model)?;
        // First on MakeHuman's bodies: the sliders the request leaves free (the height slider
        // too when a height is asked for), each kept in [0, 1], pulled weakly towards the start.
        let mut free: Vec<&str> = ["weight", "muscle", "proportions", "cup_size"]
            .into_iter()
            .filter(|name| !request.sliders.is_given(name))
            .collect();
        if request.height_m.is_some() {
            free.push("height");
        }
        let x0: Vec<f64> = free
            .iter()
            .map(|n| phenotype.get(n).unwrap_or(0.5))
            .collect();
        let at = |x: &[f64]| {
            let mut p = phenotype;
            for (name, v) in free.iter().zip(x) {
                *p.get_mut(name).expect("a slider") = *v;
            }
            p
        };
        let mut vertices = vec![nalgebra::Vector3::zeros(); model.n_vertices()];
        let (x, _) = crate::measure::least_squares(
            x0.clone(),
            &vec![(0.0, 1.0); free.len()],
            SLIDER_FIT_STEP,
            |x| {
                let betas = self.betas(&at(x))?;
                model.shaped_vertices_into(&betas, &mut vertices)?;
                let mut r = targets.relative_errors(&measurer.measure(model, &vertices, &betas)?);
                r.extend(x.iter().zip(&x0).map(|(a, b)| SLIDER_FIT_PRIOR * (a - b)));
                Ok(r)
            },
        )?;
        let phenotype = at(&x);
        // Then over the whole shape space, for what those bodies do not reach.
        let fit = crate::fit_measurements(model, &measurer, &self.betas(&phenotype)?, &targets)?;
        let misses = targets.misses(&fit.measurements);
        if !misses.is_empty() {
            return Err(Error::invalid(
                "body measurements",
                format!(
                    "no body of {} meets them: the nearest misses {}",
                    model.name(),
                    misses.join(", ")
                ),
            ));
        }
        Ok((phenotype, fit.betas))
    }

    /// [`Self::betas_for`] without the girths and mass: the sliders, and the height by
    /// bisection.
    fn phenotype_betas(
        &self,
        model: &BodyModel,
        request: &PhenotypeRequest,
    ) -> Result<(Phenotype, Vec<f64>)> {
        if model.n_betas() != self.n_betas {
            return Err(Error::invalid(
                "phenotype space",
                format!(
                    "model {} has {} betas, the phenotype space {}",
                    model.name(),
                    model.n_betas(),
                    self.n_betas
                ),
            ));
        }
        let mut phenotype = request.sliders.or_neutral();
        let Some(target_m) = request.height_m else {
            let betas = self.betas(&phenotype)?;
            return Ok((phenotype, betas));
        };
        if request.sliders.height.is_some() {
            return Err(Error::invalid(
                "phenotype request",
                "both a height slider and a height in metres are given",
            ));
        }
        let mut height_at = |h: f64| -> Result<(f64, Vec<f64>)> {
            phenotype.height = h;
            let betas = self.betas(&phenotype)?;
            Ok((model.height_m(&betas)?, betas))
        };
        let (lo_m, _) = height_at(0.0)?;
        let (hi_m, _) = height_at(1.0)?;
        if !(lo_m..=hi_m).contains(&target_m) {
            return Err(Error::invalid(
                "phenotype request",
                format!(
                    "height {target_m} m is outside the range [{lo_m:.3}, {hi_m:.3}] m reachable \
                     with the height slider for these other sliders"
                ),
            ));
        }
        let (mut lo, mut hi) = (0.0f64, 1.0f64);
        let mut best = height_at(0.5)?;
        let mut best_h = 0.5;
        for _ in 0..60 {
            let mid = 0.5 * (lo + hi);
            let (m, betas) = height_at(mid)?;
            if (m - target_m).abs() < (best.0 - target_m).abs() {
                best = (m, betas);
                best_h = mid;
            }
            if (m - target_m).abs() < 1e-4 {
                break;
            }
            if m < target_m {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        phenotype.height = best_h;
        Ok((phenotype, best.1))
    }

    /// Save into `dir` (atomically, deterministically).
    pub fn save(&self, dir: &Path) -> Result<()> {
        let t = self.targets.len();
        let mut tensors = BTreeMap::new();
        tensors.insert(
            "target_betas".to_string(),
            OwnedTensor::f32(
                &[t, self.n_betas],
                self.target_betas.iter().map(|&x| x as f32),
            ),
        );
        tensors.insert(
            "offset".to_string(),
            OwnedTensor::f32(&[self.n_betas], self.offset.iter().map(|&x| x as f32)),
        );
        let bytes = serialize_tensors(&tensors, None)?;
        let header = Header {
            format: FILES.format.into(),
            version: FILES.version,
            n_betas: self.n_betas,
            variables: self.rule.variables.clone(),
            race_weights: self.rule.race_weights.clone(),
            targets: self.targets.clone(),
            sampling: self.sampling.clone(),
            tensors_sha256: sha256_hex(&bytes),
        };
        FILES.write(dir, &header, &bytes)
    }

    /// Load a space saved by [`Self::save`] from `dir` (e.g. the built-in `datasets/body/makehuman`),
    /// checking the header, the tensors' hash, the rule and every shape.
    pub fn load(dir: &Path) -> Result<Self> {
        let header = crate::io::read_file(&dir.join(PHENOTYPE_HEADER))?;
        let tensors = crate::io::read_file(&dir.join(PHENOTYPE_TENSORS))?;
        Self::from_bytes(dir, &header, tensors)
    }

    /// [`Self::load`] from the two files' bytes, read from folder `dir` (named in errors
    /// only): how a web page, which has no file system, loads the space it fetched.
    pub fn from_bytes(dir: &Path, header_bytes: &[u8], tensor_bytes: Vec<u8>) -> Result<Self> {
        let (header, file): (Header, _) = FILES.parse(dir, header_bytes, tensor_bytes)?;
        let header_path = dir.join(PHENOTYPE_HEADER);
        let (t, nb) = (header.targets.len(), header.n_betas);
        let (_, target_betas) = file.f32("target_betas", &[Some(t), Some(nb)])?;
        let (_, offset) = file.f32("offset", &[Some(nb)])?;
        let rule = MacroRule::new(header.variables, header.race_weights)
            .map_err(|e| e.in_file(&header_path))?;
        Self::new(
            rule,
            header.targets,
            nb,
            target_betas.into_iter().map(f64::from).collect(),
            offset.into_iter().map(f64::from).collect(),
            header.sampling,
        )
        .map_err(|e| e.in_file(&header_path))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn two_part(name: &str, low: &str, mid: Option<&str>, high: &str) -> MacroVariable {
        MacroVariable {
            name: name.into(),
            parts: vec![
                MacroPart {
                    from: 0.0,
                    to: 0.5,
                    low: Some(low.into()),
                    high: mid.map(String::from),
                },
                MacroPart {
                    from: 0.5,
                    to: 1.0,
                    low: mid.map(String::from),
                    high: Some(high.into()),
                },
            ],
        }
    }

    fn rule() -> MacroRule {
        let gender = MacroVariable {
            name: "gender".into(),
            parts: vec![MacroPart {
                from: 0.0,
                to: 1.0,
                low: Some("female".into()),
                high: Some("male".into()),
            }],
        };
        MacroRule::new(
            vec![
                gender,
                two_part("weight", "minweight", Some("averageweight"), "maxweight"),
                two_part("height", "minheight", None, "maxheight"),
            ],
            vec![("asian".into(), 0.5), ("caucasian".into(), 0.5)],
        )
        .expect("valid rule")
    }

    fn target(name: &str, labels: &[&str]) -> MacroTarget {
        MacroTarget {
            name: name.into(),
            labels: labels.iter().map(|s| s.to_string()).collect(),
        }
    }

    #[test]
    fn weights_follow_makehuman_rule() {
        let r = rule();
        let targets = [
            target("a", &["female", "maxweight"]),
            target("b", &["male", "averageweight"]),
            target("c", &["male", "averageweight", "maxheight"]),
            target("d", &["asian", "female"]),
        ];
        let p = Phenotype {
            gender: 0.25,
            weight: 0.75,
            height: 0.8,
            ..Phenotype::default()
        };
        let w = r.target_weights(&targets, &p);
        let want = [0.75 * 0.5, 0.25 * 0.5, 0.25 * 0.5 * 0.6, 0.5 * 0.75];
        for (a, b) in w.iter().zip(want) {
            assert!((a - b).abs() < 1e-12, "{w:?}");
        }
        // Height 0.5: no height target at all.
        let p = Phenotype::default();
        assert_eq!(r.target_weights(&targets, &p)[2], 0.0);
        // Breakpoint: average weight is 1 from either side.
        let w = r.target_weights(&[target("b", &["averageweight"])], &p);
        assert!((w[0] - 1.0).abs() < 1e-15);
    }

    #[test]
    fn rejects_bad_rules_and_targets() {
        let mut v = two_part("weight", "a", Some("b"), "c");
        v.parts[1].from = 0.4;
        assert!(MacroRule::new(vec![v], vec![]).is_err());
        let v = two_part("shoe_size", "a", Some("b"), "c");
        assert!(MacroRule::new(vec![v], vec![]).is_err());
        let r = rule();
        assert!(r.check_target(&target("x", &["female", "purple"])).is_err());
        assert!(r.check_target(&target("x", &["female", "male"])).is_err());
        assert!(r.check_target(&target("x", &["asian", "male"])).is_ok());
    }

    #[test]
    fn betas_are_linear_in_target_weights() {
        let targets = vec![
            target("a", &["female"]),
            target("b", &["male"]),
            target("c", &["male", "maxheight"]),
        ];
        let sampling = PhenotypeSampling {
            n_samples: 0,
            seed: 0,
            ranges: BTreeMap::new(),
        };
        let space = PhenotypeSpace::new(
            rule(),
            targets,
            2,
            vec![1.0, 0.0, 0.0, 1.0, 0.0, 10.0],
            vec![-0.5, -0.5],
            sampling,
        )
        .expect("valid");
        let b = space.betas(&Phenotype::default()).expect("valid");
        assert_eq!(b, vec![0.0, 0.0]);
        let b = space
            .betas(&Phenotype {
                gender: 1.0,
                height: 1.0,
                ..Phenotype::default()
            })
            .expect("valid");
        assert_eq!(b, vec![-0.5, 10.5]);
        let err = space
            .betas(&Phenotype {
                age: 1.5,
                ..Phenotype::default()
            })
            .expect_err("out of range");
        assert!(err.to_string().contains("age"), "{err}");
    }

    #[test]
    fn parses_requests() {
        let r = PhenotypeRequest::parse("female, 1.70 m, heavy").expect("valid");
        assert_eq!(r.sliders.gender, Some(0.0));
        assert_eq!(r.sliders.weight, Some(0.75));
        assert_eq!(r.height_m, Some(1.70));
        let r = PhenotypeRequest::parse("Male,1.90m,light,muscular,old").expect("valid");
        assert_eq!(r.sliders.gender, Some(1.0));
        assert_eq!(r.sliders.weight, Some(0.25));
        assert_eq!(r.sliders.muscle, Some(0.75));
        assert!(
            (Phenotype {
                age: r.sliders.age.expect("set"),
                ..Default::default()
            }
            .age_years()
                - 75.0)
                .abs()
                < 1e-9
        );
        let r = PhenotypeRequest::parse("175cm cup_size=0.8 age_years=40 proportions=1")
            .expect("valid");
        assert_eq!(r.height_m, Some(1.75));
        assert_eq!(r.sliders.cup_size, Some(0.8));
        assert_eq!(r.sliders.proportions, Some(1.0));
        let age = r.sliders.age.expect("set");
        assert!(
            (Phenotype {
                age,
                ..Default::default()
            }
            .age_years()
                - 40.0)
                .abs()
                < 1e-9
        );
        let r = PhenotypeRequest::parse("30 years, 160 cm").expect("valid");
        assert_eq!(r.height_m, Some(1.6));
        assert!(r.measurements.is_empty());
        let r = PhenotypeRequest::parse("female 1.65 m bust_cm=94 waist_cm=76.5 hips_cm=102 60 kg")
            .expect("valid");
        let m = r.measurements;
        assert_eq!(
            (m.chest_m, m.waist_m, m.hips_m, m.mass_kg, m.height_m),
            (Some(0.94), Some(0.765), Some(1.02), Some(60.0), None)
        );
        assert_eq!(r.height_m, Some(1.65));
        let r = PhenotypeRequest::parse("chest_cm=100, weight_kg=80.5").expect("valid");
        assert_eq!(
            (r.measurements.chest_m, r.measurements.mass_kg),
            (Some(1.0), Some(80.5))
        );
        assert_eq!(
            PhenotypeRequest::parse("72kg")
                .expect("valid")
                .measurements
                .mass_kg,
            Some(72.0)
        );
    }

    #[test]
    fn parse_errors_name_the_fault() {
        let cases = [
            ("female, tall", "\"tall\""),
            ("female, male", "gender is given twice"),
            ("weight=1.5", "[0, 1]"),
            ("3.5 m", "outside"),
            ("shoe=3", "unknown key \"shoe\""),
            ("1.8", "needs a unit"),
            ("gender=abc", "not a number"),
            ("height=0.6, 1.8 m", "both"),
            ("", "empty"),
            ("age_years=120", "range"),
            ("waist_cm=500", "waist 500 cm is outside [40, 200] cm"),
            ("bust_cm=90, chest_cm=92", "chest_cm is given twice"),
            ("70 kg, mass_kg=71", "mass_kg is given twice"),
            ("hips_cm=nan", "not a number"),
            ("10 stone", "needs a unit"),
        ];
        for (text, want) in cases {
            let err = PhenotypeRequest::parse(text).expect_err(text).to_string();
            assert!(err.contains(want), "{text:?}: {err}");
        }
    }

    #[test]
    fn age_years_round_trip() {
        for years in [1.0, 10.0, 18.0, 25.0, 40.0, 90.0] {
            let age = Phenotype::age_slider_from_years(years).expect("in range");
            let p = Phenotype {
                age,
                ..Default::default()
            };
            assert!((p.age_years() - years).abs() < 1e-12);
        }
        assert!((Phenotype::age_slider_from_years(10.0).expect("ok") - 0.1875).abs() < 1e-12);
        assert!(Phenotype::age_slider_from_years(0.5).is_err());
    }
}
